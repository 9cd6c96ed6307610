"""The image-motion proxy: how fast the camera's motion moves the image (px/s), from the poses.

Clock synchronisation correlates the event rate with this proxy, so it must follow what makes
events: the optical flow of the scene, not the robot's joint speeds. Finite differences of the
poses give each pose interval's mean speed; :func:`_smooth_proxy` turns them into a smooth curve
(a real arm moves smoothly, and a staircase with a step at every pose sample would put a ripple
with the pose period into the likelihood of the offset). The curve is stored as short constant
pieces, or for long trajectories as one linear piece per pose interval, and its mean over any time
interval is exact (a cumulative integral): a sub-bin clock shift needs no resampling. It is computed
in chunks of poses, and takes at most 16 pieces per pose interval up to 2**20 pieces, one beyond
(~40 bytes a pose: 110 MB for 3 hours at 250 Hz). The derivation and the measurements behind
these choices are in ``docs/sync.md``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from evpose.core.data.trajectory import Trajectory

__all__ = ["DEFAULT_DEPTH_M", "MAX_SAMPLED_PIECES", "PROXY_SUB_US", "MotionProxy", "motion_proxy"]

DEFAULT_DEPTH_M = 0.5         # scene distance when no object gives one
PROXY_SUB_US = 250.0          # the motion proxy is sampled at least this finely (a smooth curve, not a staircase)
#: Beyond this many sampled pieces the smooth proxy is stored exactly, one linear piece per pose interval.
MAX_SAMPLED_PIECES = 2**20


@dataclass
class MotionProxy:
    """Image speed (px/s) of the camera motion, piecewise constant or linear between knots.

    Attributes
    ----------
    t0_us : int
        Pose-clock time of the first sample (absolute µs).
    knots_us : (N,) float64
        Knot times relative to ``t0_us``.
    value : (N-1,) float64
        Image speed at the start of each interval, px/s.
    kind : str
    holes_us : (H, 2) float64
        Holes of the trajectory (``[a, b]`` relative to ``t0_us``, sorted): no pose there, so no
        speed; intervals that touch one are not valid in :meth:`mean_over`.
    slope : (N-1,) float64, optional
        Rate of change of the speed within each interval, px/s per µs (None: constant on each interval).
    """

    t0_us: int
    knots_us: np.ndarray
    value: np.ndarray
    kind: str = "flow"
    holes_us: np.ndarray | None = None
    slope: np.ndarray | None = None

    def __post_init__(self):
        self.holes_us = (np.zeros((0, 2)) if self.holes_us is None
                         else np.asarray(self.holes_us, dtype=np.float64).reshape(-1, 2))
        self.knots_us = np.asarray(self.knots_us, dtype=np.float64)
        self.value = np.nan_to_num(np.asarray(self.value, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        if self.slope is not None:
            self.slope = np.nan_to_num(np.asarray(self.slope, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        if len(self.knots_us) >= 2:
            dt = np.diff(self.knots_us)
            area = self.value * dt if self.slope is None else (self.value + 0.5 * self.slope * dt) * dt
            self._F = np.concatenate([[0.0], np.cumsum(area)])
        else:
            self._F = np.zeros(len(self.knots_us))

    def _integral(self, t: np.ndarray) -> np.ndarray:
        """The speed's integral from 0 to ``t`` (px·µs/s), ``t`` relative to ``t0_us`` within the knots."""
        if self.slope is None:
            return np.interp(t, self.knots_us, self._F)
        k = np.clip(np.searchsorted(self.knots_us, t, side="right") - 1, 0, len(self.value) - 1)
        d = t - self.knots_us[k]
        return self._F[k] + d * (self.value[k] + 0.5 * self.slope[k] * d)

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
        out = np.where(valid, (self._integral(b) - self._integral(a)) / np.where(valid, b - a, 1.0), 0.0)
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
    z = np.broadcast_to(np.asarray(depth_m, dtype=np.float64), (n,))
    g = np.zeros((1, 2)) if rays_xy is None else np.asarray(rays_xy, dtype=np.float64).reshape(-1, 2)
    val = np.empty(n - 1)
    for i in range(0, n - 1, chunk):       # chunks of pose intervals: memory independent of the trajectory's length
        s = slice(i, min(i + chunk, n - 1))
        e = slice(i, s.stop + 1)           # the chunk's samples
        dt_s = np.diff(knots[e]) * 1e-6
        rot = Rotation.from_quat(trajectory.quats_xyzw[e])
        rv = (rot[:-1].inv() * rot[1:]).as_rotvec()
        w = rv / dt_s[:, None]
        mid = rot[:-1] * Rotation.from_rotvec(0.5 * rv)
        v = mid.inv().apply(np.diff(trajectory.positions_m[e], axis=0)) / dt_s[:, None]
        zs = np.clip(np.nan_to_num(0.5 * (z[e][:-1] + z[e][1:]), nan=DEFAULT_DEPTH_M), 0.02, 1e3)
        val[s] = _image_speed(v, w, zs, fx, fy, g, kind)
    out = _smooth_proxy(int(t[0]), knots, val, kind) if smooth else MotionProxy(int(t[0]), knots, val, kind)
    out.holes_us = holes
    return out


