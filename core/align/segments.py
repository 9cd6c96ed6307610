"""The skew of the clock from the offsets of consecutive segments of the sequence.

A skew makes the offset drift linearly over the recording, so the estimate measures the offset
on ``n_segments`` consecutive segments (each an NCC scan and the refinement asked for) and fits a
robust line through them: its slope is the skew (µs/s = ppm), its value at ``t_ref`` the offset.
Theil-Sen with an inlier refit keeps a segment without clear motion from tilting the line. A
line too uncertain to accept alone is handed on as ``loose_line`` for the likelihood stage.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtri

from evpose.core.align.correlation import ncc_scan, refine_ncc_offset
from evpose.core.align.correlation_peak import MIN_PEAK_NCC, peak_analysis
from evpose.core.align.likelihood import ml_offset
from evpose.core.align.rate_series import RateSeries, check_cancel
from evpose.core.align.sync_result import ClockEstimate, SegmentOffset

__all__ = ["robust_line", "segment_offset", "skew_from_segments", "theil_sen"]

#: A Theil-Sen skew is taken on its own when its 90 % interval is at most this wide either way (ppm).
MAX_LINE_HALF_CI_PPM = 100.0


def segment_offset(prob: RateSeries, sel: np.ndarray, t0_us: int, t1_us: int, centre_us: float, skew_ppm: float,
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
    lags, ncc, lo, hi = ncc_scan(prob, sel, centre_us, skew_ppm, half_range_us, guard_bins, 0.8)
    pa = peak_analysis(ncc, lo, hi)
    if pa is None or pa[5] or pa[2] < MIN_PEAK_NCC:
        return seg
    o = lags[pa[0]] + pa[1] * (lags[1] - lags[0])
    if refine:
        o, _ = refine_ncc_offset(prob, sel, o, skew_ppm, 1.5 * bin_us)
    if refine == "ml":
        o_ml, _, _ = ml_offset(prob, sel, o, skew_ppm, max(1.5 * bin_us, 8000.0))
        if o_ml is not None:
            o = o_ml
    # offsets are measured as "clock offset at t_ref"; convert to the local offset
    seg.offset_us = float(o + skew_ppm * 1e-6 * (tc - prob.prior.t_ref_us))
    seg.peak = float(pa[2])
    seg.used = True
    return seg


def theil_sen(y, x, alpha: float = 0.95) -> tuple[float, float, float, float]:
    """``(slope, intercept, low_slope, high_slope)``: the Theil-Sen line through ``(x, y)`` (the median of the
    pairwise slopes; intercept ``median(y) - slope * median(x)``) and the ``alpha`` confidence interval of the slope
    (Sen 1968, eq. 2.6, with ties). The same operations as :func:`scipy.stats.theilslopes` (``method='separate'``),
    so the same bits, without importing :mod:`scipy.stats` (~19 MB resident in the app, 0.7 s; tracker issue 25.4).
    NaN anywhere: all NaN (scipy's ``nan_policy='propagate'``)."""
    y = np.array(y, dtype=float, copy=True).ravel()
    x = np.array(x, dtype=float, copy=True).ravel()
    if len(x) != len(y):
        raise ValueError("theil_sen: x and y differ in length")
    nan = float("nan")
    if len(x) < 2 or np.isnan(x).any() or np.isnan(y).any():
        return nan, nan, nan, nan
    deltax = x[:, np.newaxis] - x
    deltay = y[:, np.newaxis] - y
    slopes = deltay[deltax > 0] / deltax[deltax > 0]
    slopes.sort()
    medslope = np.median(slopes) if slopes.size else np.float64(nan)
    medinter = np.median(y) - medslope * np.median(x)
    if alpha > 0.5:
        alpha = 1.0 - alpha
    z = ndtri(alpha / 2.0)
    nt, ny = len(slopes), len(y)
    sigsq = 1 / 18. * (ny * (ny - 1) * (2 * ny + 5)
                       - sum(k * (k - 1) * (2 * k + 5) for k in _repeat_counts(x))
                       - sum(k * (k - 1) * (2 * k + 5) for k in _repeat_counts(y)))
    try:
        sigma = np.sqrt(sigsq)
        ru = min(int(np.round((nt - z * sigma) / 2.)), len(slopes) - 1)
        rl = max(int(np.round((nt + z * sigma) / 2.)) - 1, 0)
        delta = slopes[[rl, ru]]
    except (ValueError, IndexError):
        delta = (np.float64(nan), np.float64(nan))
    return medslope, medinter, delta[0], delta[1]


def _repeat_counts(a: np.ndarray) -> np.ndarray:
    """How often each value of ``a`` that occurs more than once occurs."""
    a = np.sort(a)
    change = np.concatenate(([True], a[1:] != a[:-1]))
    freq = np.diff(np.concatenate(np.nonzero(change) + ([a.size],)))
    return freq[freq > 1]


def robust_line(used: list, t_ref_us: int, bin_us: int):
    """Theil-Sen line through the segment offsets (µs against s since ``t_ref_us``), refitted on
    the inliers (3 MAD, at least a quarter bin); outliers get ``used = False``. Returns
    ``(slope ppm, offset at t_ref µs, half 90 % CI ppm, inliers)`` or None below 3 segments."""
    if len(used) < 3:
        return None
    x = np.array([(s.t_center_us - t_ref_us) * 1e-6 for s in used])   # s
    y = np.array([s.offset_us for s in used])                           # µs
    slope, icpt, lo_s, hi_s = theil_sen(y, x, 0.9)
    resid = y - (icpt + slope * x)
    mad = 1.4826 * np.median(np.abs(resid - np.median(resid)))
    inl = np.abs(resid) <= max(3 * mad, 0.25 * bin_us)
    for s, ok in zip(used, inl):
        s.used = bool(ok)
    if inl.sum() >= 3:
        slope, icpt, lo_s, hi_s = theil_sen(y[inl], x[inl], 0.9)
    return float(slope), float(icpt), 0.5 * (hi_s - lo_s), int(inl.sum())



def _measure_segments(prob: RateSeries, bounds: np.ndarray, centre_us: float, skew_ppm: float, half_range_us: float,
                      guard_bins: int, refine, moving: np.ndarray, pass_no: int, progress, cancel) -> list:
    """One pass over the segments (bin ranges ``bounds``): each segment's offset around
    ``centre_us`` at ``skew_ppm``. ``moving`` is the proxy at the prior clock (a segment where it
    is flat has no motion to time)."""
    n_seg = len(bounds) - 1
    starts, bin_us = prob.starts, prob.bin_us
    segments = []
    for j in range(n_seg):
        check_cancel(cancel)
        sel = np.zeros(len(starts), bool)
        sel[bounds[j]:bounds[j + 1]] = True
        sel &= prob.me
        segments.append(segment_offset(prob, sel, int(starts[bounds[j]]), int(starts[bounds[j + 1] - 1]) + bin_us,
                                       centre_us, skew_ppm, half_range_us, guard_bins, refine,
                                       ok=bool(sel.sum() >= 20 * prob.sigma and np.ptp(moving[sel]) > 0)))
        if progress is not None:
            progress(0.3 + 0.25 * (pass_no - 1) + 0.25 * (j + 1) / n_seg, f"segment {j + 1}/{n_seg}")
    return segments


def _best_line(prob: RateSeries, est: ClockEstimate, n_seg: int, half_range_us: float, guard_bins: int, refine,
               max_skew_ppm: float, progress, cancel):
    """Measure the segments and fit the line, in up to two passes: pass 1 at the estimate's skew,
    centred on its offset; when the slope found differs from that skew, pass 2 measures them
    again with the slope (a drift of ~1000 ppm over a 5 s segment would otherwise smear each
    segment's own fit). Returns ``(best line or None, segments of the last pass, segments used)``
    where a line is ``(slope, offset, half CI, inliers, pass, segments)``: the better determined
    of the two."""
    bounds = np.linspace(0, len(prob.starts), n_seg + 1).astype(int)
    moving, _ = prob.proxy_bins(float(prob.prior.offset_us), prob.prior.skew_ppm)
    seg_skew, seg_centre, best = est.skew_ppm, est.offset_us, None
    for pass_no in (1, 2):
        segments = _measure_segments(prob, bounds, seg_centre, seg_skew, half_range_us, guard_bins, refine, moving,
                                     pass_no, progress, cancel)
        used = [s for s in segments if s.used]
        fit_line = robust_line(used, prob.prior.t_ref_us, prob.bin_us)
        if fit_line is not None:
            fit_line = (*fit_line, pass_no, segments)
            if best is None or fit_line[2] < best[2]:     # keep the better determined line
                best = fit_line
        if (pass_no == 2 or fit_line is None or not abs(fit_line[0]) <= max_skew_ppm
                or abs(fit_line[0] - seg_skew) <= 10.0):
            break
        seg_skew, seg_centre = fit_line[0], fit_line[1]
    return best, segments, used


def skew_from_segments(prob: RateSeries, est: ClockEstimate, duration_us: float, sigma_us: float, guard_bins: int,
                       refine, n_segments: int | None, max_skew_ppm: float, progress=None, cancel=None) -> None:
    """Stage 2 of the clock estimate: skew and offset from the segment line, into ``est``.

    Taken when the slope is within ``max_skew_ppm`` and its 90 % interval within
    :data:`MAX_LINE_HALF_CI_PPM`; a line within ``max_skew_ppm`` but looser becomes
    ``est.loose_line`` for the likelihood to confirm. The segments are kept in ``est.segments``.
    """
    bin_us = prob.bin_us
    n_seg = n_segments or int(np.clip(round(duration_us / 5e6), 4, 16))
    seg_range = max_skew_ppm * 1e-6 * duration_us + 4 * sigma_us + 2 * bin_us
    best, est.segments, used = _best_line(prob, est, n_seg, seg_range, guard_bins, refine, max_skew_ppm, progress,
                                          cancel)
    if best is None:
        est.notes.append(f"skew not estimated: only {len(used)} of {n_seg} segments gave an offset")
        return
    slope, icpt, half_ci, n_in, pass_no, est.segments = best
    if abs(slope) <= max_skew_ppm and half_ci <= MAX_LINE_HALF_CI_PPM:
        est.skew_ppm, est.offset_us = float(slope), float(icpt)
        est.skew_estimated = True
        est.notes.append(f"segments: Theil-Sen skew {slope:.1f} ppm (90% CI ±{half_ci:.1f}), "
                         f"{n_in}/{n_seg} segments used" + (" (second pass)" if pass_no == 2 else ""))
        return
    if abs(slope) <= max_skew_ppm and math.isfinite(half_ci):
        est.loose_line = (float(slope), float(icpt), float(half_ci))
    est.notes.append(f"skew not estimated: Theil-Sen slope {slope:.1f} ppm with 90% CI ±{half_ci:.1f} ppm")
