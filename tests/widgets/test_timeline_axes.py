"""The timeline's axes (issue 16 point 7): a spike in the angular speed does not compress the axis, the score
legend stands above the scores, and scores above 1 stay in view."""
import numpy as np
import pytest

from evpose.core.views.timeline import TimelineData
from evpose.widgets.timeline.view import Timeline
from evpose.widgets.timeline.plot import robust_range


@pytest.fixture
def tl(qtbot, session):
    w = Timeline(session)
    qtbot.addWidget(w)
    w.resize(1000, 300)
    w.show()
    qtbot.waitExposed(w)
    yield w
    w.stop()


def _data(session, angular, speed):
    n = len(angular)
    t_s = np.arange(n) * 1e-3
    return TimelineData(session.time_range[0], t_s, np.full(n, 1e5), np.asarray(speed, float),
                        np.asarray(angular, float), np.ones(n, bool))


def test_an_angular_speed_spike_does_not_compress_the_axis(tl, session, qtbot):
    t = np.arange(4000) * 1e-3
    angular = 80 + 60 * np.sin(2 * np.pi * t)              # 20..140 °/s motion
    angular[2000:2004] = 1300.0                             # a glitch of the trajectory: 4 ms at 1300 °/s
    speed = 0.3 + 0.2 * np.sin(2 * np.pi * t)
    speed[3000] = 25.0
    tl.set_data(_data(session, angular, speed))
    lo, hi = tl.angular_vb.viewRange()[1]
    assert lo <= 0 and 140 <= hi < 250, (lo, hi)           # the motion fills the axis: not squashed under 1300
    shown = tl.angular_item.yData                           # the data given to the curve (before downsampling)
    assert np.nanmax(shown) <= hi and shown[2001] == pytest.approx(np.nanmax(shown))   # the spike, cut at the top
    assert "spikes above" in tl.angular_axis.toolTip()
    s_lo, s_hi = tl.speed_vb.viewRange()[1]
    assert 0.5 <= s_hi < 1.0
    # without a spike nothing is cut and the axis reaches the maximum
    tl.set_data(_data(session, 80 + 60 * np.sin(2 * np.pi * t), 0.3 + 0.2 * np.sin(2 * np.pi * t)))
    lo, hi = tl.angular_vb.viewRange()[1]
    assert 140 <= hi < 150 and tl.angular_axis.toolTip() == ""


def test_robust_range():
    assert robust_range([]) == (0.0, 1.0, False)
    assert robust_range([np.nan, 2.0, 4.0]) == (0.0, 4.0, False)
    v = np.r_[np.full(999, 10.0), 1300.0]
    lo, hi, clipped = robust_range(v)
    assert clipped and lo == 0 and hi == pytest.approx(13.0)
    assert robust_range([-3.0, -1.0])[:2] == (-3.0, -1.0)


def test_the_score_legend_is_above_the_scores_and_values_above_1_stay_in_view(tl, session, qtbot):
    t_s = np.linspace(0, 3, 300)
    names = session.object_names
    scores = {n: 0.5 + 0.3 * np.sin(t_s + i) for i, n in enumerate(names)}
    scores[names[0]][10] = 1.8                               # above 1
    scores[names[1]][20] = -0.4
    tl.set_scores(t_s, scores)
    qtbot.wait(100)
    lo, hi = tl.score_vb.viewRange()[1]
    assert lo < -0.4 and hi > 1.8
    # the legend names every object and lies above the plot's data area, not over it
    legend = tl.score_row.legend
    for n in names:
        assert n in legend.text
    leg = legend.mapRectToScene(legend.boundingRect())
    data = tl.score_vb.sceneBoundingRect()
    assert leg.bottom() <= data.top() + 1 and leg.height() > 5
    # scores in [0, 1]: 0 and 1 are always in view
    tl.set_scores(t_s, {n: 0.2 + 0.1 * np.sin(t_s) for n in names})
    lo, hi = tl.score_vb.viewRange()[1]
    assert lo < 0 and hi > 1
    session.set_object_visible(names[0], False)              # a hidden object's legend entry is faint
    tl.score_row.style()
    assert "#999" in legend.text