def _image_speed(v: np.ndarray, w: np.ndarray, z: np.ndarray, fx: float, fy: float, g: np.ndarray,
                 kind: str) -> np.ndarray:
    """Image speed (px/s) of camera-frame velocities ``v`` (m/s) and ``w`` (rad/s) with the scene at depth ``z``
    (m): :func:`motion_proxy`'s ``kind`` over the normalised rays ``g`` (G, 2)."""
    if kind == "speed":
        return fx * (np.linalg.norm(v, axis=1) / z + np.linalg.norm(w, axis=1))
    x, y = g[:, 0][None], g[:, 1][None]
    vx, vy, vz = (v[:, j][:, None] / z[:, None] for j in range(3))
    wx, wy, wz = (w[:, j][:, None] for j in range(3))
    du = fx * ((x * vz - vx) + x * y * wx - (1 + x * x) * wy + y * wz)
    dv = fy * ((y * vz - vy) + (1 + y * y) * wx - x * y * wy - x * wz)
    return np.hypot(du, dv).mean(axis=1)


def _smooth_proxy(t0_us: int, knots_us: np.ndarray, value: np.ndarray, kind: str,
                  sub_us: float = PROXY_SUB_US) -> MotionProxy:
    """The per-interval speeds as a smooth curve: linear between the intervals' midpoints (constant before the
    first and after the last).

    Finite differences of the poses give each interval's *mean* speed, so the raw proxy is a
    staircase with a step at every pose sample, while a real arm (and the simulator) moves
    smoothly. Against a smooth event rate the staircase puts a ripple with the pose period
    (4 ms at 250 Hz) into the likelihood of the offset, which then locks onto a wrong ripple
    crest; the piecewise-linear curve through the midpoints follows the true speed to second
    order. Intervals stay exact where the speed is zero on both sides (dwells stay zero).

    Stored as the curve sampled on sub-intervals of at most ``sub_us`` (up to 16 per pose interval: the bin
    means the clock estimate was tuned on) while that takes at most :data:`MAX_SAMPLED_PIECES` pieces, and
    beyond (trajectories of more than ~4 minutes at 250 Hz) exactly, one linear piece per interval: the same
    bin means up to a partial sub-interval (< 0.1 % of the speed), at a sixteenth of the memory (the samples
    took 4.8 GB for 3 hours of poses at 250 Hz)."""
    dt = np.diff(knots_us)
    if len(value) < 2:
        return MotionProxy(t0_us, knots_us, value, kind)
    mids = 0.5 * (knots_us[:-1] + knots_us[1:])
    n_sub = np.clip(np.ceil(dt / sub_us), 1, 16).astype(np.int64)
    if int(n_sub.sum()) > MAX_SAMPLED_PIECES:
        knots = np.concatenate([knots_us[:1], mids, knots_us[-1:]])
        slope = np.concatenate([[0.0], np.diff(value) / np.diff(mids), [0.0]])
        return MotionProxy(t0_us, knots, np.concatenate([value[:1], value]), kind, slope=slope)
    start = np.repeat(knots_us[:-1], n_sub)
    j = np.arange(int(n_sub.sum())) - np.repeat(np.cumsum(n_sub) - n_sub, n_sub)      # piece in its interval
    width = np.repeat(dt / n_sub, n_sub)
    fine_knots = np.append(start + j * width, knots_us[-1])
    fine_val = np.interp(start + (j + 0.5) * width, mids, value)
    return MotionProxy(t0_us, fine_knots, np.maximum(fine_val, 0.0), kind)
