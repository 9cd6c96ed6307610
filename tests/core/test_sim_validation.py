"""The validation-family generator (core/sim_validation): lens rays against OpenCV, the level-crossing sensor's
statistics, motion profiles and pose rate, adaptive frame steps, and a tiny generated scene that evpose opens and
whose ground truth the events agree with."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from evpose.core.data.camera import CameraModel
from evpose.core.data.geometry import pose_error, rotation_angle
from evpose.core.sim_validation.config import ASSETS, SensorModel, ValidationConfig
from evpose.core.sim_validation.profiles import CameraMotion
from evpose.core.sim_validation.rays import distort, pixel_rays, pixel_samples
from evpose.core.sim_validation.sensor import LevelCrossingSensor

TARGET = np.array([0.02, -0.78, 0.035])


def _half_camera() -> dict:
    from evpose_testing import half_davis_camera

    return half_davis_camera()


# ------------------------------------------------------------------------------------------ lens rays
@pytest.mark.parametrize("dist", [CameraModel.davis346().dist.tolist(), [0.08, -0.2, 0.002, -0.001, 0.05], []])
def test_rays_through_distortion_round_trip_with_opencv(dist):
    """Every pixel's ray, projected by cv2.projectPoints, lands on that pixel (< 1e-6 px); the forward model
    agrees with OpenCV on its own."""
    cam = CameraModel.davis346()
    uv = pixel_samples(cam.width, cam.height)[0]
    uv = np.concatenate([uv, uv[::97] + np.random.default_rng(0).uniform(-0.5, 0.5, (len(uv[::97]), 2))])
    rays, ok = pixel_rays(uv, cam.K, dist)
    assert ok.all()
    back, _ = cv2.projectPoints(rays * 0.7, np.zeros(3), np.zeros(3), cam.K, np.asarray(dist, np.float64))
    err = np.abs(back.reshape(-1, 2) - uv).max()
    assert err < 1e-6, err
    xy = np.random.default_rng(1).uniform(-0.9, 0.9, (500, 2))
    ref, _ = cv2.projectPoints(np.c_[xy, np.ones(500)], np.zeros(3), np.zeros(3), cam.K, np.asarray(dist, np.float64))
    assert np.abs(distort(xy, cam.K, dist) - ref.reshape(-1, 2)).max() < 1e-9


def test_rays_beyond_the_monotonic_radius_are_invalid():
    """A lens whose radial polynomial folds back (k1 = -0.5, k2 = 0.1: r_d = r (1 - r^2/2 + r^4/10) peaks at
    r = 1, r_d = 0.6): a pixel beyond r_d = 0.6 gets no ray; one inside gets the ray inside r = 1, also when a
    point beyond the fold lands on it."""
    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    dist = [-0.5, 0.1, 0, 0, 0]
    uv = np.array([[80.0, 50.0], [50.0, 109.0], [120.0, 50.0]])          # r_d = 0.3, 0.59, 0.7
    rays, ok = pixel_rays(uv, K, dist)
    assert ok.tolist() == [True, True, False] and np.isnan(rays[2]).all()
    assert np.all(np.hypot(rays[:2, 0], rays[:2, 1]) < 1.0)
    folded = distort(np.array([[1.2, 0.0]]), K, dist)                     # beyond the fold: r_d = 0.584
    ray, ok = pixel_rays(folded, K, dist)
    assert ok[0] and 0.5 < ray[0, 0] < 1.0
    assert np.abs(distort(ray[:, :2], K, dist) - folded).max() < 1e-9


# ------------------------------------------------------------------------------------------ sensor
def test_static_pixels_fire_noise_and_leak_at_the_configured_rates():
    """A static scene: OFF events are half the shot noise (n/2 per pixel and second), ON events add the leak,
    which every event restarts (n e^(-n/r) / (1 - e^(-n/r))); hot pixels fire at their own rate."""
    params = SensorModel(noise_rate_hz=0.6, leak_rate_hz=0.5, rate_spread=0.3, hot_pixels=3, hot_rate_hz=80.0)
    s = LevelCrossingSensor(60, 40, params, np.random.default_rng(5))
    L = np.full((40, 60), -1.0)
    s.reset(L, 0)
    for k in range(400):                      # warm-up: the initial reference levels are arbitrary
        s.step(L, L, k * 10_000, (k + 1) * 10_000)
    evs = [s.step(L, L, k * 20_000, (k + 1) * 20_000) for k in range(200, 1200)]      # 20 s
    pix = np.concatenate([e.y.astype(np.int64) * 60 + e.x for e in evs])
    pol = np.concatenate([e.p for e in evs])
    cold = ~np.isin(pix, s.hot)
    on_exp, off_exp = s.expected_static_rates()
    mask = np.ones(s.noise_hz.size, bool)
    mask[s.hot] = False
    seconds = 20.0
    off = np.count_nonzero(cold & (pol == 0)) / (mask.sum() * seconds)
    on = np.count_nonzero(cold & (pol == 1)) / (mask.sum() * seconds)
    assert off == pytest.approx(off_exp[mask].mean(), rel=0.05), (off, off_exp[mask].mean())
    assert on == pytest.approx(on_exp[mask].mean(), rel=0.05), (on, on_exp[mask].mean())
    assert off == pytest.approx(params.noise_rate_hz / 2, rel=0.08)
    hot_rate = np.count_nonzero(~cold) / (len(s.hot) * seconds)
    assert hot_rate == pytest.approx(params.hot_rate_hz, rel=0.1)
    t = np.concatenate([e.t for e in evs])
    assert np.all(np.diff(t) >= 0)


def test_threshold_spread_and_interpolated_crossing_times():
    """A linear ramp of log intensity: each pixel fires every C_i / slope (its own threshold, µs-exact), so the
    thresholds estimated from the event counts have the configured mean and spread, separately for ON and OFF."""
    params = SensorModel(contrast=0.25, contrast_sigma=0.03, refractory_us=0, leak_rate_hz=0.0, noise_rate_hz=0.0,
                         hot_pixels=0)
    s = LevelCrossingSensor(50, 40, params, np.random.default_rng(2))
    slope = 20.0 / 1e6                        # log units per µs: 20 over one second
    for sign, pol, c in ((1.0, 1, s.c_on), (-1.0, 0, s.c_off)):
        s.reset(np.zeros((40, 50)), 0)
        evs = [s.step(np.full((40, 50), sign * slope * k * 1700), np.full((40, 50), sign * slope * (k + 1) * 1700),
                      k * 1700, (k + 1) * 1700) for k in range(588)]                        # frames 1.7 ms apart
        pix = np.concatenate([e.y.astype(np.int64) * 50 + e.x for e in evs])
        t = np.concatenate([e.t for e in evs])
        assert np.all(np.concatenate([e.p for e in evs]) == pol)
        counts = np.bincount(pix, minlength=2000)
        c_est = 20.0 / counts
        assert c_est.mean() == pytest.approx(params.contrast, abs=0.005)
        assert c_est.std() == pytest.approx(params.contrast_sigma, rel=0.15)
        order = np.lexsort((t, pix))
        same = pix[order][1:] == pix[order][:-1]
        gaps = np.diff(t[order])[same]
        assert np.abs(gaps - c[pix[order][1:][same]] / slope).max() <= 1.0     # µs rounding only


def test_refractory_period_thins_fast_changes():
    params = SensorModel(contrast=0.2, contrast_sigma=0.0, refractory_us=500, leak_rate_hz=0.0, noise_rate_hz=0.0,
                         hot_pixels=0)
    s = LevelCrossingSensor(10, 10, params, np.random.default_rng(0))
    s.reset(np.zeros((10, 10)), 0)
    ev = s.step(np.zeros((10, 10)), np.full((10, 10), 4.0), 0, 4000)     # 20 thresholds in 4 ms
    pix = ev.y.astype(np.int64) * 10 + ev.x
    for p in range(100):
        tp = ev.t[pix == p]
        assert len(tp) == 8 and np.diff(tp).min() >= 500                 # 0.2 ms per crossing, one per 0.5 ms


# ------------------------------------------------------------------------------------------ motion
@pytest.mark.parametrize("profile", ["trapezoid", "sine", "sweep"])
def test_moves_peak_at_the_requested_speed_and_stop(profile):
    cfg = ValidationConfig(speed_mps=0.5, profile=profile, trajectory="B", ringing_mm=0.0)
    m = CameraMotion(cfg, TARGET, np.random.default_rng(3), 8.0, 0)
    t = np.arange(0.0, 8.0, 2e-4)
    T = m.poses(t)
    v = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1) / 2e-4
    assert {mv.kind for mv in m.moves} == {profile}
    assert v.max() == pytest.approx(0.5, rel=0.02) and np.all(v <= 0.5 * 1.02)
    assert np.mean(v < 1e-9) > 0.05                                       # stops between the moves
    assert len(m.moves) >= 3


def test_trajectory_A_keeps_the_orientation_and_ringing_only_after_stops():
    cfg = ValidationConfig(speed_mps=1.0, trajectory="A", ringing_mm=0.1)
    m = CameraMotion(cfg, TARGET, np.random.default_rng(4), 6.0, 0)
    t = np.arange(0.0, 6.0, 1e-3)
    R = m.poses(t, ringing=False)[:, :3, :3]
    assert np.max(rotation_angle(np.swapaxes(R[:1], 1, 2) @ R)) < 1e-9
    diff = np.linalg.norm(m.poses(t)[:, :3, 3] - m.poses(t, ringing=False)[:, :3, 3], axis=1)
    assert 0.03e-3 < diff.max() <= 0.1e-3 + 1e-12
    inside = np.zeros(len(t), bool)
    for mv in m.moves:
        inside |= (t >= mv.t0) & (t <= mv.t0 + mv.T)
    assert diff[inside].max() == 0.0


def test_adaptive_steps_keep_image_motion_within_half_a_pixel():
    """Frame steps chosen by FrameSteps move no point of a dense table grid by more than ~0.5 px."""
    from evpose.core.sim_validation.stepping import FrameSteps

    cam = CameraModel.davis346()
    steps = FrameSteps(cam.K, cam.dist, cam.width, cam.height, 0.5)
    steps.r_lim /= 1.3                  # points seen within the image's corners (the generator probes hit points)
    m = CameraMotion(ValidationConfig(speed_mps=1.0), TARGET, np.random.default_rng(8), 3.0, 0)
    a = m.moves[0]
    gx, gy = np.meshgrid(np.linspace(-0.3, 0.3, 51), np.linspace(-0.3, 0.3, 51))
    dense = np.c_[gx.ravel() + TARGET[0], gy.ravel() + TARGET[1], np.full(gx.size, -0.015)]
    probe = dense[::4]
    pose_at = lambda t_us: m.poses(np.array([t_us * 1e-6]))[0]            # noqa: E731
    t, dt, T_last = int(a.t0 * 1e6), 1000, pose_at(int(a.t0 * 1e6))
    end, worst, moved = int((a.t0 + min(a.T, 0.2)) * 1e6), 0.0, []           # the start of a move at 1 m/s
    while t < end:
        t_next, T, d = steps.next_step(t, dt, end, probe, T_last, pose_at)
        worst = max(worst, steps.displacement(dense, T_last, T))
        moved.append(d)
        dt, t, T_last = t_next - t, t_next, T
    assert worst <= 0.6, worst                               # the probe grid is 4x sparser than the check
    assert len(moved) > 100 and np.median(moved) > 0.35      # and the steps are not wastefully short


# ------------------------------------------------------------------------------------------ a generated scene
@pytest.fixture(scope="module")
def tiny_validation_scene(tmp_path_factory):
    pytest.importorskip("open3d", reason="the generator casts rays with open3d")
    from evpose.core.sim_validation.assemble import generate

    out = tmp_path_factory.mktemp("validation") / "tiny"
    cfg = ValidationConfig(objects=("box", "cylinder"), mesh_dir=None, speed_mps=0.5, duration_s=0.5, seed=5,
                           offset_us=25_000, skew_ppm=60.0, pose_error_mm=5.0, pose_error_deg=3.0,
                           pose_rate_hz=250.0, clutter=2, camera=_half_camera(), max_px_per_frame=1.0)
    summary = generate(out, cfg)
    return out, summary


def test_the_scene_opens_with_evpose_and_names_its_truth(tiny_validation_scene, capsys):
    from evpose.app.cli.main import main
    from evpose.core.data.scene import Scene

    out, summary = tiny_validation_scene
    gt = json.loads((out / "ground_truth.json").read_text())
    assert {"format", "clock", "objects", "injected", "hand_eye", "moving_segments_pose_us", "generator",
            "stats"} <= set(gt)
    assert gt["generator"]["name"] == "raycast" and gt["stats"] == summary["stats"]
    scene = Scene.open(out)
    assert scene.object_names == ["box", "cylinder"] and len(gt["clutter"]) == 2        # clutter not listed
    assert scene.events.t_first_us == gt["clock"]["t_ref_us"] and scene.events.n_events == gt["stats"]["n_events"]
    assert scene.manifest.clock_offset_us == 0 and scene.manifest.clock_skew_ppm == 0.0
    for name, entry in gt["objects"].items():
        dt, dR = pose_error(scene.manifest.object(name).T_base_obj, np.array(entry["T_base_obj"]))
        assert dt * 1e3 == pytest.approx(5.0, abs=1e-6) and np.degrees(dR) == pytest.approx(3.0, abs=1e-6)
    assert np.all(np.diff(scene.trajectory.t_us) == 4000)                                # 250 Hz
    scene.close()
    assert main(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["n_events"] == gt["stats"]["n_events"] and info["objects"] == ["box", "cylinder"]


def test_recorded_poses_sample_the_motion_at_the_pose_rate():
    """100 Hz: the recorded poses are the (ringing-free) motion at their timestamps, up to the sampling jitter,
    and the hand-eye error is applied on the camera side."""
    pytest.importorskip("open3d", reason="the generator casts rays with open3d")
    from evpose.core.sim_validation.assemble import _Run

    cfg = ValidationConfig(objects=("box",), speed_mps=0.5, duration_s=2.0, pose_rate_hz=100.0, pose_jitter_us=20.0,
                           hand_eye_error_mm=2.0, hand_eye_error_deg=0.5, seed=2, camera=_half_camera(), shadows=False)
    run = _Run(cfg)
    rec = run.recorded()
    assert np.all(np.diff(rec.t_us) == 10_000)
    truth = run.motion.poses((rec.t_us - run.origin_us) * 1e-6, ringing=False)
    dt, dR = pose_error(rec.T() @ np.linalg.inv(run.E), truth)
    v_max = cfg.speed_mps
    assert np.max(dt) < 6 * 20e-6 * v_max + 1e-9 and np.max(dt) > 0                # jitter only
    e_t, e_R = pose_error(run.E, np.eye(4))
    assert e_t * 1e3 == pytest.approx(2.0) and np.degrees(e_R) == pytest.approx(0.5)


def _edge_fraction(scene, wins, clock_fix: bool, pose_fix: bool, gt) -> float:
    """Share of the windows' events within 1 px of the labelled silhouettes' contours."""
    from evpose.core.label.annotate import Annotator
    from evpose.core.label.labels import Request

    scene.corrections.set(("offset_us",), gt["clock"]["offset_us"] if clock_fix else 0)
    scene.corrections.set(("skew_ppm",), gt["clock"]["skew_ppm"] if clock_fix else 0.0)
    for name, entry in gt["objects"].items():
        d = np.array(entry["T_base_obj"]) @ np.linalg.inv(scene.manifest.object(name).T_base_obj)
        scene.corrections.set(("object", name), d if pose_fix else np.eye(4))
    ann = Annotator(scene, Request(label_map=True))
    near = total = 0
    for w in wins:
        ev = scene.events.read(w.i0, w.i1)
        lab = ann.annotate(w).label_map
        fg = (lab >= 0).astype(np.uint8)
        edge = cv2.dilate(fg, np.ones((3, 3), np.uint8)) - cv2.erode(fg, np.ones((3, 3), np.uint8))
        near += int(edge[ev.y, ev.x].sum())
        total += len(ev)
    return near / total


def test_events_cluster_on_the_true_silhouette_edges(tiny_validation_scene):
    """With the true clock and poses more events lie on the objects' contours than with the prior clock or the
    injected pose errors: the events agree with ground_truth.json (measured, both ways)."""
    from evpose.core.data.scene import Scene
    from evpose.core.label.windows import time_windows

    out, _ = tiny_validation_scene
    gt = json.loads((out / "ground_truth.json").read_text())
    scene = Scene.open(out)
    wins = [w for w in time_windows(scene.events, 10_000) if w.n_events > 800]
    assert len(wins) >= 8
    wins = wins[::2]
    right = _edge_fraction(scene, wins, True, True, gt)
    wrong_clock = _edge_fraction(scene, wins, False, True, gt)
    wrong_pose = _edge_fraction(scene, wins, True, False, gt)
    scene.close()
    assert right > 1.15 * wrong_pose and right > 1.1 * wrong_clock, (right, wrong_clock, wrong_pose)


def test_stand_ins_without_assets_and_real_meshes_with_them(tmp_path, monkeypatch):
    import evpose.core.sim_validation.objects as objects

    monkeypatch.setattr(objects, "ASSETS", tmp_path / "absent")
    m = objects.load_object("sugar_box", None)
    lo, hi = m.bbox_min_max
    assert np.allclose(np.sort(hi - lo), np.sort(objects.STAND_INS["sugar_box"][1]))
    with pytest.raises(ValueError, match="teapot"):
        objects.load_object("teapot", None)
    if not (ASSETS / "models" / "sugar_box.obj").is_file():
        pytest.skip(f"E-POSE meshes not found at {ASSETS / 'models'}")
    monkeypatch.setattr(objects, "ASSETS", ASSETS)
    assert objects.load_object("sugar_box", None).faces.shape[0] == 25_000
    rests = objects.resting_rotations(np.asarray(objects.load_object("mustard_bottle", None).vertices_m))
    assert len(rests) >= 2 and all(a > 0 for _, a in rests)


def test_cli_option_and_config_errors(capsys):
    from evpose.app.cli.main import main

    assert main(["synth", "/nonexistent/x", "--clutter", "2"]) != 0
    assert "--clutter: only with --generator raycast" in capsys.readouterr().err
    assert main(["synth", "/nonexistent/x", "--generator", "raycast", "--pose-rate-hz", "0"]) != 0
    assert "pose_rate_hz" in capsys.readouterr().err
    for kw, match in [(dict(trajectory="C"), "trajectory"), (dict(profile="zigzag"), "profile"),
                      (dict(clutter=-1), "clutter"), (dict(objects=("a", "a")), "objects"),
                      (dict(sensor=SensorModel(contrast_sigma=0.5)), "contrast")]:
        with pytest.raises(ValueError, match=match):
            ValidationConfig(**kw).validate()
