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

Long recordings (more than :data:`LONG_BINS` bins) run the same stages coarse-to-fine in time
(:func:`estimate_long`): offset and skew on the whole recording at a coarse bin, then the fine offset and
the refinement on a bounded set of windows at the requested bin.

A result is either an estimate or a reason why there is none (too short, no events, a static
camera, a flat or ambiguous correlation, a best match at the edge of the range, a trajectory that
covers too little of the events): a wrong clock silently applied would misplace every label. Method and
accuracy: ``docs/sync.md``.
"""
from __future__ import annotations

import inspect
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
from evpose.core.align.rate_refine import refine_ml, refine_ncc, refine_windows
from evpose.core.align.rate_series import BinnedCounts, RateSeries, StoreCounts, check_cancel
from evpose.core.align.scene_proxy import scene_motion_proxy
from evpose.core.align.segments import skew_from_segments
from evpose.core.align.sync_result import ClockEstimate, SyncResult, unreliable
from evpose.core.align import uncertainty
from evpose.core.align.uncertainty import with_floor
from evpose.core.data.clock import ClockModel

__all__ = ["COARSE_BINS", "COARSE_RANGE_BINS", "COARSE_REFINE", "FINE_WINDOWS", "FINE_WINDOW_US", "LONG_BINS",
           "MIN_DURATION_US", "MIN_MOTION_PX_S", "REFINE_MODES", "estimate_clock", "estimate_long", "sync_scene"]

MIN_DURATION_US = 300_000     # shorter sequences: "too short"
MIN_MOTION_PX_S = 5.0         # largest image speed below this: "static camera"
REFINE_MODES = ("ml", "ncc", False)
#: Sequences of more than this many bins are estimated coarse-to-fine in time (:func:`estimate_long`; 2.5 min at
#: 1 ms). Every stage of the direct estimate reads the proxy over all bins, hundreds of times: a 3-minute
#: recording took 75 s, a 1-hour one more than 35 min and 1.4 GB, 3 hours at 250 Hz poses ran out of time.
LONG_BINS = 150_000
#: The coarse pass of a long recording bins all of it into at most this many bins (113 ms for an hour at 1 ms, 338 ms
#: for 3 hours: fine enough for the skew to 0.1 ppm and the offset to a few ms on moves of a second). A scan of the
#: whole series costs ~ bins x lags ~ bins**2 (13 ms CPU at 32,000 bins with single-threaded BLAS) and the skew
#: search takes ~ bins scans: at 200,000 bins the coarse pass alone took 11 s.
COARSE_BINS = 32_000
#: The coarse pass's offset search reaches at least this many of its bins either way.
COARSE_RANGE_BINS = 8
#: Refinement of the coarse pass's segment offsets: the continuous NCC. A parabolic peak on the coarse lags leans
#: towards the lag grid, which follows the skew the segments start at, so a start skew a few ppm off pulled the skew
#: found towards it (3 hours started 1.5 ppm off ended 0.5 ppm off: 5 ms at the end; with the NCC refinement
#: 0.05 ppm, at ~2-4 s more CPU).
COARSE_REFINE = "ncc"
#: The fine pass reads this many windows of FINE_WINDOW_US (µs) at the requested bin width: 120 s of events,
#: 120,000 bins at 1 ms, whatever the length of the recording (~10 s with the maximum-likelihood refinement).
FINE_WINDOWS = 12
FINE_WINDOW_US = 10_000_000


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

    Notes
    -----
    Sequences of more than :data:`LONG_BINS` bins are estimated coarse-to-fine in time (:func:`estimate_long`),
    in time and memory that do not grow with their length beyond the coarse pass.
    """
    t_start = time.perf_counter()
    bin_us = int(bin_us)
    starts = np.asarray(starts_us, dtype=np.int64)
    counts = np.asarray(counts)
    _check_arguments(starts, counts, bin_us, range_us, refine)
    if len(counts) == 0 or counts.sum() == 0:
        return unreliable("no events", t_start, prior)
    opts = dict(range_us=range_us, smooth_us=smooth_us, transform=transform, estimate_skew=estimate_skew,
                n_segments=n_segments, max_skew_ppm=max_skew_ppm, refine=refine,
                min_skew_duration_us=min_skew_duration_us)
    if len(counts) - 2 > LONG_BINS:
        return estimate_long(BinnedCounts(starts[1:-1], counts[1:-1], bin_us), proxy, prior, progress=progress,
                             cancel=cancel, t_start=t_start, **opts)
    out = _rate_stages(starts[1:-1], counts[1:-1], bin_us, proxy, prior, t_start, progress, cancel, **opts)
    if isinstance(out, SyncResult):
        return out
    prob, est, scan = out
    # 3. continuous refinement on the whole sequence
    if refine == "ml":
        refine_ml(prob, est, max_skew_ppm, cancel)
    elif refine:
        refine_ncc(prob, est, cancel)
    if progress is not None:
        progress(1.0, "done")
    return _result(est, scan, prior, t_start)


