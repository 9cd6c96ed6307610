"""Timeline: model changes drive the view; clicks, drags, playback and keys drive the model."""
import time

import numpy as np
import pyqtgraph as pg
import pytest
from PySide6 import QtCore, QtGui, QtWidgets

from evpose.core.views.timeline import TimelineData
from evpose.widgets.timeline.view import Timeline
from evpose.widgets.timeline.scrub import SCRUB_INTERVAL_MS
from evpose.widgets.timeline.style import STATUS_COLORS

LEFT = QtCore.Qt.LeftButton


@pytest.fixture
def tl(qtbot, session):
    w = Timeline(session)
    qtbot.addWidget(w)
    w.resize(1000, 260)
    w.show()
    qtbot.waitExposed(w)
    # the plot layout settles after the first paints (axis widths); tests map plot x to pixels
    qtbot.waitUntil(lambda: w.vb.sceneBoundingRect().width() > 0.5 * w.width(), timeout=3000)
    yield w
    w.stop()


def rel(session, t_us):
    return (t_us - session.time_range[0]) * 1e-6


def viewport_pos(w, vb, x_s, y_frac=0.5) -> QtCore.QPoint:
    """Viewport pixel of plot coordinate x (s) at a fraction of the view's height."""
    (_, _), (y0, y1) = vb.viewRange()
    scene_pt = vb.mapViewToScene(QtCore.QPointF(x_s, y0 + y_frac * (y1 - y0)))
    view = vb.scene().views()[0]
    return view.mapFromScene(scene_pt)


def _mouse(widget, kind, pos, button, buttons):
    p = QtCore.QPointF(pos)
    ev = QtGui.QMouseEvent(kind, p, QtCore.QPointF(widget.mapToGlobal(pos)), button, buttons,
                           QtCore.Qt.NoModifier)
    QtWidgets.QApplication.sendEvent(widget, ev)


def drag(qtbot, widget, points):
    """Press, move with the left button held (QTest moves carry no buttons), release.

    ``points`` are QPoints or callables returning one; callables are evaluated when the event is
    sent, so a layout that settles during the drag (axis widths, under load) cannot skew the target.
    Moves are spaced by pyqtgraph's ``mouseRateLimit`` interval, as a real mouse's are: its scene
    drops moves that come sooner, and if every move after a first short one is dropped the drag
    never starts and the release becomes a click where the button went down (a CI flake that
    showed up whenever the machine was fast)."""
    E = QtCore.QEvent
    rate = pg.getConfigOption("mouseRateLimit")
    gap_s = 1.0 / rate + 0.002 if rate > 0 else 0.0
    at = [p if callable(p) else (lambda p=p: p) for p in points]
    _mouse(widget, E.MouseButtonPress, at[0](), LEFT, LEFT)
    for p in at[1:]:
        sent = time.perf_counter()
        _mouse(widget, E.MouseMove, p(), QtCore.Qt.NoButton, LEFT)
        QtWidgets.QApplication.processEvents()
        while time.perf_counter() - sent < gap_s:
            QtWidgets.QApplication.processEvents(QtCore.QEventLoop.AllEvents, 1)
    _mouse(widget, E.MouseButtonRelease, at[-1](), LEFT, QtCore.Qt.NoButton)
    QtWidgets.QApplication.processEvents()


# ---------------------------------------------------------------------- model -> view
def test_cursor_span_and_readout_follow_the_session(tl, session):
    t0, t1 = session.time_range
    assert tl.t_ref_us == t0
    session.set_time(t0 + 512_345)
    assert tl.cursor.value() == pytest.approx(0.512345)
    assert tl.score_cursor.value() == pytest.approx(0.512345)
    assert tl.span.getRegion() == pytest.approx((0.51, 0.52))   # the grid window holding t (export tiling)
    assert "0.512345 s" in tl.readout.text() and f"{t0 + 512_345} µs" in tl.readout.text()
    session.set_window_us(40_000)
    assert tl.span.getRegion() == pytest.approx((0.48, 0.52))
    assert "win 40 ms" in tl.readout.text()
    assert not tl.span.movable
    # the whole sequence is in view, the curves hold one value per 1 ms bin
    (x0, x1), _ = tl.vb.viewRange()
    assert x0 <= 0 and x1 >= rel(session, t1)
    assert len(tl.rate_item.xData) == len(tl.data.t_s) == pytest.approx((t1 - t0) / 1000, abs=2)


