"""Clock synchronisation: the event clock against the robot (pose) clock.

Estimates the clock model of DESIGN section 3,
``t_pose_us = t_event_us + offset_us + skew_ppm * 1e-6 * (t_event_us - t_ref_us)``,
from two signals that both follow the camera's motion:

* the **event rate**: counts per bin (default 1 ms) from the store's ms index
  (:meth:`evpose.core.data.events.EventStore.rate`, no event is read), and
* an **image-motion proxy** from the trajectory: the mean optical-flow magnitude (px/s) over a
  grid of pixel rays for a scene at the distance of the objects (``kind="flow"``, default), or
  ``fx * (|v| / z + |w|)`` (``kind="speed"``). Finite differences of the poses give each
  pose interval's mean speed; the proxy runs linearly through them at the intervals' midpoints,
  sampled every 250 µs (:func:`_smooth_proxy`: a real arm moves smoothly, and a staircase with a
  step at every pose sample would put a ripple with the pose period into the likelihood). It is
  piecewise constant on those pieces, so its mean over any time interval is exact (a cumulative
  integral): sub-bin shifts need no resampling.

Method (:func:`estimate_clock`)
-------------------------------
1. Both signals are smoothed with the same Gaussian (``smooth_us``) and mapped through a
   monotone transform (``"log"``: ``log(x + c)`` with ``c`` half the median, default; or
   ``"linear"``). The log map makes the correlation robust to the unknown gain between image
   motion and event rate (it becomes an additive term), to hot pixels (a constant rate), noise
   and bursts, and it gives the starts and stops of the motion (where the rate rises from the
   noise floor) the weight they deserve: they carry most of the timing information.
2. **Coarse offset**: masked normalised cross-correlation (NCC) of the two series for every
   whole-bin lag in ``±range_us`` around the clock in effect (FFT-based through
   :func:`scipy.signal.correlate`, which picks FFT when it pays); the NCC at each lag uses only
   the bins where the trajectory exists. Parabolic interpolation of the peak gives a sub-bin
   offset.
3. **Skew**: the same estimate on ``n_segments`` consecutive segments (search ``±`` the drift
   that ``max_skew_ppm`` allows), each refined continuously; a Theil-Sen line through the
   segment offsets gives skew (its slope, µs/s = ppm) and offset (its value at ``t_ref``).
   A line whose 90 % interval is wider than ±100 ppm (a few loose segments) is checked on the
   whole sequence's likelihood instead (:func:`_joint_skew`: accepted when the likelihood ratio
   against the prior skew passes :data:`SKEW_MIN_LR` and the optimum stays inside the interval).
4. **Continuous refinement** (``refine="ml"``, default): the Poisson likelihood of the raw
   counts under ``noise floor + exp(gain polynomial per block) x proxy`` (:class:`_PoissonFit`)
   is maximised over the offset (a quarter-bin scan of ±10 ms around the NCC estimate, then
   Brent), per segment before the Theil-Sen line and on the whole sequence after it (with the
   skew, Nelder-Mead in 2-D). The proxy is re-integrated exactly for each candidate clock.
   The gain (one smooth curve per ~1 s block of motion) takes up what the proxy cannot know -
   the scene's contrast, which edges are in view, the direction of motion - which biases the
   NCC peak by 0.2-2 ms on rendered scenes; the timing then comes from the shape of the rate,
   where motion starts and stops most of all. ``refine="ncc"`` maximises the full-sequence NCC
   instead.
5. **Uncertainty**: ``offset_std_us``, the standard error from the curvature of the likelihood's
   envelope (:func:`_likelihood_std_us`); a note when it exceeds :data:`SLOW_STD_NOTE_US`.
6. **Reliability**: no estimate (``reliable=False``, ``offset_us=None``) for a sequence that is
   too short, empty or has a constant event rate, a static camera, a flat correlation
   (low or broad peak), a periodic motion (a second correlation peak nearly as high as the
   best), or a best lag outside the search range. ``confidence`` combines the peak NCC and its
   margin over the second-best peak.

The original E-POSE approach is kept as a named baseline, :func:`sync_minima_baseline`: match
minima of the smoothed event rate to minima of the robot speed and average the differences.

Accuracy (``bench/accuracy.py``, ``docs/accuracy.txt``; rendered scenes with smooth motion): on
8 s scenes at 87x65 (~25-75 k events/s) the default estimate is within ~0.4 ms at 0.5-1.0 m/s
(NCC alone: 0.5-1.2 ms), about twice the reported standard error: the simulated events lag the
motion by ~0.4-0.9 ms, tied to the contrast thresholds (about -0.55 ms with a 4x lower
threshold, -1.3 ms with identical thresholds in every pixel; unchanged without the refractory
period or with 4x finer frames). A dead band at the onset of each move (a rate deficit over the
first fraction of a pixel of image motion, for the share of pixels whose brightness change
reverses) does not describe it: the likelihood rejects it. The likelihood also has local modes
~1.5 ms apart, and how the gain blocks are laid out decides between them at times. Other gain models measured no better on these scenes: one block per
run of motion (same), 0.5 s blocks or cubic gains (worse), a cubic spline continuous over each run
(0.5-2.7 ms). Skew of 20 s
sequences: ~9 ppm median. At 0.1 m/s the offset is off by 4-10 ms, consistent with the reported
standard error (1.6-4.9 ms): a slow move starts and stops gradually, and its rate carries little
timing. The second stage, :func:`evpose.core.align.refine.refine_offset_from_sync` (``evpose sync --edges``),
fits offset and skew to the event edges within 3 of these standard errors and takes the error to
~0.1-0.3 ms at every speed, provided the object poses are right.

Units: times are int64 µs on the event clock (``t_ref_us`` = first event), offsets µs, skew ppm.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, optimize, signal, stats
from scipy.spatial.transform import Rotation

from evpose.core.data.events import Cancelled
from evpose.core.data.trajectory import ClockModel, Trajectory

__all__ = ["MotionProxy", "SyncResult", "SegmentOffset", "motion_proxy", "scene_motion_proxy",
           "estimate_clock", "sync_scene", "minima_baseline", "sync_minima_baseline", "clock_correction",
           "apply_sync"]

#: Thresholds of the reliability decision (see :func:`estimate_clock`).
MIN_PEAK_NCC = 0.3            # peak normalised correlation below this: "flat correlation"
MAX_SECOND_PEAK_RATIO = 0.85  # second-best peak above this fraction of the best (above the curve's median): ambiguous
MAX_PEAK_HWHM_FRACTION = 0.8  # main lobe half width above this fraction of the range: "flat correlation"
MIN_DURATION_US = 300_000     # shorter sequences: "too short"
MIN_MOTION_PX_S = 5.0         # largest image speed below this: "static camera"
DEFAULT_DEPTH_M = 0.5         # scene distance when no object gives one
PROXY_SUB_US = 250.0          # the motion proxy is sampled at least this finely (a smooth curve, not a staircase)
SLOW_STD_NOTE_US = 1000.0     # offset standard error above this: a note says how loosely the rate pins it
SKEW_MIN_LR = 10.8            # likelihood ratio for a skew the segment line alone could not establish (p = 0.001)
STD_SCAN_FACTOR = 3.0         # the likelihood scan for the standard error reaches this x the ML search half width


# ---------------------------------------------------------------------------- motion proxy
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
    def span_us(self) -> float:
        return float(self.knots_us[-1]) if len(self.knots_us) else 0.0

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


def _ray_grid(camera, n_u: int = 8, n_v: int = 6) -> np.ndarray:
    """Normalised rays ``(G, 2)`` of an ``n_u x n_v`` grid of pixel centres (valid ones)."""
    xy, ok = camera.pixel_rays()
    H, W = ok.shape
    us = np.linspace(0.5 * W / n_u, W - 0.5 * W / n_u, n_u).astype(int)
    vs = np.linspace(0.5 * H / n_v, H - 0.5 * H / n_v, n_v).astype(int)
    g = xy[np.ix_(vs, us)].reshape(-1, 2)
    good = ok[np.ix_(vs, us)].ravel()
    return g[good] if good.any() else np.zeros((1, 2))


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


def _camera_trajectory(scene) -> Trajectory:
    """The scene's trajectory as camera poses (hand-eye applied for ``tcp`` trajectories)."""
    traj = scene.trajectory
    he = scene.manifest.hand_eye if scene.manifest.trajectory_frame == "tcp" else None
    dT = scene.corrections.hand_eye_delta
    if he is None and np.array_equal(dT, np.eye(4)):
        return traj
    T = traj.T()
    if he is not None:
        T = T @ he
    T = T @ dT
    return Trajectory.from_T(traj.t_us, T, source=traj.source, max_gap_us=traj.max_gap_us)