def _rate_stages(starts: np.ndarray, counts: np.ndarray, bin_us: int, proxy: MotionProxy, prior: ClockModel,
                 t_start: float, progress, cancel, *, range_us, smooth_us, transform, estimate_skew, n_segments,
                 max_skew_ppm, refine, min_skew_duration_us):
    """Stages 1 (coarse offset) and 2 (skew) on whole bins: ``(prob, est, scan)`` with ``scan`` the coarse
    correlation ``(lags, ncc, peak, second, hwhm_us, ambiguity, offset_us)`` (its best offset at the prior's skew),
    or an unreliable :class:`SyncResult`."""
    prob = _series(starts, counts, bin_us, proxy, prior, t_start, smooth_us, transform)
    if isinstance(prob, SyncResult):
        return prob
    return _scan_stages(prob, t_start, progress, cancel, range_us=range_us, estimate_skew=estimate_skew,
                        n_segments=n_segments, max_skew_ppm=max_skew_ppm, refine=refine,
                        min_skew_duration_us=min_skew_duration_us)


def _series(starts: np.ndarray, counts: np.ndarray, bin_us: int, proxy: MotionProxy, prior: ClockModel,
            t_start: float, smooth_us, transform: str):
    """The :class:`RateSeries` of whole bins, or an unreliable :class:`SyncResult` when the data cannot give a
    clock at all (too short, constant rate, static camera)."""
    duration_us = len(counts) * bin_us
    sigma_us = max(2000.0, float(bin_us)) if smooth_us is None else float(smooth_us)
    reason = _unusable(counts, duration_us, sigma_us, proxy)
    if reason:
        return unreliable(reason, t_start, prior)
    prob = RateSeries(starts, counts, bin_us, proxy, prior, sigma_us / bin_us, transform)
    if np.ptp(prob.e[prob.me]) <= 1e-9 * max(1.0, abs(prob.e[prob.me]).max()):
        return unreliable("constant event rate: nothing to correlate", t_start, prior)
    return prob


def _scan_stages(prob: RateSeries, t_start: float, progress, cancel, *, range_us, estimate_skew, n_segments,
                 max_skew_ppm, refine, min_skew_duration_us):
    """Stages 1 and 2 of :func:`_rate_stages` on the series ``prob``, centred on its prior's clock."""
    check_cancel(cancel)
    prior, bin_us = prob.prior, prob.bin_us
    duration_us = len(prob.counts) * bin_us
    sigma_us = prob.sigma * bin_us

    # 1. coarse scan over the whole sequence
    guard = max(3, int(math.ceil(3 * prob.sigma)))
    lags, ncc, i_lo, i_hi = ncc_scan(prob, prob.me.copy(), float(prior.offset_us), prior.skew_ppm, range_us, guard,
                                     0.5)
    if progress is not None:
        progress(0.3, "coarse correlation")
    if not np.isfinite(ncc).any():
        return unreliable(_no_correlation_reason(prob, range_us), t_start, prior, lags=lags, corr=ncc)
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
    if _does_skew(estimate_skew, duration_us, min_skew_duration_us):
        skew_from_segments(prob, est, duration_us, sigma_us, guard, refine, n_segments, max_skew_ppm, progress, cancel)
    elif estimate_skew == "auto":
        est.notes.append(f"skew not estimated: {duration_us / 1e6:.1f} s of events < "
                         f"{min_skew_duration_us / 1e6:.0f} s")
    return prob, est, (lags, ncc, peak, second, hwhm * bin_us, amb, offset)


def _does_skew(estimate_skew, duration_us: float, min_skew_duration_us: float) -> bool:
    """Whether the skew is estimated (``estimate_skew`` "auto": for sequences of at least ``min_skew_duration_us``)."""
    return (duration_us >= min_skew_duration_us) if estimate_skew == "auto" else bool(estimate_skew)