def test_review_marks_are_coloured_regions(tl, session):
    assert tl.marks == []
    w = session.view.window()
    session.add_review("verified")
    assert len(tl.marks) == 1
    m = tl.marks[0]
    assert (m.status, m.object) == ("verified", None)
    assert m.item.getRegion() == pytest.approx((rel(session, w.t0_us), rel(session, w.t1_us)))
    assert m.item.brush.color().getRgb()[:3] == STATUS_COLORS["verified"]
    assert m.item.span == (0.0, 1.0) and not m.item.movable
    # the next window marked verified too: one merged region
    session.step_windows(1)
    session.add_review("verified")
    assert len(tl.marks) == 1
    assert tl.marks[0].item.getRegion() == pytest.approx((rel(session, w.t0_us), rel(session, w.t1_us) + 0.01))
    # rejected and an object-specific flag: distinct colours, the object's mark is a thin lane
    session.add_review("rejected", w.t0_us + 200_000, w.t0_us + 250_000)
    session.add_review("flagged", w.t0_us + 300_000, w.t0_us + 320_000, obj="cylinder")
    by_status = {m.status: m for m in tl.marks}
    assert by_status["rejected"].item.brush.color().getRgb()[:3] == STATUS_COLORS["rejected"]
    flag = by_status["flagged"]
    assert flag.object == "cylinder" and flag.item.brush.color().getRgb()[:3] == STATUS_COLORS["flagged"]
    lo, hi = flag.item.span
    assert 0 < hi - lo <= 0.1 and hi < 1.0  # second lane from the top (cylinder is object #1)
    session.history.undo()
    assert {m.status for m in tl.marks} == {"verified", "rejected"}


def test_offset_correction_shifts_the_speed_curve(tl, session, qtbot):
    rate0 = tl.rate_item.yData.copy()
    speed0 = tl.speed_item.yData.copy()
    ang0 = tl.angular_item.yData.copy()
    session.set_offset_correction_us(50_000)
    qtbot.waitUntil(lambda: not np.array_equal(tl.speed_item.yData, speed0, equal_nan=True), timeout=2000)
    speed1, ang1 = tl.speed_item.yData, tl.angular_item.yData
    n = 50  # 50 ms at 1 ms bins: speed(t) now shows the motion of t + 50 ms
    assert np.array_equal(speed1[:-n], speed0[n:], equal_nan=True)
    assert np.array_equal(ang1[:-n], ang0[n:], equal_nan=True)
    assert np.isfinite(speed1[:-n]).sum() > 0.5 * len(speed1)
    np.testing.assert_array_equal(tl.rate_item.yData, rate0)  # the event rate does not move
    # an object nudge changes the document but not the clock: no recomputation
    data = tl.data
    session.nudge_object("box", "camera", trans_mm=(1, 0, 0))
    qtbot.wait(300)
    assert tl.data is data


# ---------------------------------------------------------------------- input -> model
def test_click_on_the_plot_scrubs(tl, session, qtbot):
    t0 = session.time_range[0]
    for x in (0.55, 0.123):
        with qtbot.waitSignal(tl.scrubbed, timeout=1000) as blocker:
            qtbot.mouseClick(tl.glw.viewport(), LEFT, pos=viewport_pos(tl, tl.vb, x))
        assert abs(session.view.t_us - (t0 + round(x * 1e6))) <= 1000  # within one bin
        assert blocker.args == [session.view.t_us]
    # a click over a review mark still scrubs (marks are not mouse targets)
    session.add_review("rejected", t0 + 600_000, t0 + 700_000)
    qtbot.mouseClick(tl.glw.viewport(), LEFT, pos=viewport_pos(tl, tl.vb, 0.65))
    assert abs(session.view.t_us - (t0 + 650_000)) <= 1000
    # the score row scrubs too
    tl.set_scores([0.1, 0.2], {"box": [1.0, 2.0]})
    qtbot.waitExposed(tl.score_glw)
    qtbot.mouseClick(tl.score_glw.viewport(), LEFT, pos=viewport_pos(tl, tl.score_vb, 0.3))
    assert abs(session.view.t_us - (t0 + 300_000)) <= 1000


