"""The space-time view's legend: the events (by polarity, or near a silhouette in its object's colour and the rest
dimmed), the current window and each shown object in its colour.

It is a Qt label in a row above the canvas, not GL text (vispy rasterises every new glyph on the CPU and compiles a
shader per text visual, seconds on software GL), and not over the canvas, where it covered the points in the front
view.
"""
from __future__ import annotations

import html

from PySide6 import QtCore, QtWidgets

from evpose.widgets.spacetime.style import DIM_ON_RGBA, OFF_RGBA, ON_RGBA, SLAB_EDGE_RGBA

#: Colour of the "events near a silhouette" entry (the objects' own colours follow in their entries).
BAND_ENTRY_RGB = (0.15, 0.15, 0.15)


def legend_entries(tubes, hidden, band_px: float | None = None) -> list[tuple[str, tuple[float, ...]]]:
    """``(text, (r, g, b) in [0, 1])`` rows: the events (the two polarities, or with ``band_px`` the events
    within the band and the dimmed rest), the window, the objects not hidden."""
    if band_px is None:
        entries = [("ON events", ON_RGBA[:3]), ("OFF events", OFF_RGBA[:3])]
    else:
        entries = [(f"events \u2264 {band_px:g} px from a silhouette: its colour", BAND_ENTRY_RGB),
                   ("other events (dimmed)", DIM_ON_RGBA[:3])]
    entries.append(("current window", SLAB_EDGE_RGBA[:3]))
    entries += [(name, tuple(c / 255.0 for c in rgb)) for name, rgb, _ in tubes if name not in hidden]
    return entries


def legend_html(entries) -> str:
    """Rich text of the rows on one wrapping line: a dot for the events, a box for the window, a dash for each
    tube."""
    rows = []
    for i, (text, rgb) in enumerate(entries):
        mark = "\u00b7 " if i < 2 else ("[ ] " if i == 2 else "\u2014 ")
        color = "#%02x%02x%02x" % tuple(int(round(255 * c)) for c in rgb)
        rows.append(f"<span style='color:{color}'>{html.escape(mark + text)}</span>")
    return "<b>" + " &nbsp; ".join(rows) + "</b>"


class Legend:
    """The legend label (a row of the view's layout, transparent to the mouse)."""

    def __init__(self, parent: QtWidgets.QWidget | None = None):
        self.label = QtWidgets.QLabel(parent)
        self.label.setAttribute(QtCore.Qt.WA_TransparentForMouseEvents)
        font = self.label.font()
        font.setPointSizeF(8.0)
        self.label.setFont(font)
        self.label.setWordWrap(True)
        # two lines, whatever the text: the canvas under it keeps its size when objects are shown or hidden
        self.label.setFixedHeight(2 * self.label.fontMetrics().lineSpacing() + 2)
        self.label.setAlignment(QtCore.Qt.AlignLeft | QtCore.Qt.AlignTop)
        self._key = None

    def show(self, tubes, hidden, band_px: float | None = None) -> None:
        """List the objects of ``tubes`` not in ``hidden`` (the text is set only when it changed)."""
        key = tuple(legend_entries(tubes, hidden, band_px))
        if key == self._key:
            return
        self._key = key
        self.label.setText(legend_html(key))
