"""Reading a correlation curve: its main peak, the runner-up, and how much to trust the match.

The reliability decision of the clock estimate rests on the shape of the NCC curve over the
lags: a low peak or a broad main lobe means the rate does not pin the clock ("flat
correlation"); a second peak nearly as high as the best means a periodic motion could match at
either lag ("ambiguous"). The thresholds of that decision live here with the measures.
"""
from __future__ import annotations

import numpy as np

__all__ = ["MAX_PEAK_HWHM_FRACTION", "MAX_SECOND_PEAK_RATIO", "MIN_PEAK_NCC", "ambiguity", "confidence", "local_maxima",
           "parabolic_offset", "peak_analysis"]

#: Thresholds of the reliability decision (see :func:`evpose.core.align.estimate.estimate_clock`).
MIN_PEAK_NCC = 0.3            # peak normalised correlation below this: "flat correlation"
MAX_SECOND_PEAK_RATIO = 0.85  # second-best peak above this fraction of the best (above the curve's median): ambiguous
MAX_PEAK_HWHM_FRACTION = 0.8  # main lobe half width above this fraction of the range: "flat correlation"


def parabolic_offset(y_m: float, y0: float, y_p: float) -> float:
    """Offset in [-0.5, 0.5] samples of the vertex of the parabola through three samples around a maximum (0
    when they do not bend down)."""
    den = y_m - 2.0 * y0 + y_p
    if not (np.isfinite(den) and den < 0):
        return 0.0
    return float(np.clip(0.5 * (y_m - y_p) / den, -0.5, 0.5))


def local_maxima(x: np.ndarray) -> np.ndarray:
    """Indices of the local maxima of ``x`` (1-D): samples, or the middle (rounded down) of flat runs, higher than
    both neighbours; never the first or the last sample. ``scipy.signal.find_peaks(x)[0]`` without importing
    :mod:`scipy.signal` (~23 MB resident in the app; tracker issue 25.4)."""
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    if n < 3:
        return np.zeros(0, np.intp)
    change = np.flatnonzero(x[1:] != x[:-1]) + 1            # starts of runs of equal values (NaN: its own run)
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change - 1, [n - 1]))
    inner = (starts > 0) & (ends < n - 1)
    s, e = starts[inner], ends[inner]
    top = (x[s - 1] < x[s]) & (x[e + 1] < x[s])
    return ((s[top] + e[top]) // 2).astype(np.intp)


def peak_analysis(ncc: np.ndarray, i_lo: int, i_hi: int):
    """Main peak (index within [i_lo, i_hi]), sub-bin shift, second-best peak and half width.

    Returns ``(i_peak, delta, peak, second, hwhm_bins, at_edge, base)`` (``base``: the curve's median)
    or None when all NaN.
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
    delta = parabolic_offset(c[i - 1], peak, c[i + 1])
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
    peaks = local_maxima(np.where(np.isfinite(c), c, -2.0))
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


def ambiguity(peak: float, second: float, base: float) -> float:
    """Height of the second-best peak relative to the best, both above the curve's median:
    ~1 for periodic motion, small for a unique match (slow motion gives broad, high
    correlation everywhere, so the raw ratio second / peak would be misleading)."""
    if not (np.isfinite(second) and np.isfinite(peak)):
        return 0.0
    b = base if np.isfinite(base) else 0.0
    b = min(b, second)
    return float(np.clip((second - b) / max(peak - b, 1e-9), 0.0, 1.0))


def confidence(peak: float, ambiguity: float) -> float:
    """In [0, 1]: the peak NCC times how clearly it beats the second-best peak."""
    if not np.isfinite(peak) or peak <= 0:
        return 0.0
    margin = 1.0 - ambiguity
    return float(np.clip(peak, 0, 1) * np.clip(margin / (1.0 - MAX_SECOND_PEAK_RATIO) / 2.0, 0, 1))