def scene_motion_proxy(scene, kind: str = "flow", grid=(8, 6)) -> MotionProxy:
    """:func:`motion_proxy` of a scene's camera, with the depth of the objects' box centres
    (median over objects, per pose sample; :data:`DEFAULT_DEPTH_M` where none is in front)."""
    traj = _camera_trajectory(scene)
    T = traj.T()
    centres = []
    for name in scene.object_names:
        try:
            c = scene.model(name).bbox_center_m
        except Exception:  # a missing mesh must not prevent synchronisation: use the origin
            c = np.zeros(3)
        Tb = scene.T_base_obj(name)
        centres.append(Tb[:3, :3] @ c + Tb[:3, 3])
    if centres:
        C = np.asarray(centres)                                      # (K, 3) base frame
        d = C[None, :, :] - T[:, None, :3, 3]                       # (N, K, 3)
        z = np.einsum("nij,nki->nkj", T[:, :3, :3], d)[..., 2]     # camera-frame z
        z = np.where(z > 0.05, z, np.nan)
        with np.errstate(all="ignore"):
            depth = np.nanmedian(np.where(np.isnan(z).all(axis=1, keepdims=True), DEFAULT_DEPTH_M, z), axis=1)
    else:
        depth = DEFAULT_DEPTH_M
    K = scene.camera.K
    return motion_proxy(traj, K[0, 0], K[1, 1], rays_xy=_ray_grid(scene.camera, *grid), depth_m=depth, kind=kind)


# ---------------------------------------------------------------------------- results
@dataclass
class SegmentOffset:
    """Offset estimated on one segment of the sequence (event clock)."""

    t0_us: int
    t1_us: int
    t_center_us: int
    offset_us: float | None
    peak: float
    used: bool

    def to_json(self) -> dict:
        return {"t0_us": self.t0_us, "t1_us": self.t1_us, "t_center_us": self.t_center_us,
                "offset_us": self.offset_us, "peak": self.peak, "used": self.used}


@dataclass
class SyncResult:
    """Outcome of a clock estimate.

    Attributes
    ----------
    offset_us : int or None
        Total effective offset (prior + correction) at ``t_ref_us``, µs; None when unreliable.
    skew_ppm : float or None
        Total effective skew, ppm; None when not estimated (too short for skew, or unreliable):
        the clock's skew in effect is then kept.
    confidence : float
        In [0, 1]: peak NCC times its margin over the second-best peak.
    reliable : bool
    reason : str
        Why the estimate is unreliable ("" when reliable).
    lags_us : (L,) float64
        Total offsets at which the correlation curve is evaluated (for plots and the GUI).
    correlation : (L,) float64
        NCC per lag; NaN where too few bins overlap.
    segments : list of SegmentOffset
        Per-segment offsets used for the skew (empty when skew was not estimated).
    runtime_s : float
    offset_std_us : float or None
        Standard error (1 sigma) of ``offset_us`` from the curvature of the Poisson likelihood
        (``refine="ml"`` only; at the skew in effect before the final 2-D refinement): how
        tightly the event rate pins the offset. ``inf`` when the likelihood is flat over its
        scan (±30 ms at 1 ms bins); None when not computed. Sub-millisecond at 0.5-1 m/s, several ms for slow (0.1 m/s) sequences
        with few moves - a property of the data, not a failure: the timing comes from where the
        motion starts and stops, and gradual starts carry little of it.
    """

    offset_us: int | None
    skew_ppm: float | None
    confidence: float
    reliable: bool
    reason: str
    lags_us: np.ndarray
    correlation: np.ndarray
    segments: list = field(default_factory=list)
    runtime_s: float = 0.0
    method: str = "xcorr"
    peak: float = float("nan")
    second_peak: float = float("nan")
    peak_hwhm_us: float = float("nan")
    prior_offset_us: int = 0
    prior_skew_ppm: float = 0.0
    t_ref_us: int = 0
    notes: list = field(default_factory=list)
    offset_std_us: float | None = None

    def clock(self) -> ClockModel | None:
        """The estimated clock model (prior skew kept when skew was not estimated)."""
        if self.offset_us is None:
            return None
        return ClockModel(int(self.offset_us), self.prior_skew_ppm if self.skew_ppm is None else float(self.skew_ppm),
                          self.t_ref_us)

    def to_json(self, curve: bool = False) -> dict:
        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)

        d = {"method": self.method, "offset_us": self.offset_us, "skew_ppm": num(self.skew_ppm),
             "confidence": float(self.confidence), "reliable": bool(self.reliable), "reason": self.reason,
             "runtime_s": float(self.runtime_s), "peak_ncc": num(self.peak), "second_peak_ncc": num(self.second_peak),
             "peak_hwhm_us": num(self.peak_hwhm_us), "prior_offset_us": int(self.prior_offset_us),
             "prior_skew_ppm": float(self.prior_skew_ppm), "t_ref_us": int(self.t_ref_us),
             "offset_std_us": None if self.offset_std_us is None else num(self.offset_std_us),
             "offset_pinned": None if self.offset_std_us is None else bool(math.isfinite(self.offset_std_us)),
             "segments": [s.to_json() for s in self.segments], "notes": list(self.notes)}
        if curve:
            d["lags_us"] = [float(x) for x in self.lags_us]
            d["correlation"] = [num(x) for x in self.correlation]
        return d


def _unreliable(reason: str, t_start: float, prior: ClockModel, method="xcorr", lags=None, corr=None,
                **kw) -> SyncResult:
    return SyncResult(None, None, 0.0, False, reason, np.zeros(0) if lags is None else lags,
                      np.zeros(0) if corr is None else corr, runtime_s=time.perf_counter() - t_start,
                      method=method, prior_offset_us=int(prior.offset_us), prior_skew_ppm=float(prior.skew_ppm),
                      t_ref_us=int(prior.t_ref_us), **kw)


# ---------------------------------------------------------------------------- signal helpers
def _gauss(x: np.ndarray, mask: np.ndarray, sigma_bins: float) -> tuple[np.ndarray, np.ndarray]:
    """Normalised (masked) Gaussian smoothing; returns ``(smoothed, still_valid)``."""
    if sigma_bins <= 0:
        return np.where(mask, x, 0.0), mask.copy()
    m = mask.astype(np.float64)
    num = ndimage.gaussian_filter1d(np.where(mask, x, 0.0), sigma_bins, mode="constant", truncate=3.0)
    den = ndimage.gaussian_filter1d(m, sigma_bins, mode="constant", truncate=3.0)
    ok = mask & (den > 0.999)  # bins whose whole kernel lies on valid data
    return np.where(den > 1e-12, num / np.maximum(den, 1e-12), 0.0), ok


