"""The model-error floors of the standard errors (core/align/uncertainty.py, tracker issue 23.2): combined in
quadrature, None and infinity kept, every floor set (a measured value, positive), and the event-rate stage's printed
sigma is its data-only sigma with the floor."""
import math

import pytest

from evpose.core.align import uncertainty as U
from evpose.core.align.uncertainty import with_floor


def test_the_floor_adds_in_quadrature_and_keeps_none_and_infinity():
    assert with_floor(30.0, 40.0) == pytest.approx(50.0)
    assert with_floor(0.0, 125.0) == pytest.approx(125.0)
    assert with_floor(None, 125.0) is None                      # no estimate stays no estimate
    assert with_floor(math.inf, 125.0) == math.inf              # not pinned stays not pinned
    assert with_floor(7.0, 0.0) == pytest.approx(7.0)


def test_every_floor_is_set():
    floors = {k: getattr(U, k) for k in U.__all__ if k.endswith(("_US", "_PPM", "_MM", "_DEG"))}
    assert len(floors) == 7 and all(v > 0 for v in floors.values()), floors


def test_the_rate_stage_prints_its_sigma_with_the_floor(tmp_path, monkeypatch):
    from evpose.core.align.estimate import sync_scene
    from tests.core.test_sync import _Open, make_rate_scene

    folder, truth = make_rate_scene(tmp_path / "s", 4.0, 12_000, 0.0, seed=5)
    floor = U.RATE_OFFSET_FLOOR_US
    with _Open(folder) as scene:
        res = sync_scene(scene, kind="speed")
        monkeypatch.setattr(U, "RATE_OFFSET_FLOOR_US", 20_000.0)
        wide = sync_scene(scene, kind="speed")
    assert res.reliable and res.offset_std_data_us < floor
    assert res.offset_std_us == pytest.approx(math.hypot(res.offset_std_data_us, floor))
    assert wide.offset_std_us == pytest.approx(math.hypot(wide.offset_std_data_us, 20_000.0))
    assert res.to_json()["offset_std_data_us"] == pytest.approx(res.offset_std_data_us)
