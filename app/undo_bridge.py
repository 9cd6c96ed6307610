"""Mirror the core :class:`~evpose.core.document.history.History` onto Qt actions and the window-modified flag."""
from __future__ import annotations

from PySide6 import QtGui, QtWidgets

from evpose.core.document.history import History
from evpose.core.document.journal import unsaved
from evpose.core.signals import Change


class UndoBridge:
    """Keeps Undo/Redo actions (enabled state and text) and ``windowModified`` in sync."""

    def __init__(self, history: History, undo: QtGui.QAction, redo: QtGui.QAction, window: QtWidgets.QWidget):
        self.history = history
        self.undo_action, self.redo_action, self.window = undo, redo, window
        undo.triggered.connect(history.undo)
        redo.triggered.connect(history.redo)
        self._connection = history.changed.connect(self._on_history)
        self.sync()

    def _on_history(self, change: Change) -> None:
        self.sync()

    def sync(self) -> None:
        h = self.history
        self.undo_action.setEnabled(h.can_undo)
        self.redo_action.setEnabled(h.can_redo)
        self.undo_action.setText(f"&Undo {h.undo_text}" if h.can_undo else "&Undo")
        self.redo_action.setText(f"&Redo {h.redo_text}" if h.can_redo else "&Redo")
        self.window.setWindowModified(not h.is_clean and unsaved(h.doc))      # edits that cancel out: not modified

    def detach(self) -> None:
        self._connection.disconnect()
        for a in (self.undo_action, self.redo_action):
            try:
                a.triggered.disconnect()
            except (RuntimeError, TypeError):
                pass
