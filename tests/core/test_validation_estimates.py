"""Issue 23 on small scenes of the validation generator (core/sim_validation: open3d ray casting through the
distorted lens, smooth shading, solid textures the meshes do not carry, level-crossing events with threshold spread,
leak and shot noise, robot poses at 100/250 Hz with jitter; no code shared with ``evpose synth`` or the
estimators), run as ``evpose sync --edges`` runs them (``bench/accuracy_validation.evaluate``, the row of the
validation benchmark): the reported sigma covers the truth, the joint fit on textured objects with clutter never
ends worse than its start, the skew is estimated on a long enough scene and said "not pinned" with a sigma that
covers it on a short one, a camera-mounting error is not turned into a clock error (nor stored as one by
``--apply``), and the kymograph says "too weak" in a window without motion."""
from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest

pytest.importorskip("open3d", reason="the validation generator casts rays with open3d")

BENCH = Path(__file__).resolve().parents[2] / "bench"

#: The scenes (half-resolution DAVIS346 lens; the procedural objects, textured by the generator).
SCENES = {
    # 3 textured objects and 2 distractors at 1 m/s, a clock 20 ms and 80 ppm off, every pose 4 mm / 2 deg off
    "textured": dict(objects=("box", "cylinder", "flatbox"), speed_mps=1.0, duration_s=3.0, seed=11,
                     offset_us=20_000, skew_ppm=80.0, pose_error_mm=4.0, pose_error_deg=2.0, clutter=2),
    # 12 s at 0.5 m/s, 60 ppm: 0.7 ms of drift over the recording, every pose 3 mm / 2 deg off
    "long": dict(objects=("box", "cylinder", "flatbox"), speed_mps=0.5, duration_s=12.0, seed=23, offset_us=-45_000,
                 skew_ppm=60.0, pose_error_mm=3.0, pose_error_deg=2.0),
    # a right clock and right poses, the camera mounted 3 mm / 0.8 deg off
    "mounted": dict(objects=("box", "cylinder", "flatbox"), speed_mps=0.5, duration_s=3.0, seed=31,
                    hand_eye_error_mm=3.0, hand_eye_error_deg=0.8),
}
_BUILT: dict[str, Path] = {}


@pytest.fixture(scope="module")
def validation_scene(tmp_path_factory):
    def build(name: str) -> Path:
        if name not in _BUILT:
            from evpose_testing import half_davis_camera

            from evpose.core.sim_validation.assemble import generate
            from evpose.core.sim_validation.config import ValidationConfig

            out = tmp_path_factory.mktemp("validation") / name
            generate(out, ValidationConfig(mesh_dir=None, camera=half_davis_camera(), max_px_per_frame=1.0,
                                           **SCENES[name]))
            _BUILT[name] = out
        return _BUILT[name]
    return build


@pytest.fixture(scope="module")
def evaluate():
    sys.path.insert(0, str(BENCH))
    try:
        import accuracy_validation
    finally:
        sys.path.remove(str(BENCH))
    return accuracy_validation.evaluate


_ROWS: dict[str, dict] = {}


def _row(name, validation_scene, evaluate) -> dict:
    if name not in _ROWS:
        _ROWS[name] = evaluate(validation_scene(name))
        print(json.dumps(_ROWS[name], indent=1, default=str))
    return _ROWS[name]


def test_textured_scene_sigma_covers_the_truth_and_the_fit_ends_better_than_its_start(validation_scene, evaluate,
                                                                                      models_dir):
    # (models_dir: its clutter draws from E-POSE's meshes; without them the generator makes another scene, on which
    # these bounds were never set -- a fresh clone without ../shared failed here by 4.1 sigma for 4)
    row = _row("textured", validation_scene, evaluate)
    rate, joint = row["rate"], row["joint"]
    assert rate["ok"] and rate["r"] <= 4, rate
    assert joint["ok"], joint["reason"]                      # accepted: the objective rose, held-out windows agree
    assert abs(joint["err_us"]) <= 200 and joint["r"] <= 4, joint
    assert abs(joint["err_us"]) < abs(rate["err_us"])
    # 3 s do not pin 80 ppm: said so, with a sigma that covers the skew it kept
    assert "skew_err_ppm" not in joint and joint["r_skew_unpinned"] <= 2, joint
    for name, o in row["objects"].items():                   # every pose better than its start, within 4 sigma
        assert "held" not in o, (name, o)
        # (the stand-in cylinder's position: 3.3 sigma until 2026-11-29, 4.1 once the fine widths left out the
        # density-step term, 3.97 with the floors set again on the calibration family)
        assert o["mm"] < 0.5 * o["start_mm"] and o["r_mm"] <= 4, (name, o)
        if name != "cylinder":                               # its tilt: the next test
            assert o["deg"] < 0.5 * o["start_deg"] and o["r_deg"] <= 4, (name, o)


