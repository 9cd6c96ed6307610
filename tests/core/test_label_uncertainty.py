"""Per-label uncertainty (issue 28.1): the first-order propagation of evpose.core.label.uncertainty against finite
differences through the scene's own pose pipeline (corrections applied as the app and the export apply them), against
a Monte Carlo over the inputs' sigma on a small scene, and the trajectory's interpolation bound against a path of
known acceleration."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evpose.core.data.geometry import T_from_rotvec, make_T
from evpose.core.data.scene import Scene
from evpose.core.data.trajectory import Trajectory
from evpose.core.label.labels import label_poses
from evpose.core.label.uncertainty import InputSigmas, interpolation_bounds, label_sigmas, skew_matrix


def pose_error(T_a, T_b):
    """(e_t, e_R) of T_a against T_b in the camera frame, written out here independently of the module."""
    e_t = T_a[..., :3, 3] - T_b[..., :3, 3]
    dR = T_a[..., :3, :3] @ np.swapaxes(T_b[..., :3, :3], -1, -2)
    e_R = Rotation.from_matrix(dR.reshape(-1, 3, 3)).as_rotvec().reshape(e_t.shape)
    return e_t, e_R


#: The tiny scene's meshes are centred on their origins; their boxes are moved off it here, so the rotation about the
#: centre moves the label's origin (the lever every real mesh has: YCB's origins are off their boxes' centres).
BOX_SHIFT_M = np.array([0.04, -0.03, 0.02])


@pytest.fixture
def scene(tiny_scene_dir):
    s = Scene.open(tiny_scene_dir)
    real_box = s.object_box
    s.object_box = lambda name: tuple(np.asarray(v) + BOX_SHIFT_M for v in real_box(name))
    yield s
    s.close()


def _times(scene, n=40):
    t0, t1 = scene.events.t_first_us, scene.events.t_last_us
    t = np.linspace(t0 + 0.1 * (t1 - t0), t1 - 0.1 * (t1 - t0), n).astype(np.int64)
    _, _, valid = label_poses(scene, t, scene.object_names)
    assert valid.all()
    return t


def _object_delta_base(T_bo, centre, d_t, d_theta):
    """The base-frame correction (left-multiplied, as Scene.T_base_obj applies it) that moves the object's centre by
    ``d_t`` and rotates it by ``d_theta`` about its centre, both in the object's axes."""
    C = make_T(np.eye(3), centre)
    body = T_from_rotvec(d_theta, d_t)
    return T_bo @ C @ body @ np.linalg.inv(C) @ np.linalg.inv(T_bo)


def test_skew_matrix_is_the_cross_product():
    rng = np.random.default_rng(0)
    v, w = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    assert np.allclose(skew_matrix(v) @ w[..., None], np.cross(v, w)[..., None])


