"""The whole sequence at a glance: event rate, robot speed, review marks, alignment scores; scrub and play.

x is seconds since the first event on the **event clock** (``(t_us - t_ref_us) * 1e-6``). The robot speed
comes from :func:`evpose.core.session.timeline.timeline_data`, which maps each bin through the clock in effect, so a wrong
time offset shows as a horizontal shift between the event-rate and speed curves; the speed is recomputed
(debounced) when the document's clock changes.

Interaction
-----------
- left click / drag on a plot, or drag the black cursor line: scrub (``session.set_time``; throttled to
  :data:`SCRUB_INTERVAL_MS` while dragging, the cursor itself follows the mouse at once);
- wheel / right drag: zoom in time; Shift+left or middle drag: pan; "Fit" shows the whole sequence;
- play / pause with a selectable speed (fraction of real time), step one window back / forward;
- Space toggles play while the timeline has keyboard focus. Other keys (arrows...) are left to the main
  window: no child takes keyboard focus.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtGui, QtWidgets

from evpose.core.session.model import Session
from evpose.core.session.timeline import TimelineData, timeline_data
from evpose.core.signals import Change
from evpose.widgets.binding import connect_view
from evpose.widgets.labels import Readout

#: Review status colours (same as the review panel's).
STATUS_COLORS = {"verified": (40, 160, 60), "rejected": (200, 40, 40), "flagged": (230, 140, 0)}
RATE_COLOR = (90, 90, 90)
SPEED_COLOR = (31, 100, 200)
ANGULAR_COLOR = (150, 60, 170)
CURSOR_COLOR = (0, 0, 0)
SPAN_COLOR = (60, 120, 220)
HOLE_COLOR = (110, 110, 110, 130)  # trajectory holes: no pose, so no label (grey, hatched)
PLAY_SPEEDS = (0.1, 0.25, 0.5, 1.0, 2.0)
SCRUB_INTERVAL_MS = 33           # at most ~30 session.set_time calls per second while dragging
PLAY_INTERVAL_MS = 30            # playback tick
BIN_US = 1000                    # timeline bin (event rate and speed), µs
READOUT_WIDEST = "-99999.999999 s │ 99999999999999999 µs │ win 9999.5 ms"   # sizes the readout
MIN_X_RANGE_S = 0.005            # deepest zoom: 5 ms across the plot
DOWNSAMPLE_PER_PX = 2.0          # peak downsampling: min/max of ~2 bins per pixel column
GLOBAL_MARK_ALPHA = 55           # marks over all objects: full-height translucent bands
OBJECT_MARK_ALPHA = 150          # object-specific marks: thin opaque-ish lanes at the top
OBJECT_LANE = 0.07               # lane height (fraction of the plot height) per object
LEFT_AXIS_W, RIGHT_AXIS_W = 62, 52


@dataclass
class MarkRegion:
    """One drawn review region: a run of merged, overlapping or adjacent marks of one status and scope.

    ``stale``: the marks were made before a later change of the clock or of the object's pose (drawn
    hatched, with the reason in the tooltip)."""

    t0_us: int
    t1_us: int
    status: str
    object: str | None
    item: pg.LinearRegionItem
    stale: bool = False


class _ScrubViewBox(pg.ViewBox):
    """A ViewBox where left click / left drag scrub instead of panning (Shift+left and middle drag pan)."""

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


def _curve(pen, name=None) -> pg.PlotDataItem:
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


class Timeline(QtWidgets.QWidget):
    """Timeline of a :class:`~evpose.core.session.model.Session`.

    Signals
    -------
    scrubbed(int)
        Event time (µs) the user moved to from the timeline: click, drag (throttled), step buttons,
        "go to worst". Not emitted for playback ticks or for time changes made elsewhere.
    worstRequested(str)
        The user asked for the worst window of an object; emitted after the timeline moved there.
    playingChanged(bool)
        Playback started / stopped.
    """

    scrubbed = QtCore.Signal("qint64")  # int64 µs: epoch event times exceed 32 bits
    worstRequested = QtCore.Signal(str)
    playingChanged = QtCore.Signal(bool)

    def __init__(self, session: Session, parent=None):
        super().__init__(parent)
        self.session = session
        self.clock = time.monotonic          # wall clock used by playback (replaceable in tests)
        self.data: TimelineData | None = None
        self.data_compute_ms = 0.0
        self.marks: list[MarkRegion] = []
        self.score_t_s: np.ndarray | None = None
        self.scores: dict[str, np.ndarray] = {}
        self.score_items: dict[str, pg.PlotDataItem] = {}
        self.lower_is_better = False
        self._t_ref = int(session.scene.t_ref_us)   # x = 0: the first event (0 without events)
        self._data_key = None
        self._updating = False
        self._pending_t: int | None = None
        self._play_pos = 0.0
        self._play_last = 0.0
        self._play_set: int | None = None

        self.setFocusPolicy(QtCore.Qt.StrongFocus)
        self._build_controls()
        self._build_plot()
        self._build_score_plot()
        lay = QtWidgets.QVBoxLayout(self)
        lay.setContentsMargins(2, 2, 2, 2)
        lay.setSpacing(0)
        lay.addLayout(self._controls)
        lay.addWidget(self.glw, 5)
        lay.addWidget(self.score_glw, 3)
        self.score_glw.setVisible(False)

        self._scrub_timer = QtCore.QTimer(self, singleShot=True, interval=SCRUB_INTERVAL_MS)
        self._scrub_timer.timeout.connect(self._scrub_timer_fired)
        self._play_timer = QtCore.QTimer(self, interval=PLAY_INTERVAL_MS)
        self._play_timer.setTimerType(QtCore.Qt.PreciseTimer)
        self._play_timer.timeout.connect(self._tick)
        self._data_timer = QtCore.QTimer(self, singleShot=True, interval=15)
        self._data_timer.timeout.connect(self._refresh_if_clock_changed)

        connect_view(self, session.changed, self._on_session)
        self.refresh_data()
        self.fit()
        self._rebuild_marks()
        self._update_time()

    # ------------------------------------------------------------------ construction
    def _build_controls(self) -> None:
        style = self.style()

        def tool(icon, tip, slot):
            b = QtWidgets.QToolButton()
            b.setIcon(style.standardIcon(icon))
            b.setToolTip(tip)
            b.setAutoRaise(True)
            b.setFocusPolicy(QtCore.Qt.NoFocus)
            b.clicked.connect(slot)
            return b

        self.back_button = tool(QtWidgets.QStyle.SP_MediaSkipBackward, "one window back", lambda: self.step(-1))
        self.play_button = tool(QtWidgets.QStyle.SP_MediaPlay, "play / pause (Space)", self.toggle_play)
        self.play_button.setCheckable(True)
        self.forward_button = tool(QtWidgets.QStyle.SP_MediaSkipForward, "one window forward", lambda: self.step(1))
        self.speed_combo = QtWidgets.QComboBox()
        self.speed_combo.setFocusPolicy(QtCore.Qt.NoFocus)
        self.speed_combo.setToolTip("playback speed (fraction of real time)")
        for s in PLAY_SPEEDS:
            self.speed_combo.addItem(f"{s:g}×", s)
        self.speed_combo.setCurrentIndex(PLAY_SPEEDS.index(1.0))
        self.readout = Readout(READOUT_WIDEST, fixed_font=True)   # no relayout per time step
        self.readout.setFocusPolicy(QtCore.Qt.NoFocus)
        self.readout.setToolTip("current time: seconds since the first event | event-clock µs | window length")
        self.fit_button = QtWidgets.QToolButton(text="Fit")
        self.fit_button.setToolTip("show the whole sequence (wheel / right drag: zoom; Shift+drag: pan)")
        self.fit_button.setAutoRaise(True)
        self.fit_button.setFocusPolicy(QtCore.Qt.NoFocus)
        self.fit_button.clicked.connect(self.fit)
        self.scores_check = QtWidgets.QCheckBox("Scores")
        self.scores_check.setFocusPolicy(QtCore.Qt.NoFocus)
        self.scores_check.setToolTip("show the per-object alignment score row")
        self.scores_check.setEnabled(False)
        self.scores_check.toggled.connect(lambda on: self.score_glw.setVisible(on and bool(self.scores)))
        self.worst_button = QtWidgets.QToolButton(text="Worst ▾")
        self.worst_button.setToolTip("go to the window with the worst alignment score of an object")
        self.worst_button.setPopupMode(QtWidgets.QToolButton.InstantPopup)
        self.worst_button.setFocusPolicy(QtCore.Qt.NoFocus)
        self.worst_menu = QtWidgets.QMenu(self.worst_button)
        self.worst_button.setMenu(self.worst_menu)
        self.worst_button.setEnabled(False)
        c = self._controls = QtWidgets.QHBoxLayout()
        c.setContentsMargins(0, 0, 0, 0)
        c.setSpacing(2)
        for w in (self.back_button, self.play_button, self.forward_button, self.speed_combo):
            c.addWidget(w)
        c.addSpacing(8)
        c.addWidget(self.readout)
        c.addStretch(1)
        self.legend = QtWidgets.QLabel(_legend_html())
        self.legend.setToolTip("review marks over all objects fill the full height; object-specific marks "
                               "are thin lanes at the top (one lane per object, in the object list's order)")
        small = self.legend.font()
        small.setPointSize(8)
        self.legend.setFont(small)
        self.legend.setSizePolicy(QtWidgets.QSizePolicy.Ignored, QtWidgets.QSizePolicy.Preferred)
        self.legend.setAlignment(QtCore.Qt.AlignRight | QtCore.Qt.AlignVCenter)
        c.addWidget(self.legend, 100)
        c.addSpacing(8)
        for w in (self.scores_check, self.worst_button, self.fit_button):
            c.addWidget(w)

    def _build_plot(self) -> None:
        self.glw = pg.GraphicsLayoutWidget()
        self.glw.setFocusPolicy(QtCore.Qt.NoFocus)
        self.glw.setBackground("w")
        self.glw.ci.setContentsMargins(2, 0, 2, 2)
        self.glw.ci.setSpacing(0)
        self.vb = _ScrubViewBox(self._scrub_to, enableMenu=False)
        self.plot: pg.PlotItem = self.glw.addPlot(row=0, col=0, viewBox=self.vb)
        p = self.plot
        p.setMenuEnabled(False)
        p.hideButtons()
        p.setDownsampling(auto=True, mode="peak")
        p.setClipToView(True)
        p.setMouseEnabled(x=True, y=False)
        p.showGrid(x=True, y=False, alpha=0.15)
        bottom = p.getAxis("bottom")
        bottom.setLabel("time since first event (s)", **_label_style())
        bottom.enableAutoSIPrefix(False)
        left = p.getAxis("left")
        left.setLabel("rate", units="ev/s", **_label_style(RATE_COLOR))
        left.setWidth(LEFT_AXIS_W)
        # speed views: drawn beneath the main ViewBox, so every click reaches the scrubbing ViewBox
        self.speed_vb = pg.ViewBox(enableMenu=False)
        self.angular_vb = pg.ViewBox(enableMenu=False)
        p.showAxis("right")
        right = p.getAxis("right")
        right.linkToView(self.speed_vb)
        right.setLabel("speed (m/s)", **_label_style(SPEED_COLOR))
        right.enableAutoSIPrefix(False)
        right.setWidth(RIGHT_AXIS_W)
        right.setPen(pg.mkPen(SPEED_COLOR))
        right.setTextPen(pg.mkPen(SPEED_COLOR))
        self.angular_axis = pg.AxisItem("right")
        self.angular_axis.setLabel("angular (°/s)", **_label_style(ANGULAR_COLOR))
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
            v.enableAutoRange(x=False, y=True)
            v.setAutoVisible(y=True)
        for ax in (bottom, left, right, self.angular_axis):
            _small_font(ax)
        self.vb.sigResized.connect(self._sync_views)
        self.vb.enableAutoRange(x=False, y=True)
        self.vb.setAutoVisible(y=True)

        self.rate_item = _curve(pg.mkPen(RATE_COLOR, width=1), "event rate")
        self.rate_item.setFillLevel(0)
        self.rate_item.setFillBrush(pg.mkBrush(*RATE_COLOR, 60))
        p.addItem(self.rate_item)
        self.speed_item = _curve(pg.mkPen(SPEED_COLOR, width=1.5), "speed")
        self.angular_item = _curve(pg.mkPen(ANGULAR_COLOR, width=1.2), "angular speed")
        self.speed_vb.addItem(self.speed_item)
        self.angular_vb.addItem(self.angular_item)

        self.span = pg.LinearRegionItem(movable=False, brush=pg.mkBrush(*SPAN_COLOR, 70),
                                        pen=pg.mkPen(*SPAN_COLOR, 160))
        self.span.setZValue(10)
        self.cursor = self._make_cursor()
        p.addItem(self.span, ignoreBounds=True)
        p.addItem(self.cursor, ignoreBounds=True)

    def _make_cursor(self) -> pg.InfiniteLine:
        line = pg.InfiniteLine(angle=90, movable=True, pen=pg.mkPen(CURSOR_COLOR, width=2),
                               hoverPen=pg.mkPen((220, 0, 0), width=3))
        line.setZValue(20)
        line.setToolTip("current time: drag to scrub")
        line.sigPositionChanged.connect(self._cursor_dragged)
        line.sigPositionChangeFinished.connect(self._cursor_released)
        return line

    def _build_score_plot(self) -> None:
        self.score_glw = pg.GraphicsLayoutWidget()
        self.score_glw.setFocusPolicy(QtCore.Qt.NoFocus)
        self.score_glw.setBackground("w")
        self.score_glw.ci.setContentsMargins(2, 0, 2, 2)
        self.score_vb = _ScrubViewBox(self._scrub_to, enableMenu=False)
        self.score_plot: pg.PlotItem = self.score_glw.addPlot(row=0, col=0, viewBox=self.score_vb)
        sp = self.score_plot
        sp.setMenuEnabled(False)
        sp.hideButtons()
        sp.setMouseEnabled(x=True, y=False)
        sp.setXLink(self.vb)
        sp.showGrid(x=True, y=True, alpha=0.15)
        sp.hideAxis("bottom")
        sp.getAxis("left").setWidth(LEFT_AXIS_W)
        sp.getAxis("left").setLabel("score", **_label_style())
        _small_font(sp.getAxis("left"))
        sp.showAxis("right")
        sp.getAxis("right").setWidth(2 * RIGHT_AXIS_W)
        sp.getAxis("right").setStyle(showValues=False)
        self.score_vb.enableAutoRange(x=False, y=True)
        self.score_vb.setAutoVisible(y=True)
        self.score_legend = sp.addLegend(offset=(4, 2), labelTextSize="8pt", colCount=6,
                                         brush=pg.mkBrush(255, 255, 255, 200))
        self.score_cursor = self._make_cursor()
        self.score_span = pg.LinearRegionItem(movable=False, brush=pg.mkBrush(*SPAN_COLOR, 70),
                                              pen=pg.mkPen(*SPAN_COLOR, 160))
        self.score_span.setZValue(10)
        sp.addItem(self.score_span, ignoreBounds=True)
        sp.addItem(self.score_cursor, ignoreBounds=True)
        self.worst_item = pg.ScatterPlotItem(size=9, symbol="x", pen=None)
        self.worst_item.setZValue(15)
        sp.addItem(self.worst_item, ignoreBounds=True)

    def _sync_views(self) -> None:
        rect = self.vb.sceneBoundingRect()
        for v in (self.speed_vb, self.angular_vb):
            v.setGeometry(rect)
            v.linkedViewChanged(self.vb, v.XAxis)

    # ------------------------------------------------------------------ coordinates
    @property
    def t_ref_us(self) -> int:
        """Event time (µs) of x = 0: the first event."""
        return self._t_ref

    def x_of(self, t_us) -> float:
        """Plot x (s) of an event time (µs)."""
        return (int(t_us) - self._t_ref) * 1e-6

    def t_of(self, x_s: float) -> int:
        """Event time (µs) of a plot x (s), clamped to the recording."""
        t0, t1 = self.session.time_range
        return int(min(max(self._t_ref + int(round(float(x_s) * 1e6)), t0), t1))

    def fit(self) -> None:
        """Show the whole sequence."""
        x0, x1 = self._x_extent()
        pad = 0.01 * (x1 - x0)
        self.vb.setLimits(xMin=x0 - pad, xMax=x1 + pad, minXRange=MIN_X_RANGE_S)
        self.vb.setXRange(x0, x1, padding=0.01)

    def _x_extent(self) -> tuple[float, float]:
        t0, t1 = self.session.time_range
        x0, x1 = self.x_of(t0), self.x_of(t1)
        if self.data is not None and len(self.data.t_s):
            x0, x1 = min(x0, float(self.data.t_s[0])), max(x1, float(self.data.t_s[-1]))
        if x1 <= x0:
            x1 = x0 + 1e-3
        return x0, x1

    # ------------------------------------------------------------------ data
    def refresh_data(self) -> None:
        """Recompute the rate and the speed curves (clock in effect) and display them."""
        t = time.perf_counter()
        data = timeline_data(self.session.scene, BIN_US)
        self.data_compute_ms = (time.perf_counter() - t) * 1e3
        self._data_key = self._clock_key()
        self.set_data(data)

    def set_data(self, data: TimelineData) -> None:
        """Display whole-sequence curves computed in core (see :func:`evpose.core.session.timeline.timeline_data`)."""
        first = self.data is None
        self.data = data
        if len(data.t_s):
            self._t_ref = int(data.t_ref_us)
        valid = np.asarray(data.speed_valid, bool)
        self.rate_item.setData(data.t_s, np.asarray(data.rate_hz, np.float64))
        self.speed_item.setData(data.t_s, np.where(valid, data.speed_mps, np.nan))
        self.angular_item.setData(data.t_s, np.where(valid, data.angular_dps, np.nan))
        self._shade_holes(getattr(data, "holes_s", np.zeros((0, 2))))
        if first:
            self.fit()
        else:
            x0, x1 = self._x_extent()
            pad = 0.01 * (x1 - x0)
            self.vb.setLimits(xMin=x0 - pad, xMax=x1 + pad)
        self._sync_views()

    def _shade_holes(self, holes_s) -> None:
        """Grey hatched bands over the trajectory's holes (no pose there, so no label)."""
        for item in getattr(self, "hole_items", []):
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

    def _clock_key(self):
        scene = self.session.scene
        c = scene.clock
        return c.offset_us, c.skew_ppm, scene.corrections.hand_eye_delta.tobytes()

    def _refresh_if_clock_changed(self) -> None:
        if self._clock_key() != self._data_key:
            self.refresh_data()

    # ------------------------------------------------------------------ session changes
    def _on_session(self, change: Change) -> None:
        if change.kind in ("time", "view"):
            self._update_time()
        elif change.kind == "document":
            if change.fields - {"reviews"}:
                # debounced: a dragged offset slider sends many changes; recomputing takes ~30 ms per 10^6 bins
                if not self._data_timer.isActive():
                    self._data_timer.setInterval(int(min(max(2 * self.data_compute_ms, 15), 250)))
                    self._data_timer.start()
            if "reviews" in change.fields or self._stale_key() != self._marks_stale_key:
                self._rebuild_marks()      # new marks, or a clock or pose change made marks stale (or fresh)
        elif change.kind == "objects":
            self._style_scores()

    def _update_time(self) -> None:
        v = self.session.view
        w = v.window()
        x = self.x_of(v.t_us)
        self._updating = True
        try:
            if self._pending_t is None:  # while a scrub is pending the cursor follows the mouse
                for c in (self.cursor, self.score_cursor):
                    c.setPos(x)
            for s in (self.span, self.score_span):
                s.setRegion((self.x_of(w.t0_us), self.x_of(w.t1_us)))
        finally:
            self._updating = False
        x0, x1 = self._x_extent()
        for c in (self.cursor, self.score_cursor):
            c.setBounds((x0, x1))
        self._update_readout()

    def _update_readout(self, t_us: int | None = None) -> None:
        v = self.session.view
        t = v.t_us if t_us is None else t_us
        self.readout.setText(f"{self.x_of(t):.6f} s │ {t} µs │ win {v.window_us / 1000:g} ms")

    _marks_stale_key = None

    def _stale_key(self) -> tuple:
        now = self.session.mark_state()
        return tuple(bool(self.session.stale_reasons(m, now=now)) for m in self.session.scene.corrections.reviews)

    def _rebuild_marks(self) -> None:
        for m in self.marks:
            self.plot.removeItem(m.item)
        self.marks = []
        names = self.session.object_names
        groups: dict[tuple, list] = {}
        why: dict[tuple, str] = {}
        now = self.session.mark_state()
        stale_flags = []
        for mark in self.session.scene.corrections.reviews:
            reasons = self.session.stale_reasons(mark, now=now)
            stale_flags.append(bool(reasons))
            key = (mark.status, mark.object, bool(reasons))
            groups.setdefault(key, []).append((mark.t0_us, mark.t1_us))
            if reasons:
                why.setdefault(key, "; ".join(reasons))
        self._marks_stale_key = tuple(stale_flags)
        for (status, obj, stale), spans in groups.items():
            spans.sort()
            runs = [list(spans[0])]
            for t0, t1 in spans[1:]:
                if t0 <= runs[-1][1]:
                    runs[-1][1] = max(runs[-1][1], t1)
                else:
                    runs.append([t0, t1])
            color = STATUS_COLORS.get(status, (128, 128, 128))
            if obj is None:
                span, alpha, z = (0.0, 1.0), GLOBAL_MARK_ALPHA, -20
            else:
                k = names.index(obj) if obj in names else len(names)
                span = (max(1.0 - (k + 1) * OBJECT_LANE, 0.0), 1.0 - k * OBJECT_LANE)
                alpha, z = OBJECT_MARK_ALPHA, -10
            if stale:
                brush = pg.mkBrush(*color, min(alpha * 3, 255))
                brush.setStyle(QtCore.Qt.BDiagPattern)      # hatched: verified on other labels
                pen = pg.mkPen(*color, min(alpha + 60, 255), style=QtCore.Qt.DashLine)
            else:
                brush, pen = pg.mkBrush(*color, alpha), pg.mkPen(*color, min(alpha + 60, 255))
            for t0, t1 in runs:
                item = pg.LinearRegionItem((self.x_of(t0), self.x_of(t1)), movable=False, span=span,
                                           brush=brush, pen=pen)
                item.setZValue(z)
                item.setAcceptedMouseButtons(QtCore.Qt.NoButton)
                for line in item.lines:
                    line.setAcceptedMouseButtons(QtCore.Qt.NoButton)
                item.setToolTip(f"{status}{'' if obj is None else ' (' + obj + ')'}: "
                                f"{self.x_of(t0):.3f}–{self.x_of(t1):.3f} s"
                                + (f"\nSTALE: {why[(status, obj, stale)]}" if stale else ""))
                self.plot.addItem(item, ignoreBounds=True)
                self.marks.append(MarkRegion(int(t0), int(t1), status, obj, item, stale))

    # ------------------------------------------------------------------ scrubbing
    def _scrub_to(self, x_s: float, final: bool) -> None:
        self.request_time(self.t_of(x_s), final)

    def request_time(self, t_us: int, immediate: bool = True) -> None:
        """Move to ``t_us`` as a user scrub: the cursor moves at once; the session follows immediately
        (``immediate``) or throttled to one update per :data:`SCRUB_INTERVAL_MS` (leading and trailing)."""
        t0, t1 = self.session.time_range
        t_us = int(min(max(int(t_us), t0), t1))
        self._pending_t = t_us
        self._updating = True
        try:
            for c in (self.cursor, self.score_cursor):
                c.setPos(self.x_of(t_us))
        finally:
            self._updating = False
        self._update_readout(t_us)
        if immediate:
            self._scrub_timer.stop()
            self._flush_scrub()
        elif not self._scrub_timer.isActive():
            self._flush_scrub()
            self._scrub_timer.start()

    def _scrub_timer_fired(self) -> None:
        if self._pending_t is not None:   # trailing update; keep the next leading one an interval away
            self._flush_scrub()
            self._scrub_timer.start()

    def _flush_scrub(self) -> None:
        t = self._pending_t
        if t is None:
            return
        self._pending_t = None
        self.session.set_time(t)
        self.scrubbed.emit(int(self.session.view.t_us))

    def _cursor_dragged(self, line: pg.InfiniteLine) -> None:
        if not self._updating:
            self.request_time(self.t_of(line.value()), immediate=False)

    def _cursor_released(self, line: pg.InfiniteLine) -> None:
        if not self._updating:
            self.request_time(self.t_of(line.value()), immediate=True)

    def step(self, n: int) -> None:
        """Move ``n`` windows (negative: back)."""
        self.session.step_windows(n)
        self.scrubbed.emit(int(self.session.view.t_us))

    # ------------------------------------------------------------------ playback
    @property
    def speed(self) -> float:
        """Playback speed as a fraction of real time."""
        return float(self.speed_combo.currentData())

    def set_speed(self, factor: float) -> None:
        i = self.speed_combo.findData(float(factor))
        if i < 0:
            raise ValueError(f"playback speed must be one of {PLAY_SPEEDS}, got {factor!r}")
        self.speed_combo.setCurrentIndex(i)

    @property
    def is_playing(self) -> bool:
        return self._play_timer.isActive()

    def play(self) -> None:
        """Start playback from the current time (from the start when at the end)."""
        if self.is_playing:
            return
        t0, t1 = self.session.time_range
        if self.session.view.t_us >= t1:
            self.session.set_time(t0)
        self._play_pos = float(self.session.view.t_us)
        self._play_set = int(self.session.view.t_us)
        self._play_last = self.clock()
        self._play_timer.start()
        self._sync_play_button(True)

    def pause(self) -> None:
        if not self.is_playing:
            return
        self._play_timer.stop()
        self._sync_play_button(False)

    def toggle_play(self) -> None:
        self.pause() if self.is_playing else self.play()

    def stop(self) -> None:
        """Stop playback and pending updates (call before discarding the session)."""
        self.pause()
        self._scrub_timer.stop()
        self._data_timer.stop()

    def _sync_play_button(self, playing: bool) -> None:
        self.play_button.blockSignals(True)
        self.play_button.setChecked(playing)
        self.play_button.blockSignals(False)
        self.play_button.setIcon(self.style().standardIcon(
            QtWidgets.QStyle.SP_MediaPause if playing else QtWidgets.QStyle.SP_MediaPlay))
        self.playingChanged.emit(playing)

    def _tick(self) -> None:
        """Advance by the elapsed wall time × speed; stop at the end of the recording."""
        now = self.clock()
        dt, self._play_last = max(now - self._play_last, 0.0), now
        cur = int(self.session.view.t_us)
        if cur != self._play_set:      # the user moved the time meanwhile: continue from there
            self._play_pos = float(cur)
        self._play_pos += dt * 1e6 * self.speed
        t1 = self.session.time_range[1]
        if self._play_pos >= t1:
            self.session.set_time(t1)
            self.pause()
        else:
            self.session.set_time(int(self._play_pos))
        self._play_set = int(self.session.view.t_us)

    # ------------------------------------------------------------------ keyboard
    def event(self, ev: QtCore.QEvent) -> bool:
        # take Space from the window's shortcuts while focused; leave every other key to them
        if ev.type() == QtCore.QEvent.ShortcutOverride and ev.key() == QtCore.Qt.Key_Space \
                and ev.modifiers() == QtCore.Qt.NoModifier:
            ev.accept()
            return True
        return super().event(ev)

    def keyPressEvent(self, ev: QtGui.QKeyEvent) -> None:
        if ev.key() == QtCore.Qt.Key_Space and ev.modifiers() == QtCore.Qt.NoModifier:
            self.toggle_play()
            ev.accept()
        else:
            ev.ignore()   # propagate to the parent / main window

    # ------------------------------------------------------------------ alignment scores
    def set_scores(self, t_s, scores: dict, *, lower_is_better: bool = False, label: str = "score") -> None:
        """Per-object alignment scores over time, drawn in each object's colour on the score row.

        Parameters
        ----------
        t_s : (N,) array
            Window label times, seconds since the first event (the timeline's x).
        scores : dict name -> (N,) float
            NaN where undefined (object out of view, no events, no pose).
        lower_is_better : bool
            False (default) for :mod:`core.score`'s ``score`` (1 = every event on an edge, 0 = noise): the worst
            window is the minimum, as in ``evpose.core.align.score.worst_window``. True for distances (``distance_px``):
            the worst window is the maximum.
        label : str
            Left-axis label, with units.
        """
        t_s = np.asarray(t_s, np.float64).ravel()
        clean = {}
        for name, s in scores.items():
            s = np.asarray(s, np.float64).ravel()
            if s.shape != t_s.shape:
                raise ValueError(f"scores[{name!r}] has {s.size} values for {t_s.size} times")
            clean[name] = s
        self.clear_scores()
        self.score_t_s, self.scores, self.lower_is_better = t_s, clean, bool(lower_is_better)
        self.score_plot.getAxis("left").setLabel(label, **_label_style())
        for name, s in clean.items():
            color = self.session.color(name) if name in self.session.object_names else (80, 80, 80)
            item = _curve(pg.mkPen(color, width=1.5), name)
            self.score_plot.addItem(item)   # add before setData: clipping needs the ViewBox
            item.setData(t_s, s)
            self.score_items[name] = item
            act = self.worst_menu.addAction(f"{name}")
            act.setIcon(_swatch(color))
            act.triggered.connect(lambda _=False, n=name: self.goto_worst(n))
        self._style_scores()
        pts = [(self.x_of(t), self._score_at(n, t), n) for n in clean if (t := self.worst_time(n)) is not None]
        self.worst_item.setData([p[0] for p in pts], [p[1] for p in pts],
                                brush=None, pen=[pg.mkPen(self._name_color(p[2]), width=2) for p in pts])
        has = bool(clean)
        self.scores_check.setEnabled(has)
        self.worst_button.setEnabled(has)
        self.scores_check.setChecked(has)
        self.score_glw.setVisible(has and self.scores_check.isChecked())

    def clear_scores(self) -> None:
        for item in self.score_items.values():
            self.score_plot.removeItem(item)
        self.score_items.clear()
        self.scores = {}
        self.score_t_s = None
        self.worst_menu.clear()
        self.worst_item.setData([], [])
        self.scores_check.setEnabled(False)
        self.worst_button.setEnabled(False)
        self.score_glw.setVisible(False)

    def worst_time(self, name: str) -> int | None:
        """Event time (µs) of the window with the worst score of ``name`` (NaN ignored): the minimum, or the
        maximum when the scores were set with ``lower_is_better``; None if the object has no defined score."""
        if name not in self.scores:
            raise KeyError(f"no scores for {name!r}")
        s = self.scores[name]
        finite = np.isfinite(s)
        if not finite.any():
            return None
        masked = np.where(finite, s, -np.inf if self.lower_is_better else np.inf)
        i = int(np.argmax(masked) if self.lower_is_better else np.argmin(masked))
        return self._t_ref + int(round(float(self.score_t_s[i]) * 1e6))

    def goto_worst(self, name: str) -> int | None:
        """Move to the worst window of ``name``; emits ``scrubbed`` and ``worstRequested``."""
        t = self.worst_time(name)
        if t is None:
            return None
        self.request_time(t, immediate=True)
        self.worstRequested.emit(name)
        return int(self.session.view.t_us)

    def _score_at(self, name: str, t_us: int) -> float:
        i = int(np.argmin(np.abs(self.score_t_s - self.x_of(t_us))))
        return float(self.scores[name][i])

    def _name_color(self, name: str):
        return self.session.color(name) if name in self.session.object_names else (80, 80, 80)

    def _style_scores(self) -> None:
        sel, hidden = self.session.view.selected, self.session.view.hidden
        for name, item in self.score_items.items():
            width = 2.5 if name == sel else 1.2
            color = self._name_color(name)
            item.setPen(pg.mkPen(*color, 90 if name in hidden else 255, width=width))
            item.setZValue(5 if name == sel else 0)