class _Transform:
    """A fixed monotone map fitted on reference values (so it stays continuous when re-applied)."""

    def __init__(self, kind: str, ref: np.ndarray):
        self.kind = kind
        ref = ref[np.isfinite(ref)]
        if kind == "log":
            med = float(np.median(ref)) if len(ref) else 0.0
            top = float(np.max(ref)) if len(ref) else 0.0
            self.c = max(0.5 * med, 1e-3 * top, 1e-12)
        elif kind != "linear":
            raise ValueError(f"transform must be 'log' or 'linear', got {kind!r}")

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if self.kind == "log":
            return np.log(np.maximum(x, 0.0) + self.c)
        return x


def _masked_ncc(a: np.ndarray, ma: np.ndarray, b: np.ndarray, mb: np.ndarray, min_overlap: float):
    """NCC of ``a`` (length K) against every length-K window of ``b`` (length K + 2L).

    Returns ``(ncc (2L+1,), overlap (2L+1,))``; lag ``j`` compares ``a[k]`` with ``b[k + j]``.
    Only bins valid in both series count; NaN where the overlap is below ``min_overlap`` bins.
    """
    A, MA = np.where(ma, a, 0.0), ma.astype(np.float64)
    B, MB = np.where(mb, b, 0.0), mb.astype(np.float64)

    def corr(x, y):  # sum_k x[k] * y[k + j]
        return signal.correlate(y, x, mode="valid", method="auto")

    N = np.rint(corr(MA, MB))
    SA, SB = corr(A, MB), corr(MA, B)
    SAA, SBB, SAB = corr(A * A, MB), corr(MA, B * B), corr(A, B)
    with np.errstate(invalid="ignore", divide="ignore"):
        Nn = np.maximum(N, 1.0)
        cov = SAB - SA * SB / Nn
        va = SAA - SA * SA / Nn
        vb = SBB - SB * SB / Nn
        ncc = cov / np.sqrt(va * vb)
    bad = (N < min_overlap) | (va <= 1e-12 * np.maximum(SAA, 1e-300)) | (vb <= 1e-12 * np.maximum(SBB, 1e-300)) \
        | ~np.isfinite(ncc)
    ncc[bad] = np.nan
    return np.clip(ncc, -1.0, 1.0), N


