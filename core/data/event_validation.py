"""Validation of an event file on its first open, cached with its ms index (issue 11).

The layout is checked first (:func:`open_columns`): ``events/x``, ``events/y``, ``events/t`` and
``events/p`` are 1-D integer datasets of one length, ``t_offset`` an integer scalar. Then the first open
of a file makes one chunked pass over all its columns (:func:`index_and_validate`, cached with the index,
so later opens read nothing): ``events/t`` must not decrease (a uint32 wrap excepted), even when the
file carries a plausible ``ms_to_idx``; ``events/x`` and ``events/y`` must not be negative (signed
types) and must lie on the sensor (:func:`check_sensor`); ``events/p`` must be 0 or 1 (-1, 0 or +1 for a
signed type). A file that breaks any of these is **refused** with :class:`EventFileError` naming
the file, the field, the first bad index and its value: nothing downstream ever sees an event
outside the sensor, and nothing is silently dropped (``evpose import ... --repair`` rewrites such
a recording without them, with a count). Cost, measured with ``bench/bench_events.py`` on 50 M
events (229 MB, Blosc-LZ4, 2 cores): 0.58 s for the first open (t pass 0.32 s, x/y/p pass 0.35 s),
2.5 ms for every later open; loading the arrays with h5py takes 1.35 s.
"""
from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import NamedTuple

import h5py
import numpy as np

from evpose.core.data import event_index
from evpose.core.data.event_index import (
    CACHE_VERSION,
    file_index_plausible,
    index_cache_file,
    int_dataset,
    scan_index,
    write_npz_atomic,
)
from evpose.core.data.events import Cancelled, EventFileError


class EventColumns(NamedTuple):
    """The four event datasets of an open file, their common length and the file's ``t_offset`` (µs)."""

    x: h5py.Dataset
    y: h5py.Dataset
    t: h5py.Dataset
    p: h5py.Dataset
    n_events: int
    t_offset_us: int


class FirstOpen(NamedTuple):
    """What the first-open pass finds (and the cache keeps).

    ``ms_to_idx`` and ``wraps`` as in :class:`evpose.core.data.event_store.EventStore`; ``base_rel``: start of
    bin 0 relative to ``t_offset`` (µs); ``stats``: ``[x_min, x_max, y_min, y_max]`` (int64)."""

    ms_to_idx: np.ndarray
    wraps: np.ndarray
    base_rel: int
    stats: np.ndarray


def open_columns(path, h5: h5py.File) -> EventColumns:
    """The event datasets of ``h5`` after the layout checks; :class:`EventFileError` names the field at fault."""
    ds = {f: int_dataset(path, h5, f"events/{f}", "iub" if f == "p" else "iu") for f in "xytp"}
    for f, d in ds.items():
        if d.ndim != 1:
            raise EventFileError(path, f"events/{f}", f"shape {d.shape} is not 1-D")
    n = ds["t"].shape[0]
    for f in "xyp":
        if ds[f].shape[0] != n:
            raise EventFileError(path, f"events/{f}", f"length {ds[f].shape[0]} != length {n} of events/t")
    t_offset_us = 0
    if "t_offset" in h5:
        off = int_dataset(path, h5, "t_offset", "iu")
        if off.size != 1:
            raise EventFileError(path, "t_offset", f"shape {off.shape} is not a scalar")
        t_offset_us = int(off[()].reshape(-1)[0] if off.shape else off[()])
    return EventColumns(ds["x"], ds["y"], ds["t"], ds["p"], n, t_offset_us)


