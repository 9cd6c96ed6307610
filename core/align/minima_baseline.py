"""The original E-POSE clock synchronisation, kept as a named baseline to compare against.

E-POSE matched minima of the smoothed event rate (the camera stops) to minima of the robot's
speed and averaged the time differences. It needs stops to match, estimates no skew and gives
no standard error; ``evpose sync --baseline`` and ``bench/accuracy.py`` report it beside the
rate estimate (:mod:`evpose.core.align.estimate`) so the improvement stays measurable.
"""
from __future__ import annotations

import time

import numpy as np
from scipy import ndimage, signal

from evpose.core.align.scene_proxy import camera_trajectory
from evpose.core.align.sync_result import SyncResult, unreliable
from evpose.core.data.clock import ClockModel
from evpose.core.data.trajectory import Trajectory

__all__ = ["minima_baseline", "sync_minima_baseline"]


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
        return unreliable("no events", t_start, prior, method)
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
        return unreliable("the trajectory has fewer than two poses", t_start, prior, method)
    v, w, _ = trajectory.speed()
    sp = v if v.max() > 1e-6 else w
    # resample the piecewise constant speed on a bin grid (over the events' pose times and the search
    # range only: a trajectory may span days) and smooth like the rate
    span = prior.pose_time(np.array([starts[0], starts[-1] + bin_us], np.int64))
    g0 = max(trajectory.t_first_us, int(span[0] - range_us))
    g1 = min(trajectory.t_last_us, int(span[1] + range_us))
    grid = np.arange(g0, max(g0, g1), bin_us, dtype=np.int64)
    if len(grid) < 3:
        return unreliable("the trajectory does not overlap the events within the search range", t_start,
                          prior, method)
    sp_g = sp[np.clip(np.searchsorted(trajectory.t_us, grid, side="right") - 1, 0, len(sp) - 1)]
    # no pose in a hole: its mean speed over the gap would make a false stop, so no minimum near one
    in_hole = ~trajectory.speed(grid)[2]
    if sp_g.max() <= 1e-9:
        return unreliable("static camera: the robot does not move", t_start, prior, method)
    sp_g = ndimage.uniform_filter1d(sp_g, n_win, mode="nearest")
    near_hole = ndimage.binary_dilation(in_hole, iterations=n_win) if in_hole.any() else in_hole
    p_min = grid[[i for i in minima(sp_g, dist) if not near_hole[i]]]
    if len(e_min) == 0 or len(p_min) == 0:
        return unreliable("no minima to match", t_start, prior, method)
    diffs = []
    p_ev = prior.event_time(p_min)            # where each speed minimum should be on the event clock
    for tp, te_expect in zip(p_min, p_ev):
        if te_expect < starts[0] or te_expect > starts[-1] + bin_us:
            continue
        j = int(np.argmin(np.abs(e_min - te_expect)))
        if abs(int(e_min[j]) - int(te_expect)) <= range_us:
            diffs.append(float(tp) - float(e_min[j]) - prior.skew_ppm * 1e-6 * float(e_min[j] - prior.t_ref_us))
    if len(diffs) < 2:
        return unreliable(f"only {len(diffs)} matched minima", t_start, prior, method)
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
        return unreliable("no events", t_start, prior, "minima-baseline")
    starts, counts = scene.events.rate(bin_us)
    res = minima_baseline(starts, counts, bin_us, camera_trajectory(scene), prior, range_us=range_ms * 1000.0,
                          **kwargs)
    res.runtime_s = time.perf_counter() - t_start
    return res
