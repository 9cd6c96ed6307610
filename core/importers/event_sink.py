"""Validation of the event stream on its way into the scene's ``events.h5`` (:class:`EventSink`).

Without ``--repair`` no event is dropped or re-timed: an event off the sensor, a bad polarity or a time that
steps back by more than the reorder window is refused with one line naming the file, the record, the event's
index in it and the field. With ``--repair`` the events off the sensor and those too far out of order are
dropped, each kind counted in ``import_report.json``.

Time order: an event older than the newest event before it (in the same chunk or an earlier one) is *out of
order*. Within ``reorder_window_us`` (default 100 ms, ``--reorder-window-ms``; 0 accepts no disorder) it is
put in its place, with or without ``--repair``, and counted (``events_out_of_order``; also
``events_decreasing_steps`` inside chunks and ``chunks_overlapping`` for chunks, e.g. ROS messages, that
overlap earlier ones). Its time is never changed. Beyond the window it is *late* (as is an event older than
one already written). The verdict depends only on the times seen so far, never on how the stream is cut into
chunks or on the file size. The merge is a **bounded stream merge**: the sink keeps the newest
``reorder_window_us`` of events (at most ``max_pending`` events) in memory and writes everything older, so
memory is bounded by the window, never by the file.
"""
from __future__ import annotations

import numpy as np

from evpose.core.data.event_writer import EventWriter
from evpose.core.data.events import EventArray
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.report import ImportContext

#: Events kept back at most by the reorder buffer (bounds memory whatever the window).
DEFAULT_MAX_PENDING = 8_000_000
_FLUSH_EVENTS = 1 << 20


def _as_int_column(a, file, record: str, fld: str, ctx: ImportContext) -> tuple[np.ndarray, np.ndarray | None]:
    """Integer view of an event column (integer dtypes kept as they are; floats must be whole numbers and become
    int64). Returns (values, bad-row mask or None)."""
    a = np.asarray(a)
    if a.dtype.kind in "iu":
        return a, None
    if a.dtype.kind == "b":
        return a.view(np.uint8), None
    if a.dtype.kind != "f":
        raise ImportFailure(file, record, fld, f"expected numbers, got dtype {a.dtype}")
    bad = ~np.isfinite(a)
    if bad.any():
        if not ctx.repair:
            i = int(np.flatnonzero(bad)[0])
            raise ImportFailure(file, f"{record}, event {i}", fld, f"not finite ({a[i]}); pass --repair to drop such events")
        a = np.where(bad, 0, a)
    frac = a != np.floor(a)
    if frac.any():
        i = int(np.flatnonzero(frac)[0])
        raise ImportFailure(file, f"{record}, event {i}", fld, f"expected an integer pixel/polarity, got {a[i]}")
    return a.astype(np.int64), (bad if bad.any() else None)