def test_the_tilt_of_the_cylinder_is_fitted_or_its_sigma_covers_it(validation_scene, evaluate, models_dir):
    # (open until 2026-11-29 -- 4.3 sigma -- the tilt still stays at its start, 1.35 -> 1.36 deg, but a width now
    # ends at its best state and the sigma, 0.42 deg, covers it: 3.3 sigma)
    o = _row("textured", validation_scene, evaluate)["objects"]["cylinder"]
    assert o["deg"] < 0.5 * o["start_deg"] or o["r_deg"] <= 4, o


def test_the_skew_is_estimated_on_a_long_scene(validation_scene, evaluate):
    row = _row("long", validation_scene, evaluate)
    joint = row["joint"]
    assert joint["ok"], joint["reason"]
    assert "skew_err_ppm" in joint, joint                    # pinned: estimated, not kept
    assert joint["r_skew"] <= 4, joint
    assert abs(joint["err_us"]) <= 200 and joint["r"] <= 4, joint


@pytest.mark.xfail(strict=True, reason="open: since the fine widths leave out the kernel's density-step term "
                                       "(JointParams.step_min_sigma_px, chosen on the main generator's campaigns), "
                                       "the long scene's skew is 26.6 ppm off (sigma ~20 with the floors set again: "
                                       "1.3 sigma; with the term at every width 3.8 ppm): the textured objects' density step carried timing "
                                       "information the ridge alone does not")
def test_the_skew_of_a_long_scene_is_within_10_ppm(validation_scene, evaluate):
    joint = _row("long", validation_scene, evaluate)["joint"]
    assert abs(joint["skew_err_ppm"]) <= 10, joint


def test_a_mounting_error_is_not_made_a_clock_error(validation_scene, evaluate, tmp_path):
    folder = validation_scene("mounted")
    row = _row("mounted", validation_scene, evaluate)
    assert row["rate"]["r"] <= 4, row["rate"]
    assert row["mounting_found"], row
    he = row["hand_eye"]
    assert he["r_mm"] <= 4 and he["r_deg"] <= 4 and he["mm"] < 1.5, he
    assert row["joint"]["ok"] and row["joint"]["r"] <= 4 and abs(row["joint"]["err_us"]) <= 200, row["joint"]
    # `sync --edges --apply` keeps the right clock (it stores an estimate only beyond its sigma of the clock in effect)
    from evpose.app.cli.main import main
    from evpose.core.data.scene import Scene

    copy = tmp_path / "scene"
    shutil.copytree(folder, copy)
    assert main(["sync", str(copy), "--edges", "--apply", "--json", "-q"]) == 0
    with Scene.open(copy) as scene:
        assert abs(scene.clock.offset_us) <= 200, scene.clock.offset_us
        assert scene.corrections.object_deltas == {}


def test_the_kymograph_is_too_weak_to_read_in_a_pause(validation_scene):
    from kymograph_scene import still_time_us

    from evpose.core.views import kymograph_confidence as conf
    from evpose.core.views.kymograph import KymographComputer, KymographRequest
    from evpose.core.session.model import Session

    folder = validation_scene("textured")
    gt = json.loads((folder / "ground_truth.json").read_text())
    s = Session.open(folder)
    try:
        kc = KymographComputer()
        for correction_us in (gt["clock"]["offset_us"], 0):        # at the true clock and at the scene's wrong one
            s.set_offset_correction_us(correction_us)
            s.set_time(still_time_us(folder, *s.time_range))
            d = kc.kymograph(KymographRequest(s.request(), None))
            assert d.lag_ms is None and d.lag.weak == conf.NO_MOTION, d.lag
    finally:
        s.close()
