"""Event storage: a lazy, indexed HDF5 reader and a streaming, atomic writer.

File layout (DSEC style, DESIGN section 4)::

    events/x  uint16   pixel column
    events/y  uint16   pixel row
    events/t  int64 or uint32, µs, relative to ``t_offset`` (0 when absent)
    events/p  uint8    polarity 0/1
    t_offset  int64 scalar, µs (optional)
    ms_to_idx int64/uint64 (optional): ms_to_idx[k] = first index with t >= k * 1000 µs (t relative to t_offset)

All times handed out are int64 microseconds of the absolute event clock (``t_offset`` added).
Windows are half-open ``[t0, t1)``, so consecutive windows tile the recording exactly.

Concurrency: an :class:`EventStore` may be used from several threads (h5py serialises every call with
its global lock), but it must not be shared across processes: open one store per process (after fork).
"""
from __future__ import annotations

import contextlib
import hashlib
import operator
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import h5py
import hdf5plugin  # noqa: F401  (registers the Blosc filter so that readers can decompress)
import numpy as np

from evpose.core.data.fileio import (
    ensure_free_space,
    fsync_dir,
    fsync_path,
    os_error_from_hdf5,
    temp_path_for,
    with_path,
)
from evpose.core.errors import InputError

__all__ = ["EventFileError", "Cancelled", "EventArray", "EventStore", "EventWriter", "write_events_h5"]

# Events per HDF5 chunk, chosen by measurement (bursty synthetic 640x480 data, uint32 t, Blosc-LZ4, 2 cores;
# 1000 random 10 ms windows from a fresh store, mean / p95 ms per window, file size):
#   50 M events at 1 M ev/s:  2**14: 0.25/0.50 ms 230 MB;  2**15: 0.30/0.62 ms 228 MB;  2**16: 0.43/0.88 ms 227 MB;
#                             2**17: 0.59/1.16 ms 212 MB;  2**18: 0.85/1.39 ms 212 MB
#   30 M events at 5 M ev/s:  2**14: 0.50/1.30 ms;  2**15: 0.51/1.29 ms;  2**16: 0.58/1.36 ms
# Window time grows with the chunk (a random window decompresses whole chunks) and compression gains little:
# 2**15 is within noise of the fastest at 5 M ev/s and close at 1 M ev/s.
DEFAULT_CHUNK_EVENTS = 2**15
_SCAN_CHUNK_EVENTS = 2**21      # events per step of the index-building pass (~16 MB of int64 times)
_BISECT_MAX = 2**16             # narrow a search range by single-element reads until it is this small
_WINDOW_T_READ_MAX = 2**22      # window(): read the times of both boundary bins at once up to this many events
_FLUSH_EVENTS = 2**20           # EventWriter buffers about this many events between HDF5 writes
#: EventWriter's free-space check: stored bytes per event before compression (x, y: 2 each, t: 8, p: 1, an upper
#: bound of the compressed size) and a margin for HDF5's metadata and for closing the file.
_BYTES_PER_EVENT = 13
_WRITER_MARGIN_BYTES = 1 << 20
# HDF5 chunk cache per dataset (default 1 MiB): 32+ chunks, about 1 s of events at 1 M ev/s, so scrubbing back and
# forth hits it; 4 x 4 MiB bounds a store's memory whatever the file size (16 MiB let a 5 M-event file fit, the
# bench then showed RSS growing with the file).
_RDCC_NBYTES = 4 * 2**20
_CACHE_VERSION = 2              # 2: the cache holds the validation result (pixel ranges) and lives in the cache dir
_WRAP = 2**32


class EventFileError(InputError):
    """A malformed event file; the message names the file and the HDF5 field at fault."""

    def __init__(self, path, field: str, message: str):
        self.path, self.field = str(path), field
        super().__init__(f"{path}: {field}: {message}")


class Cancelled(Exception):
    """Raised when a ``cancel()`` callback returned True; the operation left nothing behind."""


def _as_int_array(a, dtype, name, lo, hi, kinds="iu"):
    a = np.asarray(a)
    if a.dtype == dtype:
        return a
    if a.size == 0:
        return a.astype(dtype)
    if a.dtype.kind not in kinds:
        raise TypeError(f"{name}: expected integers, got dtype {a.dtype}")
    if a.dtype.kind != "b" and (int(a.min()) < lo or int(a.max()) > hi):
        raise ValueError(f"{name}: values outside [{lo}, {hi}]")
    return a.astype(dtype)