def test_drag_scrubs_throttled(tl, session, qtbot):
    t0 = session.time_range[0]
    updates = []
    session.changed.connect(lambda change: change.kind == "time" and updates.append(session.view.t_us))
    xs = np.linspace(0.1, 0.7, 150)
    start = time.monotonic()
    drag(qtbot, tl.glw.viewport(), [lambda x=x: viewport_pos(tl, tl.vb, x) for x in xs])
    elapsed = time.monotonic() - start
    assert abs(session.view.t_us - (t0 + 700_000)) <= 1000
    # leading + trailing throttle: at most one set_time per interval (+ press and release)
    assert 2 <= len(updates) <= elapsed / (SCRUB_INTERVAL_MS * 1e-3) + 3, "set_time must be throttled"
    assert len(updates) < len(xs)
    assert all(np.diff(updates) > 0)
    assert tl.cursor.value() == pytest.approx(rel(session, session.view.t_us))


def test_drag_the_cursor_line(tl, session, qtbot):
    t0 = session.time_range[0]
    session.set_time(t0 + 200_000)
    pts = [lambda x=x: viewport_pos(tl, tl.vb, x, 0.3) for x in np.linspace(0.2, 0.45, 20)]
    with qtbot.waitSignal(tl.scrubbed, timeout=1000):
        drag(qtbot, tl.glw.viewport(), pts)
    qtbot.wait(2 * 33)
    assert abs(session.view.t_us - (t0 + 450_000)) <= 1000
    assert tl.cursor.value() == pytest.approx(rel(session, session.view.t_us))


def test_step_buttons(tl, session, qtbot):
    t = session.view.t_us
    with qtbot.waitSignal(tl.scrubbed) as blocker:
        qtbot.mouseClick(tl.forward_button, LEFT)
    assert session.view.t_us == t + session.view.window_us and blocker.args == [t + session.view.window_us]
    qtbot.mouseClick(tl.back_button, LEFT)
    qtbot.mouseClick(tl.back_button, LEFT)
    assert session.view.t_us == t - session.view.window_us


def test_play_with_a_fake_clock(tl, session):
    now = [100.0]
    tl.clock = lambda: now[0]
    t0, t1 = session.time_range
    session.set_time(t0 + 100_000)
    tl.set_speed(0.5)
    assert [tl.speed_combo.itemData(i) for i in range(tl.speed_combo.count())] == [0.1, 0.25, 0.5, 1.0, 2.0]
    tl.play()
    assert tl.is_playing and tl.play_button.isChecked()
    now[0] += 0.1
    tl._tick()
    assert session.view.t_us == t0 + 150_000        # 0.1 s wall time at 0.5x = 50 ms
    tl.set_speed(2.0)
    seen = [session.view.t_us]
    while tl.is_playing and len(seen) < 1000:
        now[0] += 0.016
        tl._tick()
        seen.append(session.view.t_us)
    assert not tl.is_playing and seen[-1] == t1
    assert all(np.diff(seen) > 0)
    assert np.diff(seen)[:-1] == pytest.approx(32_000, abs=1)  # 16 ms at 2x
    with pytest.raises(ValueError):
        tl.set_speed(3.0)