def test_each_input_against_finite_differences_through_the_pipeline(scene):
    """One input at a time, displaced by a small step through the scene's corrections: the label moves as the
    propagation's column for that input says (object pose, hand-eye, clock offset)."""
    t = _times(scene, 12)
    names = scene.object_names
    T0, _, _ = label_poses(scene, t, names)
    k, name = 1, names[1]
    centre = np.mean(scene.object_box(name), axis=0)
    R = T0[:, k, :3, :3]
    # object: rotation about its centre by 1e-4 rad about x, centre moved 1e-5 m along y (object axes)
    d_t, d_th = np.array([0.0, 1e-5, 0.0]), np.array([1e-4, 0.0, 0.0])
    scene.corrections.object_deltas[name] = _object_delta_base(scene.manifest.object(name).T_base_obj, centre, d_t,
                                                               d_th)
    T1, _, _ = label_poses(scene, t, names)
    e_t, e_R = pose_error(T1[:, k], T0[:, k])
    assert np.allclose(e_t, (R @ (d_t + np.cross(centre, d_th))[:, None])[..., 0], atol=1e-9)
    assert np.allclose(e_R, (R @ d_th[:, None])[..., 0], atol=1e-9)
    other = [j for j in range(len(names)) if j != k]
    assert np.allclose(T1[:, other], T0[:, other])
    scene.corrections.object_deltas.clear()
    # hand-eye: T_base_cam @ dT
    d_t, d_th = np.array([2e-5, -1e-5, 0.0]), np.array([0.0, 0.0, 2e-4])
    scene.corrections.hand_eye_delta = T_from_rotvec(d_th, d_t)
    T2, _, _ = label_poses(scene, t, names)
    e_t, e_R = pose_error(T2, T0)
    t_co = T0[..., :3, 3]
    assert np.allclose(e_t, -d_t + np.cross(t_co, d_th), atol=1e-8)
    assert np.allclose(e_R, -d_th, atol=1e-9)
    scene.corrections.hand_eye_delta = np.eye(4)
    # the propagated sigma of one input equals the label's displacement by that input's sigma (here the object's
    # rotation alone: sigma_t = |c| x sigma_theta sqrt(2/3), sigma_R = sigma_theta)
    s = label_sigmas(scene, t, names, InputSigmas(pose_deg=0.5, interpolation=False))
    th = np.radians(0.5)
    assert np.allclose(s.sigma_R_deg[:, k], 0.5)
    assert np.linalg.norm(centre) > 0.03
    assert np.allclose(s.sigma_t_mm[:, k], 1e3 * th * np.sqrt(2.0 / 3.0) * np.linalg.norm(centre))


def _draw(rng, sigma_t, sigma_r):
    """Isotropic draws with RMS 3D sigma_t (m) and sigma_r (rad)."""
    return rng.normal(scale=sigma_t / np.sqrt(3), size=3), rng.normal(scale=sigma_r / np.sqrt(3), size=3)


def test_propagation_matches_a_monte_carlo_over_the_inputs(scene):
    """Clock (5 ms, 40 ppm), every object's pose (2 mm, 1 deg) and the hand-eye (1.5 mm, 0.5 deg) drawn 400 times,
    applied through the scene's corrections: the RMS of the labels' actual translation error, rotation angle and
    box-corner reprojection matches the predicted sigma within 10 % (pooled over windows and objects) and per window
    within 25 %, and the covariance's translation-rotation block its correlations within 0.2."""
    t = _times(scene, 24)
    names = scene.object_names
    sig = InputSigmas(offset_us=5000, skew_ppm=40, pose_mm=2.0, pose_deg=1.0, hand_eye_mm=1.5, hand_eye_deg=0.5,
                      interpolation=False)
    pred = label_sigmas(scene, t, names, sig)
    T0, _, _ = label_poses(scene, t, names)
    rng = np.random.default_rng(11)
    base_offset, base_skew = scene.corrections.offset_us, scene.corrections.skew_ppm
    centres = {n: np.mean(scene.object_box(n), axis=0) for n in names}
    corners = {n: np.array([[x, y, z] for x in b[:, 0] for y in b[:, 1] for z in b[:, 2]])
               for n, b in ((n, np.array(scene.object_box(n))) for n in names)}
    K = scene.camera.K
    sq_t, sq_r, sq_px, outer = 0.0, 0.0, 0.0, 0.0
    draws = 400
    for _ in range(draws):
        scene.corrections.offset_us = base_offset + int(round(rng.normal(scale=sig.offset_us)))
        scene.corrections.skew_ppm = base_skew + rng.normal(scale=sig.skew_ppm)
        for n in names:
            d_t, d_th = _draw(rng, 1e-3 * sig.pose_mm, np.radians(sig.pose_deg))
            scene.corrections.object_deltas[n] = _object_delta_base(scene.manifest.object(n).T_base_obj, centres[n],
                                                                    d_t, d_th)
        d_t, d_th = _draw(rng, 1e-3 * sig.hand_eye_mm, np.radians(sig.hand_eye_deg))
        scene.corrections.hand_eye_delta = T_from_rotvec(d_th, d_t)
        T1, _, valid = label_poses(scene, t, names)
        assert valid.all()
        e_t, e_R = pose_error(T1, T0)
        e = np.concatenate([e_t, e_R], -1)
        outer = outer + e[..., :, None] * e[..., None, :]
        sq_t = sq_t + (e_t ** 2).sum(-1)
        sq_r = sq_r + (e_R ** 2).sum(-1)
        px = np.zeros(T0.shape[:2])
        for k, n in enumerate(names):
            uv = []
            for T in (T1, T0):
                X = np.einsum("nij,cj->nci", T[:, k, :3, :3], corners[n]) + T[:, k, None, :3, 3]
                uv.append(np.stack([K[0, 0] * X[..., 0] / X[..., 2], K[1, 1] * X[..., 1] / X[..., 2]], -1))
            px[:, k] = ((uv[0] - uv[1]) ** 2).sum(-1).mean(-1)
        sq_px = sq_px + px
    rms_t = np.sqrt(sq_t / draws) * 1e3
    rms_r = np.degrees(np.sqrt(sq_r / draws))
    rms_px = np.sqrt(sq_px / draws)
    for got, want in ((rms_t, pred.sigma_t_mm), (rms_r, pred.sigma_R_deg), (rms_px, pred.sigma_px)):
        assert np.isfinite(want).all() and (want > 0).all()
        pooled = np.sqrt((got ** 2).mean() / (want ** 2).mean())
        assert abs(pooled - 1) < 0.10, pooled
        assert np.all(np.abs(got / want - 1) < 0.25), np.round(got / want, 2)
    # the whole covariance, also how translation and rotation errors go together (the lever of the centre)
    emp = outer / draws
    scale = np.sqrt(np.diagonal(emp, axis1=-2, axis2=-1))
    norm = scale[..., :, None] * scale[..., None, :]
    corr_diff = np.abs(emp - pred.cov) / norm
    assert np.median(corr_diff[..., :3, 3:].max(axis=(-1, -2))) < 0.2, np.median(corr_diff[..., :3, 3:], axis=(0, 1))
    # the clock matters: without it the translation sigma is smaller where the camera moves
    no_clock = label_sigmas(scene, t, names, InputSigmas(**{**sig.__dict__, "offset_us": 0, "skew_ppm": 0}))
    assert (no_clock.sigma_t_mm < pred.sigma_t_mm - 1e-9).any()


