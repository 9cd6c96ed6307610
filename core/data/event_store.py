"""Lazy, read-only access to an event HDF5 file (layout in :mod:`evpose.core.data.events`) through its
millisecond index (:mod:`evpose.core.data.event_index`), validated on first open
(:mod:`evpose.core.data.event_validation`).

All times handed out are int64 microseconds of the absolute event clock (``t_offset`` added). Windows are
half-open ``[t0, t1)``, so consecutive windows tile the recording exactly.

Concurrency: an :class:`EventStore` may be used from several threads (h5py serialises every call with
its global lock), but it must not be shared across processes: open one store per process (after fork).
"""
from __future__ import annotations

import operator
import os
import warnings
from pathlib import Path

import h5py
import hdf5plugin  # noqa: F401  (registers the Blosc filter so that readers can decompress)
import numpy as np

from evpose.core.data.event_index import WRAP
from evpose.core.data.event_validation import check_sensor, index_and_validate, open_columns
from evpose.core.data.events import EventArray, EventFileError

__all__ = ["EventStore"]

_BISECT_MAX = 2**16             # narrow a search range by single-element reads until it is this small
_WINDOW_T_READ_MAX = 2**22      # window(): read the times of both boundary bins at once up to this many events
# HDF5 chunk cache per dataset (default 1 MiB): 32+ chunks, about 1 s of events at 1 M ev/s, so scrubbing back and
# forth hits it; 4 x 4 MiB bounds a store's memory whatever the file size (16 MiB let a 5 M-event file fit, the
# bench then showed RSS growing with the file).
_RDCC_NBYTES = 4 * 2**20


