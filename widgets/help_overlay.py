"""A translucent overlay listing the keyboard shortcuts (toggled with F1)."""
from __future__ import annotations

from PySide6 import QtCore, QtGui, QtWidgets


class HelpOverlay(QtWidgets.QWidget):
    """Covers its parent; shows ``(keys, description)`` rows grouped by section. Click or Esc closes."""

    def __init__(self, parent: QtWidgets.QWidget):
        super().__init__(parent)
        self.setAttribute(QtCore.Qt.WA_StyledBackground, True)
        self.setStyleSheet("background: rgba(20, 20, 30, 215); color: white;")
        self._label = QtWidgets.QLabel(self)
        self._label.setTextFormat(QtCore.Qt.RichText)
        self._label.setAlignment(QtCore.Qt.AlignCenter)
        self._label.setStyleSheet("background: transparent; font-size: 13px;")
        lay = QtWidgets.QVBoxLayout(self)
        lay.addWidget(self._label)
        self.hide()
        parent.installEventFilter(self)

    def set_shortcuts(self, sections: list[tuple[str, list[tuple[str, str]]]]) -> None:
        html = ["<table cellspacing='6'>"]
        for title, rows in sections:
            html.append(f"<tr><td colspan='2'><b style='color:#9cf'>{title}</b></td></tr>")
            for keys, text in rows:
                html.append(f"<tr><td align='right'><code><b>{keys}</b></code></td><td>{text}</td></tr>")
        html.append("</table><p style='color:#aaa'>F1 or Esc closes this help</p>")
        self._label.setText("".join(html))

    def toggle(self) -> None:
        self.setVisible(not self.isVisible())
        if self.isVisible():
            self.setGeometry(self.parentWidget().rect())
            self.raise_()

    def eventFilter(self, obj, event) -> bool:
        if obj is self.parentWidget() and event.type() == QtCore.QEvent.Resize and self.isVisible():
            self.setGeometry(obj.rect())
        return False

    def mousePressEvent(self, event: QtGui.QMouseEvent) -> None:
        self.hide()

    def keyPressEvent(self, event: QtGui.QKeyEvent) -> None:
        if event.key() in (QtCore.Qt.Key_Escape, QtCore.Qt.Key_F1):
            self.hide()
        else:
            super().keyPressEvent(event)
