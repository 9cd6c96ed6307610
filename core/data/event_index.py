"""The millisecond index of an event file, the pass over ``events/t`` that builds it, and its cache.

``ms_to_idx[k]`` is the first event index with ``t >= base + 1000 * k`` (µs relative to ``t_offset``):
any time maps to a range of at most one millisecond of events, so a window is read without a search
over the file. A file's own ``ms_to_idx`` is used when cheap checks find it plausible
(:func:`file_index_plausible`); otherwise :func:`scan_index` builds one in a chunked pass that also
unwraps uint32 times and refuses unsorted ones. The result (with the validation of
:mod:`evpose.core.data.event_validation`) is cached in the user cache dir (:func:`default_cache_dir`),
never beside the event file.
"""
from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

import h5py
import numpy as np

from evpose.core.data.events import Cancelled, EventFileError
from evpose.core.data.temp_files import temp_path_for

#: 2**32 µs: a stored uint32 time wraps around after this (71.6 min).
WRAP = 2**32
#: Events per step of the chunked passes over a file (~16 MB of int64 times).
SCAN_CHUNK_EVENTS = 2**21
#: Version of the cached index: 2 holds the validation result (pixel ranges) and lives in the cache dir.
CACHE_VERSION = 2


class MsIndexBuilder:
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


def scan_index(path, dset, base_rel: int, *, builder=None, start: int = 0, progress=None, cancel=None):
    """One chunked pass over ``events/t[start:]``: check order, unwrap uint32 time, build the ms index.

    Returns
    -------
    ms_to_idx : np.ndarray of int64
    wraps : np.ndarray of int64
        Indices where the stored uint32 time wrapped around 2**32 (each adds 2**32 µs from there on).
    """
    n = dset.shape[0]
    can_wrap = dset.dtype == np.uint32
    builder = builder or MsIndexBuilder(base_rel)
    chunk = dset.chunks[0] if dset.chunks else 1
    step = max(1, SCAN_CHUNK_EVENTS // chunk) * chunk
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
            inc[neg] = WRAP
            wraps.extend((i0 + neg).tolist())
            t_rel = raw + wrap_add + np.cumsum(inc)
            wrap_add += WRAP * neg.size
        else:
            t_rel = raw + wrap_add if wrap_add else raw
        builder.add(t_rel, i0)
        prev = raw[-1:]
        if progress is not None:
            progress(min(i0 + step, n), n)
        if cancel is not None and cancel():
            raise Cancelled(f"{path}: index build cancelled")
    return builder.finish(), np.asarray(wraps, np.int64)


def int_dataset(path, h5: h5py.File, name: str, kinds: str) -> h5py.Dataset:
    """The dataset ``name`` of an open file; :class:`EventFileError` unless it is one with an integer
    (or, with ``"b"`` in ``kinds``, boolean) dtype."""
    obj = h5.get(name)
    if not isinstance(obj, h5py.Dataset):
        raise EventFileError(path, name, "missing" if obj is None else "not a dataset")
    if obj.dtype.kind not in kinds:
        raise EventFileError(path, name, f"dtype {obj.dtype} is not an integer type")
    return obj


def file_index_plausible(path, h5: h5py.File, t: h5py.Dataset, first_s: int, last_s: int, *,
                         stacklevel: int = 2) -> bool:
    """Whether the file's ``ms_to_idx`` passes cheap consistency checks (then the index is built on its
    bin grid, bin 0 at ``t_offset``). A plausible index proves nothing about the order of the events
    between its entries: the whole time column is checked by the first-open pass either way.

    ``t`` is ``events/t``, ``first_s`` / ``last_s`` its first and last stored values. An implausible index
    is ignored with a warning (``stacklevel`` as for :func:`warnings.warn` called here)."""
    if "ms_to_idx" not in h5:
        return False
    d = int_dataset(path, h5, "ms_to_idx", "iu")
    idx = np.asarray(d[()], dtype=np.int64).reshape(-1) if d.ndim == 1 else None
    n, problem = t.shape[0], None
    if idx is None or len(idx) == 0:
        problem = "not a non-empty 1-D array"
    elif t.dtype == np.uint32 and (last_s < first_s or len(idx) > WRAP // 1000 + 1):
        problem = "the uint32 time wraps around 2**32"
    elif idx[0] != 0 or first_s < 0 or idx[-1] > n or np.any(np.diff(idx) < 0):
        problem = "not a non-decreasing index into events starting at 0"
    else:
        for k in sorted({0, len(idx) // 4, len(idx) // 2, 3 * len(idx) // 4, len(idx) - 1}):
            i = int(idx[k])
            tk = t[max(i - 1, 0):i + 1].astype(np.int64)
            if (i < n and tk[-1] < 1000 * k) or (i > 0 and tk[0] >= 1000 * k):
                problem = f"entry {k} (= {i}) disagrees with events/t"
                break
    if problem:
        warnings.warn(f"{path}: ms_to_idx: {problem}; ignoring it and building an index", stacklevel=stacklevel)
        return False
    return True


def default_cache_dir() -> Path:
    """Where EventStore caches its index and validation result: ``$XDG_CACHE_HOME/evpose/msidx``
    (``~/.cache/evpose/msidx``). Never beside the event file, which may be the user's source."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache", "evpose", "msidx")


def index_cache_file(path: Path, cache_dir=None) -> Path:
    """The cache file of the event file ``path``: ``<sha1 of its resolved path>.npz`` in ``cache_dir``
    (default :func:`default_cache_dir`)."""
    key = hashlib.sha1(str(Path(path).resolve()).encode()).hexdigest()
    return (Path(cache_dir) if cache_dir is not None else default_cache_dir()) / f"{key}.npz"


def write_npz_atomic(target: Path, **arrays) -> None:
    """``np.savez`` of ``arrays`` into ``target`` through a temp file and a rename (no fsync: a cache)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path_for(target)
    try:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
