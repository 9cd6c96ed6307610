"""A translucent overlay listing the keyboard shortcuts (toggled with F1).

The sections are laid out in as many columns as the window's width allows (balanced by rows), inside a
scroll area: on a small screen every row is still reachable. It takes the keyboard focus while shown, so
Esc closes it; F1 and a click close it too, and the focus goes back where it was."""
from __future__ import annotations

import itertools

from PySide6 import QtCore, QtGui, QtWidgets

#: Width of one column of sections, px (the number of columns follows the overlay's width).
COLUMN_W = 330
CLOSE_TEXT = "F1 or Esc closes this help"
STYLE = """
#helpOverlay { background: rgba(20, 20, 30, 242); }
#helpOverlay QLabel { color: white; background: transparent; font-size: 12px; }
#helpOverlay QScrollArea, #helpOverlay #helpContent { background: transparent; border: none; }
"""


def balance_columns(sizes: list[int], n_cols: int) -> list[list[int]]:
    """Split items of ``sizes`` (kept in order) into at most ``n_cols`` consecutive groups, the tallest group as
    short as possible; returns the item indices of each group."""
    n = len(sizes)
    n_cols = max(1, min(n_cols, n))
    best = None
    for cuts in itertools.combinations(range(1, n), n_cols - 1):
        bounds = (0, *cuts, n)
        tallest = max(sum(sizes[a:b]) for a, b in zip(bounds, bounds[1:]))
        if best is None or tallest < best[0]:
            best = (tallest, bounds)
    bounds = best[1] if best else (0, n)
    return [list(range(a, b)) for a, b in zip(bounds, bounds[1:])]


def section_html(title: str, rows: list[tuple[str, str]]) -> str:
    html = [f"<table cellspacing='2'><tr><td colspan='2'><b style='color:#9cf'>{title}</b></td></tr>"]
    for keys, text in rows:
        html.append(f"<tr><td align='right'><code><b>{keys.replace(' ', '&nbsp;')}</b></code></td><td>{text}</td></tr>")
    html.append("</table>")
    return "".join(html)


class HelpOverlay(QtWidgets.QWidget):
    """Covers its parent; shows ``(keys, description)`` rows grouped by section. Click, Esc or F1 closes."""

    def __init__(self, parent: QtWidgets.QWidget):
        super().__init__(parent)
        self.setObjectName("helpOverlay")
        self.setAttribute(QtCore.Qt.WA_StyledBackground, True)
        self.setStyleSheet(STYLE)
        self.setFocusPolicy(QtCore.Qt.StrongFocus)
        self._sections: list[tuple[str, list[tuple[str, str]]]] = []
        self.section_labels: list[QtWidgets.QLabel] = []
        self._n_cols = 0
        self._focus_before: QtWidgets.QWidget | None = None
        self.content = QtWidgets.QWidget()
        self.content.setObjectName("helpContent")
        self._grid = QtWidgets.QGridLayout(self.content)
        self._grid.setHorizontalSpacing(24)
        self.scroll = QtWidgets.QScrollArea(self)
        self.scroll.setWidgetResizable(True)
        self.scroll.setFrameShape(QtWidgets.QFrame.NoFrame)
        self.scroll.setFocusPolicy(QtCore.Qt.NoFocus)
        self.scroll.viewport().setAutoFillBackground(False)
        self.scroll.setWidget(self.content)
        self.close_hint = QtWidgets.QLabel(f"<span style='color:#aaa'>{CLOSE_TEXT}</span>")
        self.close_hint.setAlignment(QtCore.Qt.AlignCenter)
        lay = QtWidgets.QVBoxLayout(self)
        lay.addWidget(self.scroll, 1)
        lay.addWidget(self.close_hint)
        self.hide()
        parent.installEventFilter(self)

    def set_shortcuts(self, sections: list[tuple[str, list[tuple[str, str]]]]) -> None:
        self._sections = list(sections)
        for label in self.section_labels:
            label.deleteLater()
        self.section_labels = []
        for title, rows in self._sections:
            label = QtWidgets.QLabel(section_html(title, rows))
            label.setTextFormat(QtCore.Qt.RichText)
            label.setAlignment(QtCore.Qt.AlignLeft | QtCore.Qt.AlignTop)
            self.section_labels.append(label)
        self._n_cols = 0
        self._arrange()

    def _arrange(self) -> None:
        """Lay the sections out in columns for the current width (nothing when the count is unchanged)."""
        n_cols = max(1, self.width() // COLUMN_W)
        if n_cols == self._n_cols or not self.section_labels:
            return
        self._n_cols = n_cols
        for label in self.section_labels:
            self._grid.removeWidget(label)
        sizes = [len(rows) + 2 for _, rows in self._sections]
        cols = balance_columns(sizes, n_cols)
        for c, idx in enumerate(cols):
            for r, i in enumerate(idx):
                self._grid.addWidget(self.section_labels[i], r, c, QtCore.Qt.AlignTop)
            self._grid.setRowStretch(len(idx), 1)
        for c in range(len(cols)):
            self._grid.setColumnStretch(c, 1)

    # ------------------------------------------------------------------ showing, closing
    def toggle(self) -> None:
        self.close_help() if self.isVisible() else self.open_help()

    def open_help(self) -> None:
        self._focus_before = QtWidgets.QApplication.focusWidget()
        self.setGeometry(self.parentWidget().rect())
        self._arrange()
        self.scroll.verticalScrollBar().setValue(0)
        self.show()
        self.raise_()
        self.setFocus(QtCore.Qt.OtherFocusReason)

    def close_help(self) -> None:
        self.hide()
        before, self._focus_before = self._focus_before, None
        if before is not None and before.isVisible():
            before.setFocus(QtCore.Qt.OtherFocusReason)

    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt API)
        if obj is self.parentWidget() and event.type() == QtCore.QEvent.Resize and self.isVisible():
            self.setGeometry(obj.rect())
        return False

    def resizeEvent(self, event: QtGui.QResizeEvent) -> None:  # noqa: N802 (Qt API)
        super().resizeEvent(event)
        self._arrange()

    def event(self, ev: QtCore.QEvent) -> bool:
        # Esc belongs to the help while it is shown, whatever the window's shortcuts say
        if ev.type() == QtCore.QEvent.ShortcutOverride and ev.key() == QtCore.Qt.Key_Escape:
            ev.accept()
            return True
        return super().event(ev)

    def mousePressEvent(self, event: QtGui.QMouseEvent) -> None:  # noqa: N802 (Qt API)
        self.close_help()

    def keyPressEvent(self, event: QtGui.QKeyEvent) -> None:  # noqa: N802 (Qt API)
        if event.key() in (QtCore.Qt.Key_Escape, QtCore.Qt.Key_F1):
            self.close_help()
        else:
            super().keyPressEvent(event)
