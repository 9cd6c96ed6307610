"""The kymograph view (issue 16, point 1; issue 23, part 8): on a synthetic scene with a known clock, the view's
measured shift is ~0 at the true clock and the clock error when the clock is 20 ms wrong, with its 1σ (asserted on
the numbers the widget holds and shows), "too weak to read" and why where the data says so, its tracks and image
are the data's, and a drag on its frame preview draws the line."""
from __future__ import annotations

import re

import numpy as np
import pytest
from kymograph_scene import TRUE_OFFSET_US, kymograph_scene, moving_session, still_time_us
from PySide6 import QtCore

from evpose.core.views import kymograph_confidence as conf
from evpose.core.views.kymograph import KymographComputer, KymographRequest


@pytest.fixture
def kymo_session(tmp_path_factory):
    s = moving_session(tmp_path_factory)
    yield s
    s.close()


@pytest.fixture
def view(qtbot, kymo_session):
    from evpose.widgets.kymograph.view import KymographView

    w = KymographView(kymo_session)
    qtbot.addWidget(w)
    w.resize(900, 420)
    w.show()
    qtbot.waitExposed(w)
    yield w
    w.close()


def shown_lag(view) -> tuple[float, float]:
    """The lag and its 1σ the readout prints (ms)."""
    m = re.search(r"events vs track: ([+-]\d+\.\d) \u00b1 (\d+\.\d) ms", view.readout.text())
    assert m, view.readout.text()
    return float(m.group(1)), float(m.group(2))


def compute(session, kc, correction_us, line):
    session.set_offset_correction_us(correction_us)
    return kc.kymograph(KymographRequest(session.request(), line, session.view.kymograph_span_us))


def test_shift_is_none_at_the_true_clock_and_the_offset_when_20ms_wrong(qtbot, view, kymo_session):
    kc = KymographComputer()
    view.set_data(compute(kymo_session, kc, TRUE_OFFSET_US, view.line))   # the default line
    line = view.line
    assert line is not None, "the default line is kept once shown"
    true_shift = view.shift_ms
    assert true_shift is not None and abs(true_shift) <= 2.0, true_shift
    assert abs(shown_lag(view)[0]) <= 2.0
    for error_us in (-20_000, 20_000):
        view.set_data(compute(kymo_session, kc, TRUE_OFFSET_US + error_us, view.line))
        assert view.line == line
        assert view.shift_ms == pytest.approx(error_us / 1e3, abs=2.5), (error_us, view.shift_ms)
        assert shown_lag(view) == pytest.approx((view.shift_ms, view.shift_sigma_ms), abs=0.051)
        assert abs(view.shift_ms - error_us / 1e3) <= 2 * view.shift_sigma_ms
        assert f"clock offset {-view.shift_ms:+.1f} ms" in view.readout.text()
        assert abs(view.shift_ms - true_shift) >= 17.0          # a measurable shift against the true clock
    # what is drawn is the data: the image, each object's track in its colour, the dashed track moved by its lag
    d = view.data
    assert view.image_item.image.shape == d.image_rgb.shape
    rect = view.image_item.mapRectToParent(view.image_item.boundingRect())
    assert rect.top() == pytest.approx(d.t_first_ms) and rect.height() == pytest.approx(d.image_rgb.shape[0])
    for tr in d.tracks:
        x, y = view.track_items[tr.name].getData()
        assert np.allclose(x, tr.segments[:, :, 0].ravel()) and np.allclose(y, tr.segments[:, :, 1].ravel())
        assert view.track_items[tr.name].opts["pen"].color().getRgb()[:3] == tr.color
        if tr.lag.lag_ms is not None:
            xf, yf = view.fit_items[tr.name].getData()
            assert np.allclose(yf, tr.segments[:, :, 1].ravel() + tr.lag.lag_ms)


