"""Reading one kymograph line: the events near it binned by position along it and time, each shown object's
edge track on it (its silhouette crossings at the track times, from the label maps) and the events' lag behind
the tracks (:mod:`~evpose.core.views.kymograph_lag`), pooled over the objects."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from evpose.core.label.overlay import object_color
from evpose.core.views.kymograph_confidence import NO_TRACK, judge
from evpose.core.views.kymograph_lag import LagEstimate, LineEvents, combine, estimate_lag
from evpose.core.views.kymograph_line import KymoLine, crossing_distances, labels_along

#: Events within this distance across the line (px) are binned.
HALF_WIDTH_PX = 1.0
#: Time bins of the image, µs.
BIN_US = 1_000
#: Crossings at consecutive track times closer than this (px) are joined into one track line.
LINK_PX = 8.0


@dataclass
class EdgeTrack:
    """One object's silhouette crossings with the line over the span.

    ``t_ms`` / ``s_px`` (P,): the crossing points (time relative to the current time, position along the line);
    ``segments`` (Q, 2, 2): crossings at consecutive track times joined, as ``[(s, t), (s, t)]`` pairs;
    ``lag``: the events' lag behind this track."""

    name: str
    color: tuple[int, int, int]
    t_ms: np.ndarray
    s_px: np.ndarray
    segments: np.ndarray
    lag: LagEstimate


def bin_events(ev, line: KymoLine, t_first_us: int, n_rows: int, bin_us: int,
               half_width_px: float = HALF_WIDTH_PX) -> tuple[np.ndarray, np.ndarray]:
    """ON and OFF counts ``(n_rows, n_cols)`` uint16 of the events within ``half_width_px`` of ``line``: rows are
    ``bin_us`` time bins from ``t_first_us``, column ``c`` holds positions ``s`` in ``[c - 0.5, c + 0.5)``."""
    n_cols = int(np.floor(line.length + 0.5)) + 1
    on = np.zeros((n_rows, n_cols), np.uint16)
    off = np.zeros((n_rows, n_cols), np.uint16)
    if len(ev) == 0:
        return on, off
    ev = ev[np.flatnonzero(near_box(ev, line, half_width_px + 1.0))]      # cheap: most events are far
    s, n = line.project(ev.x, ev.y)
    col = np.floor(s + 0.5).astype(np.int64)
    row = (ev.t - int(t_first_us)) // int(bin_us)
    keep = (np.abs(n) <= half_width_px) & (col >= 0) & (col < n_cols) & (row >= 0) & (row < n_rows)
    flat = row[keep] * n_cols + col[keep]
    pol = ev.p[keep] > 0
    size = n_rows * n_cols
    on += np.bincount(flat[pol], minlength=size).reshape(n_rows, n_cols).astype(np.uint16)
    off += np.bincount(flat[~pol], minlength=size).reshape(n_rows, n_cols).astype(np.uint16)
    return on, off


def near_box(ev, line: KymoLine, reach_px: float) -> np.ndarray:
    """Which events lie in the line's bounding box grown by ``reach_px`` (bool)."""
    lo = [max(0, int(np.floor(min(a, b) - reach_px))) for a, b in ((line.u0, line.u1), (line.v0, line.v1))]
    hi = [min(65535, int(np.ceil(max(a, b) + reach_px))) for a, b in ((line.u0, line.u1), (line.v0, line.v1))]
    return (ev.x >= lo[0]) & (ev.x <= hi[0]) & (ev.y >= lo[1]) & (ev.y <= hi[1])


def link_segments(t_ms: list[float], crossings: list[np.ndarray], link_px: float = LINK_PX) -> np.ndarray:
    """Join each crossing to the nearest crossing at the next track time within ``link_px``: (Q, 2, 2) of
    ``[(s, t), (s, t)]``."""
    segs = []
    for i in range(len(t_ms) - 1):
        a, b = crossings[i], crossings[i + 1]
        if len(a) == 0 or len(b) == 0:
            continue
        d = np.abs(a[:, None] - b[None, :])
        j = np.argmin(d, axis=1)
        ok = d[np.arange(len(a)), j] <= link_px
        for s0, s1 in zip(a[ok], b[j[ok]]):
            segs.append([[s0, t_ms[i]], [s1, t_ms[i + 1]]])
    return np.asarray(segs, np.float64).reshape(-1, 2, 2)


