"""The image-motion proxy: how fast the camera's motion moves the image (px/s), from the poses.

Clock synchronisation correlates the event rate with this proxy, so it must follow what makes
events: the optical flow of the scene, not the robot's joint speeds. Finite differences of the
poses give each pose interval's mean speed; :func:`_smooth_proxy` turns them into a smooth curve
(a real arm moves smoothly, and a staircase with a step at every pose sample would put a ripple
with the pose period into the likelihood of the offset). The curve is piecewise constant on
short pieces, so its mean over any time interval is exact (a cumulative integral): a sub-bin
clock shift needs no resampling. The derivation and the measurements behind these choices are
in ``docs/sync.md``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from evpose.core.data.trajectory import Trajectory

__all__ = ["DEFAULT_DEPTH_M", "PROXY_SUB_US", "MotionProxy", "motion_proxy"]

DEFAULT_DEPTH_M = 0.5         # scene distance when no object gives one
PROXY_SUB_US = 250.0          # the motion proxy is sampled at least this finely (a smooth curve, not a staircase)


@dataclass
class MotionProxy:
    """Image speed (px/s) of the camera motion, piecewise constant between pose samples.

    Attributes
    ----------
    t0_us : int
        Pose-clock time of the first sample (absolute µs).
    knots_us : (N,) float64
        Sample times relative to ``t0_us``.
    value : (N-1,) float64
        Image speed on each interval, px/s.
    kind : str
    holes_us : (H, 2) float64
        Holes of the trajectory (``[a, b]`` relative to ``t0_us``, sorted): no pose there, so no
        speed; intervals that touch one are not valid in :meth:`mean_over`.
    """

    t0_us: int
    knots_us: np.ndarray
    value: np.ndarray
    kind: str = "flow"
    holes_us: np.ndarray | None = None

    def __post_init__(self):
        self.holes_us = (np.zeros((0, 2)) if self.holes_us is None
                         else np.asarray(self.holes_us, dtype=np.float64).reshape(-1, 2))
        self.knots_us = np.asarray(self.knots_us, dtype=np.float64)
        self.value = np.nan_to_num(np.asarray(self.value, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        if len(self.knots_us) >= 2:
            self._F = np.concatenate([[0.0], np.cumsum(self.value * np.diff(self.knots_us))])
        else:
            self._F = np.zeros(len(self.knots_us))

    @property
    def max_px_s(self) -> float:
        return float(self.value.max()) if len(self.value) else 0.0

    def mean_over(self, a_rel: np.ndarray, b_rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean image speed over pose-time intervals ``[a, b)`` (µs relative to ``t0_us``).

        Returns ``(mean px/s, valid)``; invalid (0) where the interval leaves the trajectory or
        overlaps one of its holes (the speed there is unknown, not the mean over the gap).
        """
        a = np.asarray(a_rel, dtype=np.float64)
        b = np.asarray(b_rel, dtype=np.float64)
        if len(self.knots_us) < 2:
            return np.zeros(a.shape), np.zeros(a.shape, bool)
        valid = (a >= 0.0) & (b <= self.knots_us[-1]) & (b > a)
        if len(self.holes_us):
            j = np.searchsorted(self.holes_us[:, 1], a, side="right")      # first hole ending after a
            jc = np.minimum(j, len(self.holes_us) - 1)
            valid &= ~((j < len(self.holes_us)) & (self.holes_us[jc, 0] < b))
        Fa = np.interp(a, self.knots_us, self._F)
        Fb = np.interp(b, self.knots_us, self._F)
        out = np.where(valid, (Fb - Fa) / np.where(valid, b - a, 1.0), 0.0)
        return out, valid


