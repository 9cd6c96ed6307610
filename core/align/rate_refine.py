"""The last stage of the clock estimate: refine the offset (and skew) continuously on the whole
sequence, from the correlation or segment estimate.

``refine="ml"`` (default) maximises the Poisson likelihood of the counts
(:class:`~evpose.core.align.poisson_fit.PoissonFit`): its gain takes up what the proxy cannot
know, which biases the NCC peak, and it gives the offset's standard error. ``refine="ncc"``
maximises the full-sequence NCC instead (kept as the simpler, cheaper reference). Both keep the
earlier estimate when the refinement would move it implausibly far.

On a long recording (:func:`~evpose.core.align.estimate.estimate_long`) :func:`refine_windows` does this
stage on a bounded set of windows at the fine bin, after the coarse pass over the whole recording.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy import ndimage, optimize

from evpose.core.align.correlation import ncc_scan
from evpose.core.align.correlation_peak import MIN_PEAK_NCC, peak_analysis
from evpose.core.align.likelihood import STD_SCAN_FACTOR, joint_skew, max_clock, ml_offset
from evpose.core.align.rate_series import RateSeries, check_cancel
from evpose.core.align.segments import robust_line, segment_offset
from evpose.core.align.sync_result import SLOW_STD_NOTE_US, ClockEstimate
from evpose.core.data.clock import ClockModel

__all__ = ["fine_windows", "refine_ml", "refine_ncc", "refine_windows"]


def _slow_note(offset_std_us: float, ml_half_us: float) -> str:
    """The note for an offset the event rate pins only loosely."""
    return ("the event rate pins the offset only to " +
            (f"±{offset_std_us / 1e3:.1f} ms (1 sigma)" if math.isfinite(offset_std_us)
             else f"more than ±{STD_SCAN_FACTOR * ml_half_us / 1e3:.0f} ms") +
            ": too few or too gradual starts and stops of the motion; check the result on the "
            "event frames or with `evpose refine --offset` (edge alignment)")


def refine_ml(prob: RateSeries, est: ClockEstimate, max_skew_ppm: float, cancel=None) -> None:
    """Maximum-likelihood refinement of ``est`` on the whole sequence (in place): the offset
    within ±10 ms (at least 1.5 bins) with its standard error; then offset and skew together when
    the skew was estimated, or the joint likelihood's test of a loose segment line."""
    check_cancel(cancel)
    bin_us = prob.bin_us
    sel = np.ones(len(prob.starts), bool)
    ml_half_us = max(1.5 * bin_us, 10_000.0)
    o_ml, fit, est.offset_std_us = ml_offset(prob, sel, est.offset_us, est.skew_ppm, ml_half_us, std=True)
    if o_ml is None:
        est.notes.append("maximum-likelihood refinement failed (no motion blocks or best point at the edge of "
                         "the ±10 ms search): kept the correlation estimate")
    else:
        est.offset_us = o_ml
        if est.skew_estimated:
            o_new, s_new, _ = max_clock(fit, est.offset_us, est.skew_ppm, bin_us, skew_step_ppm=5.0, maxiter=400)
            if abs(o_new - est.offset_us) < 3 * bin_us and abs(s_new - est.skew_ppm) < 100:
                est.offset_us, est.skew_ppm = o_new, s_new
        elif est.loose_line is not None:
            accepted = joint_skew(fit, est.offset_us, est.skew_ppm, est.loose_line, bin_us, max_skew_ppm)
            if accepted is not None:
                est.offset_us, est.skew_ppm, lr = accepted
                est.skew_estimated = True
                est.notes.append(f"skew {est.skew_ppm:.1f} ppm from the joint likelihood of the whole sequence, "
                                 f"started on the Theil-Sen line (likelihood ratio {lr:.0f} against the prior skew)")
        est.notes.append(f"refined: Poisson maximum likelihood ({len(fit.blocks)} gain blocks, noise floor "
                         f"{fit.n0:.2f} per bin)")
    if est.offset_std_us is not None and not est.offset_std_us <= SLOW_STD_NOTE_US:
        est.notes.append(_slow_note(est.offset_std_us, ml_half_us))


