"""What each event representation's colours mean: the frame view's indicator (a swatch icon and a name)
and legend (a line of swatches with words), from the colours the event frames use
(:mod:`evpose.core.label.event_frames.display`, on the app's white background; 3-channel on black)."""
from __future__ import annotations

from html import escape

from PySide6 import QtCore, QtGui

from evpose.core.label.overlay import EVENT_COLORS

#: name -> (title, [(rgb, meaning), ...]) in the order of :data:`evpose.core.session.view_state.REPRESENTATION_NAMES`.
LEGENDS: dict[str, tuple[str, list[tuple[tuple[int, int, int], str]]]] = {
    "polarity": ("Polarity", [(EVENT_COLORS["ON"], "ON"), (EVENT_COLORS["OFF"], "OFF"),
                              (EVENT_COLORS["both"], "both")]),
    "spike": ("Spike", [((0, 0, 0), "any event")]),
    "three_channel": ("3-channel", [((255, 0, 0), "ON"), ((0, 255, 0), "OFF"), ((0, 0, 255), "latest")]),
    "time_surface": ("Time surface", [((0, 0, 0), "recent"), ((200, 200, 200), "older")]),
    "counts": ("Counts", [((0, 0, 0), "many events"), ((200, 200, 200), "few")]),
    "voxel": ("Voxel grid", [(EVENT_COLORS["ON"], "net ON"), (EVENT_COLORS["OFF"], "net OFF")]),
}


#: More words for the tooltip.
NOTES = {
    "polarity": "events per pixel and polarity, scaled by the 99th percentile",
    "spike": "pixels with at least one event",
    "three_channel": "the E-POSE PNG: R = ON count, G = OFF count, B = time of the latest event, on black",
    "time_surface": "exp(-(t_end - t) / τ) of each pixel's latest event, τ = a third of the window",
    "counts": "events per pixel, both polarities, scaled by the 99th percentile",
    "voxel": "sum over the time bins of a 5-bin voxel grid: net ON red, net OFF blue",
}


def legend_html(name: str) -> str:
    """One line of rich text: a coloured square and its meaning per colour of representation ``name``."""
    _, rows = LEGENDS[name]
    return "&nbsp;&nbsp;".join(f"<span style='color: rgb{tuple(rgb)}'>■</span>&nbsp;{escape(text)}"
                               for rgb, text in rows)


def legend_text(name: str) -> str:
    """The legend as plain text (tooltips, tests)."""
    title, rows = LEGENDS[name]
    return f"{title}: " + ", ".join(text for _, text in rows) + f" ({NOTES[name]})"


def swatch_icon(name: str, size: int = 16) -> QtGui.QIcon:
    """An icon of the representation's colours side by side (the indicator in the representation box)."""
    _, rows = LEGENDS[name]
    pm = QtGui.QPixmap(size, size)
    pm.fill(QtGui.QColor(0, 0, 0) if name == "three_channel" else QtGui.QColor(255, 255, 255))
    p = QtGui.QPainter(pm)
    w = size / len(rows)
    for i, (rgb, _) in enumerate(rows):
        p.fillRect(QtCore.QRectF(i * w + 1, 3, w - 2, size - 6), QtGui.QColor(*rgb))
    p.setPen(QtGui.QColor(120, 120, 120))
    p.drawRect(0, 0, size - 1, size - 1)
    p.end()
    return QtGui.QIcon(pm)
