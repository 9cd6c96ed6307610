"""The 1-sigma uncertainty of each label ``T_cam_obj`` (issue 28.1), propagated to first order from its inputs.

A window's label is ``T_cam_obj = inv(T_base_cam(t_pose)) @ T_base_obj`` with ``t_pose`` from the clock model. Its
error ``e = (e_t, e_R)`` is measured in the camera frame: ``e_t = t' - t`` (m) and ``e_R = rotvec(R' R^T)`` (rad).
Independent, zero-mean input errors, each with the 1-sigma of :class:`InputSigmas`:

* the clock: offset (µs) and skew (ppm). ``e`` moves with the camera's motion around the label time; the columns
  ``de/d offset`` and ``de/d skew`` are central differences of the labels over +-sigma (the trajectory is piecewise
  linear between its samples: a secant over the input's own spread, not a tangent);
* the object's pose in the base frame: its centre ``c`` (the mesh's bounding-box centre, object frame) displaced and
  the object rotated about ``c``, isotropic: ``e_t = R_co (dt + [c]x dtheta)``, ``e_R = R_co dtheta``;
* the hand-eye calibration, as the correction ``T_base_cam @ dT`` evpose applies: ``e_t = -dt + [t]x dtheta``,
  ``e_R = -dtheta`` (``t``: the object's origin in the camera);
* the trajectory's interpolation between its samples (linear positions, slerp rotations): at most ``|a| dt^2 / 8``
  for an acceleration ``a`` over a sample interval ``dt``, taken as the 1-sigma of a camera-frame error like the
  hand-eye's (from the second differences of the camera poses at the samples around the label time;
  :func:`interpolation_bounds`).

Input sigmas are RMS of 3D errors (``sqrt(trace)`` of their covariance: ``pose_mm = 1`` is 0.58 mm per axis), and so
are the outputs: ``sigma_t_mm = sqrt(trace Sigma_tt)``, ``sigma_R_deg = sqrt(trace Sigma_RR)`` (the RMS of the 3D
translation error and of the rotation angle); ``|err| <= 2 sigma`` holds with ~99 % probability for an isotropic
Gaussian error. ``sigma_px`` is the RMS over the corners of the object's bounding box (those in front of the camera)
of each corner's projected 1-sigma displacement (``sqrt(trace)`` of its 2x2 covariance) in the pinhole camera ``K``:
the uncertainty of the projected contour.

Linearisation: exact for the object and hand-eye terms to first order in the rotation (sigma of a few degrees), and
for the clock as long as the motion is smooth over +-sigma; tests/core/test_label_uncertainty.py checks it against
finite differences through the scene's own pose pipeline and a Monte Carlo over the inputs.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from evpose.core.label.labels import label_poses

__all__ = ["InputSigmas", "LabelSigmaOptions", "LabelSigmas", "interpolation_bounds", "label_sigmas", "skew_matrix",
           "stored_input_sigmas", "stored_label_sigmas"]


@dataclass(frozen=True)
class InputSigmas:
    """1-sigma of the label's inputs (0: exact). Translations and rotations are RMS of the 3D error."""

    offset_us: float = 0.0          # clock offset, µs
    skew_ppm: float = 0.0           # clock skew, ppm
    pose_mm: float = 0.0            # each object's centre in the base frame, mm
    pose_deg: float = 0.0           # each object's rotation about its centre, degrees
    hand_eye_mm: float = 0.0        # the camera's origin on the flange, mm
    hand_eye_deg: float = 0.0       # the camera's rotation on the flange, degrees
    interpolation: bool = True      # add the trajectory's interpolation error

    def __post_init__(self):
        for name in ("offset_us", "skew_ppm", "pose_mm", "pose_deg", "hand_eye_mm", "hand_eye_deg"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: a label input's sigma must be a finite number >= 0, got {v!r}")


@dataclass
class LabelSigmas:
    """Per window (N) and object (K): the label's covariance and its summaries."""

    cov: np.ndarray            # (N, K, 6, 6): (e_t [m], e_R [rad]) in the camera frame
    sigma_t_mm: np.ndarray     # (N, K)
    sigma_R_deg: np.ndarray    # (N, K)
    sigma_px: np.ndarray       # (N, K); NaN where no box corner is in front of the camera
    valid: np.ndarray          # (N,) the label exists (pose time inside the trajectory)


def skew_matrix(v: np.ndarray) -> np.ndarray:
    """``[v]x`` for vectors ``v`` (..., 3): ``[v]x @ w == cross(v, w)``."""
    v = np.asarray(v, np.float64)
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def _pose_error(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    """``e`` of ``T_a`` relative to ``T_b`` (..., 6): translation difference and rotvec(R_a R_b^T)."""
    dR = T_a[..., :3, :3] @ np.swapaxes(T_b[..., :3, :3], -1, -2)
    rv = Rotation.from_matrix(dR.reshape(-1, 3, 3)).as_rotvec().reshape(dR.shape[:-2] + (3,))
    return np.concatenate([T_a[..., :3, 3] - T_b[..., :3, 3], rv], -1)


def _rigid_block(sig_t_m: np.ndarray, sig_r_rad: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray):
    """Covariance of ``e = (A dt + B dtheta, C dtheta)`` with isotropic ``dt``, ``dtheta`` of RMS ``sig_t``,
    ``sig_r`` (broadcast over leading axes)."""
    vt = (np.asarray(sig_t_m) ** 2 / 3.0)[..., None, None]
    vr = (np.asarray(sig_r_rad) ** 2 / 3.0)[..., None, None]
    At, Bt, Ct = (np.swapaxes(M, -1, -2) for M in (A, B, C))
    tt = vt * A @ At + vr * B @ Bt
    tr = vr * B @ Ct
    rr = vr * C @ Ct
    top = np.concatenate([tt, tr], -1)
    bottom = np.concatenate([np.swapaxes(tr, -1, -2), rr], -1)
    return np.concatenate([top, bottom], -2)


def interpolation_bounds(scene, t_label_us, clock=None) -> tuple[np.ndarray, np.ndarray]:
    """``(bound_t_m, bound_R_rad)`` per label time: the largest error of interpolating the camera's poses linearly
    (positions) and by slerp (rotations) across the trajectory's sample interval holding the pose time, ``|a| dt^2 /
    8`` with ``a`` the larger second difference at the interval's two ends (0 where there are too few samples)."""
    traj = scene.trajectory
    clock = clock or scene.clock
    t = np.atleast_1d(np.asarray(t_label_us, np.int64))
    n = len(traj)
    if n < 3:
        return np.zeros(len(t)), np.zeros(len(t))
    T_s = scene.camera_from_trajectory(traj.T())
    ts = (traj.t_us - traj.t_us[0]).astype(np.float64) * 1e-6           # s
    p = T_s[:, :3, 3]
    dt = np.diff(ts)
    vel = np.diff(p, axis=0) / dt[:, None]
    rot = Rotation.from_matrix(T_s[:, :3, :3])
    omega = (rot[1:] * rot[:-1].inv()).as_rotvec() / dt[:, None]        # base frame, rad/s
    acc_p = np.zeros(n)
    acc_r = np.zeros(n)
    mid = 0.5 * (dt[1:] + dt[:-1])
    acc_p[1:-1] = np.linalg.norm(np.diff(vel, axis=0), axis=1) / mid
    acc_r[1:-1] = np.linalg.norm(np.diff(omega, axis=0), axis=1) / mid
    acc_p[0], acc_p[-1], acc_r[0], acc_r[-1] = acc_p[1], acc_p[-2], acc_r[1], acc_r[-2]
    t_rel = clock.pose_time_rel(t, traj.t_first_us) * 1e-6
    i = np.clip(np.searchsorted(ts, t_rel, side="right") - 1, 0, n - 2)
    h2 = dt[i] ** 2 / 8.0
    return np.maximum(acc_p[i], acc_p[i + 1]) * h2, np.maximum(acc_r[i], acc_r[i + 1]) * h2


def label_sigmas(scene, t_label_us, names, sigmas: InputSigmas, K: np.ndarray | None = None,
                 labels=None, pose_sigmas=None) -> LabelSigmas:
    """The labels' uncertainty at ``t_label_us`` (event clock, µs) for the objects ``names`` of ``scene`` (see the
    module docstring); ``K``: the pinhole camera of ``sigma_px`` (default: the scene camera's ``K``); ``labels``: the
    caller's ``label_poses(scene, t_label_us, names)`` when it has them (the export's driver); ``pose_sigmas``:
    ``(mm, deg)`` per object instead of ``sigmas``' one pose sigma for all."""
    t = np.atleast_1d(np.asarray(t_label_us, np.int64))
    T_co, _, valid = label_poses(scene, t, names) if labels is None else labels
    N, Kn = T_co.shape[:2]
    cov = np.zeros((N, Kn, 6, 6))
    clock = scene.clock
    d_us = int(round(sigmas.offset_us))              # the clock holds whole µs
    steps = []                                       # (clock + step, clock - step, input sigma / step)
    if d_us:
        steps.append((scene.clock_with(offset_us=clock.offset_us + d_us),
                      scene.clock_with(offset_us=clock.offset_us - d_us), sigmas.offset_us / d_us))
    if sigmas.skew_ppm > 0:
        steps.append((scene.clock_with(skew_ppm=clock.skew_ppm + sigmas.skew_ppm),
                      scene.clock_with(skew_ppm=clock.skew_ppm - sigmas.skew_ppm), 1.0))
    for plus, minus, scale in steps:
        Tp, _, vp = label_poses(scene, t, names, clock=plus)
        Tm, _, vm = label_poses(scene, t, names, clock=minus)
        col = _pose_error(Tp, Tm) * (0.5 * scale)                   # de per sigma of the input (N, K, 6)
        col[~(vp & vm)] = 0.0
        cov += col[..., :, None] * col[..., None, :]
    R = T_co[..., :3, :3]
    t_co = T_co[..., :3, 3]
    eye = np.broadcast_to(np.eye(3), R.shape)
    pose_mm, pose_deg = ((np.full(Kn, sigmas.pose_mm), np.full(Kn, sigmas.pose_deg)) if pose_sigmas is None else
                         (np.asarray(pose_sigmas[0], np.float64), np.asarray(pose_sigmas[1], np.float64)))
    if np.any(pose_mm > 0) or np.any(pose_deg > 0):
        centres = np.stack([_centre(scene, n) for n in names])           # (K, 3) object frame
        B = R @ skew_matrix(centres)[None]
        cov += _rigid_block(pose_mm * 1e-3, np.radians(pose_deg), R, B, R)
    he_t = np.full((N,), sigmas.hand_eye_mm * 1e-3)
    he_r = np.full((N,), np.radians(sigmas.hand_eye_deg))
    camera_terms = [(he_t, he_r)]
    if sigmas.interpolation:
        camera_terms.append(interpolation_bounds(scene, t))
    for s_t, s_r in camera_terms:
        if not (np.any(s_t > 0) or np.any(s_r > 0)):
            continue
        cov += _rigid_block(s_t[:, None], s_r[:, None], -eye, skew_matrix(t_co), -eye)
    cov[~valid] = np.nan
    tt = np.trace(cov[..., :3, :3], axis1=-2, axis2=-1)
    rr = np.trace(cov[..., 3:, 3:], axis1=-2, axis2=-1)
    sigma_px = _contour_sigma_px(scene, names, T_co, cov, scene.camera.K if K is None else np.asarray(K))
    return LabelSigmas(cov, np.sqrt(tt) * 1e3, np.degrees(np.sqrt(rr)), sigma_px, valid)


def _centre(scene, name: str) -> np.ndarray:
    lo, hi = scene.object_box(name)
    return 0.5 * (np.asarray(lo) + np.asarray(hi))


def _corners(scene, name: str) -> np.ndarray:
    lo, hi = scene.object_box(name)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _contour_sigma_px(scene, names, T_co: np.ndarray, cov: np.ndarray, K: np.ndarray) -> np.ndarray:
    """RMS over the box corners in front of the camera of each corner's projected 1-sigma, px."""
    N, Kn = T_co.shape[:2]
    out = np.full((N, Kn), np.nan)
    fx, fy = K[0, 0], K[1, 1]
    for k, name in enumerate(names):
        P = _corners(scene, name)                                          # (8, 3) object frame
        RP = np.einsum("nij,cj->nci", T_co[:, k, :3, :3], P)              # (N, 8, 3) rotated, camera axes
        X = RP + T_co[:, k, None, :3, 3]
        Z = X[..., 2]
        front = Z > 1e-6
        Zs = np.where(front, Z, 1.0)
        Ju = np.zeros(X.shape[:2] + (2, 3))
        Ju[..., 0, 0] = fx / Zs
        Ju[..., 0, 2] = -fx * X[..., 0] / Zs ** 2
        Ju[..., 1, 1] = fy / Zs
        Ju[..., 1, 2] = -fy * X[..., 1] / Zs ** 2
        dX = np.concatenate([np.broadcast_to(np.eye(3), X.shape[:2] + (3, 3)), -skew_matrix(RP)], -1)   # dX/de
        J = Ju @ dX                                                        # (N, 8, 2, 6)
        S = J @ cov[:, k, None] @ np.swapaxes(J, -1, -2)
        var = np.trace(S, axis1=-2, axis2=-1)
        var = np.where(front, var, np.nan)
        with np.errstate(invalid="ignore"):
            n_front = front.sum(axis=1)
            out[:, k] = np.where(n_front > 0, np.sqrt(np.nansum(var, axis=1) / np.maximum(n_front, 1)), np.nan)
    return out


@dataclass(frozen=True)
class LabelSigmaOptions:
    """What an export does with label uncertainty: the inputs' sigma it is computed from (``inputs``; None:
    ``auto``, each object's from the estimates stored in the scene's corrections, :func:`stored_input_sigmas`),
    and the limits above which a window is left out (None: no limit). Part of the export's fingerprint (with auto,
    the stored sigmas too: :func:`evpose.core.export.runner` adds them)."""

    inputs: InputSigmas | None
    max_mm: float | None = None
    max_deg: float | None = None

    @property
    def auto(self) -> bool:
        return self.inputs is None

    def __post_init__(self):
        for name in ("max_mm", "max_deg"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"max_label_sigma_{name[4:]}: must be a number > 0, got {v!r}")

    def to_json(self) -> dict:
        return {"inputs": "auto" if self.auto else asdict(self.inputs), "max_mm": self.max_mm,
                "max_deg": self.max_deg}

    def sigmas(self, scene, t_label_us, names, K=None, labels=None) -> "LabelSigmas":
        """:func:`label_sigmas` of these options: the given inputs, or each object's stored ones (auto)."""
        if not self.auto:
            return label_sigmas(scene, t_label_us, names, self.inputs, K, labels)
        return stored_label_sigmas(scene, t_label_us, names, K, labels)

    def keep(self, s: "LabelSigmas") -> np.ndarray:
        """(N,) whether each window's labels are within the limits (a window without a label is kept: it is
        counted as unlabeled)."""
        ok = np.ones(len(s.valid), bool)
        with np.errstate(invalid="ignore"):
            if self.max_mm is not None:
                ok &= ~(np.nanmax(s.sigma_t_mm, axis=1, initial=0.0) > self.max_mm)
            if self.max_deg is not None:
                ok &= ~(np.nanmax(s.sigma_R_deg, axis=1, initial=0.0) > self.max_deg)
        return ok | ~s.valid


def stored_input_sigmas(corrections, name: str) -> tuple[InputSigmas, list]:
    """The input sigmas of object ``name``'s labels from the estimates stored in ``corrections``
    (:attr:`~evpose.core.document.corrections.Corrections.sigmas`: the clock's offset and skew, the object's pose,
    the hand-eye), and the inputs that have none (``"clock offset"``, ``"object pose"``, ``"hand-eye"``: counted as
    exact, so the sigma understates the error by what they add -- said wherever the sigma is shown)."""
    clock = corrections.sigma("clock") or {}
    pose = corrections.sigma(f"object:{name}") or {}
    he = corrections.sigma("hand_eye") or {}
    missing = [what for what, known in (("clock offset", "offset_us" in clock), ("object pose", bool(pose)),
                                        ("hand-eye", bool(he))) if not known]
    return InputSigmas(offset_us=clock.get("offset_us", 0.0), skew_ppm=clock.get("skew_ppm", 0.0),
                       pose_mm=pose.get("mm", 0.0), pose_deg=pose.get("deg", 0.0),
                       hand_eye_mm=he.get("mm", 0.0), hand_eye_deg=he.get("deg", 0.0)), missing


def stored_label_sigmas(scene, t_label_us, names, K=None, labels=None) -> LabelSigmas:
    """:func:`label_sigmas` with each object's own stored input sigmas (:func:`stored_input_sigmas`: the clock and
    the hand-eye are the scene's, shared; the pose sigma each object's), in one pass: ~4 ms a window for 3 objects
    where one pass per object took ~10 (the clock's steps are interpolated once)."""
    inputs = [stored_input_sigmas(scene.corrections, n)[0] for n in names]
    shared = inputs[0] if inputs else InputSigmas()
    return label_sigmas(scene, t_label_us, names, shared, K, labels,
                        pose_sigmas=([i.pose_mm for i in inputs], [i.pose_deg for i in inputs]))
