"""The last stage of the clock estimate: refine the offset (and skew) continuously on the whole
sequence, from the correlation or segment estimate.

``refine="ml"`` (default) maximises the Poisson likelihood of the counts
(:class:`~evpose.core.align.poisson_fit.PoissonFit`): its gain takes up what the proxy cannot
know, which biases the NCC peak, and it gives the offset's standard error. ``refine="ncc"``
maximises the full-sequence NCC instead (kept as the simpler, cheaper reference). Both keep the
earlier estimate when the refinement would move it implausibly far.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage, optimize

from evpose.core.align.likelihood import STD_SCAN_FACTOR, joint_skew, max_clock, ml_offset
from evpose.core.align.rate_series import RateSeries, check_cancel
from evpose.core.align.sync_result import SLOW_STD_NOTE_US, ClockEstimate

__all__ = ["refine_ml", "refine_ncc"]


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
