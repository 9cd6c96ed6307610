"""The whole sequence at a glance: event rate, robot speed, review marks, alignment scores; scrub and play.

x is seconds since the first event on the **event clock** (``(t_us - t_ref_us) * 1e-6``). The robot speed
comes from :func:`evpose.core.views.timeline.timeline_data`, which maps each bin through the clock in effect, so a wrong
time offset shows as a horizontal shift between the event-rate and speed curves; the speed is recomputed
(debounced) when the document's clock changes.

Interaction
-----------
- left click / drag on a plot, or drag the black cursor line: scrub (``session.set_time``; throttled to
  :data:`~evpose.widgets.timeline.scrub.SCRUB_INTERVAL_MS` while dragging, the cursor itself follows the mouse at once);
- wheel / right drag: zoom in time; Shift+left or middle drag: pan; "Fit" shows the whole sequence;
- play / pause with a selectable speed (fraction of real time), step one window back / forward;
- Space toggles play while the timeline has keyboard focus. Other keys (arrows...) are left to the main
  window: no child takes keyboard focus.

The pieces live beside this module: the control row (:mod:`~evpose.widgets.timeline.controls`), the main
row of curves (:mod:`~evpose.widgets.timeline.plot`), the review marks (:mod:`~evpose.widgets.timeline.marks`),
the score row (:mod:`~evpose.widgets.timeline.scores`) and the shared colours and items
(:mod:`~evpose.widgets.timeline.style`); playback and scrubbing are :mod:`~evpose.widgets.timeline.playback`
and :mod:`~evpose.widgets.timeline.scrub`.
"""
from __future__ import annotations

import time

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from evpose.core.session.model import Session
from evpose.core.views.timeline import TIMELINE_BIN_US as BIN_US, TimelineData, timeline_data
from evpose.core.signals import Change, DOCUMENT, OBJECTS, TIME, VIEW
from evpose.widgets.binding import connect_view
from evpose.widgets.timeline.controls import ControlBar
from evpose.widgets.timeline.marks import MarkRegion, mark_regions, stale_key
from evpose.widgets.timeline.playback import Playback
from evpose.widgets.timeline.plot import RatePlot
from evpose.widgets.timeline.scores import ScoreRow
from evpose.widgets.timeline.scrub import Scrubber
from evpose.widgets.timeline.style import MIN_PLOT_H, MIN_SCORE_H, legend_html

