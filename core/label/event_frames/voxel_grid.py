"""The event voxel grid of one window, bilinear in time (Zhu et al. 2019)."""
from __future__ import annotations

import numpy as np

from evpose.core.data.events import EventArray
from evpose.core.label.event_frames.accumulate import check_events, check_size, check_window, event_chunks


def voxel_grid(ev: EventArray, width: int, height: int, t0_us: int, t1_us: int, bins: int = 5) -> np.ndarray:
    """Event voxel grid, bilinear in time (Zhu et al. 2019), normalised by the window bounds.

    Each event's normalised time is ``tau = (bins - 1) * (t - t0_us) / (t1_us - t0_us)`` in
    ``[0, bins - 1)``, so bin ``k`` is centred at ``t0_us + k * (t1_us - t0_us) / (bins - 1)`` (first centre at
    the window start, last at its end). The event adds its polarity ``+1`` (ON) / ``-1`` (OFF) times
    ``1 - (tau - floor(tau))`` to bin ``floor(tau)`` and times ``tau - floor(tau)`` to the next bin. The split
    is computed in integers, so an event exactly at a bin centre goes entirely to that bin. With
    ``bins = 1`` every event goes to bin 0. Using the window bounds (not the first/last event) keeps the grid a
    function of the window alone.

    Parameters
    ----------
    ev : EventArray
        Events with ``t0_us <= t < t1_us`` (any order).
    width, height : int
        Sensor size, pixels.
    t0_us, t1_us : int
        Half-open window, µs.
    bins : int
        Number of temporal bins B (>= 1).

    Returns
    -------
    (B, H, W) float32
        Summing over bins gives the signed count ``ON - OFF`` per pixel.
    """
    W, H = check_size(width, height)
    if int(bins) != bins or bins < 1:
        raise ValueError(f"bins: must be a positive integer, got {bins}")
    B = int(bins)
    t0, t1 = check_window(ev, t0_us, t1_us)
    check_events(ev, W, H)
    HW = H * W
    if len(ev) == 0:
        return np.zeros((B, H, W), np.float32)
    D = t1 - t0
    if D * (B - 1) >= 2**62:
        raise ValueError(f"bins: (t1_us - t0_us) * (bins - 1) = {D * (B - 1)} overflows int64 arithmetic")
    grid = None
    for part, keys in event_chunks(ev, W, H, polarity=False):
        m = len(part)
        sign = part.p.astype(np.float64)
        sign *= 2.0
        sign -= 1.0
        if B == 1:
            b = np.bincount(keys, weights=sign, minlength=HW)
        else:
            num = part.t - t0
            num *= B - 1
            lo = num // D                      # <= B - 2 because t < t1, so lo + 1 is a valid bin
            num -= lo * D
            kk = np.empty(2 * m, np.intp)      # [lower-bin keys, upper-bin keys]: one bincount per chunk
            ww = np.empty(2 * m, np.float64)
            np.multiply(lo, HW, out=kk[:m])
            kk[:m] += keys
            np.add(kk[:m], HW, out=kk[m:])
            np.divide(num, D, out=ww[m:])      # frac: exactly 0 at a bin centre
            ww[m:] *= sign
            np.subtract(sign, ww[m:], out=ww[:m])
            b = np.bincount(kk, weights=ww, minlength=B * HW)
        if grid is None:
            grid = b
        else:
            grid += b
    return grid.astype(np.float32).reshape(B, H, W)
