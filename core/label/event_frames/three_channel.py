"""The E-POSE 3-channel event image of one window (ON count, OFF count, latest time)."""
from __future__ import annotations

import numpy as np

from evpose.core.data.events import EventArray
from evpose.core.label.event_frames.accumulate import check_events, check_size, check_window, event_chunks


def three_channel(ev: EventArray, width: int, height: int, t0_us: int, t1_us: int,
                  *, time_norm: str = "max") -> np.ndarray:
    """The E-POSE 3-channel event image of one window, computed from this window's events only.

    Parameters
    ----------
    ev : EventArray
        Events with ``t0_us <= t < t1_us`` (any order).
    width, height : int
        Sensor size, pixels.
    t0_us, t1_us : int
        Half-open window, µs.
    time_norm : {"max", "window"}
        How channel 2 is scaled: ``"max"`` (default) divides by its maximum over the image, so the window's
        latest event is 1 like the count channels; ``"window"`` divides by ``t1_us - t0_us``, a fixed scale
        on which an event at ``t1_us - 1`` is 1 (comparable across windows of equal length).

    Returns
    -------
    (H, W, 3) float32
        Channel 0: ON count / max ON count. Channel 1: OFF count / max OFF count. Channel 2: the latest
        event time at the pixel (either polarity) as ``t_last - t0_us + 1`` µs, scaled per ``time_norm``.
        The ``+ 1`` makes a pixel whose only event is at ``t0_us`` strictly positive, distinguishable from
        a pixel without events (exactly 0). Each channel is in [0, 1]; an empty window gives all zeros
        (no NaN, no warning).

    Raises
    ------
    ValueError
        Reversed window, events outside ``[t0_us, t1_us)`` (``t``), outside the sensor (``x``/``y``),
        or an invalid ``time_norm``.
    """
    W, H = check_size(width, height)
    if time_norm not in ("max", "window"):
        raise ValueError(f"time_norm: expected 'max' or 'window', got {time_norm!r}")
    t0, t1 = check_window(ev, t0_us, t1_us)
    check_events(ev, W, H)
    HW = H * W
    out = np.zeros((H, W, 3), np.float32)
    if len(ev) == 0:
        return out
    c = None
    last2 = np.zeros(2 * HW, np.int64)           # t_last - t0 + 1 per (polarity, pixel); 0 = no event
    for part, k in event_chunks(ev, W, H, polarity=True):
        b = np.bincount(k, minlength=2 * HW)
        c = b if c is None else c.__iadd__(b)
        np.maximum.at(last2, k, part.t - (t0 - 1))
    c = c.reshape(2, H, W)
    last = np.maximum(last2[:HW], last2[HW:]).reshape(H, W)
    for ch, a in ((0, c[1]), (1, c[0])):
        m = a.max()
        if m > 0:
            out[..., ch] = a / float(m)
    scale = float(last.max()) if time_norm == "max" else float(t1 - t0)
    out[..., 2] = last / scale
    return out