@dataclass(frozen=True, eq=False)
class EventArray:
    """A time-sorted batch of events (sortedness is the producer's duty; :class:`EventWriter` checks it).

    Attributes
    ----------
    x, y : np.ndarray of uint16
        Pixel column and row.
    t : np.ndarray of int64
        Absolute event-clock time, µs.
    p : np.ndarray of uint8
        Polarity, 0 or 1.
    """

    x: np.ndarray
    y: np.ndarray
    t: np.ndarray
    p: np.ndarray

    def __post_init__(self):
        cast = {"x": _as_int_array(self.x, np.uint16, "x", 0, 65535),
                "y": _as_int_array(self.y, np.uint16, "y", 0, 65535),
                "t": _as_int_array(self.t, np.int64, "t", -(2**63), 2**63 - 1),
                "p": _as_int_array(self.p, np.uint8, "p", 0, 1, kinds="iub")}
        n = len(cast["t"]) if cast["t"].ndim == 1 else -1
        for name, a in cast.items():
            if a.ndim != 1 or len(a) != n:
                raise ValueError(f"EventArray: {name} has shape {a.shape}, expected ({max(n, 0)},) like t")
            object.__setattr__(self, name, a)

    def __len__(self) -> int:
        return len(self.t)

    def __getitem__(self, sl) -> "EventArray":
        if isinstance(sl, (int, np.integer)):
            raise TypeError("EventArray: index with a slice or an index/boolean array, not a scalar")
        return EventArray(self.x[sl], self.y[sl], self.t[sl], self.p[sl])

    def __repr__(self) -> str:
        span = f", t=[{self.t[0]}, {self.t[-1]}] µs" if len(self) else ""
        return f"EventArray(n={len(self)}{span})"

    @staticmethod
    def empty() -> "EventArray":
        return EventArray(np.empty(0, np.uint16), np.empty(0, np.uint16), np.empty(0, np.int64), np.empty(0, np.uint8))

    @staticmethod
    def concatenate(parts) -> "EventArray":
        parts = list(parts)
        if not parts:
            return EventArray.empty()
        return EventArray(*(np.concatenate([getattr(e, f) for e in parts]) for f in "xytp"))


class _MsIndexBuilder:
    """Incremental ms index over sorted relative times fed in consecutive pieces.

    ``finish()[k]`` is the first global index with ``t_rel >= base_rel + 1000 * k``; the index ends with the
    bin that holds the last event. Counts are int64 throughout (10**7 events per ms do not overflow).
    """

    def __init__(self, base_rel: int, parts=None, next_k: int = 0):
        self.base, self.parts, self.next_k = base_rel, list(parts or []), next_k

    def add(self, t_rel: np.ndarray, i0: int) -> None:
        if len(t_rel) == 0:
            return
        k_max = (int(t_rel[-1]) - self.base) // 1000
        if k_max >= self.next_k:
            thresholds = self.base + 1000 * np.arange(self.next_k, k_max + 1, dtype=np.int64)
            self.parts.append(i0 + np.searchsorted(t_rel, thresholds, side="left").astype(np.int64))
            self.next_k = k_max + 1

    def finish(self) -> np.ndarray:
        return np.concatenate(self.parts).astype(np.int64) if self.parts else np.empty(0, np.int64)