def test_a_drag_on_the_frame_draws_the_line(qtbot, view, kymo_session):
    kc = KymographComputer()
    view.set_data(compute(kymo_session, kc, TRUE_OFFSET_US, None))
    qtbot.wait(50)
    vb, gv = view.preview.vb, view.preview

    def to_widget(u, v):
        return gv.mapFromScene(vb.mapViewToScene(QtCore.QPointF(u, v)))

    lines = []
    view.lineChanged.connect(lambda: lines.append(view.line))
    a, b = to_widget(30.0, 60.0), to_widget(120.0, 70.0)
    qtbot.mousePress(gv.viewport(), QtCore.Qt.LeftButton, pos=a)
    for f in (0.3, 0.6, 1.0):
        qtbot.mouseMove(gv.viewport(), QtCore.QPoint(int(a.x() + f * (b.x() - a.x())), int(a.y() + f * (b.y() - a.y()))))
    qtbot.mouseRelease(gv.viewport(), QtCore.Qt.LeftButton, pos=b)
    assert lines, "no line was drawn"
    u0, v0, u1, v1 = view.line
    assert (u0, v0) == pytest.approx((30.0, 60.0), abs=2.0) and (u1, v1) == pytest.approx((120.0, 70.0), abs=2.0)
    x, y = view.preview.line_item.getData()
    assert np.allclose([x[0], y[0], x[-1], y[-1]], view.line)
    d = compute(kymo_session, kc, TRUE_OFFSET_US, view.line)        # what the owner computes for it
    view.set_data(d)
    assert not d.auto_line and d.line.as_tuple() == pytest.approx(view.line)
    assert view.data.image_rgb.shape[1] == int(np.floor(d.line.length + 0.5)) + 1
    n = len(lines)
    view.reset_line()                                                 # back to the default line
    assert view.line is None and len(lines) == n + 1 and lines[-1] is None


def test_span_spin_writes_the_view_state_and_follows_it(qtbot, view, kymo_session):
    view.span_spin.setValue(300)
    assert kymo_session.view.kymograph_span_us == 300_000
    kymo_session.set_view_option(kymograph_span_us=150_000)
    assert view.span_spin.value() == 150
    d = KymographComputer().kymograph(KymographRequest(kymo_session.request(), None, 150_000))
    view.set_data(d)
    assert d.image_rgb.shape[0] == 150 and d.t_first_ms == pytest.approx(-75.0)


def test_too_weak_readouts_say_why(qtbot, view, kymo_session, tmp_path_factory):
    """A line far from every object, and the default line while the camera pauses: no lag, no dashed track, and
    the readout says "too weak to read" and why."""
    d = KymographComputer().kymograph(KymographRequest(kymo_session.request(), (2.0, 2.0, 12.0, 2.0)))
    view.set_data(d)
    assert view.shift_ms is None and view.readout.text() == f"events vs track: too weak to read\n{conf.NO_TRACK}"
    kymo_session.set_time(still_time_us(kymograph_scene(tmp_path_factory), *kymo_session.time_range))
    d = compute(kymo_session, KymographComputer(), TRUE_OFFSET_US, None)
    view.set_data(d)
    assert d.tracks and view.shift_ms is None and view.shift_sigma_ms is None
    assert view.readout.text() == f"events vs track: too weak to read\n{conf.NO_MOTION}"
    assert all(np.size(view.fit_items[tr.name].getData()[0]) == 0 for tr in d.tracks)


def test_drawing_a_line_asks_for_one_kymograph_on_release(view):
    """While the line is dragged only the preview follows; the owner computes once the mouse is released."""
    asked = []
    view.lineChanged.connect(lambda: asked.append(view.line))
    for x in (40.0, 50.0, 60.0):
        view.preview._drag((10.0, 20.0, x, 80.0), False)
    assert asked == []
    view.preview._drag((10.0, 20.0, 70.0, 80.0), True)
    assert len(asked) == 1 and view.line == pytest.approx((10.0, 20.0, 70.0, 80.0))