def _result(est: ClockEstimate, scan: tuple, prior: ClockModel, t_start: float) -> SyncResult:
    """The reliable result of ``est`` with the coarse correlation ``scan`` of :func:`_rate_stages`."""
    lags, ncc, peak, second, hwhm_us, amb, _ = scan
    return SyncResult(int(round(est.offset_us)), float(est.skew_ppm) if est.skew_estimated else None,
                      confidence(peak, amb), True, "", lags, ncc, est.segments, time.perf_counter() - t_start,
                      "xcorr", peak, second, hwhm_us, int(prior.offset_us), float(prior.skew_ppm),
                      int(prior.t_ref_us), est.notes, est.offset_std_us)


def estimate_long(source, proxy: MotionProxy, prior: ClockModel, *, range_us: float, smooth_us, transform: str,
                  estimate_skew, n_segments, max_skew_ppm: float, refine, min_skew_duration_us: float,
                  progress=None, cancel=None, t_start: float | None = None) -> SyncResult:
    """The clock of a long recording, coarse-to-fine in time, in bounded time and memory.

    1. **coarse**: stages 1 and 2 (offset, skew from segments refined by :data:`COARSE_REFINE`) on the whole
       recording binned to at most :data:`COARSE_BINS` bins (``k x bin``; the offset search reaches at least
       :data:`COARSE_RANGE_BINS` of them, but the offset must lie within ``range_us``). When the whole recording
       does not correlate at the prior's skew (over hours a skew error of a few ppm drifts by more than a coarse
       bin) and the skew is estimated, :func:`_skew_search` looks for the skew at which it does, and the stages
       start from there;
    2. **fine** (:func:`~evpose.core.align.rate_refine.refine_windows`): :data:`FINE_WINDOWS` windows of
       :data:`FINE_WINDOW_US` at ``bin`` spread over the part of the recording the trajectory covers under the
       coarse clock (skew included): the offset from their summed NCC, then each window's offset with the
       refinement asked for, and the line through them (skew from the windows or the coarse segments, whichever
       is better determined) with the offset's standard error from their scatter.

    Cost: the coarse pass handles at most :data:`COARSE_BINS` bins and the fine pass ``FINE_WINDOWS x
    FINE_WINDOW_US`` of bins, whatever the length; only reading the coarse counts and the trajectory's proxy grow
    with it (linearly, in chunks). The notes say which passes ran at which bin width.

    ``source``: a :class:`~evpose.core.align.rate_series.BinnedCounts` or
    :class:`~evpose.core.align.rate_series.StoreCounts`. The other arguments are those of :func:`estimate_clock`.
    """
    t_start = time.perf_counter() if t_start is None else t_start
    bin_us = source.bin_us
    t0_us, t1_us = source.span_us
    factor = max(1, int(math.ceil((t1_us - t0_us) / bin_us / COARSE_BINS)))
    coarse_bin_us = bin_us * factor
    starts_c, counts_c = source.coarse(factor)
    coarse_range = max(float(range_us), COARSE_RANGE_BINS * coarse_bin_us)
    how = (f"long recording ({(t1_us - t0_us) / 3.6e9:.2f} h): the whole of it at {coarse_bin_us / 1e3:g} ms bins, "
           f"then windows at {bin_us / 1e3:g} ms")
    sub = None if progress is None else (lambda f, m: progress(0.6 * f, f"{m} (whole recording)"))
    stages = dict(range_us=coarse_range, estimate_skew=estimate_skew, n_segments=n_segments,
                  max_skew_ppm=max_skew_ppm, refine=COARSE_REFINE, min_skew_duration_us=min_skew_duration_us)
    prob = _series(starts_c[1:-1], counts_c[1:-1], coarse_bin_us, proxy, prior, t_start, None, transform)
    if isinstance(prob, SyncResult):
        prob.notes.append(how)
        return prob
    skew_on = _does_skew(estimate_skew, t1_us - t0_us, min_skew_duration_us)
    out = _coarse_pass(prob, t_start, sub, cancel, stages, skew_on)
    if isinstance(out, SyncResult):
        out.prior_skew_ppm = float(prior.skew_ppm)
        out.notes.append(how)
        return out
    _, est, scan = out
    lags, ncc, first_offset_us = scan[0], scan[1], scan[6]
    if abs(first_offset_us - prior.offset_us) > range_us + 0.5 * coarse_bin_us:
        return unreliable(f"the best match ({first_offset_us / 1e3:+.1f} ms) is beyond the search range "
                          f"{prior.offset_us / 1e3:+.1f} ± {range_us / 1e3:.0f} ms; widen the range", t_start, prior,
                          peak=scan[2], second_peak=scan[3], peak_hwhm_us=scan[4], lags=lags, corr=ncc,
                          notes=[how] + est.notes)
    est.notes.insert(0, how)
    fine = None if progress is None else (lambda f, m: progress(0.6 + 0.4 * f, m))
    refine_windows(source, proxy, prior, est, coarse_bin_us=coarse_bin_us, smooth_us=smooth_us, transform=transform,
                   refine=refine, max_skew_ppm=max_skew_ppm, fit_skew=skew_on, n_windows=FINE_WINDOWS,
                   window_us=FINE_WINDOW_US, progress=fine, cancel=cancel)
    if progress is not None:
        progress(1.0, "done")
    return _result(est, scan, prior, t_start)