def refine_ncc(prob: RateSeries, est: ClockEstimate, cancel=None) -> None:
    """Full-sequence NCC refinement of ``est`` (in place) on the bins well inside the motion:
    offset and skew (Nelder-Mead) when the skew was estimated, else the offset within 1.5 bins."""
    check_cancel(cancel)
    bin_us = prob.bin_us
    _, ok0 = prob.prepared_proxy(est.offset_us, est.skew_ppm)
    sel = ndimage.binary_erosion(prob.me & ok0, iterations=4 + int(3 * prob.sigma), border_value=0)
    if sel.sum() < 10:
        return
    offset, skew = est.offset_us, est.skew_ppm
    if est.skew_estimated:
        s_scale, o_scale = 10.0, 100.0

        def f(q):
            return -np.nan_to_num(prob.ncc_at(offset + q[0] * o_scale, skew + q[1] * s_scale, sel), nan=-1e9)

        res = optimize.minimize(f, np.zeros(2), method="Nelder-Mead",
                                options={"xatol": 0.002, "fatol": 1e-12, "maxiter": 400,
                                         "initial_simplex": np.array([[0, 0], [bin_us / o_scale, 0], [0, 1.0]])})
        o_new, s_new = offset + res.x[0] * o_scale, skew + res.x[1] * s_scale
        if abs(o_new - offset) < 3 * bin_us and abs(s_new - skew) < 100:
            est.offset_us, est.skew_ppm = o_new, s_new
    else:
        r1 = optimize.minimize_scalar(lambda o: -np.nan_to_num(prob.ncc_at(o, skew, sel), nan=-1e9),
                                      bounds=(offset - 1.5 * bin_us, offset + 1.5 * bin_us),
                                      method="bounded", options={"xatol": 1.0})
        est.offset_us = float(r1.x)
    est.notes.append("refined: full-sequence NCC")