def test_play_in_real_time_stops_at_the_end(tl, session, qtbot):
    t0, t1 = session.time_range
    session.set_time(t1 - 150_000)
    seen = []
    session.changed.connect(lambda change: change.kind == "time" and seen.append(session.view.t_us))
    tl.set_speed(1.0)
    start = time.monotonic()
    with qtbot.waitSignal(tl.playingChanged, timeout=500):
        qtbot.mouseClick(tl.play_button, LEFT)
    qtbot.waitUntil(lambda: not tl.is_playing, timeout=3000)
    elapsed = time.monotonic() - start
    assert elapsed >= 0.14
    assert len(seen) >= 3 and all(np.diff(seen) > 0) and seen[-1] == t1
    # play at the end restarts from the beginning
    tl.play()
    assert session.view.t_us == t0 and tl.is_playing
    tl.pause()
    assert not tl.is_playing and not tl.play_button.isChecked()


def test_space_toggles_play_and_arrows_reach_the_window(qtbot, session):
    win = QtWidgets.QMainWindow()
    qtbot.addWidget(win)
    tl = Timeline(session)
    win.setCentralWidget(tl)
    fired = []
    for key, name in (("Right", "right"), ("Space", "space")):
        act = QtGui.QAction(name, win)
        act.setShortcut(QtGui.QKeySequence(key))
        act.setShortcutContext(QtCore.Qt.WindowShortcut)
        act.triggered.connect(lambda _=False, n=name: fired.append(n))
        win.addAction(act)
    win.resize(900, 260)
    with qtbot.waitActive(win):
        win.show()
        win.activateWindow()
    # clicking the plot focuses the timeline itself, not a child that would eat keys
    qtbot.mouseClick(tl.glw.viewport(), LEFT, pos=viewport_pos(tl, tl.vb, 0.4))
    assert QtWidgets.QApplication.focusWidget() is tl
    qtbot.keyClick(QtWidgets.QApplication.focusWidget(), QtCore.Qt.Key_Right)
    assert fired == ["right"]
    qtbot.keyClick(tl, QtCore.Qt.Key_Space)
    assert tl.is_playing and fired == ["right"]
    qtbot.keyClick(tl, QtCore.Qt.Key_Space)
    assert not tl.is_playing
    tl.stop()


# ---------------------------------------------------------------------- scores
def test_scores_curves_and_worst_window(tl, session, qtbot):
    t0 = session.time_range[0]
    t_s = 0.005 + 0.01 * np.arange(80)
    rng = np.random.default_rng(1)
    scores = {n: rng.uniform(0.5, 2.0, 80) for n in session.object_names}
    scores["box"][[10, 11, 12]] = np.nan
    scores["box"][42] = 0.01                 # worst: lowest score (evpose.core.align.score: 1 = on the edges, 0 = noise)
    scores["cylinder"][:] = np.nan           # undefined everywhere
    scores["flatbox"][7] = 9.0               # best: irrelevant
    scores["flatbox"][63] = 0.02
    assert not tl.score_glw.isVisible()
    tl.set_scores(t_s, scores, label="alignment score")
    assert tl.score_glw.isVisible() and tl.scores_check.isChecked()
    assert set(tl.score_items) == set(session.object_names)
    for name, item in tl.score_items.items():
        np.testing.assert_array_equal(item.xData, t_s)
        np.testing.assert_array_equal(item.yData, scores[name])
        assert item.opts["pen"].color().getRgb()[:3] == session.color(name)
    assert tl.worst_time("box") == t0 + 425_000
    assert tl.worst_time("flatbox") == t0 + 635_000
    assert tl.worst_time("cylinder") is None
    with pytest.raises(KeyError):
        tl.worst_time("nope")
    # through the menu: moves there and tells the app
    act = next(a for a in tl.worst_menu.actions() if a.text().startswith("box:"))
    assert act.text() == f"box: {scores['box'][42]:.3g} at {t_s[42]:.3f} s"      # the value and where
    with qtbot.waitSignal(tl.worstRequested) as req, qtbot.waitSignal(tl.scrubbed):
        act.trigger()
    assert req.args == ["box"] and session.view.t_us == t0 + 425_000
    assert tl.goto_worst("cylinder") is None
    # a distance (lower is better): the worst window is the maximum
    tl.set_scores(t_s, scores, lower_is_better=True, label="edge distance (px)")
    assert tl.worst_time("flatbox") == t0 + 75_000
    # selection thickens the object's curve; the row can be hidden
    session.select("flatbox")
    assert tl.score_items["flatbox"].opts["pen"].widthF() > tl.score_items["box"].opts["pen"].widthF()
    tl.scores_check.setChecked(False)
    assert not tl.score_glw.isVisible()
    with pytest.raises(ValueError):
        tl.set_scores(t_s, {"box": np.ones(3)})
    tl.clear_scores()
    assert tl.score_items == {} and not tl.worst_button.isEnabled()


