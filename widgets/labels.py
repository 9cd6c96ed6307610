"""A one-line text readout whose text changes often without moving anything else in the window.

``QLabel.setText`` always asks the layout for a new geometry; the layout is then activated up to
the main window and repaints what it touches. Where the window holds an OpenGL view, every repaint
is a flush of the whole window through the GL compositor (~12 ms with software GL under Xvfb, see
``bench/bench_scrub.py``), so readouts that change on every scrub step or mouse move use
:class:`Readout`: a constant size hint (sized for a template text), and a new text only repaints
the widget itself.
"""
from __future__ import annotations

from PySide6 import QtCore, QtGui, QtWidgets


class Readout(QtWidgets.QWidget):
    """Text of ``lines`` lines (default one) with a constant size hint, ``template`` wide.

    ``stretch=True``: the width follows the layout (each line is elided on the right when it does
    not fit); otherwise the width is the template's. The text's lines are separated by ``\n`` (lines
    beyond ``lines`` are not shown). An optional second text (:meth:`setRightText`) is drawn
    right-aligned on the (first) line and wins when space is short. The context menu copies both.
    """

    def __init__(self, template: str, text: str = "", parent=None, *, fixed_font: bool = False,
                 stretch: bool = False, lines: int = 1):
        super().__init__(parent)
        self._text = str(text)
        self._right = ""
        self._template = template
        self._lines = max(int(lines), 1)
        if fixed_font:
            self.setFont(QtGui.QFontDatabase.systemFont(QtGui.QFontDatabase.FixedFont))
        self.setSizePolicy(QtWidgets.QSizePolicy.Ignored if stretch else QtWidgets.QSizePolicy.Fixed,
                           QtWidgets.QSizePolicy.Fixed)
        self.setContextMenuPolicy(QtCore.Qt.ActionsContextMenu)
        copy = QtGui.QAction("Copy", self)
        copy.triggered.connect(lambda: QtWidgets.QApplication.clipboard().setText(
            "  ".join(t for t in (self._text, self._right) if t)))
        self.addAction(copy)

    def text(self) -> str:
        return self._text

    def setText(self, text: str) -> None:  # noqa: N802 (Qt naming)
        text = str(text)
        if text != self._text:
            self._text = text
            self.update()          # no updateGeometry(): the size hint never depends on the text

    def rightText(self) -> str:  # noqa: N802 (Qt naming)
        return self._right

    def setRightText(self, text: str) -> None:  # noqa: N802 (Qt naming)
        text = str(text)
        if text != self._right:
            self._right = text
            self.update()

    def sizeHint(self) -> QtCore.QSize:  # noqa: N802 (Qt API)
        fm = self.fontMetrics()
        height = fm.height() + (self._lines - 1) * fm.lineSpacing() + 6
        return QtCore.QSize(fm.horizontalAdvance(self._template) + 8, height)

    def minimumSizeHint(self) -> QtCore.QSize:  # noqa: N802 (Qt API)
        return QtCore.QSize(40, self.sizeHint().height())

    def paintEvent(self, event) -> None:  # noqa: N802 (Qt API)
        p = QtGui.QPainter(self)
        fm = self.fontMetrics()
        r = self.contentsRect().adjusted(3, 0, -3, 0)
        p.setPen(self.palette().color(QtGui.QPalette.WindowText))
        left_w = r.width()
        if self._right:
            right = fm.elidedText(self._right, QtCore.Qt.ElideLeft, r.width())
            p.drawText(r, QtCore.Qt.AlignRight | QtCore.Qt.AlignVCenter, right)
            left_w = max(r.width() - fm.horizontalAdvance(right) - fm.horizontalAdvance("   "), 0)
        rows = self._text.split("\n")[:self._lines]
        h = fm.lineSpacing()
        top = r.top() + (r.height() - (fm.height() + (len(rows) - 1) * h)) // 2
        for k, row in enumerate(rows):
            w = left_w if k == 0 else r.width()
            if w > 0:
                line = QtCore.QRect(r.left(), top + k * h, w, fm.height())
                p.drawText(line, QtCore.Qt.AlignLeft | QtCore.Qt.AlignVCenter,
                           fm.elidedText(row, QtCore.Qt.ElideRight, w))
        p.end()
