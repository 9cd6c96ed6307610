"""Normalised cross-correlation of the event rate with the motion proxy over whole-bin lags.

The coarse offset of the clock estimate, and each skew segment's first offset, come from this
scan: a masked NCC (only bins where both series exist count, so holes in the trajectory do not
bias it) for every whole-bin lag of a search range, computed with FFTs where that pays
(:func:`correlate_valid`: :func:`scipy.signal.correlate`'s choice and arithmetic, without importing
:mod:`scipy.signal`); :func:`refine_ncc_offset` then maximises the full NCC continuously around the
scan's peak.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import fft as sp_fft
from scipy import optimize

from evpose.core.align.rate_series import RateSeries

__all__ = ["ncc_scan", "refine_ncc_offset", "correlate_valid"]


def correlate_valid(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``sum_k x[k] * y[k + j]`` for every ``j`` in ``[0, len(y) - len(x)]`` (1-D float64, ``len(y) >= len(x)``):
    ``scipy.signal.correlate(y, x, mode="valid", method="auto")`` bit for bit -- the same choice between the direct
    sum and FFTs (scipy 1.17's operation-count model) and the same operations -- without importing
    :mod:`scipy.signal` (which imports :mod:`scipy.stats`: ~23 MB resident in the app, 1 s; tracker issue 25.4)."""
    y = np.asarray(y, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    n, k = len(y), len(x)
    if y.ndim != 1 or x.ndim != 1 or n < k or k == 0:
        raise ValueError(f"correlate_valid: 1-D arrays with len(y) >= len(x) > 0, got {y.shape}, {x.shape}")
    kernel = x[::-1]
    full = n + k - 1
    fft_ops, direct_ops = 3 * full * np.log(full), (n - k + 1) * k
    if k == 1 or not 1.89095737e-9 * fft_ops < 2.1364985e-10 * direct_ops - 1e-3:
        return np.convolve(y, kernel, "valid")
    fshape = [sp_fft.next_fast_len(full, True)]
    ret = sp_fft.irfftn(sp_fft.rfftn(y, fshape, axes=[0]) * sp_fft.rfftn(kernel, fshape, axes=[0]), fshape,
                        axes=[0])[:full]
    start = (full - (n - k + 1)) // 2
    return ret[start:start + n - k + 1].copy()


def _masked_ncc(a: np.ndarray, ma: np.ndarray, b: np.ndarray, mb: np.ndarray, min_overlap: float):
    """NCC of ``a`` (length K) against every length-K window of ``b`` (length K + 2L).

    Returns ``(ncc (2L+1,), overlap (2L+1,))``; lag ``j`` compares ``a[k]`` with ``b[k + j]``.
    Only bins valid in both series count; NaN where the overlap is below ``min_overlap`` bins.
    """
    A, MA = np.where(ma, a, 0.0), ma.astype(np.float64)
    B, MB = np.where(mb, b, 0.0), mb.astype(np.float64)

    def corr(x, y):  # sum_k x[k] * y[k + j]
        return correlate_valid(y, x)

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


def ncc_scan(prob: RateSeries, sel: np.ndarray, centre_us: float, skew_ppm: float, half_range_us: float,
             guard_bins: int, min_overlap_frac: float):
    """Whole-bin NCC scan of the bins in ``sel`` over ``centre ± half_range``.

    Returns ``(lags_us, ncc, i_lo, i_hi)`` where [i_lo, i_hi] is the in-range index span.
    """
    bin_us = prob.bin_us
    idx = np.flatnonzero(sel)
    k0, k1 = int(idx[0]), int(idx[-1]) + 1
    L = int(math.ceil(half_range_us / bin_us)) + guard_bins
    kk = np.arange(k0 - L, k1 + L, dtype=np.float64)
    p, mp = prob.prepared_proxy(centre_us, skew_ppm, shift_bins=kk)
    a = prob.e[k0:k1]
    ma = prob.me[k0:k1] & sel[k0:k1]
    ncc, _ = _masked_ncc(a, ma, p, mp, max(min_overlap_frac * ma.sum(), 10))
    step = bin_us * (1.0 + skew_ppm * 1e-6)
    lags = centre_us + (np.arange(-L, L + 1)) * step
    return lags, ncc, guard_bins, 2 * L - guard_bins


def refine_ncc_offset(prob: RateSeries, sel, offset0, skew, half_width_us, xatol=1.0) -> tuple[float, float]:
    """The offset maximising the full NCC within ``offset0 ± half_width_us`` (bounded Brent), and that NCC."""
    res = optimize.minimize_scalar(lambda o: -np.nan_to_num(prob.ncc_at(o, skew, sel), nan=-2.0),
                                   bounds=(offset0 - half_width_us, offset0 + half_width_us), method="bounded",
                                   options={"xatol": xatol})
    return float(res.x), float(-res.fun)

