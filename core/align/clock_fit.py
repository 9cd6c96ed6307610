"""Offset and skew from the per-window shares of the edge objective, sampled on a grid of offsets.

The clock refinement does not take the optimiser's last point: the edge objective is rough on a
fine scale (events changing their nearest edge sample), so each window's share of it is sampled
on a grid of offsets and the estimate is the centre of a parabola through the top of their sum.
A window only sees the clock through its effective offset at its own time, so a skew change
reads windows at different times at different offsets; the skew is the change that makes the
windows agree best. Standard errors are jackknifed over the windows.
"""
from __future__ import annotations

import numpy as np

__all__ = ["fit_clock", "jackknife_clock", "peak_fit"]


def peak_fit(grid: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Centre and height of a least-squares parabola through the upper half of a sampled peak
    (the points within half the sampled range of the maximum), so the fine-scale roughness of
    the objective (events changing their nearest edge sample) does not decide the offset.
    ``(nan, nan)`` when the peak is not inside the evenly spaced ``grid``."""
    nan = (float("nan"), float("nan"))
    ok = np.isfinite(y)
    if ok.sum() < 3:
        return nan
    j = int(np.argmax(np.where(ok, y, -np.inf)))
    if j == 0 or j == len(y) - 1:
        return nan
    ymax, ymin = float(y[j]), float(np.min(y[ok]))
    use = ok & (y >= ymax - 0.5 * (ymax - ymin))
    if use.sum() < 3:
        use = np.zeros(len(y), bool)
        use[j - 1:j + 2] = True
    step = float(grid[1] - grid[0])
    x = (grid[use] - grid[j]) / step
    c2, c1, c0 = np.polyfit(x, y[use], 2)
    if not c2 < 0:
        return nan
    xc = -c1 / (2.0 * c2)
    centre = float(grid[j] + xc * step)
    if not grid[0] <= centre <= grid[-1]:
        return nan
    return centre, float(c0 + c1 * xc + c2 * xc * xc)


def fit_clock(grid_us: np.ndarray, parts: np.ndarray, tau_us: np.ndarray, dk_ppm: np.ndarray) -> tuple:
    """Offset and skew change that maximise the windows' summed objective.

    ``parts[:, w]`` is window w's share of the objective at the offsets ``grid_us`` (all at the
    start skew); a window only sees the clock through its effective offset, so under a skew
    change ``dk`` window w at ``tau_us[w]`` (µs after the clock's reference) is read at
    ``c + dk * (tau_w - mean tau)``, where ``c`` is the offset at the windows' mean time. For
    each ``dk`` of the evenly spaced ``dk_ppm`` the summed curve's peak (:func:`peak_fit` on
    the grid's central part, which every window covers) gives ``c`` and a height; the heights'
    peak over ``dk`` gives the skew change. Returns ``(offset_us at the clock reference,
    dk_ppm)``; NaNs when the peak is not inside the grids. With ``dk_ppm = [0]`` it is the 1-D
    offset fit at the start skew.
    """
    nan = (float("nan"), float("nan"))
    rel = (tau_us - tau_us.mean()) * 1e-6
    margin = float(np.max(np.abs(dk_ppm))) * float(np.max(np.abs(rel), initial=0.0))
    cgrid = grid_us[(grid_us >= grid_us[0] + margin - 1e-6) & (grid_us <= grid_us[-1] - margin + 1e-6)]
    if len(cgrid) < 3:
        return nan

    def peak_at(dk):
        tot = np.zeros(len(cgrid))
        for w in range(parts.shape[1]):
            tot += np.interp(cgrid + dk * rel[w], grid_us, parts[:, w])
        return peak_fit(cgrid, tot)

    if len(dk_ppm) == 1:
        c, _ = peak_at(float(dk_ppm[0]))
        dk = float(dk_ppm[0])
    else:
        heights = np.array([peak_at(float(d))[1] for d in dk_ppm])
        dk, _ = peak_fit(dk_ppm, heights)
        if not np.isfinite(dk):
            return nan
        c, _ = peak_at(dk)
    if not np.isfinite(c):
        return nan
    return c - dk * 1e-6 * float(tau_us.mean()), dk


def jackknife_clock(grid_us: np.ndarray, parts: np.ndarray, tau_us: np.ndarray, dk_ppm: np.ndarray) -> tuple:
    """Jackknife standard errors of :func:`fit_clock` over windows: ``(offset std µs, skew std
    ppm)`` from the leave-one-window-out fits (their spread scaled by ``(n - 1) / n``); ``inf``
    when a leave-one-out peak is not inside the grids (the windows do not pin it), NaN for fewer
    than 3 windows."""
    n = parts.shape[1]
    if n < 3:
        return float("nan"), float("nan")
    fits = np.array([fit_clock(grid_us, np.delete(parts, i, axis=1), np.delete(tau_us, i), dk_ppm)
                     for i in range(n)])
    if not np.isfinite(fits).all():
        return float("inf"), float("inf")
    sd = np.sqrt((n - 1) / n * ((fits - fits.mean(axis=0)) ** 2).sum(axis=0))
    return float(sd[0]), float(sd[1])
