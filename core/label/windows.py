"""Event windows: the tilings of a recording into half-open ``[t0_us, t1_us)`` windows, and label times.

Every event belongs to exactly one window of a tiling, by time (:func:`time_windows`) or by event count
(:func:`count_windows`). A window's label time is its centre (default), its end (E-POSE) or its start.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evpose.core.errors import InputError

#: The default event window, µs: E-POSE's label window (10 ms), used wherever a window length is not given.
DEFAULT_WINDOW_US = 10_000

LABEL_AT = ("center", "end", "start")
#: Shortest window the command line accepts (``--window-ms``), ms: poses are sampled every few ms, so
#: shorter windows add no label information, while the work and the files grow with the window count
#: (0.1 ms is 10 000 windows per second of recording, 100x the default; 1 µs windows made a 0.8 s scene
#: export run for hours).
MIN_WINDOW_MS = 0.1
#: Most windows one tiling may hold (a Python list of windows; ~17 µs and ~200 bytes each to build):
#: 28 hours of 10 ms windows.
MAX_WINDOWS = 10_000_000


class WindowError(InputError):
    """A window tiling that cannot be built (non-positive length, too many windows)."""


@dataclass(frozen=True)
class Window:
    """An event window ``[t0_us, t1_us)`` on the event clock, with its label time."""

    index: int
    t0_us: int
    t1_us: int
    t_label_us: int
    i0: int = -1  # event index range [i0, i1) when known
    i1: int = -1

    @property
    def n_events(self) -> int:
        return max(self.i1 - self.i0, 0)


def label_time(t0_us: int, t1_us: int, label_at: str = "center") -> int:
    """Label time of ``[t0, t1)``: its centre (default), its end (E-POSE) or its start."""
    if label_at == "center":
        return int(t0_us + (t1_us - t0_us) // 2)
    if label_at == "end":
        return int(t1_us)
    if label_at == "start":
        return int(t0_us)
    raise ValueError(f"label_at must be one of {LABEL_AT}, got {label_at!r}")


def time_windows(store, window_us: int, *, label_at: str = "center", t_start_us=None, t_end_us=None) -> list[Window]:
    """Tile the recording with consecutive half-open windows of ``window_us``.

    The first window starts at the first event (or ``t_start_us``); the last one ends after the
    last event, so every event belongs to exactly one window.
    """
    if window_us <= 0:
        raise WindowError(f"window length must be positive, got {window_us} us")
    if store.t_first_us is None:
        return []
    t_a = store.t_first_us if t_start_us is None else int(t_start_us)
    t_b = store.t_last_us + 1 if t_end_us is None else int(t_end_us)
    if t_b <= t_a:
        return []
    n = -(-(t_b - t_a) // int(window_us))
    if n > MAX_WINDOWS:
        raise WindowError(f"{getattr(store, 'path', 'events')}: window length {window_us} us makes {n:,} windows "
                          f"over {(t_b - t_a) / 1e6:g} s, more than {MAX_WINDOWS:,}; use longer windows")
    edges = np.arange(t_a, t_b, int(window_us), dtype=np.int64)
    edges = np.append(edges, edges[-1] + int(window_us))
    idx = store.indices_of(edges)
    return [Window(k, int(edges[k]), int(edges[k + 1]), label_time(edges[k], edges[k + 1], label_at),
                   int(idx[k]), int(idx[k + 1])) for k in range(len(edges) - 1)]


def count_windows(store, n_events: int, *, label_at: str = "center") -> list[Window]:
    """Consecutive windows of ``n_events`` events each (the last may be shorter).

    Windows are index ranges, so every event belongs to exactly one window; the time span is
    ``[t of first event, t of last event + 1)``.
    """
    if n_events <= 0:
        raise WindowError(f"events per window must be positive, got {n_events}")
    n = store.n_events
    if -(-n // int(n_events)) > MAX_WINDOWS:
        raise WindowError(f"{getattr(store, 'path', 'events')}: {n_events} events per window make "
                          f"{-(-n // int(n_events)):,} windows, more than {MAX_WINDOWS:,}; use longer windows")
    out = []
    starts = np.arange(0, n, int(n_events), dtype=np.int64)
    if len(starts) == 0:
        return out
    ends = np.minimum(starts + n_events, n)
    firsts = [int(store.read(i, i + 1).t[0]) for i in starts]
    lasts = [int(store.read(i - 1, i).t[0]) for i in ends]
    for k, (i0, i1, a, b) in enumerate(zip(starts, ends, firsts, lasts)):
        out.append(Window(k, int(a), int(b) + 1, label_time(int(a), int(b) + 1, label_at), int(i0), int(i1)))
    return out
