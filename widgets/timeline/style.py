"""Colours, sizes and the small pyqtgraph pieces the timeline is built from: the scrubbing ViewBox,
long downsampled curves, the cursor line, the current-window span, axis fonts, the legend."""
from __future__ import annotations

import pyqtgraph as pg
from PySide6 import QtCore, QtGui, QtWidgets

#: Review status colours (same as the review panel's).
STATUS_COLORS = {"verified": (40, 160, 60), "rejected": (200, 40, 40), "flagged": (230, 140, 0)}
RATE_COLOR = (90, 90, 90)
SPEED_COLOR = (31, 100, 200)
ANGULAR_COLOR = (150, 60, 170)
CURSOR_COLOR = (0, 0, 0)
SPAN_COLOR = (60, 120, 220)
HOLE_COLOR = (110, 110, 110, 130)  # trajectory holes: no pose, so no label (grey, hatched)
LOW_EVIDENCE_COLOR = (140, 140, 140)  # scores without evidence (grey rings; hatched where no object has any)
DOWNSAMPLE_PER_PX = 2.0          # peak downsampling: min/max of ~2 bins per pixel column
LEFT_AXIS_W, RIGHT_AXIS_W = 62, 52
#: Smallest heights of the main row (its bottom axis included) and of the score row, px: the timeline's
#: minimum height, so that no dock or window size squeezes a plot to a sliver.
MIN_PLOT_H, MIN_SCORE_H = 120, 72


class ScrubViewBox(pg.ViewBox):
    """A ViewBox where left click / left drag scrub instead of panning (Shift+left and middle drag pan).

    ``scrub(x_s, final)`` receives the plot x (seconds) under the mouse; ``final`` is True for a click
    and at the end of a drag."""

    def __init__(self, scrub, **kwargs):
        super().__init__(**kwargs)
        self._scrub = scrub  # callable(x_s: float, final: bool)

    def mouseClickEvent(self, ev):
        if ev.button() == QtCore.Qt.LeftButton:
            ev.accept()
            self._scrub(self.mapSceneToView(ev.scenePos()).x(), True)
        else:
            super().mouseClickEvent(ev)

    def mouseDragEvent(self, ev, axis=None):
        if ev.button() == QtCore.Qt.LeftButton and not (ev.modifiers() & QtCore.Qt.ShiftModifier):
            ev.accept()
            self._scrub(self.mapSceneToView(ev.scenePos()).x(), ev.isFinish())
        else:
            super().mouseDragEvent(ev, axis)


def long_curve(pen, name=None) -> pg.PlotDataItem:
    """A long curve: NaN-separated, peak-downsampled to ~2 samples per pixel, clipped to the view, drawn
    as line segments and cached as a pixmap (moving the cursor over 10^6 bins repaints in ~5 ms; a dashed
    or width-1 path stroker takes 50-1000 ms on such curves)."""
    item = pg.PlotDataItem(pen=pen, name=name, connect="finite")
    item.setDownsampling(auto=True, method="peak")
    item.setClipToView(True)
    item.opts["autoDownsampleFactor"] = DOWNSAMPLE_PER_PX   # no setter in pyqtgraph 0.14
    item.curve.setSegmentedLineMode("on")
    item.curve.setCacheMode(QtWidgets.QGraphicsItem.DeviceCoordinateCache)
    return item


def make_cursor(dragged, released) -> pg.InfiniteLine:
    """The current-time line: ``dragged(line)`` while it moves, ``released(line)`` when let go."""
    line = pg.InfiniteLine(angle=90, movable=True, pen=pg.mkPen(CURSOR_COLOR, width=2),
                           hoverPen=pg.mkPen((220, 0, 0), width=3))
    line.setZValue(20)
    line.setToolTip("current time: drag to scrub")
    line.sigPositionChanged.connect(dragged)
    line.sigPositionChangeFinished.connect(released)
    return line


def make_span() -> pg.LinearRegionItem:
    """The current event window, a translucent band."""
    span = pg.LinearRegionItem(movable=False, brush=pg.mkBrush(*SPAN_COLOR, 70), pen=pg.mkPen(*SPAN_COLOR, 160))
    span.setZValue(10)
    return span


def white_layout() -> pg.GraphicsLayoutWidget:
    """A white plot canvas that never takes keyboard focus (keys belong to the main window)."""
    glw = pg.GraphicsLayoutWidget()
    glw.setFocusPolicy(QtCore.Qt.NoFocus)
    glw.setBackground("w")
    glw.ci.setContentsMargins(2, 0, 2, 2)
    return glw


def small_font(axis: pg.AxisItem, pt: int = 8) -> None:
    font = QtGui.QFont()
    font.setPointSize(pt)
    axis.setStyle(tickFont=font)


def label_style(color=(0, 0, 0), pt: int = 8) -> dict:
    return {"color": pg.mkColor(color).name(), "font-size": f"{pt}pt"}


def legend_html(poses: bool = True) -> str:
    """Key of the curves and review colours (shown in the control row, leaving the plot its height); without
    ``poses`` (an event-only scene) the event rate alone."""
    def hexc(c):
        return pg.mkColor(c).name()

    parts = [f"<span style='color:{hexc(RATE_COLOR)}'>&#9632;</span>&nbsp;event rate"]
    if poses:
        parts += [f"<span style='color:{hexc(SPEED_COLOR)}'><b>&#8212;</b></span>&nbsp;speed",
                  f"<span style='color:{hexc(ANGULAR_COLOR)}'><b>&#8212;</b></span>&nbsp;angular"]
        parts += [f"<span style='color:{hexc(c)}'>&#9608;</span>&nbsp;{s}" for s, c in STATUS_COLORS.items()]
    return "&nbsp;&nbsp; ".join(parts)


def swatch(color) -> QtGui.QIcon:
    """A 12 px square of ``color`` (menu icons)."""
    pm = QtGui.QPixmap(12, 12)
    pm.fill(QtGui.QColor(*color))
    return QtGui.QIcon(pm)
