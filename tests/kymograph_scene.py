"""A synthetic scene for the kymograph and the space-time band (a uniquely named module, like occlusion_scene.py):
three objects, the camera translating (trajectory A) at 2 m/s so that edges sweep the half-resolution image at
about 0.5 px/ms, a clock offset of 20 ms injected and no pose error, so that a clock error is the only thing
that moves the projected edges off the events. Built once per test session (about 4 s)."""
from __future__ import annotations

import json
from pathlib import Path

from evpose_testing import half_davis_camera

#: The injected clock offset (µs): the true clock is a correction of this much (the prior is 0).
TRUE_OFFSET_US = 20_000
KYMO_SCENE = dict(objects=("box", "cylinder", "flatbox"), trajectory="A", speed_mps=2.0, duration_s=1.0,
                  offset_us=TRUE_OFFSET_US, skew_ppm=0.0, pose_error_mm=0.0, pose_error_deg=0.0, seed=3)
#: Half-span of the kymograph plus its largest lag (ms): the chosen time keeps this far from the recording's ends.
MARGIN_US = 180_000

_BUILT: dict = {}


def kymograph_scene(tmp_path_factory) -> Path:
    """The scene folder (built on first use in this test session; never modify it)."""
    if "path" not in _BUILT:
        from evpose.core.sim.synth import generate
        from evpose.core.sim.synth_config import SynthConfig

        out = tmp_path_factory.mktemp("kymograph") / "scene"
        generate(out, SynthConfig(**KYMO_SCENE, camera=half_davis_camera()))
        _BUILT["path"] = out
    return _BUILT["path"]


def moving_time_us(scene_dir: Path, t_first_us: int, t_last_us: int) -> int:
    """The event-clock time in the middle of the longest camera move that keeps ``MARGIN_US`` from both ends."""
    gt = json.loads((Path(scene_dir) / "ground_truth.json").read_text())
    off = int(gt["clock"]["offset_us"])
    best = None
    for a, b in gt["moving_segments_pose_us"]:
        mid = (a + b) // 2 - off            # pose clock -> event clock
        if t_first_us + MARGIN_US <= mid <= t_last_us - MARGIN_US and (best is None or b - a > best[0]):
            best = (b - a, mid)
    assert best is not None, "no camera move far enough from the recording's ends"
    return int(best[1])


def moving_session(tmp_path_factory):
    """A :class:`~evpose.core.session.model.Session` on :func:`kymograph_scene`, at a time the object moves (close it)."""
    from evpose.core.session.model import Session

    path = kymograph_scene(tmp_path_factory)
    s = Session.open(path)
    s.set_time(moving_time_us(path, *s.time_range))
    return s