def first_where(dset, pred, start: int = 0):
    """First index ``i >= start`` (and its value) where ``pred(dset[i])``, by a chunked pass; None if none."""
    n = dset.shape[0]
    chunk = dset.chunks[0] if dset.chunks else 1
    step = max(1, event_index.SCAN_CHUNK_EVENTS // chunk) * chunk   # the one chunk knob of both passes
    for i0 in range(start, n, step):
        a = dset[i0:i0 + step]
        hit = np.flatnonzero(pred(a))
        if len(hit):
            return i0 + int(hit[0]), a[hit[0]].item()
    return None


def scan_values(path, ds: dict, *, progress=None, cancel=None) -> np.ndarray:
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
    step = max(1, event_index.SCAN_CHUNK_EVENTS // chunk) * chunk   # the one chunk knob of both passes
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


def index_and_validate(path: Path, h5: h5py.File, cols: EventColumns, first_s: int, last_s: int, *,
                       cache_dir=None, progress=None, cancel=None, stacklevel: int = 2) -> FirstOpen:
    """The ms index and the pixel ranges: from the cache, else from one chunked pass over the file
    (which also refuses unsorted times, negative pixels and bad polarities), then cached.

    The cache (:func:`evpose.core.data.event_index.index_cache_file`) is valid while the file's size,
    mtime, inode, event count, first/last stored time, ``t_offset`` and dtypes are unchanged. ``first_s``
    and ``last_s`` are the first and last stored times; ``progress(k, n)`` and ``cancel()`` as for
    :class:`evpose.core.data.event_store.EventStore`. ``stacklevel`` as for :func:`warnings.warn` called here."""
    st = os.stat(path)
    dtypes = sum(ord(c) << (8 * k) for k, c in enumerate("".join(d.dtype.char for d in cols[:4])))
    meta = np.array([CACHE_VERSION, st.st_size, st.st_mtime_ns, st.st_ino, cols.n_events, first_s, last_s,
                     cols.t_offset_us, dtypes], np.int64)
    cache = index_cache_file(path, cache_dir)
    try:
        with np.load(cache, allow_pickle=False) as z:
            if np.array_equal(z["meta"], meta):
                return FirstOpen(z["ms_to_idx"].astype(np.int64), z["wraps"].astype(np.int64), int(z["base_rel"]),
                                 z["stats"].astype(np.int64))
    except Exception:  # missing, unreadable, corrupt or foreign: rebuild
        pass
    n = cols.n_events
    both = None if progress is None else (lambda k, _n, off=0: progress(off + k, 2 * n))
    plausible = file_index_plausible(path, h5, cols.t, first_s, last_s, stacklevel=stacklevel + 1)
    base_rel = 0 if plausible else (first_s // 1000) * 1000
    ms_to_idx, wraps = scan_index(path, cols.t, base_rel, progress=both, cancel=cancel)
    stats = scan_values(path, {"x": cols.x, "y": cols.y, "p": cols.p}, cancel=cancel,
                        progress=None if progress is None else (lambda k, _n: progress(n + k, 2 * n)))
    try:
        write_npz_atomic(cache, meta=meta, ms_to_idx=ms_to_idx, wraps=wraps, base_rel=np.int64(base_rel), stats=stats)
    except OSError as exc:
        warnings.warn(f"{path}: could not cache the ms index in {cache} ({exc.strerror or exc}); "
                      "the next open scans the file again", stacklevel=stacklevel)
    return FirstOpen(ms_to_idx, wraps, base_rel, stats)


def check_sensor(path, cols: EventColumns, stats: np.ndarray, sensor_size) -> None:
    """Refuse events beyond the sensor (``sensor_size = (width, height)`` pixels, None: no check),
    naming the first one."""
    if sensor_size is None:
        return
    for f, k, limit, dim in (("x", 1, sensor_size[0], "width"), ("y", 3, sensor_size[1], "height")):
        if int(stats[k]) >= limit:
            hit = first_where(getattr(cols, f), lambda a, lim=limit: a >= lim)
            i, v = hit if hit is not None else (-1, int(stats[k]))
            raise EventFileError(path, f"events/{f}", f"{v} at index {i} is outside the "
                                 f"{sensor_size[0]}x{sensor_size[1]} sensor ({f} must be < {dim} "
                                 f"{limit}); `evpose import ... --repair` drops such events with a count")
