"""The exponentially decaying time surface of the latest event per pixel."""
from __future__ import annotations

import numpy as np

from evpose.core.data.events import EventArray
from evpose.core.label.event_frames.accumulate import check_events, check_size, event_chunks

_I64_MAX = np.iinfo(np.int64).max


def time_surface(ev: EventArray, width: int, height: int, t_ref_us: int, tau_us: float = 30_000,
                 polarity: str = "split") -> np.ndarray:
    """Exponentially decaying time surface of the most recent event per pixel.

    Parameters
    ----------
    ev : EventArray
        Events (any order). Events with ``t > t_ref_us`` are ignored; an event at ``t_ref_us`` gives 1.
    width, height : int
        Sensor size, pixels.
    t_ref_us : int
        Reference time, µs (typically the window end).
    tau_us : float
        Decay constant, µs (> 0).
    polarity : {"split", "merged"}
        ``"split"``: one surface per polarity, ``[0]`` ON, ``[1]`` OFF; ``"merged"``: one surface.

    Returns
    -------
    float32, (2, H, W) for "split" or (H, W) for "merged"
        ``exp(-(t_ref_us - t_last) / tau_us)`` of the latest event ``t_last <= t_ref_us`` at the pixel
        (and polarity); 0 where there is none.
    """
    W, H = check_size(width, height)
    if polarity not in ("split", "merged"):
        raise ValueError(f"polarity: expected 'split' or 'merged', got {polarity!r}")
    if not tau_us > 0:
        raise ValueError(f"tau_us: must be > 0, got {tau_us}")
    t_ref = int(t_ref_us)
    check_events(ev, W, H)
    if len(ev) and int(ev.t.max()) > t_ref:
        ev = ev[ev.t <= t_ref]
    HW = H * W
    n = 2 * HW if polarity == "split" else HW
    age = np.full(n, _I64_MAX, np.int64)
    for part, k in event_chunks(ev, W, H, polarity=polarity == "split"):
        np.minimum.at(age, k, t_ref - part.t)
    has = age != _I64_MAX
    ts = np.zeros(n, np.float32)
    ts[has] = np.exp(-age[has] / float(tau_us))
    if polarity == "merged":
        return ts.reshape(H, W)
    ts = ts.reshape(2, H, W)
    return np.ascontiguousarray(ts[::-1])   # keys put OFF in [0]; return ON first