class EventSink:
    """Validates event chunks and streams them, time-sorted, into an :class:`EventWriter`.

    Parameters
    ----------
    writer : EventWriter or None
        None = validate only (reference/link modes).
    width, height : int
        Sensor size; an event outside ``[0, width) x [0, height)`` is refused (``--repair``: dropped, counted).
    reorder_window_us : int
        How far (µs) an event may be out of time order and still be put in its place (counted); events are
        held back until they are older than the newest event seen minus this window. An event further out of
        order, or older than one already written, is "late": refused (``--repair``: dropped, counted).
    """

    def __init__(self, ctx: ImportContext, writer: EventWriter | None, width: int, height: int, *,
                 reorder_window_us: int | None = None, max_pending: int = DEFAULT_MAX_PENDING):
        self.ctx, self.writer, self.width, self.height = ctx, writer, int(width), int(height)
        self.window = int(ctx.options.reorder_window_us if reorder_window_us is None else reorder_window_us)
        self.max_pending = int(max_pending)
        self.pending: list[tuple] = []
        self.n_pending = self._retained = 0
        self.pending_max: int | None = None
        self.need_merge = False
        self.last_written: int | None = None
        self.n_in = self.n_out = 0
        self.n_dropped_sensor = self.n_unsorted_chunks = self.n_inversions = 0
        self.n_overlap_chunks = self.n_late = self.n_nonfinite = self.n_out_of_order = 0
        self.t_first = self.t_last = self.t_origin = None
        self.max_span_us = int(float(ctx.options.max_span_s) * 1e6)
        self._where = ("(events)", "-")
        self._first_sensor_drop = None
        self.x_max = self.y_max = -1
        self.x_min = self.y_min = None
        #: Appended to the refusal of an event off the sensor (a format's likely cause, e.g. 1-based pixels).
        self.off_sensor_hint = ""
        self._first: int | None = None

    def add(self, x, y, t_us, p, *, file, record: str, first: int | None = None) -> None:
        """Add one chunk. ``t_us`` int64 µs (absolute event clock); x/y integer pixels (any int dtype, floats
        must be whole); p in {0, 1}, {-1, 1} or bool. ``first``: the index of the chunk's first event in the file,
        when the file is a plain sequence of events (an error then names the event by its index in the file;
        otherwise by ``record`` and its index in the chunk)."""
        self.ctx.check_cancel()
        self._first = first
        t = self._check_times(t_us, x, y, p, file, record)
        if len(t) == 0:
            return
        self.n_in += len(t)
        cols = self._on_sensor(*self._integer_columns(x, y, p, file, record), t, file, record)
        if cols is None:
            return
        self._check_span(cols[2], file, record)
        cols = self._in_time_order(*cols, file, record)
        if cols is None:
            return
        self._hold(*cols, file, record)

    def _event(self, record: str, i: int) -> str:
        """Where event ``i`` of the current chunk is, for a message."""
        return f"event {self._first + i}" if self._first is not None else f"{record}, event {i}"

    # ------------------------------------------------------------------- the steps of add()
    @staticmethod
    def _check_times(t_us, x, y, p, file, record: str) -> np.ndarray:
        """The chunk's times as int64 µs; refuses columns of different lengths."""
        t = np.asarray(t_us)
        if t.dtype.kind not in "iu":
            raise ImportFailure(file, record, "t", f"internal: times must be integer µs, got {t.dtype}")
        t = t.astype(np.int64, copy=False)
        n = len(t)
        if not (np.ndim(x) == np.ndim(y) == np.ndim(p) == 1 and len(x) == len(y) == len(p) == n):
            raise ImportFailure(file, record, "x/y/t/p", f"columns have different lengths ({len(x)}, {len(y)}, {n}, "
                                f"{len(p)})")
        return t

    def _integer_columns(self, x, y, p, file, record: str):
        """``(x, y, polarity as uint8 0/1, keep)``: ``keep`` masks out rows with a NaN/inf coordinate or
        polarity (``--repair`` only; None when every row is finite)."""
        ctx = self.ctx
        xi, bx = _as_int_column(x, file, record, "x", ctx)
        yi, by = _as_int_column(y, file, record, "y", ctx)
        pi, bp = _as_int_column(p, file, record, "p", ctx)
        keep = None
        for b in (bx, by, bp):
            if b is not None:
                keep = ~b if keep is None else keep & ~b
        if keep is not None:
            self.n_nonfinite += int(len(xi) - keep.sum())
        # polarity: 0/1, -1/+1 or bool
        if pi.size:
            pmin, pmax = int(pi.min()), int(pi.max())
            if pmin < -1 or pmax > 1:
                i = int(np.flatnonzero((pi < -1) | (pi > 1))[0])
                raise ImportFailure(file, self._event(record, i), "p",
                                    f"polarity must be 0/1 or -1/+1, got {int(pi[i])}")
            p8 = (pi > 0).view(np.uint8) if pmin < 0 else pi.astype(np.uint8, copy=False)
        else:
            p8 = pi.astype(np.uint8, copy=False)
        return xi, yi, p8, keep

    def _on_sensor(self, xi, yi, p8, keep, t, file, record: str):
        """The rows inside the sensor (and finite). An event off the sensor is refused, or with ``--repair``
        dropped and counted; None when no row is left."""
        n = len(t)
        inside = (xi >= 0) & (xi < self.width) & (yi >= 0) & (yi < self.height)
        if keep is not None:
            inside &= keep
            n_sensor = int(np.count_nonzero(~inside & keep))
        else:
            n_sensor = n - int(np.count_nonzero(inside))
        if n_sensor:
            i = int(np.flatnonzero(~inside if keep is None else (~inside & keep))[0])
            if not self.ctx.repair:
                fld, v, side = ("x", xi[i], self.width) if not 0 <= xi[i] < self.width else ("y", yi[i], self.height)
                raise ImportFailure(file, self._event(record, i), fld, f"{int(v)} is outside the {self.width}x"
                                    f"{self.height} sensor ({fld} in [0, {side})){self.off_sensor_hint}; pass "
                                    "--repair to drop events off the sensor")
            if self._first_sensor_drop is None:
                self._first_sensor_drop = f"{self._event(record, i)}: (x={int(xi[i])}, y={int(yi[i])})"
            self.n_dropped_sensor += n_sensor
        if n_sensor or keep is not None:
            xi, yi, t, p8 = xi[inside], yi[inside], t[inside], p8[inside]
            if len(t) == 0:
                return None
        if len(xi):
            self.x_max, self.y_max = max(self.x_max, int(xi.max())), max(self.y_max, int(yi.max()))
            mnx, mny = int(xi.min()), int(yi.min())
            self.x_min = mnx if self.x_min is None else min(self.x_min, mnx)
            self.y_min = mny if self.y_min is None else min(self.y_min, mny)
        return xi, yi, t, p8

    def _check_span(self, t, file, record: str) -> None:
        """A corrupt time stamp (or a wrong unit) would make the ms index of the event file explode."""
        if self.t_origin is None:
            self.t_origin = int(t[0])
        if int(t.max()) - self.t_origin > self.max_span_us or self.t_origin - int(t.min()) > self.max_span_us:
            j = int(np.argmax(np.abs(t - self.t_origin) > self.max_span_us))
            raise ImportFailure(file, self._event(record, j), "t", f"t={int(t[j])} µs is "
                                f"{abs(int(t[j]) - self.t_origin) / 3.6e9:.3g} h from the first event "
                                f"(t={self.t_origin} µs): more than --max-span-s {self.max_span_us / 1e6:g} s "
                                "(corrupt time stamp or wrong time unit?)")

    def _newest(self) -> int | None:
        """The newest event time seen so far (µs), None before the first event."""
        return self.pending_max if self.pending_max is not None else self.last_written

    def _in_time_order(self, xi, yi, t, p8, file, record: str):
        """The chunk sorted by time (stable). Events out of order by at most the window are counted; late ones
        (further, or older than an event already written) are refused, or with ``--repair`` dropped and
        counted. None when no row is left."""
        newest = self._newest()
        dec = np.count_nonzero(t[1:] < t[:-1])
        if not dec and (newest is None or t[0] >= newest):
            return xi, yi, t, p8
        before = np.empty_like(t)                  # the newest time before each event
        before[0] = t[0] if newest is None else newest
        np.maximum.accumulate(t[:-1], out=before[1:])
        if newest is not None:
            np.maximum(before, newest, out=before)
        limit = before - self.window
        if self.last_written is not None:
            np.maximum(limit, self.last_written, out=limit)
        late = t < limit
        n_late = int(np.count_nonzero(late))
        if n_late and not self.ctx.repair:
            i = int(np.flatnonzero(late)[0])
            raise ImportFailure(file, self._event(record, i), "t", f"t={int(t[i])} µs is {int(before[i] - t[i])} µs "
                                f"older than an event before it (t={int(before[i])} µs): out of time order by more "
                                f"than the reorder window ({self.window} µs). Pass --repair to drop such events, or "
                                "a larger --reorder-window-ms")
        self.n_out_of_order += int(np.count_nonzero(t < before)) - n_late
        if n_late:
            self.n_late += n_late
            ok = ~late
            xi, yi, t, p8 = xi[ok], yi[ok], t[ok], p8[ok]
            if len(t) == 0:
                return None
            dec = np.count_nonzero(t[1:] < t[:-1])
        if dec:
            self.n_unsorted_chunks += 1
            self.n_inversions += int(dec)
            o = np.argsort(t, kind="stable")
            xi, yi, t, p8 = xi[o], yi[o], t[o], p8[o]
        return xi, yi, t, p8

    def _hold(self, xi, yi, t, p8, file, record: str) -> None:
        """Keep the chunk in the reorder buffer; write what is older than the window."""
        if self.pending_max is not None and t[0] < self.pending_max:
            self.need_merge = True
            self.n_overlap_chunks += 1
        self._where = (file, record)
        self.pending.append((xi.astype(np.uint16, copy=False), yi.astype(np.uint16, copy=False), t, p8))
        self.n_pending += len(t)
        self.pending_max = int(t[-1]) if self.pending_max is None else max(self.pending_max, int(t[-1]))
        if self.n_pending >= _FLUSH_EVENTS + self._retained:       # amortised: each event is copied O(1) times
            self._emit(final=False)

    # ------------------------------------------------------------------- output
    def _emit(self, final: bool) -> None:
        if not self.pending:
            return
        if len(self.pending) == 1:
            x, y, t, p = self.pending[0]
        else:
            x, y, t, p = (np.concatenate([c[k] for c in self.pending]) for k in range(4))
        if self.need_merge:
            o = np.argsort(t, kind="stable")
            x, y, t, p = x[o], y[o], t[o], p[o]
            self.need_merge = False
        if final:
            cut = len(t)
        else:
            cut = int(np.searchsorted(t, self.pending_max - self.window, side="left"))
            if len(t) - cut > self.max_pending:     # bound memory: the window shrinks at extreme rates
                cut = len(t) - self.max_pending
        if cut > 0:
            self._write(x[:cut], y[:cut], t[:cut], p[:cut])
        self.pending = [(x[cut:], y[cut:], t[cut:], p[cut:])] if cut < len(t) else []
        self.n_pending = self._retained = len(t) - cut

    def _write(self, x, y, t, p) -> None:
        if self.t_first is None:
            self.t_first = int(t[0])
        self.t_last = int(t[-1])
        self.last_written = int(t[-1])
        self.n_out += len(t)
        if self.writer is not None:
            try:
                self.writer.append(EventArray(x, y, t, p))
            except ValueError as exc:       # EventFileError and range errors of the writer: name the input
                raise ImportFailure(self._where[0], self._where[1], "events", f"cannot be written: {exc}") from None

    def close(self) -> None:
        """Write what is held back and put the counters into the report."""
        self._emit(final=True)
        r = self.ctx.report
        r.counts.update(events_in=self.n_in, events_written=self.n_out)
        if self.n_dropped_sensor:
            r.repair(f"dropped {self.n_dropped_sensor} event(s) outside the {self.width}x{self.height} sensor "
                     f"(first: {self._first_sensor_drop})")
            r.counts["events_dropped_outside_sensor"] = self.n_dropped_sensor
        if self.n_nonfinite:
            r.repair(f"dropped {self.n_nonfinite} event(s) with a NaN/inf coordinate or polarity (--repair)")
            r.counts["events_dropped_nonfinite"] = self.n_nonfinite
        if self.n_out_of_order:
            r.counts["events_out_of_order"] = self.n_out_of_order
        if self.n_unsorted_chunks:
            r.repair(f"sorted events inside {self.n_unsorted_chunks} chunk(s)/message(s) with unsorted times "
                     f"({self.n_inversions} decreasing step(s); {self.n_out_of_order} event(s) out of order, all "
                     f"within the reorder window of {self.window} µs); stable sort, equal times keep file order, no "
                     "time changed")
            r.counts["events_decreasing_steps"] = self.n_inversions
        if self.n_overlap_chunks:
            r.repair(f"merged {self.n_overlap_chunks} chunk(s)/message(s) that overlap earlier ones in time "
                     f"(bounded stream merge, window {self.window} µs)")
            r.counts["chunks_overlapping"] = self.n_overlap_chunks
        if self.n_late:
            r.repair(f"dropped {self.n_late} event(s) arriving later than the reorder window (--repair)")
            r.counts["events_dropped_late"] = self.n_late
