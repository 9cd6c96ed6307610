"""Validation of the event stream on its way into the scene's ``events.h5`` (:class:`EventSink`).

Out-of-sensor events are dropped and counted, events unsorted inside a chunk are sorted (stable, counted),
and chunks that overlap in time (e.g. ROS messages) are merged by a **bounded stream merge**: the sink keeps
the newest ``reorder_window_us`` of events (default 100 ms, at most ``max_pending`` events) in memory and
writes everything older. An event that arrives later than that (older than the newest event seen so far
minus the window, or than an event already written) is an error (``--repair``: dropped and counted), whatever
the buffer holds, so the outcome does not depend on file size. Memory is bounded by the window, never by the
file.
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
        Sensor size; events outside ``[0, width) x [0, height)`` are dropped and counted.
    reorder_window_us : int
        Bounded stream merge: events are held back until they are older than the newest event seen minus
        this window; an event older than one already written is "late" (error, or dropped with ``--repair``).
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
        self.n_overlap_chunks = self.n_late = self.n_nonfinite = 0
        self.t_first = self.t_last = self.t_origin = None
        self.max_span_us = int(float(ctx.options.max_span_s) * 1e6)
        self._where = ("(events)", "-")
        self._first_sensor_drop = None
        self.x_max = self.y_max = -1
        self.x_min = self.y_min = None

    def add(self, x, y, t_us, p, *, file, record: str) -> None:
        """Add one chunk. ``t_us`` int64 µs (absolute event clock); x/y integer pixels (any int dtype, floats
        must be whole); p in {0, 1}, {-1, 1} or bool."""
        self.ctx.check_cancel()
        t = self._check_times(t_us, x, y, p, file, record)
        if len(t) == 0:
            return
        self.n_in += len(t)
        cols = self._on_sensor(*self._integer_columns(x, y, p, file, record), t, record)
        if cols is None:
            return
        cols = self._sorted(*cols)
        self._check_span(cols[2], file, record)
        cols = self._drop_late(*cols, file, record)
        if cols is None:
            return
        self._hold(*cols, file, record)

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
                raise ImportFailure(file, f"{record}, event {i}", "p", f"polarity must be 0/1 or -1/+1, got {int(pi[i])}")
            p8 = (pi > 0).view(np.uint8) if pmin < 0 else pi.astype(np.uint8, copy=False)
        else:
            p8 = pi.astype(np.uint8, copy=False)
        return xi, yi, p8, keep

    def _on_sensor(self, xi, yi, p8, keep, t, record: str):
        """The rows inside the sensor (and finite), counting the dropped ones; None when none is left."""
        n = len(t)
        inside = (xi >= 0) & (xi < self.width) & (yi >= 0) & (yi < self.height)
        if keep is not None:
            inside &= keep
            n_sensor = int(np.count_nonzero(~inside & keep))
        else:
            n_sensor = n - int(np.count_nonzero(inside))
        if n_sensor:
            if self._first_sensor_drop is None:
                i = int(np.flatnonzero(~inside if keep is None else (~inside & keep))[0])
                self._first_sensor_drop = f"{record}, event {i}: (x={int(xi[i])}, y={int(yi[i])})"
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

    def _sorted(self, xi, yi, t, p8):
        """Sort inside the chunk (stable: equal times keep their file order), counting the decreasing steps."""
        if len(t) > 1:
            dec = np.count_nonzero(t[1:] < t[:-1])
            if dec:
                self.n_unsorted_chunks += 1
                self.n_inversions += int(dec)
                o = np.argsort(t, kind="stable")
                xi, yi, t, p8 = xi[o], yi[o], t[o], p8[o]
        return xi, yi, t, p8

    def _check_span(self, t, file, record: str) -> None:
        """A corrupt time stamp (or a wrong unit) would make the ms index of the event file explode."""
        if self.t_origin is None:
            self.t_origin = int(t[0])
        if int(t[-1]) - self.t_origin > self.max_span_us or self.t_origin - int(t[0]) > self.max_span_us:
            j = int(np.argmax(np.abs(t - self.t_origin) > self.max_span_us))
            raise ImportFailure(file, f"{record}, event {j}", "t", f"t={int(t[j])} µs is {abs(int(t[j]) - self.t_origin) / 3.6e9:.3g} h "
                                f"from the first event (t={self.t_origin} µs): more than --max-span-s "
                                f"{self.max_span_us / 1e6:g} s (corrupt time stamp or wrong time unit?)")

    def _drop_late(self, xi, yi, t, p8, file, record: str):
        """Late events: older than the newest event seen minus the window (or than one already written).
        Refused, or dropped and counted with ``--repair``; None when none is left."""
        thr = self.last_written
        if self.pending_max is not None:
            thr = max(thr if thr is not None else self.pending_max - self.window, self.pending_max - self.window)
        if thr is not None and t[0] < thr:
            late = t < thr
            nl = int(np.count_nonzero(late))
            if not self.ctx.repair:
                newest = self.pending_max if self.pending_max is not None else self.last_written
                raise ImportFailure(file, record, "t", f"{nl} event(s) from t={int(t[0])} µs arrive more than the reorder "
                                    f"window ({self.window} µs) after later events (newest so far t={newest} µs); the "
                                    "stream is not sorted. Pass --repair to drop them, or a larger --reorder-window-ms")
            self.n_late += nl
            ok = ~late
            xi, yi, t, p8 = xi[ok], yi[ok], t[ok], p8[ok]
            if len(t) == 0:
                return None
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
        if self.n_unsorted_chunks:
            r.repair(f"sorted events inside {self.n_unsorted_chunks} chunk(s)/message(s) with unsorted times "
                     f"({self.n_inversions} decreasing step(s)); stable sort, equal times keep file order")
            r.counts["events_decreasing_steps"] = self.n_inversions
        if self.n_overlap_chunks:
            r.repair(f"merged {self.n_overlap_chunks} chunk(s)/message(s) that overlap earlier ones in time "
                     f"(bounded stream merge, window {self.window} µs)")
            r.counts["chunks_overlapping"] = self.n_overlap_chunks
        if self.n_late:
            r.repair(f"dropped {self.n_late} event(s) arriving later than the reorder window (--repair)")
            r.counts["events_dropped_late"] = self.n_late