def _ncc_1d(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    d = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / d if d > 0 else float("nan")


def _parabolic(y_m: float, y0: float, y_p: float) -> float:
    den = y_m - 2.0 * y0 + y_p
    if not (np.isfinite(den) and den < 0):
        return 0.0
    return float(np.clip(0.5 * (y_m - y_p) / den, -0.5, 0.5))


def _peak_analysis(ncc: np.ndarray, bin_lag: float, i_lo: int, i_hi: int):
    """Main peak (index within [i_lo, i_hi]), sub-bin shift, second-best peak and half width.

    Returns ``(i_peak, delta, peak, second, hwhm_bins, at_edge)`` or None when all NaN.
    """
    c = np.where(np.isfinite(ncc), ncc, -np.inf)
    if not np.isfinite(c).any():
        return None
    i = int(np.argmax(c))
    at_edge = not (i_lo <= i <= i_hi) or i == 0 or i == len(c) - 1 or not (
        np.isfinite(c[i - 1]) and np.isfinite(c[i + 1]))
    if at_edge:
        # the best match overall is outside the search range: also report the best inside
        return i, 0.0, float(c[i]), float("nan"), float("nan"), True, float("nan")
    peak = float(c[i])
    delta = _parabolic(c[i - 1], peak, c[i + 1])
    finite = c[np.isfinite(c)]
    base = float(np.median(finite))
    half = 0.5 * (peak + base)
    left = i
    while left > 0 and c[left - 1] > half:
        left -= 1
    right = i
    while right < len(c) - 1 and c[right + 1] > half:
        right += 1
    hwhm = 0.5 * (right - left + 1)
    # second-best peak: the highest other local maximum separated from the main peak by a real
    # valley (deeper than a quarter of its height above the median), so that ripples on the
    # flanks of the main lobe do not count
    second = float("-inf")
    peaks, _ = signal.find_peaks(np.where(np.isfinite(c), c, -2.0))
    for p in peaks:
        if p == i or not np.isfinite(c[p]):
            continue
        seg = c[min(p, i):max(p, i) + 1]
        valley = float(np.min(seg[np.isfinite(seg)])) if np.isfinite(seg).any() else -2.0
        if c[p] - valley >= 0.25 * max(c[p] - base, 1e-3) and c[p] - valley >= 0.02:
            second = max(second, float(c[p]))
    if not np.isfinite(second):
        second = base
    return i, delta, peak, second, hwhm, False, base


def _ambiguity(peak: float, second: float, base: float) -> float:
    """Height of the second-best peak relative to the best, both above the curve's median:
    ~1 for periodic motion, small for a unique match (slow motion gives broad, high
    correlation everywhere, so the raw ratio second / peak would be misleading)."""
    if not (np.isfinite(second) and np.isfinite(peak)):
        return 0.0
    b = base if np.isfinite(base) else 0.0
    b = min(b, second)
    return float(np.clip((second - b) / max(peak - b, 1e-9), 0.0, 1.0))


def _confidence(peak: float, ambiguity: float) -> float:
    """In [0, 1]: the peak NCC times how clearly it beats the second-best peak."""
    if not np.isfinite(peak) or peak <= 0:
        return 0.0
    margin = 1.0 - ambiguity
    return float(np.clip(peak, 0, 1) * np.clip(margin / (1.0 - MAX_SECOND_PEAK_RATIO) / 2.0, 0, 1))


# ---------------------------------------------------------------------------- the estimator
class _Problem:
    """The event series and the proxy, prepared for NCC evaluations at arbitrary clocks."""

    def __init__(self, starts_us, counts, bin_us, proxy: MotionProxy, prior: ClockModel, sigma_bins, transform):
        self.bin_us = int(bin_us)
        self.starts = np.asarray(starts_us, dtype=np.int64)
        self.proxy = proxy
        self.prior = prior
        self.sigma = sigma_bins
        self.transform_kind = transform
        c = np.asarray(counts, dtype=np.float64)
        self.counts = c
        m = np.ones(len(c), bool)
        e, ok = _gauss(c, m, sigma_bins)
        self.e_raw = e
        self.e_tf = _Transform(transform, e[ok])
        self.e = self.e_tf(e)
        self.me = ok
        # float offsets of the bin starts relative to the trajectory origin and to t_ref
        self.d0 = (self.starts - np.int64(proxy.t0_us)).astype(np.float64)
        self.dr = (self.starts - np.int64(prior.t_ref_us)).astype(np.float64)
        self.p_tf = None

    def proxy_bins(self, offset_us: float, skew_ppm: float, shift_bins: np.ndarray | None = None):
        """Bin means of the proxy for event bins (optionally shifted by whole bins)."""
        d0, dr = self.d0, self.dr
        if shift_bins is not None:
            d0 = d0[0] + shift_bins * float(self.bin_us)
            dr = dr[0] + shift_bins * float(self.bin_us)
        k = 1.0 + skew_ppm * 1e-6
        a = d0 + offset_us + skew_ppm * 1e-6 * dr
        return self.proxy.mean_over(a, a + self.bin_us * k)

    def prepared_proxy(self, offset_us, skew_ppm, shift_bins=None):
        p, mp = self.proxy_bins(offset_us, skew_ppm, shift_bins)
        ps, ok = _gauss(p, mp, self.sigma)
        if self.p_tf is None:
            self.p_tf = _Transform(self.transform_kind, ps[ok])
        return self.p_tf(ps), ok, ps

    def calibrate(self, offset_us, skew_ppm, sel, gain_us: float = 50_000):
        """Fit the rate model ``lambda = G(t) * proxy + n0`` at a clock (for :meth:`fit_at`):
        ``n0`` is the rate where the camera stands still, ``G(t)`` the ratio of rate to proxy
        smoothed over ``gain_us`` (the scene's content changes the gain slowly)."""
        _, ok, ps = self.prepared_proxy(offset_us, skew_ppm)
        use = sel & ok
        e = self.e_raw
        top = float(ps[use].max()) if use.any() else 0.0
        still = use & (ps <= 0.002 * top)
        self.n0 = float(np.median(e[still])) if still.sum() >= 20 else float(np.percentile(e[use], 5)) if use.any() else 0.0
        moving = use & (ps > 0.05 * top)
        w = moving.astype(np.float64)
        r = np.where(moving, np.log(np.maximum(e - self.n0, 1e-3)) - np.log(np.maximum(ps, 1e-12)), 0.0)
        W = gain_us / self.bin_us
        num = ndimage.gaussian_filter1d(r * w, W, mode="nearest")
        den = ndimage.gaussian_filter1d(w, W, mode="nearest")
        glob = float(np.median(r[moving])) if moving.any() else 0.0
        self.G = np.exp(np.where(den > 1e-3, num / np.maximum(den, 1e-3), glob))
        self.c = max(self.n0, 1.0)
        self.E = np.log(e + self.c)

    def fit_at(self, offset_us, skew_ppm, sel) -> float:
        """Weighted least squares of log rate against the calibrated model (higher is better):
        ``-sum w (log(e + c) - log(G p + n0 + c))^2 / sum w`` with ``w = G p + n0``, the inverse
        variance of a log Poisson count (the maximum-likelihood weighting)."""
        _, ok, ps = self.prepared_proxy(offset_us, skew_ppm)
        use = sel & ok
        if use.sum() < 10:
            return float("nan")
        lam = self.G[use] * ps[use] + self.n0
        w = lam + 1e-9
        r = self.E[use] - np.log(lam + self.c)
        return -float((w * r * r).sum() / w.sum())

    def ncc_at(self, offset_us, skew_ppm, sel: np.ndarray) -> float:
        """Full NCC at a clock over the fixed bin selection ``sel``."""
        p, ok, _ = self.prepared_proxy(offset_us, skew_ppm)
        use = sel & ok
        if use.sum() < 10:
            return float("nan")
        return _ncc_1d(self.e[use], p[use])


class _PoissonFit:
    """Poisson likelihood of the binned counts under ``lambda = n0 + exp(g_b(t)) * proxy``: a
    noise floor ``n0`` (background activity and hot pixels, per bin) plus the image motion
    times a gain that varies slowly inside each block ``b`` (a polynomial of degree ``deg`` in
    time). The gain absorbs what the proxy does not know (the scene's contrast, which edges are
    in view, the direction of motion), so the timing comes from the *shape* of the rate - most
    of all where the motion starts and stops - and not from its level.

    The blocks are fixed bin ranges (runs of motion at the start clock, widened by ``margin``
    bins and cut into pieces of at most ``max_len`` bins), so the likelihood of different clocks
    is computed on the same bins. :meth:`loglik` profiles the gains out (Fisher scoring, all
    blocks at once).
    """

    def __init__(self, prob: "_Problem", offset_us: float, skew_ppm: float, sel: np.ndarray, margin: int,
                 max_len: int, deg: int = 2):
        self.prob = prob
        c = prob.counts
        p_lo, ok_lo = prob.proxy_bins(offset_us - margin * prob.bin_us, skew_ppm)
        p_hi, ok_hi = prob.proxy_bins(offset_us + margin * prob.bin_us, skew_ppm)
        p, ok = prob.proxy_bins(offset_us, skew_ppm)
        use = sel & ok & ok_lo & ok_hi
        top = float(p[use].max()) if use.any() else 0.0
        moving = use & (p > 1e-3 * top)
        still = use & (p <= 0.0) & (p_lo <= 0.0) & (p_hi <= 0.0)
        if still.sum() >= 50:
            n0 = float(np.mean(c[still]))
        elif use.any():
            n0 = 0.5 * float(np.percentile(c[use], 5))
        else:
            n0 = 0.0
        self.n0 = max(n0, 0.05)
        wide = ndimage.binary_dilation(moving, iterations=max(int(margin), 1)) & use
        blocks = []
        lab, n = ndimage.label(wide)
        for sl in ndimage.find_objects(lab):
            a, b = sl[0].start, sl[0].stop
            k = max(1, int(math.ceil((b - a) / max_len)))
            edges = np.linspace(a, b, k + 1).astype(int)
            blocks += [(int(x), int(y)) for x, y in zip(edges[:-1], edges[1:]) if y - x >= 10]
        self.blocks = blocks
        self.ok = bool(blocks) and moving.sum() >= 10
        if not self.ok:
            return
        self.idx = np.concatenate([np.arange(a, b) for a, b in blocks])
        self.bid = np.concatenate([np.full(b - a, j) for j, (a, b) in enumerate(blocks)])
        self.starts = np.cumsum([0] + [b - a for a, b in blocks[:-1]])
        u = np.concatenate([np.linspace(-1.0, 1.0, b - a) for a, b in blocks])
        self.X = np.polynomial.legendre.legvander(u, deg)                    # (N, D)
        self.XX = self.X[:, :, None] * self.X[:, None, :]                    # (N, D, D)
        self.c = c[self.idx]
        self.beta = None

    def loglik(self, offset_us: float, skew_ppm: float) -> float:
        """Profile log-likelihood (up to a constant) at a clock; higher is better."""
        p, _ = self.prob.proxy_bins(offset_us, skew_ppm)
        p = np.maximum(p[self.idx], 0.0)
        B, D = len(self.blocks), self.X.shape[1]
        c, n0, X = self.c, self.n0, self.X
        if self.beta is None:
            sc = np.add.reduceat(c, self.starts)
            sp = np.add.reduceat(p, self.starts)
            beta = np.zeros((B, D))
            beta[:, 0] = np.log(np.maximum(sc - n0 * np.diff(np.append(self.starts, len(c))), 1.0)
                                / np.maximum(sp, 1e-9))
        else:
            beta = self.beta.copy()
        ridge = 1e-8 * np.eye(D)
        for _ in range(30):
            mu = np.exp(np.clip(np.einsum("nd,nd->n", X, beta[self.bid]), -50, 50)) * p
            lam = n0 + mu
            grad = np.add.reduceat(X * ((c / lam - 1.0) * mu)[:, None], self.starts)
            H = np.add.reduceat(self.XX * (mu * mu / lam)[:, None, None], self.starts)
            H += ridge * (1.0 + np.trace(H, axis1=1, axis2=2))[:, None, None]
            step = np.clip(np.linalg.solve(H, grad[..., None])[..., 0], -2.0, 2.0)
            beta += step
            if np.abs(step).max() < 1e-7:
                break
        self.beta = beta
        mu = np.exp(np.clip(np.einsum("nd,nd->n", X, beta[self.bid]), -50, 50)) * p
        lam = n0 + mu
        return float(np.sum(c * np.log(lam) - lam))


def _ml_offset(prob, sel, offset0, skew, half_width_us, margin_extra_us=50_000, max_block_us=1_000_000,
               xatol=2.0, std: bool = False):
    """Maximum-likelihood offset (:class:`_PoissonFit`) in ``offset0 ± half_width``: a scan at a
    quarter bin, then a bounded Brent search around the best point.

    Returns ``(offset, fit, std_us)``; ``offset`` is None when the model cannot be set up or the
    best point is at the edge of the scan. With ``std``, the scan is extended at whole-bin steps
    to ``± STD_SCAN_FACTOR x half_width`` and ``std_us`` is :func:`_likelihood_std_us` (also when
    the maximum is at the edge: then around ``offset0``); otherwise None."""
    bin_us = prob.bin_us
    outer_us = STD_SCAN_FACTOR * half_width_us if std else half_width_us
    margin = int(math.ceil((outer_us + margin_extra_us) / bin_us))
    fit = _PoissonFit(prob, offset0, skew, sel, margin, max(int(max_block_us / bin_us), 20))
    if not fit.ok:
        return None, fit, None
    step = max(bin_us / 4.0, 50.0)
    n = int(math.ceil(half_width_us / step))
    grid = offset0 + step * np.arange(-n, n + 1)
    ll = np.array([fit.loglik(o, skew) for o in grid])
    if not np.isfinite(ll).any():
        return None, fit, None
    if std:     # whole-bin steps beyond the fine scan (_likelihood_std_us needs no order)
        k = np.arange(1, int(math.ceil((outer_us - n * step) / bin_us)) + 1)
        far = np.concatenate([grid[0] - bin_us * k, grid[-1] + bin_us * k])
        scan = (np.concatenate([grid, far]), np.concatenate([ll, [fit.loglik(o, skew) for o in far]]))
    i = int(np.nanargmax(ll))
    if i == 0 or i == len(grid) - 1:
        best = None
    else:
        res = optimize.minimize_scalar(lambda o: -fit.loglik(o, skew), bounds=(grid[i - 1], grid[i + 1]),
                                       method="bounded", options={"xatol": xatol})
        best = float(res.x) if -res.fun >= ll[i] else float(grid[i])
    std_us = _likelihood_std_us(*scan, offset0 if best is None else best, bin_us) if std else None
    return best, fit, std_us


def _likelihood_std_us(grid_us: np.ndarray, loglik: np.ndarray, best_us: float, bin_us: int) -> float:
    """Standard error (1 sigma, µs) of the offset from the curvature of the profile
    log-likelihood: a least-squares parabola ``a x^2 + b x + c`` through the scan, first over all
    of it, then over ``best ± max(3 sigma, 2 bins)``; ``sigma = sqrt(-1 / 2a)``.

    The parabola follows the likelihood's *envelope*: its local curvature at the maximum can be
    far sharper (ripples at the pose-sample period where the camera really moves piecewise
    linearly, a kink where bins line up with the simulator's frames) and would claim a precision
    the data do not hold. On counts drawn from the fitted model the spread of the estimates
    matches this sigma (0.1 m/s, 8 s scenes: RMS 3.5 / 4.1 ms against sigma 3.8 / 4.7 ms), and
    on rate-level scenes RMS error / sigma is 1.2 (``tests/core/test_sync.py``). Model error is
    not in it. Returns ``inf`` when the scan is flat or curves up (the offset is not pinned
    within it)."""
    x = (np.asarray(grid_us, np.float64) - best_us) * 1e-3            # ms: a well-conditioned fit
    y = np.asarray(loglik, np.float64)
    ok = np.isfinite(y)
    half_ms = float(np.abs(x[ok]).max()) if ok.any() else 0.0
    sigma = math.inf
    for width in (half_ms, None):
        if width is None:
            if not math.isfinite(sigma):
                break
            width = max(3.0 * sigma, 2e-3 * bin_us)
        use = ok & (np.abs(x) <= width + 1e-9)
        if use.sum() < 5:
            break
        a = float(np.polyfit(x[use], y[use], 2)[0])
        sigma = math.sqrt(-0.5 / a) if a < 0 else math.inf
    if not sigma <= half_ms:
        return math.inf
    return sigma * 1e3


def _max_clock(fit: "_PoissonFit", offset_us: float, skew_ppm: float, bin_us: int, skew_step_ppm: float,
               maxiter: int) -> tuple[float, float, float]:
    """Nelder-Mead on the likelihood over (offset, skew) from a start clock, with a first simplex
    of a quarter bin and ``skew_step_ppm``; returns ``(offset, skew, log-likelihood)``."""
    o_scale, s_scale = 100.0, 10.0                                  # µs and ppm per unit step
    f = lambda q: -fit.loglik(offset_us + q[0] * o_scale, skew_ppm + q[1] * s_scale)
    res = optimize.minimize(f, np.zeros(2), method="Nelder-Mead",
                            options={"xatol": 0.002, "fatol": 1e-9, "maxiter": maxiter,
                                     "initial_simplex": np.array([[0, 0], [bin_us / o_scale / 4, 0],
                                                                  [0, skew_step_ppm / s_scale]])})
    return offset_us + res.x[0] * o_scale, skew_ppm + res.x[1] * s_scale, float(-res.fun)


def _joint_skew(fit: "_PoissonFit", offset_us: float, skew_ppm: float, line: tuple, bin_us: int,
                max_skew_ppm: float, min_lr: float = SKEW_MIN_LR):
    """Offset and skew maximising the whole sequence's likelihood, started on a Theil-Sen line
    whose confidence interval was too wide to accept on its own (a few segments, each with a
    loose offset, give a good slope but a wide interval: with 4 points it spans their pairwise
    slopes). Accepted when the likelihood ratio against the current clock (``offset_us`` at
    ``skew_ppm``) exceeds ``min_lr`` (2 x log, chi-square with one degree of freedom: 10.8 is
    p = 0.001) and the skew stays inside the line's interval. Returns ``(offset, skew, LR)``
    or None."""
    slope, icpt, half_ci = line
    ll0 = fit.loglik(offset_us, skew_ppm)
    o1, s1, ll1 = _max_clock(fit, icpt, slope, bin_us, skew_step_ppm=10.0, maxiter=600)
    lr = 2.0 * (ll1 - ll0)
    if not (np.isfinite(lr) and lr >= min_lr and abs(s1 - slope) <= half_ci and abs(s1) <= max_skew_ppm):
        return None
    return float(o1), float(s1), float(lr)


def _check_cancel(cancel):
    if cancel is not None and cancel():
        raise Cancelled("clock synchronisation cancelled")


def _search(prob: _Problem, sel: np.ndarray, centre_us: float, skew_ppm: float, half_range_us: float,
            guard_bins: int, min_overlap_frac: float):
    """Whole-bin NCC scan of the bins in ``sel`` over ``centre ± half_range``.

    Returns ``(lags_us, ncc, i_lo, i_hi)`` where [i_lo, i_hi] is the in-range index span.
    """
    bin_us = prob.bin_us
    idx = np.flatnonzero(sel)
    k0, k1 = int(idx[0]), int(idx[-1]) + 1
    L = int(math.ceil(half_range_us / bin_us)) + guard_bins
    kk = np.arange(k0 - L, k1 + L, dtype=np.float64)
    p, mp, _ = prob.prepared_proxy(centre_us, skew_ppm, shift_bins=kk)
    a = prob.e[k0:k1]
    ma = prob.me[k0:k1] & sel[k0:k1]
    ncc, _ = _masked_ncc(a, ma, p, mp, max(min_overlap_frac * ma.sum(), 10))
    step = bin_us * (1.0 + skew_ppm * 1e-6)
    lags = centre_us + (np.arange(-L, L + 1)) * step
    return lags, ncc, guard_bins, 2 * L - guard_bins


def _refine_offset(prob, sel, offset0, skew, half_width_us, xatol=1.0) -> tuple[float, float]:
    res = optimize.minimize_scalar(lambda o: -np.nan_to_num(prob.ncc_at(o, skew, sel), nan=-2.0),
                                   bounds=(offset0 - half_width_us, offset0 + half_width_us), method="bounded",
                                   options={"xatol": xatol})
    return float(res.x), float(-res.fun)


def _segment_offset(prob: "_Problem", sel: np.ndarray, t0_us: int, t1_us: int, centre_us: float, skew_ppm: float,
                    half_range_us: float, guard_bins: int, refine, ok: bool) -> SegmentOffset:
    """Offset of one segment (bins ``sel``, events ``[t0_us, t1_us)``): NCC scan around
    ``centre_us`` at ``skew_ppm``, then the refinement asked for. ``used`` is False when the segment
    has too little motion (``ok``) or no clear correlation peak. The offset is the local one, at
    the segment's centre."""
    tc = (t0_us + t1_us) // 2
    seg = SegmentOffset(t0_us, t1_us, tc, None, float("nan"), False)
    if not ok:
        return seg
    bin_us = prob.bin_us
    lags, ncc, lo, hi = _search(prob, sel, centre_us, skew_ppm, half_range_us, guard_bins, 0.8)
    pa = _peak_analysis(ncc, bin_us, lo, hi)
    if pa is None or pa[5] or pa[2] < MIN_PEAK_NCC:
        return seg
    o = lags[pa[0]] + pa[1] * (lags[1] - lags[0])
    if refine:
        o, _ = _refine_offset(prob, sel, o, skew_ppm, 1.5 * bin_us)
    if refine == "ml":
        o_ml, _, _ = _ml_offset(prob, sel, o, skew_ppm, max(1.5 * bin_us, 8000.0))
        if o_ml is not None:
            o = o_ml
    # offsets are measured as "clock offset at t_ref"; convert to the local offset
    seg.offset_us = float(o + skew_ppm * 1e-6 * (tc - prob.prior.t_ref_us))
    seg.peak = float(pa[2])
    seg.used = True
    return seg


def _robust_line(used: list, t_ref_us: int, bin_us: int):
    """Theil-Sen line through the segment offsets (µs against s since ``t_ref_us``), refitted on
    the inliers (3 MAD, at least a quarter bin); outliers get ``used = False``. Returns
    ``(slope ppm, offset at t_ref µs, half 90 % CI ppm, inliers)`` or None below 3 segments."""
    if len(used) < 3:
        return None
    x = np.array([(s.t_center_us - t_ref_us) * 1e-6 for s in used])   # s
    y = np.array([s.offset_us for s in used])                           # µs
    slope, icpt, lo_s, hi_s = stats.theilslopes(y, x, 0.9)
    resid = y - (icpt + slope * x)
    mad = 1.4826 * np.median(np.abs(resid - np.median(resid)))
    inl = np.abs(resid) <= max(3 * mad, 0.25 * bin_us)
    for s, ok in zip(used, inl):
        s.used = bool(ok)
    if inl.sum() >= 3:
        slope, icpt, lo_s, hi_s = stats.theilslopes(y[inl], x[inl], 0.9)
    return float(slope), float(icpt), 0.5 * (hi_s - lo_s), int(inl.sum())


def estimate_clock(starts_us, counts, bin_us: int, proxy: MotionProxy, prior: ClockModel, *,
                   range_us: float = 500_000, smooth_us: float | None = None, transform: str = "log",
                   estimate_skew: bool | str = "auto", n_segments: int | None = None,
                   max_skew_ppm: float = 1500.0, refine: str | bool = "ml", min_skew_duration_us: float = 6e6,
                   progress=None, cancel=None) -> SyncResult:
    """Estimate offset (and skew) from binned event counts and a motion proxy.

    Parameters
    ----------
    starts_us, counts : int arrays
        Bin start times (event clock, µs) and event counts, as from ``EventStore.rate(bin_us)``.
        The first and last bins (partial) are ignored.
    bin_us : int
        Bin width, µs.
    proxy : MotionProxy
        Image speed of the camera (pose clock).
    prior : ClockModel
        The clock in effect: the search is centred on its offset, its skew is used until the
        skew is estimated, its ``t_ref_us`` is the reference of the result.
    range_us : float
        Half width of the offset search, µs (default 500 ms).
    smooth_us : float, optional
        Gaussian smoothing of both series (default ``max(2 ms, bin)``).
    transform : {"log", "linear"}
    estimate_skew : bool or "auto"
        "auto": when the events span at least ``min_skew_duration_us``.
    n_segments : int, optional
        Segments for the skew (default: one per ~5 s, 4 to 16: shorter segments hold too few
        starts and stops of the motion for a sub-millisecond offset each).
    max_skew_ppm : float
        Largest skew the segment search allows for.
    refine : {"ml", "ncc", "wls", False}
        Continuous refinement of the offset (and skew): ``"ml"`` (default) maximises the Poisson
        likelihood of the counts under ``noise floor + slowly varying gain x proxy``
        (:class:`_PoissonFit`; per segment and on the whole sequence, after the NCC);
        ``"ncc"`` maximises the full NCC; ``"wls"`` fits the log rate to a calibrated rate model
        (gain field + noise floor, Poisson weights); False keeps the parabolic peak / Theil-Sen
        line.
    progress : callable, optional
        ``progress(fraction, message)``.
    cancel : callable, optional
        ``cancel() -> bool``; True raises :class:`evpose.core.data.events.Cancelled`.
    """
    t_start = time.perf_counter()
    bin_us = int(bin_us)
    starts = np.asarray(starts_us, dtype=np.int64)
    counts = np.asarray(counts)
    if len(starts) != len(counts):
        raise ValueError(f"starts ({len(starts)}) and counts ({len(counts)}) differ in length")
    if bin_us <= 0:
        raise ValueError(f"bin_us must be positive, got {bin_us}")
    if not range_us > 0:
        raise ValueError(f"range_us must be positive, got {range_us}")
    if len(counts) == 0 or counts.sum() == 0:
        return _unreliable("no events", t_start, prior)
    # drop the partial first and last bins
    starts, counts = starts[1:-1], counts[1:-1]
    duration_us = len(counts) * bin_us
    sigma_us = max(2000.0, float(bin_us)) if smooth_us is None else float(smooth_us)
    sigma_bins = sigma_us / bin_us
    if duration_us < max(MIN_DURATION_US, 20 * sigma_us):
        return _unreliable(f"too short: {duration_us / 1e3:.0f} ms of events (need at least "
                           f"{max(MIN_DURATION_US, 20 * sigma_us) / 1e3:.0f} ms)", t_start, prior)
    if np.all(counts == counts[0]):
        return _unreliable("constant event rate: nothing to correlate", t_start, prior)
    if len(proxy.knots_us) < 2:
        return _unreliable("the trajectory has fewer than two poses", t_start, prior)
    if proxy.max_px_s < MIN_MOTION_PX_S:
        return _unreliable(f"static camera: the image moves at most {proxy.max_px_s:.2g} px/s", t_start, prior)
    prob = _Problem(starts, counts, bin_us, proxy, prior, sigma_bins, transform)
    if np.ptp(prob.e[prob.me]) <= 1e-9 * max(1.0, abs(prob.e[prob.me]).max()):
        return _unreliable("constant event rate: nothing to correlate", t_start, prior)
    _check_cancel(cancel)

    # 1. coarse scan over the whole sequence
    sel_all = prob.me.copy()
    guard = max(3, int(math.ceil(3 * sigma_bins)))
    lags, ncc, i_lo, i_hi = _search(prob, sel_all, float(prior.offset_us), prior.skew_ppm, range_us, guard, 0.5)
    if progress is not None:
        progress(0.3, "coarse correlation")
    kw = dict(lags=lags, corr=ncc)
    # motion within the best-overlapping part?
    p_at, mp_at = prob.proxy_bins(float(prior.offset_us), prior.skew_ppm)
    if not np.isfinite(ncc).any():
        return _unreliable("the trajectory does not overlap the events within the search range", t_start, prior, **kw)
    pa = _peak_analysis(ncc, bin_us, i_lo, i_hi)
    i_pk, delta, peak, second, hwhm, at_edge, base = pa
    ambiguity = _ambiguity(peak, second, base)
    lag_pk = lags[i_pk] + delta * (lags[1] - lags[0])
    common = dict(peak=peak, second_peak=second, peak_hwhm_us=hwhm * bin_us, **kw)
    if at_edge:
        return _unreliable(f"the best match ({lags[i_pk] / 1e3:+.1f} ms) is at or beyond the edge of the search "
                           f"range {prior.offset_us / 1e3:+.1f} ± {range_us / 1e3:.0f} ms; widen the range",
                           t_start, prior, **common)
    if peak < MIN_PEAK_NCC:
        return _unreliable(f"flat correlation: peak NCC {peak:.2f} < {MIN_PEAK_NCC}", t_start, prior, **common)
    if hwhm * bin_us > MAX_PEAK_HWHM_FRACTION * range_us:
        return _unreliable(f"flat correlation: the peak is {hwhm * bin_us / 1e3:.0f} ms wide", t_start, prior,
                           **common)
    if ambiguity > MAX_SECOND_PEAK_RATIO:
        return _unreliable(f"ambiguous: a second correlation peak ({second:.2f}) is nearly as high as the best "
                           f"({peak:.2f}); periodic or repetitive motion?", t_start, prior, **common)
    _check_cancel(cancel)

    offset = float(lag_pk)
    skew = float(prior.skew_ppm)
    offset_std = None
    notes = [f"coarse offset {offset:.0f} us (peak NCC {peak:.3f}, second {second:.3f}, "
             f"half width {hwhm * bin_us / 1e3:.1f} ms)"]
    t_ref = prior.t_ref_us
    t_mid_rel = float(starts[len(starts) // 2] - t_ref)

    # 2. segments -> skew
    segments: list[SegmentOffset] = []
    do_skew = (duration_us >= min_skew_duration_us) if estimate_skew == "auto" else bool(estimate_skew)
    skew_estimated = False
    loose_line = None           # a Theil-Sen line too uncertain to accept alone: (slope, offset, half CI)
    if do_skew:
        n_seg = n_segments or int(np.clip(round(duration_us / 5e6), 4, 16))
        edges = np.linspace(0, len(starts), n_seg + 1).astype(int)
        seg_range = max_skew_ppm * 1e-6 * duration_us + 4 * sigma_us + 2 * bin_us
        # pass 1 measures the segments with the prior skew, centred on the global offset; when
        # the slope found differs from it, pass 2 measures them again with that slope (a drift
        # of ~1000 ppm over a 5 s segment would otherwise smear each segment's own fit)
        seg_skew, seg_centre, best = skew, offset, None
        for pass_no in (1, 2):
            segments = []
            for j in range(n_seg):
                _check_cancel(cancel)
                sel = np.zeros(len(starts), bool)
                sel[edges[j]:edges[j + 1]] = True
                sel &= prob.me
                segments.append(_segment_offset(prob, sel, int(starts[edges[j]]), int(starts[edges[j + 1] - 1]) + bin_us,
                                                seg_centre, seg_skew, seg_range, guard, refine,
                                                ok=bool(sel.sum() >= 20 * sigma_bins and np.ptp(p_at[sel]) > 0)))
                if progress is not None:
                    progress(0.3 + 0.25 * (pass_no - 1) + 0.25 * (j + 1) / n_seg, f"segment {j + 1}/{n_seg}")
            used = [s for s in segments if s.used]
            fit_line = _robust_line(used, t_ref, bin_us)
            if fit_line is not None:
                fit_line = (*fit_line, pass_no, segments)
                if best is None or fit_line[2] < best[2]:     # keep the better determined line
                    best = fit_line
            if (pass_no == 2 or fit_line is None or not abs(fit_line[0]) <= max_skew_ppm
                    or abs(fit_line[0] - seg_skew) <= 10.0):
                break
            seg_skew, seg_centre = fit_line[0], fit_line[1]
        if best is not None:
            slope, icpt, half_ci, n_in, pass_no, segments = best
            if abs(slope) <= max_skew_ppm and half_ci <= 100.0:
                skew, offset = float(slope), float(icpt)
                skew_estimated = True
                notes.append(f"segments: Theil-Sen skew {slope:.1f} ppm (90% CI ±{half_ci:.1f}), "
                             f"{n_in}/{n_seg} segments used" + (" (second pass)" if pass_no == 2 else ""))
            else:
                if abs(slope) <= max_skew_ppm and math.isfinite(half_ci):
                    loose_line = (float(slope), float(icpt), float(half_ci))
                notes.append(f"skew not estimated: Theil-Sen slope {slope:.1f} ppm with 90% CI ±{half_ci:.1f} ppm")
        else:
            notes.append(f"skew not estimated: only {len(used)} of {n_seg} segments gave an offset")
    elif estimate_skew == "auto":
        notes.append(f"skew not estimated: {duration_us / 1e6:.1f} s of events < {min_skew_duration_us / 1e6:.0f} s")

    # 3. continuous refinement on the whole sequence: weighted least squares of the log rate
    #    against a calibrated rate model (gain field + noise floor), which weights every bin by
    #    its Poisson information instead of the NCC's uniform weights
    if refine == "ml":
        _check_cancel(cancel)
        sel = np.ones(len(starts), bool)
        ml_half_us = max(1.5 * bin_us, 10_000.0)
        o_ml, fit, offset_std = _ml_offset(prob, sel, offset, skew, ml_half_us, std=True)
        if o_ml is None:
            notes.append("maximum-likelihood refinement failed (no motion blocks or best point at the edge of "
                         "the ±10 ms search): kept the correlation estimate")
        else:
            offset = o_ml
            if skew_estimated:
                o_new, s_new, _ = _max_clock(fit, offset, skew, bin_us, skew_step_ppm=5.0, maxiter=400)
                if abs(o_new - offset) < 3 * bin_us and abs(s_new - skew) < 100:
                    offset, skew = o_new, s_new
            elif loose_line is not None:
                accepted = _joint_skew(fit, offset, skew, loose_line, bin_us, max_skew_ppm)
                if accepted is not None:
                    offset, skew, lr = accepted
                    skew_estimated = True
                    notes.append(f"skew {skew:.1f} ppm from the joint likelihood of the whole sequence, started on "
                                 f"the Theil-Sen line (likelihood ratio {lr:.0f} against the prior skew)")
            notes.append(f"refined: Poisson maximum likelihood ({len(fit.blocks)} gain blocks, noise floor "
                         f"{fit.n0:.2f} per bin)")
        if offset_std is not None and not offset_std <= SLOW_STD_NOTE_US:
            notes.append(("the event rate pins the offset only to " +
                          (f"±{offset_std / 1e3:.1f} ms (1 sigma)" if math.isfinite(offset_std)
                           else f"more than ±{STD_SCAN_FACTOR * ml_half_us / 1e3:.0f} ms") +
                          ": too few or too gradual starts and stops of the motion; check the result on the "
                          "event frames or with `evpose refine --offset` (edge alignment)"))
    elif refine:
        _check_cancel(cancel)
        p0, ok0, _ = prob.prepared_proxy(offset, skew)
        sel = ndimage.binary_erosion(prob.me & ok0, iterations=4 + int(3 * sigma_bins), border_value=0)
        if sel.sum() >= 10:
            use_wls = refine == "wls"
            rounds = 2 if use_wls else 1
            for _round in range(rounds):
                if use_wls:
                    prob.calibrate(offset, skew, sel)
                    score = prob.fit_at
                else:
                    score = prob.ncc_at
                if skew_estimated:
                    s_scale, o_scale = 10.0, 100.0
                    f = lambda q: -np.nan_to_num(score(offset + q[0] * o_scale, skew + q[1] * s_scale, sel),
                                                 nan=-1e9)
                    res = optimize.minimize(f, np.zeros(2), method="Nelder-Mead",
                                            options={"xatol": 0.002, "fatol": 1e-12, "maxiter": 400,
                                                     "initial_simplex": np.array([[0, 0], [bin_us / o_scale, 0],
                                                                                  [0, 1.0]])})
                    o_new, s_new = offset + res.x[0] * o_scale, skew + res.x[1] * s_scale
                    if abs(o_new - offset) < 3 * bin_us and abs(s_new - skew) < 100:
                        offset, skew = o_new, s_new
                else:
                    r1 = optimize.minimize_scalar(lambda o: -np.nan_to_num(score(o, skew, sel), nan=-1e9),
                                                  bounds=(offset - 1.5 * bin_us, offset + 1.5 * bin_us),
                                                  method="bounded", options={"xatol": 1.0})
                    offset = float(r1.x)
            notes.append("refined: " + (f"weighted log fit (noise floor {prob.n0:.2f} per bin)" if use_wls
                                        else "full-sequence NCC"))
    if progress is not None:
        progress(1.0, "done")
    conf = _confidence(peak, ambiguity)
    return SyncResult(int(round(offset)), float(skew) if skew_estimated else None, conf, True, "", lags, ncc,
                      segments, time.perf_counter() - t_start, "xcorr", peak, second, hwhm * bin_us,
                      int(prior.offset_us), float(prior.skew_ppm), int(t_ref), notes, offset_std)


def sync_scene(scene, *, range_ms: float = 500.0, bin_us: int = 1000, kind: str = "flow", progress=None,
               cancel=None, **kwargs) -> SyncResult:
    """Estimate the clock of a scene (see :func:`estimate_clock` for the keyword arguments).

    The search is centred on the clock in effect (prior + corrections); the result holds total
    values. Use :func:`clock_correction` for the values to store as corrections.
    """
    t_start = time.perf_counter()
    prior = scene.clock
    if scene.events.n_events == 0:
        return _unreliable("no events", t_start, prior)
    starts, counts = scene.events.rate(bin_us)
    proxy = scene_motion_proxy(scene, kind=kind)
    res = estimate_clock(starts, counts, bin_us, proxy, prior, range_us=range_ms * 1000.0, progress=progress,
                         cancel=cancel, **kwargs)
    res.runtime_s = time.perf_counter() - t_start
    return res


# ---------------------------------------------------------------------------- corrections
def clock_correction(scene, result: SyncResult) -> tuple[int, float] | None:
    """The corrections (``offset_us``, ``skew_ppm``) that make the scene's clock equal the
    estimate: total minus the manifest prior. None when the result has no offset. The skew
    correction is the current one when the skew was not estimated."""
    if result.offset_us is None:
        return None
    off = int(result.offset_us) - int(scene.manifest.clock_offset_us)
    skew = (float(result.skew_ppm) - float(scene.manifest.clock_skew_ppm)) if result.skew_ppm is not None \
        else float(scene.corrections.skew_ppm)
    return off, skew


def apply_sync(history, scene, result: SyncResult, text: str = "clock sync") -> bool:
    """Apply a reliable result through ``history`` as one undo step; returns whether applied."""
    corr = clock_correction(scene, result)
    if corr is None or not result.reliable:
        return False
    with history.group(text):
        history.set(("offset_us",), corr[0])
        history.set(("skew_ppm",), corr[1])
    return True


# ---------------------------------------------------------------------------- E-POSE baseline
def minima_baseline(starts_us, counts, bin_us: int, trajectory: Trajectory, prior: ClockModel, *,
                    range_us: float = 500_000, smooth_us: float = 50_000, min_separation_us: float = 150_000,
                    prominence: float = 0.2) -> SyncResult:
    """The original E-POSE synchronisation: minima of the smoothed event rate matched to minima
    of the robot speed; the offset is the mean of the time differences.

    Speed minima (the stops between moves) are mapped to the event clock with ``prior``; each
    is matched to the nearest event-rate minimum within ``range_us``. ``prominence`` is relative
    to each signal's range. No skew is estimated.
    """
    t_start = time.perf_counter()
    starts = np.asarray(starts_us, dtype=np.int64)
    counts = np.asarray(counts, dtype=np.float64)
    method = "minima-baseline"
    if len(counts) < 3 or counts.sum() == 0:
        return _unreliable("no events", t_start, prior, method)
    starts, counts = starts[1:-1], counts[1:-1]
    n_win = max(1, int(round(smooth_us / bin_us)))
    rate = ndimage.uniform_filter1d(counts, n_win, mode="nearest")
    dist = max(1, int(min_separation_us / bin_us))

    def minima(x, d):
        rng = float(np.ptp(x))
        if rng <= 0:
            return np.zeros(0, int)
        idx, _ = signal.find_peaks(-x, prominence=prominence * rng, distance=d)
        return idx

    e_min = starts[minima(rate, dist)] + bin_us // 2
    if len(trajectory) < 2:
        return _unreliable("the trajectory has fewer than two poses", t_start, prior, method)
    v, w, _ = trajectory.speed()
    sp = v if v.max() > 1e-6 else w
    # resample the piecewise constant speed on a bin grid (over the events' pose times and the search
    # range only: a trajectory may span days) and smooth like the rate
    span = prior.pose_time(np.array([starts[0], starts[-1] + bin_us], np.int64))
    g0 = max(trajectory.t_first_us, int(span[0] - range_us))
    g1 = min(trajectory.t_last_us, int(span[1] + range_us))
    grid = np.arange(g0, max(g0, g1), bin_us, dtype=np.int64)
    if len(grid) < 3:
        return _unreliable("the trajectory does not overlap the events within the search range", t_start,
                           prior, method)
    sp_g = sp[np.clip(np.searchsorted(trajectory.t_us, grid, side="right") - 1, 0, len(sp) - 1)]
    # no pose in a hole: its mean speed over the gap would make a false stop, so no minimum near one
    in_hole = ~trajectory.speed(grid)[2]
    if sp_g.max() <= 1e-9:
        return _unreliable("static camera: the robot does not move", t_start, prior, method)
    sp_g = ndimage.uniform_filter1d(sp_g, n_win, mode="nearest")
    near_hole = ndimage.binary_dilation(in_hole, iterations=n_win) if in_hole.any() else in_hole
    p_min = grid[[i for i in minima(sp_g, dist) if not near_hole[i]]]
    if len(e_min) == 0 or len(p_min) == 0:
        return _unreliable("no minima to match", t_start, prior, method)
    diffs = []
    p_ev = prior.event_time(p_min)            # where each speed minimum should be on the event clock
    for tp, te_expect in zip(p_min, p_ev):
        if te_expect < starts[0] or te_expect > starts[-1] + bin_us:
            continue
        j = int(np.argmin(np.abs(e_min - te_expect)))
        if abs(int(e_min[j]) - int(te_expect)) <= range_us:
            diffs.append(float(tp) - float(e_min[j]) - prior.skew_ppm * 1e-6 * float(e_min[j] - prior.t_ref_us))
    if len(diffs) < 2:
        return _unreliable(f"only {len(diffs)} matched minima", t_start, prior, method)
    d = np.asarray(diffs)
    off = float(d.mean())
    spread = float(d.std())
    conf = float(np.clip(1.0 - spread / max(range_us, 1.0), 0.0, 1.0))
    return SyncResult(int(round(off)), None, conf, True, "", np.zeros(0), np.zeros(0), [],
                      time.perf_counter() - t_start, method, prior_offset_us=int(prior.offset_us),
                      prior_skew_ppm=float(prior.skew_ppm), t_ref_us=int(prior.t_ref_us),
                      notes=[f"{len(d)} matched minima, spread {spread / 1e3:.1f} ms"])


def sync_minima_baseline(scene, *, range_ms: float = 500.0, bin_us: int = 10_000, **kwargs) -> SyncResult:
    """:func:`minima_baseline` on a scene (camera trajectory, clock in effect as the prior)."""
    t_start = time.perf_counter()
    prior = scene.clock
    if scene.events.n_events == 0:
        return _unreliable("no events", t_start, prior, "minima-baseline")
    starts, counts = scene.events.rate(bin_us)
    res = minima_baseline(starts, counts, bin_us, _camera_trajectory(scene), prior, range_us=range_ms * 1000.0,
                          **kwargs)
    res.runtime_s = time.perf_counter() - t_start
    return res
