"""The timeline's main row: event rate (left axis), camera speed and angular speed (two right axes),
the current window's span, the cursor line and the trajectory's holes.

x is seconds since the first event on the event clock. The speed views are drawn beneath the main
ViewBox and follow its x range, so every click reaches the scrubbing ViewBox."""
from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtGui

from evpose.widgets.timeline.style import (
    ANGULAR_COLOR,
    HOLE_COLOR,
    LEFT_AXIS_W,
    RATE_COLOR,
    RIGHT_AXIS_W,
    SPEED_COLOR,
    ScrubViewBox,
    label_style,
    long_curve,
    make_cursor,
    make_span,
    small_font,
    white_layout,
)

__all__ = ["RatePlot", "robust_range"]

#: The speed axes reach ``CLIP_MARGIN`` × the ``CLIP_QUANTILE`` quantile of the curve; higher samples (glitches of
#: the trajectory, e.g. a 1300 °/s spike among 100 °/s motion) are drawn cut at the top.
CLIP_QUANTILE, CLIP_MARGIN = 0.99, 1.3


def robust_range(values) -> tuple[float, float, bool]:
    """``(low, high, clipped)`` y range of a curve that spikes do not compress: from ``low`` = min(0, minimum) to
    :data:`CLIP_MARGIN` × the :data:`CLIP_QUANTILE` quantile (measured from ``low``), or to the maximum when that is
    lower (then nothing is clipped). NaN ignored; (0, 1, False) without a finite value."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return 0.0, 1.0, False
    lo, top = min(float(v.min()), 0.0), float(v.max())
    cap = lo + CLIP_MARGIN * (float(np.quantile(v, CLIP_QUANTILE)) - lo)
    hi, clipped = (cap, True) if top > cap > lo else (top, False)
    if hi <= lo:
        hi = lo + 1.0
    return lo, hi, clipped


class RatePlot:
    """The pyqtgraph items of the main row.

    Parameters
    ----------
    scrub : callable(x_s, final)
        Left click / drag on the plot.
    cursor_dragged, cursor_released : callable(line)
        The cursor line moved by the mouse / let go.
    """

    def __init__(self, scrub, cursor_dragged, cursor_released):
        self.glw = white_layout()
        self.glw.ci.setSpacing(0)
        self.vb = ScrubViewBox(scrub, enableMenu=False)
        self.plot: pg.PlotItem = self.glw.addPlot(row=0, col=0, viewBox=self.vb)
        self.hole_items: list[pg.LinearRegionItem] = []
        p = self.plot
        p.setMenuEnabled(False)
        p.hideButtons()
        p.setDownsampling(auto=True, mode="peak")
        p.setClipToView(True)
        p.setMouseEnabled(x=True, y=False)
        p.showGrid(x=True, y=False, alpha=0.15)
        bottom = p.getAxis("bottom")
        bottom.setLabel("time since first event (s)", **label_style())
        bottom.enableAutoSIPrefix(False)
        left = p.getAxis("left")
        left.setLabel("rate", units="ev/s", **label_style(RATE_COLOR))
        left.setWidth(LEFT_AXIS_W)
        self._build_speed_axes()
        for ax in (bottom, left, p.getAxis("right"), self.angular_axis):
            small_font(ax)
        self.vb.sigResized.connect(self.sync_views)
        self.vb.enableAutoRange(x=False, y=True)
        self.vb.setAutoVisible(y=True)

        self.rate_item = long_curve(pg.mkPen(RATE_COLOR, width=1), "event rate")
        self.rate_item.setFillLevel(0)
        self.rate_item.setFillBrush(pg.mkBrush(*RATE_COLOR, 60))
        p.addItem(self.rate_item)
        self.speed_item = long_curve(pg.mkPen(SPEED_COLOR, width=1.5), "speed")
        self.angular_item = long_curve(pg.mkPen(ANGULAR_COLOR, width=1.2), "angular speed")
        self.speed_vb.addItem(self.speed_item)
        self.angular_vb.addItem(self.angular_item)

        self.span = make_span()
        self.cursor = make_cursor(cursor_dragged, cursor_released)
        p.addItem(self.span, ignoreBounds=True)
        p.addItem(self.cursor, ignoreBounds=True)

    def _build_speed_axes(self) -> None:
        """Speed (m/s) on the plot's right axis, angular speed (°/s) on a second right axis; their views
        lie beneath the main ViewBox, x-linked to it, and take no mouse input."""
        p = self.plot
        self.speed_vb = pg.ViewBox(enableMenu=False)
        self.angular_vb = pg.ViewBox(enableMenu=False)
        p.showAxis("right")
        right = p.getAxis("right")
        right.linkToView(self.speed_vb)
        right.setLabel("speed (m/s)", **label_style(SPEED_COLOR))
        right.enableAutoSIPrefix(False)
        right.setWidth(RIGHT_AXIS_W)
        right.setPen(pg.mkPen(SPEED_COLOR))
        right.setTextPen(pg.mkPen(SPEED_COLOR))
        self.angular_axis = pg.AxisItem("right")
        self.angular_axis.setLabel("angular (°/s)", **label_style(ANGULAR_COLOR))
        self.angular_axis.enableAutoSIPrefix(False)
        self.angular_axis.setWidth(RIGHT_AXIS_W)
        self.angular_axis.setPen(pg.mkPen(ANGULAR_COLOR))
        self.angular_axis.setTextPen(pg.mkPen(ANGULAR_COLOR))
        p.layout.addItem(self.angular_axis, 2, 3)
        self.angular_axis.linkToView(self.angular_vb)
        for v in (self.speed_vb, self.angular_vb):
            p.scene().addItem(v)
            v.setZValue(-100)
            v.setXLink(self.vb)
            v.setMouseEnabled(x=False, y=False)
            v.setAcceptedMouseButtons(QtCore.Qt.NoButton)
            v.enableAutoRange(x=False, y=False)     # robust range from set_curves: spikes do not squash the curve

    def set_curves(self, data) -> None:
        """Show a :class:`~evpose.core.views.timeline.TimelineData`: rate, speeds (NaN where the
        trajectory gives none) and the holes."""
        valid = np.asarray(data.speed_valid, bool)
        self.rate_item.setData(data.t_s, np.asarray(data.rate_hz, np.float64))
        for item, vb, axis, values, unit in ((self.speed_item, self.speed_vb, self.plot.getAxis("right"),
                                              data.speed_mps, "m/s"),
                                             (self.angular_item, self.angular_vb, self.angular_axis,
                                              data.angular_dps, "°/s")):
            values = np.where(valid, np.asarray(values, np.float64), np.nan)
            lo, hi, clipped = robust_range(values)
            item.setData(data.t_s, np.clip(values, lo, hi))     # spikes drawn flat at the top, not off the axis
            vb.setYRange(lo, hi, padding=0.02)
            axis.setToolTip(f"spikes above {hi:.3g} {unit} are cut at the top of the axis (robust scale: "
                            f"{CLIP_MARGIN:g} × the {100 * CLIP_QUANTILE:g}th percentile)" if clipped else "")
        self.shade_holes(getattr(data, "holes_s", np.zeros((0, 2))))

    def shade_holes(self, holes_s) -> None:
        """Grey hatched bands over the trajectory's holes (no pose there, so no label); ``holes_s``:
        (N, 2) plot x (s)."""
        for item in self.hole_items:
            self.plot.removeItem(item)
        self.hole_items = []
        brush = QtGui.QBrush(QtGui.QColor(*HOLE_COLOR), QtCore.Qt.BDiagPattern)
        for a, b in np.asarray(holes_s, np.float64).reshape(-1, 2):
            item = pg.LinearRegionItem(values=(float(a), float(b)), movable=False, brush=brush,
                                       pen=pg.mkPen(HOLE_COLOR[:3]))
            item.setZValue(-30)
            item.setToolTip(f"trajectory hole: no pose from {a:.3f} s to {b:.3f} s, so no label")
            self.plot.addItem(item, ignoreBounds=True)
            self.hole_items.append(item)

    def sync_views(self) -> None:
        """Keep the speed views on the main ViewBox's rectangle and x range."""
        rect = self.vb.sceneBoundingRect()
        for v in (self.speed_vb, self.angular_vb):
            v.setGeometry(rect)
            v.linkedViewChanged(self.vb, v.XAxis)