def _coarse_pass(prob: RateSeries, t_start: float, progress, cancel, stages: dict, skew_on: bool):
    """Stages 1 and 2 (:func:`_scan_stages`) on the coarse series ``prob`` of a long recording: ``(prob, est,
    scan)`` or an unreliable result. With ``skew_on``, when they fail at the prior's skew they start from the skew
    of :func:`_skew_search`, and the first note says so."""
    out = _scan_stages(prob, t_start, progress, cancel, **stages)
    if not (isinstance(out, SyncResult) and skew_on):
        return out
    found = _skew_search(prob, out, t_start, progress, cancel, stages)
    if isinstance(found, SyncResult):
        return found
    skew, note = found
    out = _scan_stages(_at_skew(prob, skew), t_start, progress, cancel, **stages)
    if isinstance(out, SyncResult):
        out.reason = f"{note}, but there: {out.reason}"
        return out
    out[1].notes.insert(0, f"skew search: {note}; the stages started there")
    return out


def _at_skew(prob: RateSeries, skew_ppm: float) -> RateSeries:
    """``prob`` with its prior's skew replaced (offset and ``t_ref`` kept): the stages start from that skew."""
    start = ClockModel(prob.prior.offset_us, float(skew_ppm), prob.prior.t_ref_us)
    return RateSeries(prob.starts, prob.counts, prob.bin_us, prob.proxy, start, prob.sigma, prob.transform_kind)


