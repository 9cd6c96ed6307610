"""The synthetic scene generator: files, ground truth, injected errors, physical plausibility."""
import json

import numpy as np
import pytest

from evpose.core.data.clock import ClockModel
from evpose.core.data.event_store import EventStore
from evpose.core.data.events import Cancelled
from evpose.core.data.geometry import pose_error, rotation_angle
from evpose.core.data.scene import Scene
from evpose.core.label.annotate import Annotator
from evpose.core.label.labels import Request
from evpose.core.label.windows import time_windows
from evpose.core.sim.motion import make_motion, make_trajectory
from evpose.core.sim.simulate import NOISE_STEP_US, render_times
from evpose.core.sim.synth import generate, load_ground_truth
from evpose.core.sim.synth_config import SynthConfig


def test_scene_files_and_ground_truth(tiny_scene_dir):
    names = {p.name for p in tiny_scene_dir.iterdir()}
    assert {"scene.toml", "events.h5", "trajectory.csv", "ground_truth.json", "models"} <= names
    gt = load_ground_truth(tiny_scene_dir)
    scene = Scene.open(tiny_scene_dir)
    assert scene.manifest.clock_offset_us == 0  # the manifest holds the erroneous prior
    assert gt["clock"]["offset_us"] == 20_000
    assert gt["clock"]["t_ref_us"] == scene.events.t_first_us
    for name, entry in gt["objects"].items():
        dt, dR = pose_error(scene.manifest.object(name).T_base_obj, np.array(entry["T_base_obj"]))
        assert dt * 1e3 == pytest.approx(5.0, abs=1e-6)
        assert np.degrees(dR) == pytest.approx(3.0, abs=1e-6)


def test_event_rate_and_time_order(tiny_scene_dir):
    gt = load_ground_truth(tiny_scene_dir)
    with EventStore(tiny_scene_dir / "events.h5") as ev:
        assert ev.n_events == gt["stats"]["n_events"]
        t = ev.read(0, ev.n_events).t
        assert np.all(np.diff(t) >= 0)
        # half-resolution sensor: a quarter of the DAVIS346 pixels
        assert 2e4 < gt["stats"]["event_rate_hz"] < 2e6


def test_stops_between_segments(tiny_scene_dir):
    scene = Scene.open(tiny_scene_dir)
    v, w, _ = scene.trajectory.speed()
    assert v.max() == pytest.approx(0.5, rel=0.05)  # min-jerk peak at the requested top speed
    assert np.count_nonzero(v < 1e-6) > 10  # the robot stands still between segments


def test_trajectory_A_is_translation_only():
    rng = np.random.default_rng(0)
    traj, segs = make_trajectory(SynthConfig(trajectory="A", duration_s=2.0), rng, 0.3)
    R = traj.T()[:, :3, :3]
    assert np.max(rotation_angle(np.swapaxes(R[:1], 1, 2) @ R)) < 1e-9
    assert len(segs) >= 2


def test_events_are_where_the_true_objects_are(tiny_scene_dir):
    """With the true clock and poses, more events fall on the (dilated) object masks than with
    the injected errors: the simulated events agree with the ground truth geometry."""
    import cv2

    gt = load_ground_truth(tiny_scene_dir)
    scene = Scene.open(tiny_scene_dir)
    wins = [w for w in time_windows(scene.events, 10_000) if w.n_events > 2000]
    assert len(wins) >= 10

    def on_mask_fraction():
        ann = Annotator(scene, Request(label_map=True))
        inside = total = 0
        for w in wins[::3]:
            ev = scene.events.read(w.i0, w.i1)
            lab = ann.annotate(w)
            m = cv2.dilate((lab.label_map >= 0).astype(np.uint8), np.ones((3, 3), np.uint8))
            inside += int(m[ev.y, ev.x].sum())
            total += len(ev)
        return inside / total

    wrong = on_mask_fraction()
    scene.corrections.set(("offset_us",), gt["clock"]["offset_us"])
    for name, entry in gt["objects"].items():
        scene.corrections.set(("object", name), np.array(entry["T_base_obj"]) @ np.linalg.inv(scene.manifest.object(name).T_base_obj))
    right = on_mask_fraction()
    assert right > wrong + 0.02, (wrong, right)


def test_deterministic_for_a_seed(tmp_path):
    from evpose_testing import half_davis_camera

    cfg = dict(objects=("box",), duration_s=0.15, seed=11, camera=half_davis_camera())
    a = generate(tmp_path / "a", SynthConfig(**cfg))
    b = generate(tmp_path / "b", SynthConfig(**cfg))
    assert a["stats"]["n_events"] == b["stats"]["n_events"]
    with EventStore(tmp_path / "a" / "events.h5") as ea, EventStore(tmp_path / "b" / "events.h5") as eb:
        np.testing.assert_array_equal(ea.read(0, ea.n_events).t, eb.read(0, eb.n_events).t)


def test_cancel_and_existing_folder_leave_nothing(tmp_path):
    from evpose_testing import half_davis_camera

    out = tmp_path / "s"
    calls = {"n": 0}

    def cancel():
        calls["n"] += 1
        return calls["n"] > 3

    with pytest.raises(Cancelled):
        generate(out, SynthConfig(objects=("box",), duration_s=0.3, camera=half_davis_camera()), cancel=cancel)
    assert not out.exists() and list(tmp_path.iterdir()) == []
    out.mkdir()
    (out / "keep.txt").write_text("user data")
    with pytest.raises(FileExistsError, match="not empty"):
        generate(out, SynthConfig(objects=("box",), duration_s=0.1, camera=half_davis_camera()))
    assert (out / "keep.txt").read_text() == "user data"