def motion_proxy(trajectory: Trajectory, fx: float, fy: float | None = None, *, rays_xy=None,
                 depth_m=DEFAULT_DEPTH_M, kind: str = "flow", chunk: int = 20000, smooth: bool = True) -> MotionProxy:
    """Image-motion proxy of a trajectory of camera poses ``T_base_cam``.

    Parameters
    ----------
    trajectory : Trajectory
        Camera poses (a ``tcp`` trajectory should be mapped to the camera first).
    fx, fy : float
        Focal lengths, px.
    rays_xy : (G, 2) array, optional
        Normalised image points at which the flow is averaged (default: the optical axis).
    depth_m : float or (N,) array
        Scene distance along the optical axis, metres (per pose sample or constant).
    kind : {"flow", "speed"}
        ``"flow"``: mean over ``rays_xy`` of the optical-flow magnitude of a fronto-parallel
        scene at ``depth_m`` (rotation and translation combined with their true geometry);
        ``"speed"``: ``fx * (|v| / z + |w|)``.
    smooth : bool
        Resample the per-interval speeds as a piecewise-linear curve (:func:`_smooth_proxy`,
        default); False keeps the staircase of interval means.

    Notes
    -----
    Velocities come from consecutive samples: angular from the relative rotation's rotation
    vector (magnitude <= pi, so a 180-degree turn between samples gives pi / dt, no NaN), linear
    expressed in the camera frame at the interval's mid-rotation.
    """
    if kind not in ("flow", "speed"):
        raise ValueError(f"kind must be 'flow' or 'speed', got {kind!r}")
    fy = fx if fy is None else fy
    t = trajectory.t_us
    knots = (t - t[0]).astype(np.float64)
    n = len(t)
    holes = np.array([(a - t[0], b - t[0]) for a, b in trajectory.holes], np.float64).reshape(-1, 2)
    if n < 2:
        return MotionProxy(int(t[0]), knots, np.zeros(0), kind)
    dt_s = np.diff(knots) * 1e-6
    rot = Rotation.from_quat(trajectory.quats_xyzw)
    rv = (rot[:-1].inv() * rot[1:]).as_rotvec()
    w = rv / dt_s[:, None]
    mid = rot[:-1] * Rotation.from_rotvec(0.5 * rv)
    v = mid.inv().apply(np.diff(trajectory.positions_m, axis=0)) / dt_s[:, None]
    z = np.broadcast_to(np.asarray(depth_m, dtype=np.float64), (n,))
    z = np.clip(np.nan_to_num(0.5 * (z[:-1] + z[1:]), nan=DEFAULT_DEPTH_M), 0.02, 1e3)
    if kind == "speed":
        val = fx * (np.linalg.norm(v, axis=1) / z + np.linalg.norm(w, axis=1))
    else:
        g = np.zeros((1, 2)) if rays_xy is None else np.asarray(rays_xy, dtype=np.float64).reshape(-1, 2)
        x, y = g[:, 0][None], g[:, 1][None]
        val = np.empty(n - 1)
        for i in range(0, n - 1, chunk):
            s = slice(i, i + chunk)
            vx, vy, vz = (v[s, j][:, None] / z[s, None] for j in range(3))
            wx, wy, wz = (w[s, j][:, None] for j in range(3))
            du = fx * ((x * vz - vx) + x * y * wx - (1 + x * x) * wy + y * wz)
            dv = fy * ((y * vz - vy) + (1 + y * y) * wx - x * y * wy - x * wz)
            val[s] = np.hypot(du, dv).mean(axis=1)
    out = _smooth_proxy(int(t[0]), knots, val, kind) if smooth else MotionProxy(int(t[0]), knots, val, kind)
    out.holes_us = holes
    return out


def _smooth_proxy(t0_us: int, knots_us: np.ndarray, value: np.ndarray, kind: str,
                  sub_us: float = PROXY_SUB_US) -> MotionProxy:
    """The per-interval speeds as a smooth curve: linear between the intervals' midpoints,
    sampled on sub-intervals of at most ``sub_us`` (up to 16 per pose interval).

    Finite differences of the poses give each interval's *mean* speed, so the raw proxy is a
    staircase with a step at every pose sample, while a real arm (and the simulator) moves
    smoothly. Against a smooth event rate the staircase puts a ripple with the pose period
    (4 ms at 250 Hz) into the likelihood of the offset, which then locks onto a wrong ripple
    crest; the piecewise-linear curve through the midpoints follows the true speed to second
    order. Intervals stay exact where the speed is zero on both sides (dwells stay zero)."""
    dt = np.diff(knots_us)
    if len(value) < 2:
        return MotionProxy(t0_us, knots_us, value, kind)
    n_sub = np.clip(np.ceil(dt / sub_us), 1, 16).astype(np.int64)
    start = np.repeat(knots_us[:-1], n_sub)
    j = np.arange(int(n_sub.sum())) - np.repeat(np.cumsum(n_sub) - n_sub, n_sub)      # piece in its interval
    width = np.repeat(dt / n_sub, n_sub)
    fine_knots = np.append(start + j * width, knots_us[-1])
    mids = 0.5 * (knots_us[:-1] + knots_us[1:])
    fine_val = np.interp(start + (j + 0.5) * width, mids, value)
    return MotionProxy(t0_us, fine_knots, np.maximum(fine_val, 0.0), kind)