MIN_X_RANGE_S = 0.005            # deepest zoom: 5 ms across the plot


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
        self.data: TimelineData | None = None
        self.data_compute_ms = 0.0
        self.marks: list[MarkRegion] = []
        self._marks_stale_key = None
        self._t_ref = int(session.scene.t_ref_us)   # x = 0: the first event (0 without events)
        self._data_key = None
        #: set by the app: asks for the curves on a worker (its result comes back through :meth:`set_data`);
        #: None: computed here, on the GUI thread
        self.data_feed = None

        self.setFocusPolicy(QtCore.Qt.StrongFocus)
        self.scrubber = Scrubber(self)
        self._build()
        self.scrubber.cursors = (self.cursor, self.score_cursor)
        self.playback = Playback(self, session, lambda: self.controls.speed)
        self.playback.changed.connect(self._sync_play_button)

        self._data_timer = QtCore.QTimer(self, singleShot=True, interval=15)
        self._data_timer.timeout.connect(self._refresh_if_clock_changed)

        connect_view(self, session.changed, self._on_session, {TIME, VIEW, DOCUMENT, OBJECTS})
        self.refresh_data()
        self.fit()
        self._rebuild_marks()
        self._update_time()

    # ------------------------------------------------------------------ construction
    def _build(self) -> None:
        """The control row, the main row and the (hidden until scored) score row; their widgets and
        items are also attributes of the timeline (``play_button``, ``vb``, ``rate_item``, ``score_glw``...)."""
        c = self.controls = ControlBar(self.step, self.toggle_play, self.fit,
                                       lambda on: self.score_glw.setVisible(on and bool(self.scores)))
        self.back_button, self.play_button, self.forward_button = c.back_button, c.play_button, c.forward_button
        self.speed_combo, self.readout, self.fit_button = c.speed_combo, c.readout, c.fit_button
        self.scores_check, self.worst_button, self.worst_menu, self.legend = (c.scores_check, c.worst_button,
                                                                              c.worst_menu, c.legend)
        r = self.rate_plot = RatePlot(self.scrubber.scrub_to, self.scrubber.cursor_dragged,
                                      self.scrubber.cursor_released)
        self.glw, self.vb, self.plot, self.speed_vb, self.angular_vb = r.glw, r.vb, r.plot, r.speed_vb, r.angular_vb
        self.rate_item, self.speed_item, self.angular_item = r.rate_item, r.speed_item, r.angular_item
        self.angular_axis, self.span, self.cursor = r.angular_axis, r.span, r.cursor
        s = self.score_row = ScoreRow(self.session, self.scrubber.scrub_to, self.vb, self.scrubber.cursor_dragged,
                                      self.scrubber.cursor_released, controls=c, goto_worst=self.goto_worst,
                                      axis=self)
        self.score_glw, self.score_vb, self.score_plot, self.score_legend = s.glw, s.vb, s.plot, s.legend
        self.score_cursor, self.score_span, self.worst_item = s.cursor, s.span, s.worst_item
        lay = QtWidgets.QVBoxLayout(self)
        lay.setContentsMargins(2, 2, 2, 2)
        lay.setSpacing(0)
        lay.addLayout(c.layout)
        self.glw.setMinimumHeight(MIN_PLOT_H)          # never squeezed to a sliver by the docks or the window
        self.score_glw.setMinimumHeight(MIN_SCORE_H)
        lay.addWidget(self.glw, 5)
        lay.addWidget(self.score_glw, 3)
        self.score_glw.setVisible(False)

    @property
    def hole_items(self) -> list:
        """The hatched bands over the trajectory's holes."""
        return self.rate_plot.hole_items

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
        """Recompute the rate and the speed curves (clock in effect) here and display them."""
        t = time.perf_counter()
        data = timeline_data(self.session.scene, BIN_US)
        self.set_data(data, self.clock_key(), (time.perf_counter() - t) * 1e3)

    def show_pose_curves(self, on: bool) -> None:
        """Show the camera's speed curves, their axes and the review colours in the legend (off for an event-only
        scene: it has no poses and no review marks)."""
        r = self.rate_plot
        for item in (r.speed_item, r.angular_item, r.plot.getAxis("right"), r.angular_axis):
            item.setVisible(on)
        self.legend.setText(legend_html(on))

    def set_data(self, data: TimelineData, clock_key=None, compute_ms: float | None = None) -> None:
        """Display whole-sequence curves computed in core (see :func:`evpose.core.views.timeline.timeline_data`),
        computed with the clock ``clock_key`` (:meth:`clock_key`) in ``compute_ms``."""
        if clock_key is not None:
            self._data_key = clock_key
        if compute_ms is not None:
            self.data_compute_ms = compute_ms
        first = self.data is None
        self.data = data
        if len(data.t_s):
            self._t_ref = int(data.t_ref_us)
        self.rate_plot.set_curves(data)
        if first:
            self.fit()
        else:
            x0, x1 = self._x_extent()
            pad = 0.01 * (x1 - x0)
            self.vb.setLimits(xMin=x0 - pad, xMax=x1 + pad)
        self.rate_plot.sync_views()

    def clock_key(self):
        """What the speed curves depend on: the clock offset and skew and the hand-eye correction in effect."""
        scene = self.session.scene
        c = scene.clock
        return c.offset_us, c.skew_ppm, scene.corrections.hand_eye_delta.tobytes()

    def _refresh_if_clock_changed(self) -> None:
        if self.clock_key() != self._data_key:
            if self.data_feed is not None:
                self.data_feed()
            else:
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
        if self.scrubber.pending_t is None:  # while a scrub is pending the cursor follows the mouse
            self.scrubber.place_cursors(self.x_of(v.t_us))
        for s in (self.span, self.score_span):
            s.setRegion((self.x_of(w.t0_us), self.x_of(w.t1_us)))
        x0, x1 = self._x_extent()
        for c in (self.cursor, self.score_cursor):
            c.setBounds((x0, x1))
        self.show_readout()

    def show_readout(self, t_us: int | None = None) -> None:
        """The time readout at ``t_us`` (default: the session's time)."""
        v = self.session.view
        t = v.t_us if t_us is None else t_us
        self.readout.setText(f"{self.x_of(t):.6f} s │ {t} µs │ win {v.window_us / 1000:g} ms")

    def _stale_key(self) -> tuple:
        return stale_key(self.session)

    def _rebuild_marks(self) -> None:
        for m in self.marks:
            self.plot.removeItem(m.item)
        self.marks, self._marks_stale_key = mark_regions(self.session, self.x_of)
        for m in self.marks:
            self.plot.addItem(m.item, ignoreBounds=True)

    # ------------------------------------------------------------------ scrubbing
    def request_time(self, t_us: int, immediate: bool = True) -> None:
        """Move to ``t_us`` as a user scrub (see :meth:`Scrubber.request_time`)."""
        self.scrubber.request_time(t_us, immediate)

    def step(self, n: int) -> None:
        """Move ``n`` windows (negative: back)."""
        self.session.step_windows(n)
        self.scrubbed.emit(int(self.session.view.t_us))

    # ------------------------------------------------------------------ playback
    @property
    def speed(self) -> float:
        """Playback speed as a fraction of real time."""
        return self.controls.speed

    def set_speed(self, factor: float) -> None:
        self.controls.set_speed(factor)

    @property
    def clock(self):
        """Wall clock (s) used by playback (replaceable in tests)."""
        return self.playback.clock

    @clock.setter
    def clock(self, fn) -> None:
        self.playback.clock = fn

    @property
    def is_playing(self) -> bool:
        return self.playback.is_playing

    def play(self) -> None:
        """Start playback from the current time (from the start when at the end)."""
        self.playback.play()

    def pause(self) -> None:
        self.playback.pause()

    def toggle_play(self) -> None:
        self.pause() if self.is_playing else self.play()

    def stop(self) -> None:
        """Stop playback and pending updates (call before discarding the session)."""
        self.pause()
        self.scrubber.stop()
        self._data_timer.stop()

    def _sync_play_button(self, playing: bool) -> None:
        self.controls.show_playing(playing)
        self.playingChanged.emit(playing)

    def _tick(self) -> None:
        self.playback.tick()

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
    @property
    def scores(self) -> dict[str, np.ndarray]:
        """Per-object scores shown on the score row (name -> (N,) float)."""
        return self.score_row.scores

    @property
    def score_items(self) -> dict:
        return self.score_row.items

    @property
    def score_t_s(self) -> np.ndarray | None:
        return self.score_row.t_s

    @property
    def lower_is_better(self) -> bool:
        return self.score_row.lower_is_better

    def set_scores(self, t_s, scores: dict, *, lower_is_better: bool = False, label: str = "score",
                   low_evidence: dict | None = None) -> None:
        """Per-object alignment scores over time on the score row (see :meth:`ScoreRow.set_scores`):
        ``t_s`` (N,) window label times in plot x (s), ``scores`` name -> (N,) float (NaN: undefined),
        ``low_evidence`` name -> (N,) bool (drawn apart, never the worst). The row is shown fresh."""
        self.score_row.set_scores(t_s, scores, lower_is_better=lower_is_better, label=label,
                                  low_evidence=low_evidence)

    @property
    def scores_stale(self) -> bool:
        """True while the score row shows scores computed before a change of the clock or a pose."""
        return self.score_row.stale

    def set_scores_stale(self, stale: bool, text: str | None = None) -> None:
        """Dim the score row with a label ("stale — recomputing" by default) until fresh scores are set."""
        if text is None:
            self.score_row.set_stale(stale)
        else:
            self.score_row.set_stale(stale, text)

    def clear_scores(self) -> None:
        self.score_row.clear_scores()

    def worst_time(self, name: str) -> int | None:
        """Event time (µs) of the window with the worst score of ``name``; None if it has no defined score."""
        return self.score_row.worst_time(name)

    def goto_worst(self, name: str) -> int | None:
        """Move to the worst window of ``name``; emits ``scrubbed`` and ``worstRequested``."""
        t = self.worst_time(name)
        if t is None:
            return None
        self.request_time(t, immediate=True)
        self.worstRequested.emit(name)
        return int(self.session.view.t_us)

    def _style_scores(self) -> None:
        self.score_row.style()
