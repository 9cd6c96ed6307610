"""The detail pane of the dataset view: everything known about the selected scene in full (a failure's whole
message, the triage's reasons and next command, a proposed change with its sigma and what it keeps), and the buttons
that apply or reject the proposal.

The pane shows text it is given (the window composes it); it emits ``applyRequested(name)`` and
``rejectRequested(name)`` and knows nothing of scenes or files.
"""
from __future__ import annotations

from PySide6 import QtCore, QtWidgets

__all__ = ["SceneDetail"]


class SceneDetail(QtWidgets.QWidget):
    """Read-only text of one scene plus *Apply proposal* / *Reject proposal* (enabled when it has one)."""

    applyRequested = QtCore.Signal(str)
    rejectRequested = QtCore.Signal(str)

    def __init__(self, parent=None):
        super().__init__(parent)
        self._name: str | None = None
        self.text = QtWidgets.QPlainTextEdit(readOnly=True)
        self.text.setLineWrapMode(QtWidgets.QPlainTextEdit.WidgetWidth)
        self.text.setPlaceholderText("select a scene to see its status, flags and proposed changes in full")
        self.apply_button = QtWidgets.QPushButton("Apply proposal")
        self.apply_button.setToolTip("store the proposed changes in the scene's corrections.json as one undo step "
                                     "(refused when the corrections changed since the proposal)")
        self.reject_button = QtWidgets.QPushButton("Reject proposal")
        self.reject_button.setToolTip("drop the proposal; nothing is written")
        self.apply_button.clicked.connect(lambda: self._name and self.applyRequested.emit(self._name))
        self.reject_button.clicked.connect(lambda: self._name and self.rejectRequested.emit(self._name))
        buttons = QtWidgets.QVBoxLayout()
        buttons.addWidget(self.apply_button)
        buttons.addWidget(self.reject_button)
        buttons.addStretch(1)
        layout = QtWidgets.QHBoxLayout(self)
        layout.setContentsMargins(4, 4, 4, 4)
        layout.addWidget(self.text, 1)
        layout.addLayout(buttons)
        self.show_scene(None, "", False)

    @property
    def name(self) -> str | None:
        return self._name

    def show_scene(self, name: str | None, text: str, has_proposal: bool) -> None:
        """Show ``text`` for scene ``name`` (None: nothing selected); the buttons act on ``name``'s proposal."""
        self._name = name
        if self.text.toPlainText() != text:
            self.text.setPlainText(text)
        self.apply_button.setEnabled(bool(name) and has_proposal)
        self.reject_button.setEnabled(bool(name) and has_proposal)
