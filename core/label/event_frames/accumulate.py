"""Input checks shared by every event frame, and the chunked pixel keys they accumulate over."""
from __future__ import annotations

import numpy as np

from evpose.core.data.events import EventArray

CHUNK_EVENTS = 2**17          # events per accumulation step (see event_chunks)


def check_size(width, height) -> tuple[int, int]:
    """``(width, height)`` as ints; ValueError unless both are positive integers (pixels)."""
    if int(width) != width or int(height) != height or width <= 0 or height <= 0:
        raise ValueError(f"width/height: must be positive integers, got {width}x{height}")
    return int(width), int(height)


def check_events(ev: EventArray, width: int, height: int) -> None:
    """Raise ValueError naming the field if a coordinate or polarity is out of range."""
    if len(ev) == 0:
        return
    xmax, ymax, pmax = int(ev.x.max()), int(ev.y.max()), int(ev.p.max())
    if xmax >= width:
        raise ValueError(f"x: event column {xmax} outside the sensor (width {width}, valid 0..{width - 1})")
    if ymax >= height:
        raise ValueError(f"y: event row {ymax} outside the sensor (height {height}, valid 0..{height - 1})")
    if pmax > 1:
        raise ValueError(f"p: polarity {pmax} is not 0 or 1")


def check_window(ev: EventArray, t0_us, t1_us) -> tuple[int, int]:
    """Validate a half-open window ``[t0, t1)`` and that every event lies inside it."""
    t0, t1 = int(t0_us), int(t1_us)
    if t0 != t0_us or t1 != t1_us:
        raise ValueError(f"t0_us/t1_us: must be integer µs, got {t0_us!r}, {t1_us!r}")
    if t1 < t0:
        raise ValueError(f"t1_us: reversed window [{t0}, {t1}) µs")
    if len(ev):
        tmin, tmax = int(ev.t.min()), int(ev.t.max())
        if tmin < t0 or tmax >= t1:
            raise ValueError(f"t: events span [{tmin}, {tmax}] µs, outside the half-open window [{t0}, {t1}) µs")
    return t0, t1


def pixel_keys(ev: EventArray, width: int, height: int, polarity: bool, out: np.ndarray | None = None) -> np.ndarray:
    """Flat intp key per event: ``y*W + x``, plus ``p*H*W`` when ``polarity`` (so a (2, H, W) layout
    holds OFF in [0] and ON in [1]). Built in place in one buffer (``out`` if given)."""
    k = np.empty(len(ev), np.intp) if out is None else out
    if polarity:
        np.multiply(ev.p, height, out=k, dtype=np.intp)
        k += ev.y
    else:
        k[...] = ev.y
    k *= width
    k += ev.x
    return k


def event_chunks(ev: EventArray, width: int, height: int, polarity: bool):
    """Yield ``(events, keys)`` for consecutive pieces of at most ``CHUNK_EVENTS`` events.

    Bounds the temporaries of a huge window (10^7 events would otherwise allocate several 80 MB arrays per
    call; the voxel grid about ten). Measured on DAVIS346 frames, 2 cores: 2**17 events per step against one
    pass is 1.5x faster at 10^7 events for the counts and 2x for the voxel grid, and costs nothing up to
    2**17 events. ``keys`` is a reused buffer: consume it before the next iteration."""
    n = len(ev)
    buf = np.empty(min(n, CHUNK_EVENTS), np.intp)
    for i in range(0, n, CHUNK_EVENTS):
        part = ev if n <= CHUNK_EVENTS else ev[i:i + CHUNK_EVENTS]
        yield part, pixel_keys(part, width, height, polarity, out=buf[:len(part)])
