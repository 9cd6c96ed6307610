"""Per-pixel event counts of a window: ON/OFF counts and the spike (any event) image."""
from __future__ import annotations

import numpy as np

from evpose.core.data.events import EventArray
from evpose.core.label.event_frames.accumulate import check_events, check_size, event_chunks


def polarity_counts(ev: EventArray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Number of ON and OFF events per pixel.

    Parameters
    ----------
    ev : EventArray
        The window's events (any order).
    width, height : int
        Sensor size, pixels.

    Returns
    -------
    pos, neg : (H, W) int64
        ON (p=1) and OFF (p=0) counts, indexed ``[v, u]``. int64 is exact for any window that fits in
        memory (no overflow at 10^7 or 10^9 events on one pixel). The two arrays are non-overlapping views
        of one buffer.

    Raises
    ------
    ValueError
        If an event lies outside the sensor (``x``/``y``) or has ``p > 1``.
    """
    W, H = check_size(width, height)
    check_events(ev, W, H)
    c = _counts(ev, W, H).reshape(2, H, W)
    return c[1], c[0]


def _counts(ev: EventArray, W: int, H: int) -> np.ndarray:
    """Flat (2*H*W,) int64 counts, OFF then ON."""
    c = None
    for _, k in event_chunks(ev, W, H, polarity=True):
        b = np.bincount(k, minlength=2 * H * W)
        c = b if c is None else c.__iadd__(b)
    return np.zeros(2 * H * W, np.int64) if c is None else c


def spike(ev: EventArray, width: int, height: int) -> np.ndarray:
    """``(H, W) bool``: True where the window has at least one event (any polarity)."""
    W, H = check_size(width, height)
    check_events(ev, W, H)
    out = np.zeros(H * W, bool)
    for _, k in event_chunks(ev, W, H, polarity=False):
        out[k] = True
    return out.reshape(H, W)
