"""Streaming, atomic writer of the event file layout (:mod:`evpose.core.data.events`), with bounded memory.

The file appears only on a successful close (temp file + fsync + rename); the ms index is built on the way
(:class:`evpose.core.data.event_index.MsIndexBuilder`). A full disk fails a write HDF5 can recover from:
the file has no chunk cache, every block is flushed, and free space is checked before each block.
"""
from __future__ import annotations

import contextlib
import operator
import os
from pathlib import Path

import h5py
import hdf5plugin
import numpy as np

from evpose.core.data.atomic import fsync_dir, fsync_path
from evpose.core.data.event_index import WRAP, MsIndexBuilder
from evpose.core.data.events import Cancelled, EventArray, EventFileError
from evpose.core.data.os_errors import ensure_free_space, os_error_from_hdf5, with_path
from evpose.core.data.temp_files import temp_path_for

__all__ = ["DEFAULT_CHUNK_EVENTS", "EventWriter", "write_events_h5"]

# Events per HDF5 chunk, chosen by measurement (bursty synthetic 640x480 data, uint32 t, Blosc-LZ4, 2 cores;
# 1000 random 10 ms windows from a fresh store, mean / p95 ms per window, file size):
#   50 M events at 1 M ev/s:  2**14: 0.25/0.50 ms 230 MB;  2**15: 0.30/0.62 ms 228 MB;  2**16: 0.43/0.88 ms 227 MB;
#                             2**17: 0.59/1.16 ms 212 MB;  2**18: 0.85/1.39 ms 212 MB
#   30 M events at 5 M ev/s:  2**14: 0.50/1.30 ms;  2**15: 0.51/1.29 ms;  2**16: 0.58/1.36 ms
# Window time grows with the chunk (a random window decompresses whole chunks) and compression gains little:
# 2**15 is within noise of the fastest at 5 M ev/s and close at 1 M ev/s.
DEFAULT_CHUNK_EVENTS = 2**15
_FLUSH_EVENTS = 2**20           # EventWriter buffers about this many events between HDF5 writes
#: EventWriter's free-space check: stored bytes per event before compression (x, y: 2 each, t: 8, p: 1, an upper
#: bound of the compressed size) and a margin for HDF5's metadata and for closing the file.
_BYTES_PER_EVENT = 13
_WRITER_MARGIN_BYTES = 1 << 20


class EventWriter:
    """Streaming, atomic writer of the event layout, with bounded memory.

    Parameters
    ----------
    path : str or Path
        Destination; it appears only on a successful :meth:`close` (temp file + fsync + rename).
    time_dtype : {"int64", "uint32"}
        Storage type of ``events/t`` (stored = t - t_offset).
    t_offset_us : int, optional
        µs. Default for uint32: the first event's time. For int64: the first event's whole ms when the first time
        lies in ``[0, 2**32)`` µs (the index's ms bins stay on whole ms of the sensor clock, as with 0, and
        ``ms_to_idx`` follows the recording's duration, not its start: a recording starting 913 s into the sensor
        clock had 7.3 MB of index for 1.6 MB of events with ``t_offset = 0``), else the first event's time (epoch
        and negative clocks: kept as before, so the bins of existing scenes do not move).
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
        self._last_t, self._index, self._closed = None, MsIndexBuilder(0), False
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
        if offset is None:      # the ms index counts from the first event's ms, not from the sensor clock's zero
            offset = int(t[0]) if (self._u32 or not 0 <= int(t[0]) < WRAP) else (int(t[0]) // 1000) * 1000
        if int(t[0]) < offset:
            raise ValueError(f"{self.path}: events/t: t={int(t[0])} µs is before t_offset={offset} µs")
        if self._u32 and int(t[-1]) - offset > WRAP - 1:
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
