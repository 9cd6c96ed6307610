"""Maximum-likelihood clock search on :class:`~evpose.core.align.poisson_fit.PoissonFit`, and how
tightly the likelihood pins the offset.

The stages of the clock estimate use these to refine an offset (a fine scan, then Brent), to
fit offset and skew together (Nelder-Mead), to accept a skew that the segment line alone could
not establish (a likelihood-ratio test), and to report the offset's standard error from the
curvature of the likelihood's envelope (its local curvature would claim a precision the data do
not hold; see ``docs/sync.md``).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from evpose.core.align.poisson_fit import PoissonFit

__all__ = ["SKEW_MIN_LR", "STD_SCAN_FACTOR", "joint_skew", "likelihood_std_us", "max_clock", "ml_offset"]

SKEW_MIN_LR = 10.8            # likelihood ratio for a skew the segment line alone could not establish (p = 0.001)
STD_SCAN_FACTOR = 3.0         # the likelihood scan for the standard error reaches this x the ML search half width


def ml_offset(prob, sel, offset0, skew, half_width_us, margin_extra_us=50_000, max_block_us=1_000_000,
              xatol=2.0, std: bool = False):
    """Maximum-likelihood offset (:class:`PoissonFit`) in ``offset0 ± half_width``: a scan at a
    quarter bin, then a bounded Brent search around the best point.

    Returns ``(offset, fit, std_us)``; ``offset`` is None when the model cannot be set up or the
    best point is at the edge of the scan. With ``std``, the scan is extended at whole-bin steps
    to ``± STD_SCAN_FACTOR x half_width`` and ``std_us`` is :func:`likelihood_std_us` (also when
    the maximum is at the edge: then around ``offset0``); otherwise None."""
    bin_us = prob.bin_us
    outer_us = STD_SCAN_FACTOR * half_width_us if std else half_width_us
    margin = int(math.ceil((outer_us + margin_extra_us) / bin_us))
    fit = PoissonFit(prob, offset0, skew, sel, margin, max(int(max_block_us / bin_us), 20))
    if not fit.ok:
        return None, fit, None
    step = max(bin_us / 4.0, 50.0)
    n = int(math.ceil(half_width_us / step))
    grid = offset0 + step * np.arange(-n, n + 1)
    ll = np.array([fit.loglik(o, skew) for o in grid])
    if not np.isfinite(ll).any():
        return None, fit, None
    if std:     # whole-bin steps beyond the fine scan (likelihood_std_us needs no order)
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
    std_us = likelihood_std_us(*scan, offset0 if best is None else best, bin_us) if std else None
    return best, fit, std_us


def likelihood_std_us(grid_us: np.ndarray, loglik: np.ndarray, best_us: float, bin_us: int) -> float:
    """Standard error (1 sigma, µs) of the offset from the curvature of the profile
    log-likelihood: a least-squares parabola ``a x^2 + b x + c`` through the scan, first over all
    of it, then over ``best ± max(3 sigma, 2 bins)``; ``sigma = sqrt(-1 / 2a)``.

    The parabola follows the likelihood's *envelope*: its local curvature at the maximum can be
    far sharper (ripples at the pose-sample period where the camera really moves piecewise
    linearly, a kink where bins line up with the simulator's frames) and would claim a precision
    the data do not hold; how well the envelope's sigma matches the actual error is measured in
    ``docs/sync.md``. Model error is not in it. Returns ``inf`` when the scan is flat or curves
    up (the offset is not pinned within it)."""
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


def max_clock(fit: PoissonFit, offset_us: float, skew_ppm: float, bin_us: int, skew_step_ppm: float,
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


def joint_skew(fit: PoissonFit, offset_us: float, skew_ppm: float, line: tuple, bin_us: int,
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
    o1, s1, ll1 = max_clock(fit, icpt, slope, bin_us, skew_step_ppm=10.0, maxiter=600)
    lr = 2.0 * (ll1 - ll0)
    if not (np.isfinite(lr) and lr >= min_lr and abs(s1 - slope) <= half_ci and abs(s1) <= max_skew_ppm):
        return None
    return float(o1), float(s1), float(lr)