def track_travel(segments: np.ndarray, n_times: int) -> float:
    """How far (px) a track moves along the line over its times: the joined crossings' summed motion per chain
    (segments per time step)."""
    if len(segments) == 0 or n_times < 2:
        return 0.0
    chains = len(segments) / (n_times - 1)
    return float(np.abs(segments[:, 1, 0] - segments[:, 0, 0]).sum() / max(chains, 1.0))


@dataclass
class SpanData:
    """What a line is read against: the events of the extended span (``n_ext`` bins of ``BIN_US`` from
    ``t_ext0_us``), the track times (event clock, µs) and their label maps (None: no pose), the objects' names
    and the hidden ones; ``tc_us`` the current time."""

    ev: object
    t_ext0_us: int
    n_ext: int
    tc_us: int
    times: np.ndarray
    maps: list
    names: list
    hidden: frozenset

    def __post_init__(self):
        self.times = np.asarray(self.times, np.int64)

    @cached_property
    def valid(self) -> np.ndarray:
        """Indices of the track times with a label map."""
        return np.array([i for i, m in enumerate(self.maps) if m is not None], np.int64)

    @cached_property
    def stack(self) -> np.ndarray:
        """The label maps of the :attr:`valid` times, stacked (n, H, W)."""
        return np.stack([self.maps[i] for i in self.valid]) if len(self.valid) else np.zeros((0, 1, 1), np.int8)

    def nearest_map(self, t_us: int) -> np.ndarray | None:
        """The label map of the track time nearest ``t_us`` (None: none has one)."""
        if not len(self.valid):
            return None
        return self.maps[self.valid[np.argmin(np.abs(self.times[self.valid].astype(np.int64) - int(t_us)))]]


@dataclass
class LineReading:
    """One line read: its events (ON / OFF counts over the extended span, binned), each shown object's track and
    the pooled lag."""

    line: KymoLine
    on: np.ndarray
    off: np.ndarray
    events: LineEvents
    tracks: list
    lag: LagEstimate


def read_line(span: SpanData, line: KymoLine, judge: bool = True) -> LineReading:
    """The events along ``line``, each shown object's crossings with it at the track times and the events' lag
    behind them (``judge`` False: without σ and verdict yet, see :func:`judge_reading`)."""
    on, off = bin_events(span.ev, line, span.t_ext0_us, span.n_ext, BIN_US)
    events = LineEvents(on.astype(np.float32) + off, (span.t_ext0_us - span.tc_us) / 1e3, BIN_US / 1e3)
    s, uv = line.samples()
    n_cols = on.shape[1]
    d_axis, _ = line.axes()
    cols = np.arange(n_cols, dtype=np.float64)
    uv_cols = np.column_stack([line.u0 + cols * d_axis[0], line.v0 + cols * d_axis[1]])
    t_ms = [(int(t) - span.tc_us) / 1e3 for t in span.times[span.valid]]
    labels, labels_cols = labels_along(span.stack, uv), labels_along(span.stack, uv_cols)
    tracks = []
    for k, name in enumerate(span.names):
        if name in span.hidden:
            continue
        crossings, dist = crossing_distances(labels, s, labels_cols, k)
        if not any(len(c) for c in crossings):
            continue
        pt_t = np.concatenate([np.full(len(c), t) for t, c in zip(t_ms, crossings)])
        segs = link_segments(t_ms, crossings)
        lag = estimate_lag(events, t_ms, dist, track_travel(segs, len(t_ms)), judge)
        tracks.append(EdgeTrack(name, object_color(k), pt_t, np.concatenate(crossings), segs, lag))
    lag = combine([tr.lag for tr in tracks], judge) if tracks else LagEstimate(None, weak=NO_TRACK, judged=True)
    return LineReading(line, on, off, events, tracks, lag)


def judge_reading(reading: LineReading) -> LineReading:
    """``reading`` with the σ and verdict of each track's lag and of the pooled one (in place)."""
    for est in [tr.lag for tr in reading.tracks] + [reading.lag]:
        judge(est)
    return reading