def _scan_index(path, dset, base_rel: int, *, builder=None, start: int = 0, progress=None, cancel=None):
    """One chunked pass over ``events/t[start:]``: check order, unwrap uint32 time, build the ms index.

    Returns
    -------
    ms_to_idx : np.ndarray of int64
    wraps : np.ndarray of int64
        Indices where the stored uint32 time wrapped around 2**32 (each adds 2**32 µs from there on).
    """
    n = dset.shape[0]
    can_wrap = dset.dtype == np.uint32
    builder = builder or _MsIndexBuilder(base_rel)
    chunk = dset.chunks[0] if dset.chunks else 1
    step = max(1, _SCAN_CHUNK_EVENTS // chunk) * chunk
    wraps, prev, wrap_add = [], None, 0
    for i0 in range(start, n, step):
        raw = dset[i0:i0 + step].astype(np.int64)
        d = np.diff(raw, prepend=raw[:1] if prev is None else prev)
        neg = np.flatnonzero(d < 0)
        if neg.size:
            is_wrap = (d[neg] < -(2**31)) if can_wrap else np.zeros(neg.size, bool)
            if not is_wrap.all():
                j = int(neg[~is_wrap][0])
                before = int(raw[j - 1]) if j else int(prev[0])
                raise EventFileError(path, "events/t", f"not sorted at index {i0 + j} "
                                     f"(stored t={int(raw[j])} < previous {before})")
            inc = np.zeros(len(raw), np.int64)
            inc[neg] = _WRAP
            wraps.extend((i0 + neg).tolist())
            t_rel = raw + wrap_add + np.cumsum(inc)
            wrap_add += _WRAP * neg.size
        else:
            t_rel = raw + wrap_add if wrap_add else raw
        builder.add(t_rel, i0)
        prev = raw[-1:]
        if progress is not None:
            progress(min(i0 + step, n), n)
        if cancel is not None and cancel():
            raise Cancelled(f"{path}: index build cancelled")
    return builder.finish(), np.asarray(wraps, np.int64)


def _first_where(dset, pred, start: int = 0):
    """First index ``i >= start`` (and its value) where ``pred(dset[i])``, by a chunked pass; None if none."""
    n = dset.shape[0]
    chunk = dset.chunks[0] if dset.chunks else 1
    step = max(1, _SCAN_CHUNK_EVENTS // chunk) * chunk
    for i0 in range(start, n, step):
        a = dset[i0:i0 + step]
        hit = np.flatnonzero(pred(a))
        if len(hit):
            return i0 + int(hit[0]), a[hit[0]].item()
    return None


def _scan_values(path, ds: dict, *, progress=None, cancel=None) -> np.ndarray:
    """One chunked pass over ``events/x``, ``events/y`` and ``events/p``: refuse negative pixel
    coordinates and polarities other than 0/1 (-1/0/+1 for a signed type), and measure the pixel range.

    Returns
    -------
    stats : np.ndarray of int64, ``[x_min, x_max, y_min, y_max]`` (all 0 for an empty file).
    """
    n = ds["x"].shape[0]
    if n == 0:
        return np.zeros(4, np.int64)
    chunk = max((d.chunks[0] if d.chunks else 1) for d in ds.values())
    step = max(1, _SCAN_CHUNK_EVENTS // chunk) * chunk
    lo = {"x": None, "y": None}
    hi = {"x": None, "y": None}
    p_signed = ds["p"].dtype.kind == "i"
    for i0 in range(0, n, step):
        for f in "xy":
            a = ds[f][i0:i0 + step]
            a_min, a_max = a.min().item(), a.max().item()
            if a_min < 0:
                j = int(np.flatnonzero(a < 0)[0])
                raise EventFileError(path, f"events/{f}", f"{a[j].item()} at index {i0 + j} is negative "
                                     "(pixel coordinates start at 0)")
            lo[f] = a_min if lo[f] is None else min(lo[f], a_min)
            hi[f] = a_max if hi[f] is None else max(hi[f], a_max)
        if ds["p"].dtype.kind != "b":
            a = ds["p"][i0:i0 + step]
            bad = (a > 1) | (a < (-1 if p_signed else 0))
            if bad.any():
                j = int(np.flatnonzero(bad)[0])
                raise EventFileError(path, "events/p", f"{a[j].item()} at index {i0 + j} is not a polarity "
                                     f"(expected {'-1, 0 or 1' if p_signed else '0 or 1'})")
        if progress is not None:
            progress(min(i0 + step, n), n)
        if cancel is not None and cancel():
            raise Cancelled(f"{path}: validation cancelled")
    return np.array([lo["x"], hi["x"], lo["y"], hi["y"]], np.int64)


def default_cache_dir() -> Path:
    """Where EventStore caches its index and validation result: ``$XDG_CACHE_HOME/evpose/msidx``
    (``~/.cache/evpose/msidx``). Never beside the event file, which may be the user's source."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache", "evpose", "msidx")


def _write_npz_atomic(target: Path, **arrays) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path_for(target)
    try:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


class EventStore:
    """Lazy, read-only access to an event HDF5 file through a millisecond index.

    Parameters
    ----------
    path : str or Path
        The event file; opened read-only and never modified. It must be a regular file (a FIFO or a
        device is refused before HDF5 opens it).
    cache_dir : str or Path, optional
        Where the index and the validation result are cached (default :func:`default_cache_dir`,
        ``$XDG_CACHE_HOME/evpose/msidx``); one ``<sha1 of the resolved path>.npz`` per file, valid while
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
    The first open of a file makes one chunked pass over all its columns (cached with the index, so
    later opens read nothing): ``events/t`` must not decrease (a uint32 wrap excepted), even when the
    file carries a plausible ``ms_to_idx``; ``events/x`` and ``events/y`` must not be negative (signed
    types) and must lie on the sensor (``sensor_size``); ``events/p`` must be 0 or 1 (-1, 0 or +1 for a
    signed type). A file that breaks any of these is **refused** with :class:`EventFileError` naming
    the file, the field, the first bad index and its value: nothing downstream ever sees an event
    outside the sensor, and nothing is silently dropped (``evpose import ... --repair`` rewrites such
    a recording without them, with a count). Cost, measured with ``bench/bench_events.py`` on 50 M
    events (229 MB, Blosc-LZ4, 2 cores): 0.58 s for the first open (t pass 0.32 s, x/y/p pass 0.35 s),
    2.5 ms for every later open; loading the arrays with h5py takes 1.35 s.

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
    def _dataset(self, name, kinds):
        obj = self._h5.get(name)
        if not isinstance(obj, h5py.Dataset):
            raise EventFileError(self.path, name, "missing" if obj is None else "not a dataset")
        if obj.dtype.kind not in kinds:
            raise EventFileError(self.path, name, f"dtype {obj.dtype} is not an integer type")
        return obj

    def _open(self, progress, cancel):
        ds = {f: self._dataset(f"events/{f}", "iub" if f == "p" else "iu") for f in "xytp"}
        for f, d in ds.items():
            if d.ndim != 1:
                raise EventFileError(self.path, f"events/{f}", f"shape {d.shape} is not 1-D")
        self.n_events = n = ds["t"].shape[0]
        for f in "xyp":
            if ds[f].shape[0] != n:
                raise EventFileError(self.path, f"events/{f}", f"length {ds[f].shape[0]} != length {n} of events/t")
        self._x, self._y, self._t, self._p = ds["x"], ds["y"], ds["t"], ds["p"]
        self.t_offset_us = 0
        if "t_offset" in self._h5:
            off = self._dataset("t_offset", "iu")
            if off.size != 1:
                raise EventFileError(self.path, "t_offset", f"shape {off.shape} is not a scalar")
            self.t_offset_us = int(off[()].reshape(-1)[0] if off.shape else off[()])
        self.wraps = np.empty(0, np.int64)
        self.ms_to_idx, self._base_rel = np.empty(0, np.int64), 0
        self.t_first_us = self.t_last_us = None
        if n == 0:
            self.ms_index_t0_us = self.t_offset_us
            return
        first_s, last_s = int(self._t[0]), int(self._t[n - 1])
        stats = self._index_and_validate(first_s, last_s, progress, cancel)
        self._check_sensor(stats)
        self.ms_index_t0_us = self.t_offset_us + self._base_rel
        self._first_rel = first_s
        self._last_rel = last_s + _WRAP * len(self.wraps)
        self.t_first_us, self.t_last_us = self.t_offset_us + self._first_rel, self.t_offset_us + self._last_rel
        if len(self.wraps):
            warnings.warn(f"{self.path}: events/t: uint32 time wraps around 2**32 µs at {len(self.wraps)} "
                          f"index(es) (first {int(self.wraps[0])}); unwrapped on read", stacklevel=3)

    def _file_index_plausible(self, first_s, last_s) -> bool:
        """Whether the file's ``ms_to_idx`` passes cheap consistency checks (then the index is built on its
        bin grid, bin 0 at ``t_offset``). A plausible index proves nothing about the order of the events
        between its entries: the whole time column is checked by the first-open pass either way."""
        if "ms_to_idx" not in self._h5:
            return False
        d = self._dataset("ms_to_idx", "iu")
        idx = np.asarray(d[()], dtype=np.int64).reshape(-1) if d.ndim == 1 else None
        n, problem = self.n_events, None
        if idx is None or len(idx) == 0:
            problem = "not a non-empty 1-D array"
        elif self._t.dtype == np.uint32 and (last_s < first_s or len(idx) > _WRAP // 1000 + 1):
            problem = "the uint32 time wraps around 2**32"
        elif idx[0] != 0 or first_s < 0 or idx[-1] > n or np.any(np.diff(idx) < 0):
            problem = "not a non-decreasing index into events starting at 0"
        else:
            for k in sorted({0, len(idx) // 4, len(idx) // 2, 3 * len(idx) // 4, len(idx) - 1}):
                i = int(idx[k])
                t = self._t[max(i - 1, 0):i + 1].astype(np.int64)
                if (i < n and t[-1] < 1000 * k) or (i > 0 and t[0] >= 1000 * k):
                    problem = f"entry {k} (= {i}) disagrees with events/t"
                    break
        if problem:
            warnings.warn(f"{self.path}: ms_to_idx: {problem}; ignoring it and building an index", stacklevel=5)
            return False
        return True

    def _cache_file(self) -> Path:
        key = hashlib.sha1(str(self.path.resolve()).encode()).hexdigest()
        return (self._cache_dir or default_cache_dir()) / f"{key}.npz"

    def _index_and_validate(self, first_s, last_s, progress, cancel) -> np.ndarray:
        """The ms index and the pixel ranges: from the cache, else from one chunked pass over the file
        (which also refuses unsorted times, negative pixels and bad polarities), then cached."""
        st = os.stat(self.path)
        dtypes = sum(ord(c) << (8 * k) for k, c in enumerate("".join(d.dtype.char for d in (self._x, self._y, self._t, self._p))))
        meta = np.array([_CACHE_VERSION, st.st_size, st.st_mtime_ns, st.st_ino, self.n_events, first_s, last_s,
                         self.t_offset_us, dtypes], np.int64)
        cache = self._cache_file()
        try:
            with np.load(cache, allow_pickle=False) as z:
                if np.array_equal(z["meta"], meta):
                    self.ms_to_idx, self.wraps = z["ms_to_idx"].astype(np.int64), z["wraps"].astype(np.int64)
                    self._base_rel = int(z["base_rel"])
                    return z["stats"].astype(np.int64)
        except Exception:  # missing, unreadable, corrupt or foreign: rebuild
            pass
        n = self.n_events
        both = None if progress is None else (lambda k, _n, off=0: progress(off + k, 2 * n))
        self._base_rel = 0 if self._file_index_plausible(first_s, last_s) else (first_s // 1000) * 1000
        self.ms_to_idx, self.wraps = _scan_index(self.path, self._t, self._base_rel, progress=both, cancel=cancel)
        stats = _scan_values(self.path, {"x": self._x, "y": self._y, "p": self._p}, cancel=cancel,
                             progress=None if progress is None else (lambda k, _n: progress(n + k, 2 * n)))
        try:
            _write_npz_atomic(cache, meta=meta, ms_to_idx=self.ms_to_idx, wraps=self.wraps,
                              base_rel=np.int64(self._base_rel), stats=stats)
        except OSError as exc:
            warnings.warn(f"{self.path}: could not cache the ms index in {cache} ({exc.strerror or exc}); "
                          "the next open scans the file again", stacklevel=4)
        return stats

    def _check_sensor(self, stats: np.ndarray) -> None:
        """Refuse events beyond the sensor (``sensor_size``), naming the first one."""
        if self.sensor_size is None:
            return
        for f, k, limit, dim in (("x", 1, self.sensor_size[0], "width"), ("y", 3, self.sensor_size[1], "height")):
            if int(stats[k]) >= limit:
                hit = _first_where(getattr(self, f"_{f}"), lambda a, lim=limit: a >= lim)
                i, v = hit if hit is not None else (-1, int(stats[k]))
                raise EventFileError(self.path, f"events/{f}", f"{v} at index {i} is outside the "
                                     f"{self.sensor_size[0]}x{self.sensor_size[1]} sensor ({f} must be < {dim} "
                                     f"{limit}); `evpose import ... --repair` drops such events with a count")

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
            t += _WRAP * before
            for w in self.wraps[before:]:
                if w >= i1:
                    break
                t[w - i0:] += _WRAP
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


class EventWriter:
    """Streaming, atomic writer of the event layout, with bounded memory.

    Parameters
    ----------
    path : str or Path
        Destination; it appears only on a successful :meth:`close` (temp file + fsync + rename).
    time_dtype : {"int64", "uint32"}
        Storage type of ``events/t`` (stored = t - t_offset).
    t_offset_us : int, optional
        µs. Default for uint32: the first event's time. For int64: 0 when the first time lies in
        ``[0, 2**32)`` µs (times stored absolute), else the first event's time (keeps ``ms_to_idx`` small).
    chunk_events : int
        Events per HDF5 chunk (see ``DEFAULT_CHUNK_EVENTS`` for the measurement).
    compression : {"blosc-lz4", "gzip", None}
    progress : callable, optional
        ``progress(n_written, expected_events)`` after every flushed block.
    cancel : callable, optional
        ``cancel() -> bool``; True aborts the file and raises :class:`Cancelled`.
    expected_events : int, optional
        Passed through to ``progress``.
    """

    def __init__(self, path, *, time_dtype="int64", t_offset_us=None, chunk_events=DEFAULT_CHUNK_EVENTS,
                 compression="blosc-lz4", progress=None, cancel=None, expected_events=None):
        if operator.index(chunk_events) <= 0:
            raise ValueError(f"EventWriter: chunk_events must be positive, got {chunk_events}")
        if time_dtype not in ("int64", "uint32"):
            raise ValueError(f"EventWriter: time_dtype must be 'int64' or 'uint32', got {time_dtype!r}")
        comp = {"blosc-lz4": dict(hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=hdf5plugin.Blosc.SHUFFLE)),
                "gzip": dict(compression="gzip", compression_opts=4, shuffle=True), None: {}}
        if compression not in comp:
            raise ValueError(f"EventWriter: compression must be 'blosc-lz4', 'gzip' or None, got {compression!r}")
        self.path = Path(path)
        # named with our pid: a cleaner in another process never takes it for a leftover while we live (not
        # flock'ed: HDF5 takes its own flock on the files it opens)
        self._tmp = temp_path_for(self.path)
        self._u32 = time_dtype == "uint32"
        self._offset = None if t_offset_us is None else operator.index(t_offset_us)
        self._progress, self._cancel, self._expected = progress, cancel, expected_events
        self._block = int(chunk_events) * max(1, _FLUSH_EVENTS // int(chunk_events))   # flush whole chunks only
        self._pending, self._n_pending, self._n_written, self._n_appended = [], 0, 0, 0
        self._last_t, self._index, self._closed = None, _MsIndexBuilder(0), False
        self._h5, self._ds = None, []
        try:
            ensure_free_space(self.path, _WRITER_MARGIN_BYTES, "a new event file")
            # no chunk cache: every write reaches the file at once, so a full disk fails that write (an evicted
            # chunk's failure would surface only when HDF5 closes the file, and it could not close it then)
            self._h5 = h5py.File(self._tmp, "w", rdcc_nbytes=0)
            # one handle per dataset for the writer's life (no lookup per block)
            self._ds = [self._h5.create_dataset(f"events/{f}", shape=(0,), maxshape=(None,), dtype=dt,
                                                chunks=(int(chunk_events),), **comp[compression])
                        for f, dt in zip("xytp", (np.uint16, np.uint16, np.uint32 if self._u32 else np.int64, np.uint8))]
        except BaseException as exc:
            self.abort()
            raise self._output_error(exc) from None

    def _check_cancel(self):
        if self._cancel is not None and self._cancel():
            self.abort()
            raise Cancelled(f"{self.path}: writing cancelled")

    def append(self, x, y=None, t=None, p=None) -> None:
        """Append time-sorted events: ``append(EventArray)`` or ``append(x, y, t, p)`` with t absolute µs."""
        if self._closed:
            raise ValueError(f"{self.path}: EventWriter is closed")
        self._check_cancel()
        ev = x if isinstance(x, EventArray) else EventArray(x, y, t, p)
        if len(ev) == 0:
            return
        t = ev.t
        bad = np.flatnonzero(np.diff(t) < 0)
        j = 0 if self._last_t is not None and t[0] < self._last_t else int(bad[0]) + 1 if len(bad) else None
        if j is not None:
            prev = int(t[j - 1]) if j else self._last_t
            raise EventFileError(self.path, "events/t", f"not sorted at appended event {self._n_appended + j} "
                                 f"(t={int(t[j])} < previous {prev})")
        offset = self._offset
        if offset is None:
            offset = int(t[0]) if (self._u32 or not 0 <= int(t[0]) < _WRAP) else 0
        if int(t[0]) < offset:
            raise ValueError(f"{self.path}: events/t: t={int(t[0])} µs is before t_offset={offset} µs")
        if self._u32 and int(t[-1]) - offset > _WRAP - 1:
            raise ValueError(f"{self.path}: events/t: t={int(t[-1])} µs is {int(t[-1]) - offset} µs after "
                             f"t_offset={offset} µs, more than uint32 holds (2**32-1 µs = 71.6 min); "
                             "use time_dtype='int64'")
        self._offset = offset
        rel = t - offset
        self._index.add(rel, self._n_appended)
        self._n_appended += len(ev)
        self._last_t = int(t[-1])
        parts = (ev.x, ev.y, rel.astype(np.uint32) if self._u32 else rel, ev.p)   # copied: callers reuse buffers
        i = 0
        while i < len(ev):
            take = min(len(ev) - i, self._block - self._n_pending)
            self._pending.append(tuple(a[i:i + take].copy() for a in parts))
            self._n_pending += take
            i += take
            if self._n_pending >= self._block:
                self._flush()

    def _output_error(self, exc: BaseException) -> BaseException:
        """An HDF5 or OS error of writing, as an ``OSError`` naming :attr:`path` (the temp file is gone)."""
        exc = os_error_from_hdf5(exc, self.path)
        if isinstance(exc, OSError) and exc.errno is not None:
            return with_path(exc, self.path, replace_temp=self._tmp)
        return exc

    def _flush(self) -> None:
        if self._n_pending:
            n0, n1 = self._n_written, self._n_written + self._n_pending
            # a full disk must fail here, before HDF5 runs into it (HDF5 then cannot even close the file)
            ensure_free_space(self.path, self._n_pending * _BYTES_PER_EVENT + _WRITER_MARGIN_BYTES,
                              f"{self._n_pending:,} events")
            try:
                for k, ds in enumerate(self._ds):
                    ds.resize((n1,))
                    ds[n0:n1] = np.concatenate([part[k] for part in self._pending])
                self._h5.flush()             # metadata too: a full disk fails here, where the file can still close
            except (OSError, RuntimeError) as exc:
                raise self._output_error(exc) from None
            self._pending, self._n_pending, self._n_written = [], 0, n1
            if self._progress is not None:
                self._progress(n1, self._expected)
        self._check_cancel()

    def close(self) -> Path:
        """Flush, write ``ms_to_idx`` and ``t_offset``, fsync and rename onto ``path``; returns ``path``."""
        if self._closed:
            return self.path
        try:
            self._flush()
            index = self._index.finish()
            ensure_free_space(self.path, index.nbytes + _WRITER_MARGIN_BYTES, "the event index")
            self._h5.create_dataset("ms_to_idx", data=index)
            self._h5.create_dataset("t_offset", data=np.int64(self._offset or 0))
            self._h5.flush()                 # a full disk fails here; close() then has nothing left to write
            self._h5.close()
            fsync_path(self._tmp)
            os.replace(self._tmp, self.path)
        except BaseException as exc:
            self.abort()
            raise self._output_error(exc) from None
        self._closed = True
        fsync_dir(self.path.parent)          # make the rename durable (best effort)
        return self.path

    def abort(self) -> None:
        """Discard everything written so far (no file at ``path``, no temp file left).

        A full disk fails a write or a flush (the file has no chunk cache), leaving HDF5 able to close
        the file; the temp file is also truncated before the close, so that a close that still has
        metadata to write finds room (an HDF5 file that cannot be closed crashes the interpreter at exit).
        """
        self._closed = True
        try:
            if self._h5 is not None and self._h5.id.valid:
                with contextlib.suppress(OSError):
                    os.truncate(self._tmp, 0)
                with contextlib.suppress(Exception):
                    self._h5.close()
        finally:
            self._h5 = None
            self._ds = []
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> "EventWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.abort()
        else:
            self.close()


def write_events_h5(path, events_or_chunks, **kwargs) -> Path:
    """Write one EventArray, or an iterable of time-ordered EventArray chunks, with :class:`EventWriter`."""
    if isinstance(events_or_chunks, EventArray):
        kwargs.setdefault("expected_events", len(events_or_chunks))
        events_or_chunks = [events_or_chunks]
    with EventWriter(path, **kwargs) as w:
        for chunk in events_or_chunks:
            w.append(chunk)
    return w.path