def _small_font(axis: pg.AxisItem, pt: int = 8) -> None:
    font = QtGui.QFont()
    font.setPointSize(pt)
    axis.setStyle(tickFont=font)


def _label_style(color=(0, 0, 0), pt: int = 8) -> dict:
    return {"color": pg.mkColor(color).name(), "font-size": f"{pt}pt"}


def _legend_html() -> str:
    """Key of the curves and review colours (shown in the control row, leaving the plot its height)."""
    def hexc(c):
        return pg.mkColor(c).name()

    parts = [f"<span style='color:{hexc(RATE_COLOR)}'>&#9632;</span>&nbsp;event rate",
             f"<span style='color:{hexc(SPEED_COLOR)}'><b>&#8212;</b></span>&nbsp;speed",
             f"<span style='color:{hexc(ANGULAR_COLOR)}'><b>&#8212;</b></span>&nbsp;angular"]
    parts += [f"<span style='color:{hexc(c)}'>&#9608;</span>&nbsp;{s}" for s, c in STATUS_COLORS.items()]
    return "&nbsp;&nbsp; ".join(parts)


def _swatch(color) -> QtGui.QIcon:
    pm = QtGui.QPixmap(12, 12)
    pm.fill(QtGui.QColor(*color))
    return QtGui.QIcon(pm)
