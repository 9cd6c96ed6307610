"""Clock synchronisation: the event clock against the robot (pose) clock, from the event rate.

Estimates the clock model of DESIGN section 3,
``t_pose_us = t_event_us + offset_us + skew_ppm * 1e-6 * (t_event_us - t_ref_us)``,
from two signals that both follow the camera's motion: the event rate (counts per bin from the
store's ms index, no event is read) and the image-motion proxy of the trajectory
(:mod:`evpose.core.align.proxy`). The estimate runs in stages, each in its own module:

1. **coarse offset**: NCC over every whole-bin lag of the search range
   (:mod:`~evpose.core.align.correlation`), with the reliability decision on the curve's shape
   (:mod:`~evpose.core.align.correlation_peak`);
2. **skew**: a robust line through the offsets of consecutive segments
   (:mod:`~evpose.core.align.segments`), for sequences long enough to show a drift;
3. **continuous refinement** on the whole sequence (:mod:`~evpose.core.align.rate_refine`):
   the Poisson likelihood of the counts by default, with the offset's standard error.

A result is either an estimate or a reason why there is none (too short, no events, a static
camera, a flat or ambiguous correlation, a best match at the edge of the range): a wrong clock
silently applied would misplace every label. Method and accuracy: ``docs/sync.md``.
"""
from __future__ import annotations

import math
import time

import numpy as np

from evpose.core.align.correlation import ncc_scan
from evpose.core.align.correlation_peak import (
    MAX_PEAK_HWHM_FRACTION,
    MAX_SECOND_PEAK_RATIO,
    MIN_PEAK_NCC,
    ambiguity,
    confidence,
    peak_analysis,
)
from evpose.core.align.proxy import MotionProxy
from evpose.core.align.rate_refine import refine_ml, refine_ncc
from evpose.core.align.rate_series import RateSeries, check_cancel
from evpose.core.align.scene_proxy import scene_motion_proxy
from evpose.core.align.segments import skew_from_segments
from evpose.core.align.sync_result import ClockEstimate, SyncResult, unreliable
from evpose.core.align import uncertainty
from evpose.core.align.uncertainty import with_floor
from evpose.core.data.clock import ClockModel

__all__ = ["MIN_DURATION_US", "MIN_MOTION_PX_S", "REFINE_MODES", "estimate_clock", "sync_scene"]