class EventStore:
    """Lazy, read-only access to an event HDF5 file through a millisecond index.

    Parameters
    ----------
    path : str or Path
        The event file; opened read-only and never modified. It must be a regular file (a FIFO or a
        device is refused before HDF5 opens it).
    cache_dir : str or Path, optional
        Where the index and the validation result are cached (default
        :func:`evpose.core.data.event_index.default_cache_dir`, ``$XDG_CACHE_HOME/evpose/msidx``); one ``<sha1 of the resolved path>.npz`` per file, valid while
        the file's size, mtime and inode are unchanged. Nothing is ever written beside the file.
    sensor_size : (int, int), optional
        ``(width, height)`` in pixels: events with ``x >= width`` or ``y >= height`` are refused.
    progress, cancel : callable, optional
        ``progress(n_scanned, n_total)`` and ``cancel() -> bool`` for the first-open pass.

    Attributes
    ----------
    n_events : int
    t_first_us, t_last_us : int or None
        Absolute time of the first / last event, µs (None for a file without events).
    t_offset_us : int
        Added to the stored times, µs.
    ms_to_idx : np.ndarray of int64
        ``ms_to_idx[k]`` is the first index with ``t >= ms_index_t0_us + 1000 * k``; the last entry is the bin
        of the last event. From the file when present and consistent, else built and cached.
    ms_index_t0_us : int
        Absolute start of bin 0, µs: ``t_offset_us`` for a file index, the ms holding the first event for a built one.
    wraps : np.ndarray of int64
        Indices where a uint32 time wrapped (2**32 µs are added from each on); usually empty.

    Validation
    ----------
    The first open of a file checks its layout and makes one chunked pass over all its columns, cached
    with the index (:mod:`evpose.core.data.event_validation`): unsorted times, negative or off-sensor
    pixels and bad polarities are **refused** with :class:`EventFileError` naming the file, the field,
    the first bad index and its value; nothing is silently dropped.

    Notes
    -----
    Threads may share a store (h5py serialises reads with its global lock). Processes must not: open one
    store per process, after any fork. Signed polarity datasets (-1/+1) are read as 0/1.
    """

    def __init__(self, path, *, cache_dir=None, sensor_size=None, progress=None, cancel=None):
        from evpose.core.data.input_files import InputFileError, check_regular

        self.path = Path(path)
        self._cache_dir = Path(cache_dir) if cache_dir is not None else None
        self.sensor_size = None if sensor_size is None else (int(sensor_size[0]), int(sensor_size[1]))
        if not os.path.lexists(self.path):
            raise FileNotFoundError(f"{self.path}: no such file")
        try:
            check_regular(self.path)
        except InputFileError as exc:
            raise EventFileError(self.path, "(file)", exc.reason) from None
        try:
            self._h5 = h5py.File(self.path, "r", rdcc_nbytes=_RDCC_NBYTES, rdcc_nslots=10007, locking="best-effort")
        except FileNotFoundError:
            raise
        except OSError as e:
            if not self.path.exists():
                raise FileNotFoundError(f"{self.path}: no such file") from e
            raise EventFileError(self.path, "(file)", f"cannot open as HDF5: {e}") from e
        try:
            self._open(progress, cancel)
        except BaseException:
            self.close()
            raise

    # ----------------------------------------------------------------------------------------- opening
    def _open(self, progress, cancel):
        cols = open_columns(self.path, self._h5)
        self.n_events = n = cols.n_events
        self._x, self._y, self._t, self._p = cols.x, cols.y, cols.t, cols.p
        self.t_offset_us = cols.t_offset_us
        self.wraps = np.empty(0, np.int64)
        self.ms_to_idx, self._base_rel = np.empty(0, np.int64), 0
        self.t_first_us = self.t_last_us = None
        if n == 0:
            self.ms_index_t0_us = self.t_offset_us
            return
        first_s, last_s = int(self._t[0]), int(self._t[n - 1])
        found = index_and_validate(self.path, self._h5, cols, first_s, last_s, cache_dir=self._cache_dir,
                                   progress=progress, cancel=cancel, stacklevel=4)    # warn at EventStore(...)
        self.ms_to_idx, self.wraps, self._base_rel = found.ms_to_idx, found.wraps, found.base_rel
        check_sensor(self.path, cols, found.stats, self.sensor_size)
        self.ms_index_t0_us = self.t_offset_us + self._base_rel
        self._first_rel = first_s
        self._last_rel = last_s + WRAP * len(self.wraps)
        self.t_first_us, self.t_last_us = self.t_offset_us + self._first_rel, self.t_offset_us + self._last_rel
        if len(self.wraps):
            warnings.warn(f"{self.path}: events/t: uint32 time wraps around 2**32 µs at {len(self.wraps)} "
                          f"index(es) (first {int(self.wraps[0])}); unwrapped on read", stacklevel=3)

    # ----------------------------------------------------------------------------------------- reading
    def __len__(self) -> int:
        return self.n_events

    def __repr__(self) -> str:
        return f"EventStore({str(self.path)!r}, n={self.n_events}, t=[{self.t_first_us}, {self.t_last_us}] µs)"

    def _check_open(self):
        if self._h5 is None:
            raise ValueError(f"{self.path}: EventStore is closed")

    def _read_t_rel(self, i0: int, i1: int) -> np.ndarray:
        """Unwrapped times relative to t_offset of events [i0, i1), int64 µs."""
        self._check_open()
        t = self._t[i0:i1].astype(np.int64, copy=False)
        if len(self.wraps):
            before = int(np.searchsorted(self.wraps, i0, side="right"))
            t += WRAP * before
            for w in self.wraps[before:]:
                if w >= i1:
                    break
                t[w - i0:] += WRAP
        return t

    def _bounds(self, t_rel: int) -> tuple[int, int]:
        """Index range [lo, hi) that holds the first event with t >= t_rel (Python ints, no overflow)."""
        if t_rel <= self._first_rel:
            return 0, 0
        if t_rel > self._last_rel:
            return self.n_events, self.n_events
        idx, k = self.ms_to_idx, (t_rel - self._base_rel) // 1000
        if k >= len(idx):
            return int(idx[-1]), self.n_events
        lo = int(idx[k])
        if t_rel == self._base_rel + 1000 * k:
            return lo, lo
        return lo, int(idx[k + 1]) if k + 1 < len(idx) else self.n_events

    def _find(self, t_rel: int, lo: int, hi: int) -> int:
        while hi - lo > _BISECT_MAX:
            mid = (lo + hi) // 2
            if self._read_t_rel(mid, mid + 1)[0] < t_rel:
                lo = mid + 1
            else:
                hi = mid
        return lo + int(np.searchsorted(self._read_t_rel(lo, hi), t_rel, side="left")) if hi > lo else lo

    def index_of(self, t_us) -> int:
        """Index of the first event with ``t >= t_us`` (µs, absolute); ``n_events`` if there is none."""
        if self.n_events == 0:
            return 0
        t_rel = operator.index(t_us) - self.t_offset_us
        return self._find(t_rel, *self._bounds(t_rel))

    def indices_of(self, t_us) -> np.ndarray:
        """Vectorised :meth:`index_of` for an integer array of times (µs); returns int64 indices."""
        t_us = np.asarray(t_us)
        if t_us.dtype.kind not in "iu":
            raise TypeError(f"indices_of: times must be integer µs, got dtype {t_us.dtype}")
        return np.array([self.index_of(int(v)) for v in t_us.reshape(-1)], np.int64).reshape(t_us.shape)

    def index_range(self, t0_us, t1_us) -> tuple[int, int]:
        """Index range of the half-open window ``[t0_us, t1_us)``; ``(i, i)`` when ``t1_us <= t0_us``."""
        i0 = self.index_of(t0_us)
        return (i0, i0) if operator.index(t1_us) <= operator.index(t0_us) else (i0, self.index_of(t1_us))

    def _events(self, i0: int, i1: int, t_rel: np.ndarray) -> EventArray:
        if i1 <= i0:
            return EventArray.empty()
        p = self._p[i0:i1]
        if p.dtype.kind == "i":             # signed polarity (-1/+1 or 0/1) -> 0/1
            p = (p > 0).view(np.uint8)
        return EventArray(self._x[i0:i1], self._y[i0:i1], t_rel + self.t_offset_us, p)

    def read(self, i0, i1) -> EventArray:
        """Events with index in ``[i0, i1)``, clipped to ``[0, n_events)``."""
        i0 = min(max(operator.index(i0), 0), self.n_events)
        i1 = min(max(operator.index(i1), i0), self.n_events)
        return self._events(i0, i1, self._read_t_rel(i0, i1) if i1 > i0 else None)

    def window(self, t0_us, t1_us) -> EventArray:
        """Events with ``t0_us <= t < t1_us`` (µs, absolute). Reversed, zero-length or outside: empty."""
        a = operator.index(t0_us) - self.t_offset_us
        b = operator.index(t1_us) - self.t_offset_us
        if b <= a or self.n_events == 0:
            return EventArray.empty()
        (lo0, hi0), (lo1, hi1) = self._bounds(a), self._bounds(b)
        if hi1 - lo0 > _WINDOW_T_READ_MAX:   # huge window or a pathologically dense ms: search separately
            return self.read(self._find(a, lo0, hi0), self._find(b, lo1, hi1))
        t = self._read_t_rel(lo0, hi1) if hi1 > lo0 else np.empty(0, np.int64)
        i0 = lo0 + int(np.searchsorted(t[:hi0 - lo0], a, side="left"))
        i1 = lo1 + int(np.searchsorted(t[lo1 - lo0:], b, side="left"))
        return self._events(i0, i1, t[i0 - lo0:i1 - lo0])

    def window_by_count(self, t_us, n, align="end") -> EventArray:
        """``n`` events next to ``t_us`` (µs), fewer at the ends of the file.

        ``align="end"``: the n events with ``t < t_us``; ``"start"``: the n events with ``t >= t_us``;
        ``"center"``: ``n // 2`` events before ``t_us`` and the rest from ``t_us`` on.
        """
        n = operator.index(n)
        if n < 0:
            raise ValueError(f"window_by_count: n must be >= 0, got {n}")
        i = self.index_of(t_us)
        starts = {"end": i - n, "start": i, "center": i - n // 2}
        if align not in starts:
            raise ValueError(f"window_by_count: align must be 'end', 'start' or 'center', got {align!r}")
        return self.read(max(starts[align], 0), max(starts[align] + n, 0))

    def rate(self, bin_us=1000) -> tuple[np.ndarray, np.ndarray]:
        """Event counts per bin over the whole recording, from the ms index alone (no event is read).

        Parameters
        ----------
        bin_us : int
            Bin width, µs; a positive multiple of 1000. Bins start at ``t_offset_us + j * bin_us``, from the bin
            holding the first event to the bin holding the last one.

        Returns
        -------
        starts : np.ndarray of int64
            Absolute bin start times, µs.
        counts : np.ndarray of int64
        """
        if not isinstance(bin_us, (int, np.integer)) or bin_us <= 0 or bin_us % 1000:
            raise ValueError(f"rate: bin_us must be a positive multiple of 1000 µs, got {bin_us!r}")
        if self.n_events == 0:
            return np.empty(0, np.int64), np.empty(0, np.int64)
        m, base_k = int(bin_us) // 1000, self._base_rel // 1000          # ms numbers count from t_offset
        j0, j1 = (self._first_rel // 1000) // m, (self._last_rel // 1000) // m
        ks = m * np.arange(j0, j1 + 1, dtype=np.int64)                  # first ms of each bin
        first_idx = np.where(ks < base_k, 0, self.ms_to_idx[np.maximum(ks - base_k, 0)])
        counts = np.diff(np.append(first_idx, self.n_events))
        return self.t_offset_us + 1000 * ks, counts

    def iter_chunks(self, chunk_events=1_000_000, t0_us=None, t1_us=None):
        """Yield the events of ``[t0_us, t1_us)`` (default: all) as EventArrays of at most ``chunk_events``."""
        if chunk_events <= 0:
            raise ValueError(f"iter_chunks: chunk_events must be positive, got {chunk_events}")
        i0 = 0 if t0_us is None else self.index_of(t0_us)
        i1 = self.n_events if t1_us is None else max(i0, self.index_of(t1_us))
        for j in range(i0, i1, chunk_events):
            yield self.read(j, min(j + chunk_events, i1))

    def close(self) -> None:
        if getattr(self, "_h5", None) is not None:
            self._h5.close()
            self._h5 = None

    def __enter__(self) -> "EventStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