def test_low_evidence_windows_are_drawn_apart_and_never_the_worst(tl, session, qtbot):
    from evpose.widgets.timeline.style import LOW_EVIDENCE_COLOR

    t0 = session.time_range[0]
    t_s = 0.005 + 0.01 * np.arange(80)
    rng = np.random.default_rng(2)
    scores = {n: rng.uniform(0.3, 0.9, 80) for n in session.object_names}
    low = {n: np.zeros(80, bool) for n in session.object_names}
    scores["box"][42] = -0.5                 # the raw minimum, but a stationary window with ~100 events ...
    low["box"][42] = True                    # ... low evidence
    scores["box"][63] = 0.05                 # the worst window with evidence
    for n in session.object_names:           # a dwell: no object has evidence in windows 20-29
        low[n][20:30] = True
        scores[n][20:30] = 0.0
    low["flatbox"][:] = True                 # never any evidence
    tl.set_scores(t_s, scores, low_evidence=low)
    assert tl.worst_time("box") == t0 + 635_000
    assert tl.worst_time("flatbox") is None
    act = {a.text().split(" ")[0].rstrip(":"): a for a in tl.worst_menu.actions()}
    assert act["box"].isEnabled() and act["box"].text() == f"box: {scores['box'][63]:.3g} at {t_s[63]:.3f} s"
    assert not act["flatbox"].isEnabled() and "no window with enough evidence" in act["flatbox"].text()
    with qtbot.waitSignal(tl.worstRequested):
        act["box"].trigger()
    assert session.view.t_us == t0 + 635_000
    assert tl.goto_worst("flatbox") is None
    # not on the object's curve (a gap there), but grey rings at their scores
    y = tl.score_items["box"].yData
    assert np.isnan(y[42]) and np.isnan(y[20:30]).all() and y[63] == scores["box"][63]
    assert np.isnan(tl.score_items["flatbox"].yData).all()
    xs, ys = tl.score_row.low_item.getData()
    assert (t_s[42], -0.5) in set(zip(xs.tolist(), ys.tolist()))
    assert len(xs) == 1 + 3 * 10 + (80 - 10)
    assert tl.score_row.low_item.opts["pen"].color().getRgb()[:3] == LOW_EVIDENCE_COLOR
    # where no object has evidence: one hatched band over the run, half-way to the neighbouring windows
    bands = tl.score_row.low_bands
    assert len(bands) == 1 and bands[0].getRegion() == pytest.approx((0.2, 0.3))
    assert bands[0].brush.style() == QtCore.Qt.BDiagPattern
    # the tables have evidence everywhere again: no grey left
    tl.set_scores(t_s, scores)
    assert tl.score_row.low_bands == [] and len(tl.score_row.low_item.getData()[0]) == 0
    assert tl.worst_time("box") == t0 + 425_000
    with pytest.raises(ValueError):
        tl.set_scores(t_s, scores, low_evidence={"box": np.ones(3, bool)})