def test_interpolation_bound_on_a_path_of_known_acceleration():
    """Positions 0.5 a t^2 and angle 0.5 alpha t^2 about z sampled every 10 ms: the bound is a dt^2/8 (and alpha
    dt^2/8), which is the interpolation's actual error half-way between samples."""
    from types import SimpleNamespace

    from evpose.core.data.clock import ClockModel

    a, alpha, dt_us = 2.0, 30.0, 10_000
    t_us = np.arange(0, 400_000 + 1, dt_us, dtype=np.int64)
    ts = t_us * 1e-6
    T = np.stack([T_from_rotvec([0, 0, 0.5 * alpha * s * s], [0.5 * a * s * s, 0, 0])
                  for s in ts])
    traj = Trajectory.from_T(t_us, T)
    fake = SimpleNamespace(trajectory=traj, clock=ClockModel(0, 0.0, 0), camera_from_trajectory=lambda T: T)
    t_mid = t_us[5:-5] + dt_us // 2
    b_t, b_r = interpolation_bounds(fake, t_mid)
    h = dt_us * 1e-6
    assert np.allclose(b_t, a * h * h / 8, rtol=1e-6) and np.allclose(b_r, alpha * h * h / 8, rtol=1e-6)
    T_int, _ = traj.interpolate(t_mid)
    s = t_mid * 1e-6
    err_t = np.abs(T_int[:, 0, 3] - 0.5 * a * s * s)
    err_r = np.abs(Rotation.from_matrix(T_int[:, :3, :3]).as_rotvec()[:, 2] - 0.5 * alpha * s * s)
    assert np.allclose(err_t, b_t, rtol=1e-6) and np.allclose(err_r, b_r, rtol=1e-4)


def test_input_sigmas_are_checked():
    for bad in (-1.0, float("nan"), "1"):
        with pytest.raises(ValueError, match="pose_mm"):
            InputSigmas(pose_mm=bad)