def test_render_schedule_keeps_event_timing():
    """No "unchanged image" step inside a motion (the next frame's change would be spread over a
    shortened interval: late events), a frame where each motion starts, noise steps while still."""
    rng = np.random.default_rng(3)
    traj, segs = make_trajectory(SynthConfig(trajectory="B", duration_s=3.0), rng, 0.3)
    clock = ClockModel(20_000, 0.0, 0)
    e0 = traj.t_first_us + 300_000 - 20_000
    e1 = e0 + 3_000_000
    steps, render = render_times(traj, clock, e0, e1, 300.0, 0.4, 1.0)
    assert np.all(np.diff(steps) > 0) and steps[0] > e0 and steps[-1] == e1
    assert np.max(np.diff(np.r_[e0, steps])) <= NOISE_STEP_US           # noise even while still
    v, w, _ = traj.speed()
    seg_ev = clock.event_time(traj.t_us)
    k = np.searchsorted(seg_ev, steps, side="left") - 1
    px_s = 300.0 * (v / 0.4 + w)              # the image speed bound render_times uses
    moving = px_s[np.clip(k, 0, len(v) - 1)] > 1e-6
    mv = px_s > 1e-6
    starts = seg_ev[:-1][mv & ~np.r_[False, mv[:-1]]]
    starts = np.rint(starts[(starts > e0) & (starts <= e1)]).astype(np.int64)
    assert render[moving].all(), "every step inside a motion renders a frame"
    assert not render[~moving & ~np.isin(steps, starts)].any(), "nothing is rendered while standing still"
    assert len(starts) >= 2 and np.isin(starts, steps[render]).all(), "a frame where each motion starts"
    # frames at most max_px apart in the image, and at most max_interval_us apart when asked
    dense, r2 = render_times(traj, clock, e0, e1, 300.0, 0.4, 1.0, max_interval_us=1000)
    gaps = np.diff(dense[r2])
    assert r2.sum() > render.sum() and np.median(gaps) <= 1000


def test_rendered_motion_is_smooth_and_the_recorded_poses_sample_it():
    """The camera renders a finely sampled minimum-jerk motion; the trajectory file holds its
    samples at the robot's rate. Its speed changes by a small step per 0.25 ms, not by a
    staircase at every 4 ms pose sample (which put a 4 ms ripple into the sync likelihood)."""
    cfg = SynthConfig(trajectory="B", duration_s=2.0, speed_mps=0.3)
    m = make_motion(cfg, np.random.default_rng(5), 0.3)
    assert np.all(np.diff(m.recorded.t_us) == 4000)
    T_rec = m.recorded.T()
    T_true, ok = m.true.interpolate(m.recorded.t_us)
    assert ok.all()
    assert np.abs(T_true[:, :3, 3] - T_rec[:, :3, 3]).max() < 1e-9
    assert np.abs(T_true[:, :3, :3] - T_rec[:, :3, :3]).max() < 1e-9
    # inside a move: the true motion's speed steps by at most a few percent of its peak between
    # consecutive samples, the recorded one's by ~16x that at the 4 ms steps
    a, b = m.segments[0]
    sel = (m.true.t_us[:-1] > a) & (m.true.t_us[1:] < b)
    v_true = m.true.speed()[0][sel]
    sel_r = (m.recorded.t_us[:-1] > a) & (m.recorded.t_us[1:] < b)
    v_rec = m.recorded.speed()[0][sel_r]
    assert abs(v_true.max() / cfg.speed_mps - 1) < 0.01 and abs(v_rec.max() / cfg.speed_mps - 1) < 0.01
    step_true = np.abs(np.diff(v_true)).max() / v_true.max()
    step_rec = np.abs(np.diff(v_rec)).max() / v_rec.max()
    assert step_true < 0.002 and step_rec > 8 * step_true, (step_true, step_rec)
    with pytest.raises(ValueError, match="motion_rate_hz"):
        SynthConfig(pose_rate_hz=500, motion_rate_hz=100).validate()


def test_invalid_config_is_named():
    for kw, match in [(dict(trajectory="C"), "trajectory"), (dict(speed_mps=0), "speed"),
                      (dict(objects=()), "objects"), (dict(objects=("box", "box")), "unique"),
                      (dict(max_px_per_frame=0), "max_px_per_frame"), (dict(max_frame_interval_us=-1), "interval")]:
        with pytest.raises(ValueError, match=match):
            SynthConfig(**kw).validate()
    with pytest.raises(ValueError, match="unknown built-in"):
        generate("/nonexistent/never", SynthConfig(objects=("teapot",)))


def test_real_meshes(models_dir, tmp_path):
    from evpose_testing import half_davis_camera

    s = generate(tmp_path / "r", SynthConfig(objects=("sugar_box", "mustard_bottle"), mesh_dir=str(models_dir),
                                            duration_s=0.2, camera=half_davis_camera(), seed=2))
    assert s["stats"]["n_events"] > 1000
    scene = Scene.open(tmp_path / "r")
    assert scene.model("sugar_box").faces.shape[0] == 25_000
    assert json.loads((tmp_path / "r" / "ground_truth.json").read_text())["generator"]["mesh_dir"] == str(models_dir)