def test_a_stale_score_row_is_dimmed_with_a_label(tl, session, qtbot):
    from evpose.widgets.timeline.evidence import STALE_ALPHA

    t_s = 0.005 + 0.01 * np.arange(80)
    tl.set_scores_stale(True)
    assert not tl.scores_stale                        # nothing shown: nothing stale
    scores = {n: np.linspace(0.2, 0.8, 80) for n in session.object_names}
    tl.set_scores(t_s, scores)
    label = tl.score_row.stale_label
    assert not tl.scores_stale and not label.item.isVisible()
    assert all(i.opts["pen"].color().alpha() == 255 for i in tl.score_items.values())
    tl.set_scores_stale(True)
    assert tl.scores_stale and label.item.isVisible() and label.text == "stale — recomputing"
    assert all(i.opts["pen"].color().alpha() == STALE_ALPHA for i in tl.score_items.values())
    session.select("box")                             # restyling keeps it dimmed
    assert tl.score_items["box"].opts["pen"].color().alpha() == STALE_ALPHA

    def label_pixels() -> int:
        """Pixels of the label's colour (dark orange, (150, 60, 0)) in the row's top strip."""
        qtbot.wait(20)
        img = tl.score_glw.grab().toImage()
        rgb = np.array([[img.pixelColor(x, y).getRgb()[:3] for x in range(0, img.width())]
                        for y in range(0, min(img.height(), 30))], np.int32)
        return int((np.abs(rgb - (150, 60, 0)).max(axis=-1) <= 20).sum())

    drawn = label_pixels()                            # the label is drawn ...
    label.item.setVisible(False)
    assert drawn > 20 + label_pixels()                # ... (its pixels, not a curve's)
    label.item.setVisible(True)
    tl.set_scores(t_s, scores)                        # fresh scores: fresh row
    assert not tl.scores_stale and not label.item.isVisible()
    assert all(i.opts["pen"].color().alpha() == 255 for i in tl.score_items.values())


# ---------------------------------------------------------------------- scale and looks
def test_a_million_bins_are_downsampled_and_clipped_to_the_view(tl, session, qtbot):
    """A 1000 s recording: the curves drawn are downsampled (whole view) and clipped (zoomed in), which is what keeps
    set + draw and a drag fast (times printed, not asserted: timings belong to bench/, bench_scrub)."""
    n = 1_000_000  # 1000 s at 1 ms
    t_s = (np.arange(n) + 0.5) * 1e-3
    rng = np.random.default_rng(0)
    data = TimelineData(session.time_range[0], t_s, rng.uniform(0, 1e6, n), np.abs(np.sin(t_s)),
                        np.abs(np.cos(t_s)) * 90, np.ones(n, bool))
    start = time.perf_counter()
    tl.set_data(data)
    tl.fit()
    tl.grab()
    t_draw = time.perf_counter() - start
    shown = len(tl.rate_item.getData()[0])
    assert shown < 20_000, f"{shown} points drawn: downsampling/clipping is off"
    start = time.perf_counter()
    for x in np.linspace(0.0, 0.8, 200):  # a drag: cursor moves every event, the session is throttled
        tl.request_time(tl.t_of(x), immediate=False)
        QtWidgets.QApplication.processEvents()
    t_drag = time.perf_counter() - start
    tl.vb.setXRange(100, 101, padding=0)  # zoom in: clipped to the view, full resolution
    QtWidgets.QApplication.processEvents()
    assert len(tl.rate_item.getData()[0]) < 5_000
    print(f"1e6 bins: set+draw {t_draw * 1e3:.0f} ms, 200 drag steps {t_drag * 1e3:.0f} ms")


def test_screenshot(tl, session, qtbot):
    t0 = session.time_range[0]
    session.add_review("verified", t0 + 100_000, t0 + 200_000)
    session.add_review("rejected", t0 + 450_000, t0 + 500_000)
    session.add_review("flagged", t0 + 600_000, t0 + 650_000, obj="box")
    t_s = 0.005 + 0.01 * np.arange(80)
    rng = np.random.default_rng(0)
    tl.set_scores(t_s, {n: np.clip(rng.normal(0.8 - 0.2 * k, 0.1, 80), -1, 1)
                        for k, n in enumerate(session.object_names)}, label="score")
    tl.resize(1100, 240)
    qtbot.wait(50)
    img = tl.grab().toImage()
    assert img.save("/tmp/timeline.png")
    rgb = np.array([[img.pixelColor(x, y).getRgb()[:3] for x in range(0, img.width(), 3)]
                    for y in range(0, img.height(), 3)])
    # the verified band (light green over white) is drawn
    assert ((rgb[..., 1] > rgb[..., 0] + 20) & (rgb[..., 1] > rgb[..., 2] + 20)).any()
