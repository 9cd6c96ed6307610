"""The timeline's curves (evpose.core.views.timeline), without Qt: the rate counts every event once, and the speed
curve moves with the clock in effect (a wrong offset shows as a shift between the two curves)."""
from __future__ import annotations

import numpy as np

from evpose.core.data.scene import Scene
from evpose.core.views.timeline import TIMELINE_BIN_US, timeline_data


def test_the_rate_counts_every_event_once(tiny_scene_dir):
    scene = Scene.open(tiny_scene_dir, corrections=None)
    try:
        d = timeline_data(scene)
        assert np.isclose(d.rate_hz.sum() * TIMELINE_BIN_US * 1e-6, len(scene.events))
        assert np.all(np.diff(d.t_s) > 0) and d.t_ref_us == scene.t_ref_us
        assert d.speed_valid.any() and np.all(d.speed_mps[d.speed_valid] >= 0)
    finally:
        scene.close()


def test_the_speed_curve_follows_the_clock_offset(tiny_scene_dir):
    """With the offset corrected by +20 ms the camera's speed at event time t is the speed it had at t + 20 ms:
    the curve moves 20 bins (the rate curve does not)."""
    scene = Scene.open(tiny_scene_dir, corrections=None)
    try:
        a = timeline_data(scene)
        scene.corrections.offset_us += 20_000
        b = timeline_data(scene)
        assert np.array_equal(a.rate_hz, b.rate_hz)
        k = 20_000 // TIMELINE_BIN_US
        both = a.speed_valid[k:] & b.speed_valid[:-k]
        assert both.sum() > 100
        np.testing.assert_allclose(b.speed_mps[:-k][both], a.speed_mps[k:][both], rtol=1e-6, atol=1e-9)
        assert not np.allclose(a.speed_mps[both.nonzero()[0]], b.speed_mps[both.nonzero()[0]])
    finally:
        scene.close()
