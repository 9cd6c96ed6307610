"""The space-time view's legend: ON / OFF events, the current window and each shown object in its colour.

It is a Qt label over the canvas, not GL text: vispy rasterises every new glyph on the CPU and compiles
a shader per text visual (seconds on software GL).
"""
from __future__ import annotations

import html

from PySide6 import QtCore, QtWidgets

from evpose.widgets.spacetime_style import OFF_RGBA, ON_RGBA, SLAB_EDGE_RGBA


def legend_entries(tubes, hidden) -> list[tuple[str, tuple[float, ...]]]:
    """``(text, (r, g, b) in [0, 1])`` rows: the two polarities, the window, the objects not hidden."""
    entries = [("ON events", ON_RGBA[:3]), ("OFF events", OFF_RGBA[:3]), ("current window", SLAB_EDGE_RGBA[:3])]
    entries += [(name, tuple(c / 255.0 for c in rgb)) for name, rgb, _ in tubes if name not in hidden]
    return entries


def legend_html(entries) -> str:
    """Rich text of the rows: a dot for the events, a box for the window, a dash for each tube."""
    rows = []
    for i, (text, rgb) in enumerate(entries):
        mark = "\u00b7 " if i < 2 else ("[ ] " if i == 2 else "\u2014 ")
        color = "#%02x%02x%02x" % tuple(int(round(255 * c)) for c in rgb)
        rows.append(f"<span style='color:{color}'>{html.escape(mark + text)}</span>")
    return "<b>" + "<br>".join(rows) + "</b>"


class Legend:
    """The legend label in the top-left corner of ``canvas_widget`` (transparent to the mouse)."""

    def __init__(self, canvas_widget: QtWidgets.QWidget):
        self.label = QtWidgets.QLabel(canvas_widget)
        self.label.setAttribute(QtCore.Qt.WA_TransparentForMouseEvents)
        self.label.setStyleSheet("background: transparent; font-size: 8pt;")
        self.label.move(6, 4)
        self._key = None

    def show(self, tubes, hidden) -> None:
        """List the objects of ``tubes`` not in ``hidden`` (the text is set only when it changed)."""
        key = tuple(legend_entries(tubes, hidden))
        if key == self._key:
            return
        self._key = key
        self.label.setText(legend_html(key))
        self.label.adjustSize()