def _skew_search(prob: RateSeries, failed: SyncResult, t_start: float, progress, cancel, stages: dict):
    """The skew at which the whole series correlates best, after stage 1 failed at the prior's (``failed``):
    ``(skew_ppm, note)`` with ``note`` saying what was tried and found, or an unreliable result whose reason says
    what was tried.

    The grid covers ``± max_skew_ppm`` in steps over which the clocks drift apart by one bin over the series
    (31 ppm for :data:`COARSE_BINS` bins): at each skew the whole-bin NCC scan of stage 1 over the offset range;
    the best is the highest peak inside the range, not at its edge. Cost: ~100 scans of the coarse series."""
    prior = prob.prior
    range_us, max_skew_ppm = stages["range_us"], stages["max_skew_ppm"]
    step_ppm = 1e6 / len(prob.counts)                 # one bin of drift over the series
    n = int(math.ceil(max_skew_ppm / step_ppm))
    grid = step_ppm * np.arange(-n, n + 1)
    grid = grid[np.abs(grid) <= max_skew_ppm + 1e-9]
    guard = max(3, int(math.ceil(3 * prob.sigma)))
    best_skew, best_peak = None, -np.inf
    for j, skew in enumerate(grid):
        check_cancel(cancel)
        lags, ncc, i_lo, i_hi = ncc_scan(prob, prob.me.copy(), float(prior.offset_us), float(skew), range_us, guard,
                                         0.5)
        pa = peak_analysis(ncc, i_lo, i_hi) if np.isfinite(ncc).any() else None
        if pa is not None and not pa[5] and pa[2] > best_peak:
            best_skew, best_peak = float(skew), float(pa[2])
        if progress is not None:
            progress(0.3, f"skew search {j + 1}/{len(grid)}")
    if best_skew is None or best_peak < MIN_PEAK_NCC:
        found = "" if best_skew is None else f", the best peak NCC {best_peak:.2f} at {best_skew:+.0f} ppm"
        return unreliable(f"{failed.reason}; no skew within ±{max_skew_ppm:.0f} ppm makes the whole recording "
                          f"correlate either ({len(grid)} skews, {step_ppm:.1f} ppm steps{found})", t_start, prior,
                          lags=failed.lags_us, corr=failed.correlation, peak=failed.peak,
                          second_peak=failed.second_peak, peak_hwhm_us=failed.peak_hwhm_us, notes=list(failed.notes))
    return best_skew, (f"at the prior skew {prior.skew_ppm:+.1f} ppm the whole recording does not correlate "
                       f"({failed.reason}); over {len(grid)} skews within ±{max_skew_ppm:.0f} ppm ({step_ppm:.1f} ppm "
                       f"steps), the best is {best_skew:+.0f} ppm (peak NCC {best_peak:.2f})")


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
    Recordings of more than :data:`LONG_BINS` bins go coarse-to-fine (:func:`estimate_long`), reading the
    event counts from the store's ms index bin by bin where they are needed.
    """
    t_start = time.perf_counter()
    prior = scene.clock
    ev = scene.events
    if ev.n_events == 0:
        return unreliable("no events", t_start, prior)
    source = StoreCounts(ev, bin_us)                 # the bins of ev.rate(bin_us) without its first and last
    proxy = scene_motion_proxy(scene, kind=kind)
    if source.n_bins > LONG_BINS:
        opts = _estimate_defaults() | kwargs
        _check_arguments(np.zeros(0), np.zeros(0), source.bin_us, range_ms * 1000.0, opts["refine"])
        res = estimate_long(source, proxy, prior, range_us=range_ms * 1000.0, progress=progress, cancel=cancel,
                            t_start=t_start, **opts)
    else:
        starts, counts = ev.rate(bin_us)
        res = estimate_clock(starts, counts, bin_us, proxy, prior, range_us=range_ms * 1000.0, progress=progress,
                             cancel=cancel, **kwargs)
    res.offset_std_data_us = res.offset_std_us          # the honest sigma adds the model-error floor (issue 23.2)
    res.offset_std_us = with_floor(res.offset_std_us, uncertainty.RATE_OFFSET_FLOOR_US)
    res.runtime_s = time.perf_counter() - t_start
    return res


def _estimate_defaults() -> dict:
    """The keyword defaults of :func:`estimate_clock` that :func:`estimate_long` takes too."""
    return {k: p.default for k, p in inspect.signature(estimate_clock).parameters.items()
            if p.kind is p.KEYWORD_ONLY and k not in ("range_us", "progress", "cancel")}


def _no_correlation_reason(prob: RateSeries, range_us: float) -> str:
    """Why the coarse correlation is undefined at every lag: how much of the events the trajectory covers at the
    clock in effect, skew included (the scan needs half of them at some lag), or else that a series is flat."""
    prior = prob.prior
    _, covered = prob.proxy_bins(float(prior.offset_us), prior.skew_ppm)
    n = len(covered)
    ev0, ev1 = int(prob.starts[0]), int(prob.starts[-1]) + prob.bin_us
    p0, p1 = (int(x) for x in prior.pose_time(np.array([ev0, ev1])))
    traj0, traj1 = prob.proxy.t0_us, prob.proxy.t0_us + int(prob.proxy.knots_us[-1])
    clock = (f"offset {prior.offset_us / 1e3:+.1f} ms, skew {prior.skew_ppm:+.1f} ppm: the events' "
             f"{(ev1 - ev0) / 1e6:.1f} s map to pose times {(p0 - traj0) / 1e6:+.1f} to {(p1 - traj0) / 1e6:+.1f} s "
             f"from the trajectory's start; it spans {(traj1 - traj0) / 1e6:.1f} s")
    if covered.sum() < 0.5 * n:
        return (f"the trajectory covers {100 * covered.mean():.0f} % of the events at the clock in effect ({clock}); "
                f"the correlation needs at least half of them within ± {range_us / 1e3:.0f} ms")
    return (f"no correlation at any lag within ± {range_us / 1e3:.0f} ms although the trajectory covers "
            f"{100 * covered.mean():.0f} % of the events ({clock}): the event rate or the image motion is constant "
            "where they overlap, or the trajectory's holes cut the overlap below half")