MIN_DURATION_US = 300_000     # shorter sequences: "too short"
MIN_MOTION_PX_S = 5.0         # largest image speed below this: "static camera"
REFINE_MODES = ("ml", "ncc", False)


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
    refine : {"ml", "ncc", False}
        Continuous refinement of the offset (and skew): ``"ml"`` (default) maximises the Poisson
        likelihood of the counts under ``noise floor + slowly varying gain x proxy``
        (:class:`~evpose.core.align.poisson_fit.PoissonFit`; per segment and on the whole sequence, after
        the NCC); ``"ncc"`` maximises the full NCC; False keeps the parabolic peak / Theil-Sen line.
    progress : callable, optional
        ``progress(fraction, message)``.
    cancel : callable, optional
        ``cancel() -> bool``; True raises :class:`evpose.core.data.events.Cancelled`.
    """
    t_start = time.perf_counter()
    bin_us = int(bin_us)
    starts = np.asarray(starts_us, dtype=np.int64)
    counts = np.asarray(counts)
    _check_arguments(starts, counts, bin_us, range_us, refine)
    if len(counts) == 0 or counts.sum() == 0:
        return unreliable("no events", t_start, prior)
    starts, counts = starts[1:-1], counts[1:-1]          # drop the partial first and last bins
    duration_us = len(counts) * bin_us
    sigma_us = max(2000.0, float(bin_us)) if smooth_us is None else float(smooth_us)
    reason = _unusable(counts, duration_us, sigma_us, proxy)
    if reason:
        return unreliable(reason, t_start, prior)
    prob = RateSeries(starts, counts, bin_us, proxy, prior, sigma_us / bin_us, transform)
    if np.ptp(prob.e[prob.me]) <= 1e-9 * max(1.0, abs(prob.e[prob.me]).max()):
        return unreliable("constant event rate: nothing to correlate", t_start, prior)
    check_cancel(cancel)

    # 1. coarse scan over the whole sequence
    guard = max(3, int(math.ceil(3 * prob.sigma)))
    lags, ncc, i_lo, i_hi = ncc_scan(prob, prob.me.copy(), float(prior.offset_us), prior.skew_ppm, range_us, guard,
                                     0.5)
    if progress is not None:
        progress(0.3, "coarse correlation")
    if not np.isfinite(ncc).any():
        return unreliable("the trajectory does not overlap the events within the search range", t_start, prior,
                          lags=lags, corr=ncc)
    i_pk, delta, peak, second, hwhm, at_edge, base = peak_analysis(ncc, i_lo, i_hi)
    amb = ambiguity(peak, second, base)
    reason = _peak_problem(float(lags[i_pk]), peak, second, hwhm * bin_us, at_edge, amb, prior, range_us)
    if reason:
        return unreliable(reason, t_start, prior, peak=peak, second_peak=second, peak_hwhm_us=hwhm * bin_us,
                          lags=lags, corr=ncc)
    check_cancel(cancel)
    offset = float(lags[i_pk] + delta * (lags[1] - lags[0]))
    note = (f"coarse offset {offset:.0f} us (peak NCC {peak:.3f}, second {second:.3f}, "
            f"half width {hwhm * bin_us / 1e3:.1f} ms)")
    est = ClockEstimate(offset, float(prior.skew_ppm), [note])

    # 2. segments -> skew
    do_skew = (duration_us >= min_skew_duration_us) if estimate_skew == "auto" else bool(estimate_skew)
    if do_skew:
        skew_from_segments(prob, est, duration_us, sigma_us, guard, refine, n_segments, max_skew_ppm, progress, cancel)
    elif estimate_skew == "auto":
        est.notes.append(f"skew not estimated: {duration_us / 1e6:.1f} s of events < "
                         f"{min_skew_duration_us / 1e6:.0f} s")

    # 3. continuous refinement on the whole sequence
    if refine == "ml":
        refine_ml(prob, est, max_skew_ppm, cancel)
    elif refine:
        refine_ncc(prob, est, cancel)
    if progress is not None:
        progress(1.0, "done")
    return SyncResult(int(round(est.offset_us)), float(est.skew_ppm) if est.skew_estimated else None,
                      confidence(peak, amb), True, "", lags, ncc, est.segments, time.perf_counter() - t_start,
                      "xcorr", peak, second, hwhm * bin_us, int(prior.offset_us), float(prior.skew_ppm),
                      int(prior.t_ref_us), est.notes, est.offset_std_us)


def _check_arguments(starts: np.ndarray, counts: np.ndarray, bin_us: int, range_us: float, refine) -> None:
    """Raise ValueError for arguments no estimate can be made from (a caller's mistake)."""
    if len(starts) != len(counts):
        raise ValueError(f"starts ({len(starts)}) and counts ({len(counts)}) differ in length")
    if bin_us <= 0:
        raise ValueError(f"bin_us must be positive, got {bin_us}")
    if not range_us > 0:
        raise ValueError(f"range_us must be positive, got {range_us}")
    if not any(refine is m or refine == m for m in REFINE_MODES):
        raise ValueError(f"refine must be one of {REFINE_MODES}, got {refine!r}")


def _unusable(counts: np.ndarray, duration_us: float, sigma_us: float, proxy: MotionProxy) -> str:
    """Why the data cannot give a clock before any correlation ("" when they may)."""
    if duration_us < max(MIN_DURATION_US, 20 * sigma_us):
        return (f"too short: {duration_us / 1e3:.0f} ms of events (need at least "
                f"{max(MIN_DURATION_US, 20 * sigma_us) / 1e3:.0f} ms)")
    if np.all(counts == counts[0]):
        return "constant event rate: nothing to correlate"
    if len(proxy.knots_us) < 2:
        return "the trajectory has fewer than two poses"
    if proxy.max_px_s < MIN_MOTION_PX_S:
        return f"static camera: the image moves at most {proxy.max_px_s:.2g} px/s"
    return ""


def _peak_problem(best_lag_us: float, peak: float, second: float, hwhm_us: float, at_edge: bool, amb: float,
                  prior: ClockModel, range_us: float) -> str:
    """Why the coarse correlation does not pin the clock ("" when it does)."""
    if at_edge:
        return (f"the best match ({best_lag_us / 1e3:+.1f} ms) is at or beyond the edge of the search "
                f"range {prior.offset_us / 1e3:+.1f} ± {range_us / 1e3:.0f} ms; widen the range")
    if peak < MIN_PEAK_NCC:
        return f"flat correlation: peak NCC {peak:.2f} < {MIN_PEAK_NCC}"
    if hwhm_us > MAX_PEAK_HWHM_FRACTION * range_us:
        return f"flat correlation: the peak is {hwhm_us / 1e3:.0f} ms wide"
    if amb > MAX_SECOND_PEAK_RATIO:
        return (f"ambiguous: a second correlation peak ({second:.2f}) is nearly as high as the best "
                f"({peak:.2f}); periodic or repetitive motion?")
    return ""


def sync_scene(scene, *, range_ms: float = 500.0, bin_us: int = 1000, kind: str = "flow", progress=None,
               cancel=None, **kwargs) -> SyncResult:
    """Estimate the clock of a scene (see :func:`estimate_clock` for the keyword arguments).

    The search is centred on the clock in effect (prior + corrections); the result holds total
    values. Use :func:`evpose.core.align.apply.clock_correction` for the values to store as corrections.
    ``offset_std_us`` is the rate's own standard error with the model-error floor of
    :mod:`evpose.core.align.uncertainty` in quadrature (``offset_std_data_us`` without it).
    """
    t_start = time.perf_counter()
    prior = scene.clock
    if scene.events.n_events == 0:
        return unreliable("no events", t_start, prior)
    starts, counts = scene.events.rate(bin_us)
    proxy = scene_motion_proxy(scene, kind=kind)
    res = estimate_clock(starts, counts, bin_us, proxy, prior, range_us=range_ms * 1000.0, progress=progress,
                         cancel=cancel, **kwargs)
    res.offset_std_data_us = res.offset_std_us          # the honest sigma adds the model-error floor (issue 23.2)
    res.offset_std_us = with_floor(res.offset_std_us, uncertainty.RATE_OFFSET_FLOOR_US)
    res.runtime_s = time.perf_counter() - t_start
    return res