def fine_windows(source, proxy, prior: ClockModel, est: ClockEstimate, n_windows: int, window_us: int,
                 margin_us: float) -> list[tuple[int, int]]:
    """``(t0_us, n_bins)`` of up to ``n_windows`` windows of ``window_us`` spread evenly over the part of the
    recording (``source.span_us``, event clock) whose pose times under the clock ``est`` (skew included) lie on
    the trajectory at least ``margin_us`` inside its ends. When that part is shorter than the windows together
    it is cut into ``n_windows`` consecutive windows (one window over all of it when those would be shorter
    than a tenth of ``window_us``); none when it is shorter than a tenth of ``window_us``. Bin starts lie on
    the source's grid."""
    bin_us = source.bin_us
    clock = ClockModel(int(round(est.offset_us)), float(est.skew_ppm), prior.t_ref_us)
    ends = clock.event_time(np.array([proxy.t0_us, proxy.t0_us + int(proxy.knots_us[-1])], dtype=np.int64))
    s0, s1 = source.span_us
    a = max(s0, int(ends[0]) + int(math.ceil(margin_us)))
    a = s0 + -(-(a - s0) // bin_us) * bin_us                  # up to the grid
    total = (min(s1, int(ends[1]) - int(math.ceil(margin_us))) - a) // bin_us
    n_bins = max(int(window_us) // bin_us, 1)
    shortest = max(n_bins // 10, 1)
    if total < shortest:
        return []
    if total <= n_windows * n_bins:
        n_bins = int(total) // n_windows
        if n_bins < shortest:
            return [(a, int(total))]
        return [(a + j * n_bins * bin_us, n_bins) for j in range(n_windows)]
    first = np.rint(np.linspace(0, total - n_bins, n_windows)).astype(np.int64)
    return [(a + int(k) * bin_us, n_bins) for k in first]


def refine_windows(source, proxy, prior: ClockModel, est: ClockEstimate, *, coarse_bin_us: int, smooth_us,
                   transform: str, refine, max_skew_ppm: float, fit_skew: bool, n_windows: int, window_us: int,
                   progress=None, cancel=None) -> None:
    """The fine pass of a long recording's estimate (in place on ``est``, the coarse pass's clock).

    The windows of :func:`fine_windows` are read from ``source`` at its bin. Their NCC curves, summed (each a
    whole-bin scan within ``± (2 coarse bins + 4 sigma + 2 bins)`` of the coarse offset, weighted by its bins),
    give the offset at the coarse skew (parabolic peak). Each window then gives its local offset as a skew
    segment does (:func:`~evpose.core.align.segments.segment_offset` with ``refine``, within ``± (4 sigma + 2 bins
    + 2 ms)``); they become ``est.segments``.

    The skew: with ``fit_skew``, the better determined (narrower 90 % interval) of the robust line through the
    window offsets (:func:`~evpose.core.align.segments.robust_line`, which also drops outlying windows) and the
    coarse pass's segment line; without, the skew in effect (``est.skew_ppm``). The offset at ``t_ref`` is the
    line's, or for a skew taken from elsewhere the mean of the (inlying) window offsets moved to ``t_ref`` along
    it.
    ``offset_std_us`` is its standard error from the windows' scatter about the line (so model error is in it)
    and the skew's uncertainty; ``inf`` below 3 windows. When no window gives an offset the summed-NCC offset is
    kept (``offset_std_us`` None).

    Cost: about as much as the direct estimate of ``n_windows x window_us`` of events, whatever the recording's
    length (the windows' per-segment likelihood replaces the joint 2-D search on the whole sequence, which
    needs ~1000 likelihood evaluations)."""
    bin_us = source.bin_us
    sigma_us = max(2000.0, float(bin_us)) if smooth_us is None else float(smooth_us)
    half_us = 2.0 * coarse_bin_us + 4.0 * sigma_us + 2.0 * bin_us
    windows = fine_windows(source, proxy, prior, est, n_windows, window_us, half_us + coarse_bin_us)
    parts = []
    for j, (t0_us, n_bins) in enumerate(windows):
        check_cancel(cancel)
        w = RateSeries(*source.window(t0_us, n_bins), bin_us, proxy, prior, sigma_us / bin_us, transform)
        if w.me.sum() >= 20 * w.sigma:
            parts.append(w)
        if progress is not None:
            progress(0.2 * (j + 1) / len(windows), f"window {j + 1}/{len(windows)}")
    if not parts:
        est.notes.append("fine pass skipped: at the coarse clock the trajectory covers no window of the events; "
                         "coarse offset kept")
        return
    what = (f"{len(parts)} windows of {parts[0].counts.size * bin_us / 1e6:g} s at {bin_us / 1e3:g} ms "
            f"({sum(w.counts.size for w in parts):,} bins)")
    guard = max(3, int(math.ceil(3 * parts[0].sigma)))
    _summed_ncc_offset(parts, est, half_us, guard, what)
    segs = []
    for j, w in enumerate(parts):
        check_cancel(cancel)
        moving, _ = w.proxy_bins(est.offset_us, est.skew_ppm)
        segs.append(segment_offset(w, w.me.copy(), int(w.starts[0]), int(w.starts[-1]) + bin_us, est.offset_us,
                                   est.skew_ppm, 4.0 * sigma_us + 2.0 * bin_us + 2000.0, guard, refine,
                                   ok=bool(np.ptp(moving[w.me]) > 0)))
        if progress is not None:
            progress(0.2 + 0.8 * (j + 1) / len(parts), f"window offset {j + 1}/{len(parts)}")
    coarse = _segment_line(est, prior.t_ref_us, coarse_bin_us) if fit_skew else None     # before est.segments go
    est.segments = segs
    if not any(g.used for g in segs):
        est.notes.append(f"fine: none of the {len(segs)} windows gave an offset: summed-NCC offset kept")
        return
    _window_line(est, segs, prior.t_ref_us, bin_us, coarse, fit_skew, max_skew_ppm)
    if math.isfinite(est.offset_std_us) and est.offset_std_us > SLOW_STD_NOTE_US:
        est.notes.append(f"the event rate pins the offset only to ±{est.offset_std_us / 1e3:.1f} ms (1 sigma); check "
                         "the result on the event frames or with `evpose refine --offset` (edge alignment)")


def _window_line(est: ClockEstimate, segs: list, t_ref_us: int, bin_us: int, coarse, fit_skew: bool,
                 max_skew_ppm: float) -> None:
    """Offset at ``t_ref_us``, skew and ``offset_std_us`` from the window offsets ``segs`` (in place on ``est``;
    :func:`refine_windows` says how). Outlying windows get ``used = False``: those off the windows' own robust
    line, or without ``fit_skew`` those more than 3 MAD (at least a quarter bin) off the median about the skew
    in effect."""
    used = [g for g in segs if g.used]
    line = robust_line(used, t_ref_us, bin_us) if fit_skew else None       # marks outlying windows unused
    lines = [(ln[2], ln[0], name) for ln, name in ((line, "windows"), (coarse, "coarse segments"))
             if ln is not None and abs(ln[0]) <= max_skew_ppm and math.isfinite(ln[2])]
    if lines:
        half_ci, slope, name = min(lines)
        slope_var = (half_ci / 1.645) ** 2
        skew_note = f"skew of the {name} {slope:.2f} ppm (90% CI ±{half_ci:.2f})"
        est.skew_estimated = True
    else:
        slope, slope_var, name = float(est.skew_ppm), 0.0, None
        skew_note = (f"skew {slope:.2f} ppm kept (" + ("not estimated" if not fit_skew else
                     f"no line through the {len(used)} window offsets") + ")")
    used = [g for g in segs if g.used]
    r = np.array([g.offset_us - slope * (g.t_center_us - t_ref_us) * 1e-6 for g in used])   # offsets at t_ref
    if not fit_skew and len(r) >= 3:
        dev = np.abs(r - np.median(r))
        keep = dev <= max(3 * 1.4826 * np.median(dev), 0.25 * bin_us)
        for g, k in zip(used, keep):
            g.used = bool(k)
        used, r = [g for g, k in zip(used, keep) if k], r[keep]
    icpt = line[1] if name == "windows" else float(r.mean())
    est.offset_us, est.skew_ppm = float(icpt), float(slope)
    est.offset_std_us = _intercept_std(used, t_ref_us, slope, icpt, slope_var, slope_fitted=name == "windows")
    std_note = (f"offset ±{est.offset_std_us:.0f} us (1 sigma, from the scatter of {len(used)} window offsets about "
                "the line)" if math.isfinite(est.offset_std_us) else
                f"no standard error: {len(used)} window offset(s), at least 3 needed")
    est.notes.append(f"fine: {skew_note}, {std_note}")


def _summed_ncc_offset(parts: list, est: ClockEstimate, half_us: float, guard: int, what: str) -> None:
    """``est.offset_us`` from the NCC curves of the windows ``parts`` summed (weighted by their valid bins),
    or kept with a note when the sum has no clear peak inside the scan."""
    total = weight = lags = None
    for w in parts:
        lags, ncc, lo, hi = ncc_scan(w, w.me.copy(), est.offset_us, est.skew_ppm, half_us, guard, 0.5)
        if total is None:
            total, weight = np.zeros(len(ncc)), np.zeros(len(ncc))
        ok = np.isfinite(ncc)
        total[ok] += w.me.sum() * ncc[ok]
        weight[ok] += w.me.sum()
    with np.errstate(invalid="ignore", divide="ignore"):
        curve = np.where(weight > 0, total / weight, np.nan)
    pa = peak_analysis(curve, lo, hi)
    if pa is None or pa[5] or pa[2] < MIN_PEAK_NCC:
        est.notes.append(f"fine offset: no clear NCC peak within ±{half_us / 1e3:.0f} ms of the coarse offset over "
                         f"{what}: coarse offset kept")
        return
    est.offset_us = float(lags[pa[0]] + pa[1] * (lags[1] - lags[0]))
    est.notes.append(f"fine offset {est.offset_us:.0f} us (summed NCC peak {pa[2]:.3f}) over {what}")


def _segment_line(est: ClockEstimate, t_ref_us: int, bin_us: int):
    """The robust line of the segments of ``est`` (``(slope, offset, half CI, inliers)`` of
    :func:`~evpose.core.align.segments.robust_line` on copies, so their flags stay), or None when its skew was not
    estimated."""
    if not est.skew_estimated:
        return None
    used = [replace(g) for g in est.segments if g.used]
    return robust_line(used, t_ref_us, bin_us)


def _intercept_std(used: list, t_ref_us: int, slope: float, icpt: float, slope_var: float,
                   slope_fitted: bool = True) -> float:
    """Standard error (µs) at ``t_ref_us`` of the line ``icpt + slope * x`` through the window offsets ``used``
    (x in s since ``t_ref_us``): their scatter about it over their number (degrees of freedom: less 2 when the
    slope was fitted to them, else 1), and ``slope_var`` (ppm², the slope's variance) times the squared distance
    of their mean time from ``t_ref_us``; ``inf`` below 3 windows."""
    if len(used) < 3:
        return math.inf
    x = np.array([(g.t_center_us - t_ref_us) * 1e-6 for g in used])
    r = np.array([g.offset_us for g in used]) - (icpt + slope * x)
    s2 = float(r @ r) / (len(x) - (2 if slope_fitted else 1))
    return math.sqrt(s2 / len(x) + slope_var * float(x.mean()) ** 2)
