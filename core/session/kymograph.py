"""The kymograph (an x-t / y-t slice of the events): the events near a line drawn across an object edge, binned
by position along the line and time, and each object's projected edge track on that line, so that a clock
offset shows as a shift in time between the event streaks and the tracks (and a skew as a slow drift).

A request (:class:`KymographRequest`) is a frame request (the session snapshot) plus the line and the span; the
app computes it on a worker thread with :meth:`KymographComputer.stages` (checkpoints between label maps).
Tracks come from the label maps (one z-buffered render per track time, the poses and clock in effect) sampled
along the line; the maps are cached by time and poses (byte-bounded), so moving the line, or a step in time,
renders only what is new. The readout (:mod:`~evpose.core.session.kymograph_lag`) is the lag of the event
streaks behind the tracks, per object and combined.
"""
from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from evpose.core.label import represent
from evpose.core.label.annotate import Annotator
from evpose.core.label.overlay import mask_contours, object_color
from evpose.core.label.windows import Window
from evpose.core.session.frames import FrameRequest, run_stages
from evpose.core.session.kymograph_lag import (
    MAX_LAG_MS,
    LagEstimate,
    combine,
    contrast_density,
    estimate_lag,
    signed_edge_distance,
)
from evpose.core.session.kymograph_line import KymoLine, default_line, edge_crossings, labels_along
from evpose.core.session.spacetime_slices import SLICE_REQUEST, slice_key, slice_times

#: Events within this distance across the line (px) are binned.
HALF_WIDTH_PX = 1.0
#: Time bins of the image, µs.
BIN_US = 1_000
#: Edge tracks are sampled at this many times over the span (a step of 4 ms over the default 200 ms).
TRACK_SAMPLES = 50
#: Crossings at consecutive track times closer than this (px) are joined into one track line.
LINK_PX = 8.0
#: The label maps kept for the tracks (int8, one per track time and pose set): at most this many bytes.
LABEL_CACHE_BYTES = 48 << 20
#: The default line is placed from the silhouettes this far before and after the current time (µs).
MOTION_PROBE_US = 10_000
#: Event colours of the image (RGB): dark, so the objects' coloured tracks stand out; ON warm, OFF cool.
ON_RGB, OFF_RGB = (150, 40, 40), (40, 60, 150)
#: Events per bin at which a bin's colour saturates.
SATURATION_COUNT = 3.0


@dataclass(frozen=True)
class KymographRequest:
    """What to compute: the session snapshot (``frame``), the line ``(u0, v0, u1, v1)`` px (None: a default line
    across the selected or fastest-moving object) and the span around the current time (µs)."""

    frame: FrameRequest
    line: tuple[float, float, float, float] | None = None
    span_us: int = 200_000

    @property
    def serial(self) -> int:
        return self.frame.serial


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


@dataclass
class KymographData:
    """Display-ready kymograph: rows are time bins (``t_first_ms + i * bin_ms``, relative to ``t_center_us``),
    columns positions along the line (column ``c`` at ``s = c`` px)."""

    t_center_us: int
    line: KymoLine
    auto_line: bool               # True: the default line (the user drew none)
    span_us: int
    bin_ms: float
    t_first_ms: float
    counts_on: np.ndarray         # (n_t, n_s) uint16
    counts_off: np.ndarray        # (n_t, n_s) uint16
    image_rgb: np.ndarray         # (n_t, n_s, 3) uint8
    tracks: list[EdgeTrack] = field(default_factory=list)
    lag: LagEstimate = field(default_factory=lambda: LagEstimate(None))
    n_events: int = 0
    compute_ms: float = 0.0
    #: the current window's event image (H, W, 3) uint8 and the silhouettes' contours at the current time
    #: ``[(name, rgb, [polyline (M, 2)])]``: where the user draws the line
    frame_rgb: np.ndarray | None = None
    frame_contours: list = field(default_factory=list)

    @property
    def lag_ms(self) -> float | None:
        """The combined lag of the events behind the tracks (ms; None: not measurable here)."""
        return self.lag.lag_ms


class LabelMapCache:
    """Label maps (int8) by :func:`~evpose.core.session.spacetime_slices.slice_key`, least recently used first out
    beyond ``max_bytes``; ``hits`` / ``misses`` count the lookups."""

    def __init__(self, max_bytes: int = LABEL_CACHE_BYTES):
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict = OrderedDict()
        self.nbytes = 0
        self.hits = self.misses = 0

    def __len__(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        self._items.clear()
        self.nbytes = 0

    def label_map(self, ann: Annotator, t_us: int, T_cam_obj: np.ndarray, T_base_cam: np.ndarray) -> np.ndarray:
        """The label map at ``t_us`` with these poses (-1 background), cached."""
        key = slice_key(t_us, T_cam_obj)
        hit = self._items.get(key)
        if hit is not None:
            self._items.move_to_end(key)
            self.hits += 1
            return hit
        self.misses += 1
        lab = ann.annotate(Window(-1, int(t_us), int(t_us) + 1, int(t_us)), pose=(T_cam_obj, T_base_cam, True))
        H, W = ann.camera.height, ann.camera.width
        lm = np.full((H, W), -1, np.int8) if lab.label_map is None else lab.label_map.astype(np.int8)
        self._items[key] = lm
        self.nbytes += lm.nbytes + len(key[1])
        while self.nbytes > self.max_bytes and len(self._items) > 1:
            k, v = self._items.popitem(last=False)
            self.nbytes -= v.nbytes + len(k[1])
        return lm


def bin_events(ev, line: KymoLine, t_first_us: int, n_rows: int, bin_us: int,
               half_width_px: float = HALF_WIDTH_PX) -> tuple[np.ndarray, np.ndarray]:
    """ON and OFF counts ``(n_rows, n_cols)`` uint16 of the events within ``half_width_px`` of ``line``: rows are
    ``bin_us`` time bins from ``t_first_us``, column ``c`` holds positions ``s`` in ``[c - 0.5, c + 0.5)``."""
    n_cols = int(np.floor(line.length + 0.5)) + 1
    on = np.zeros((n_rows, n_cols), np.uint16)
    off = np.zeros((n_rows, n_cols), np.uint16)
    if len(ev) == 0:
        return on, off
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


def counts_rgb(on: np.ndarray, off: np.ndarray) -> np.ndarray:
    """White where no event, ``ON_RGB`` / ``OFF_RGB`` (darker where both) as the counts grow (uint8 RGB)."""
    img = np.full(on.shape + (3,), 1.0, np.float32)
    for counts, rgb in ((on, ON_RGB), (off, OFF_RGB)):
        a = np.clip(counts.astype(np.float32) / SATURATION_COUNT, 0.0, 1.0)[..., None]
        img *= 1.0 - a * (1.0 - np.asarray(rgb, np.float32) / 255.0)
    return np.round(img * 255.0).astype(np.uint8)


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


class KymographComputer:
    """Computes :class:`KymographData` from :class:`KymographRequest`; caches the annotator and the label maps
    (use one instance per worker thread).

    Parameters
    ----------
    cache : evpose.core.data.event_cache.EventChunkCache, optional
        Decoded event blocks shared with other computers; without it windows are read from the store.
    """

    def __init__(self, cache=None):
        self.cache = cache
        self.maps = LabelMapCache()
        self._ann: Annotator | None = None
        self._ann_key = None

    def kymograph(self, req: KymographRequest) -> KymographData:
        """The whole computation at once (:meth:`stages` run to its end)."""
        return run_stages(self.stages(req))

    def _annotator(self, scene) -> Annotator:
        key = (id(scene.manifest),)
        if self._ann is None or self._ann_key != key:
            self._ann, self._ann_key = Annotator(scene, SLICE_REQUEST), key
            self.maps.clear()
        self._ann.scene = scene
        return self._ann

    def _events(self, scene, t0_us: int, t1_us: int):
        if self.cache is not None:
            return self.cache.window(scene.events, t0_us, t1_us)
        return scene.events.window(t0_us, t1_us)

    def stages(self, req: KymographRequest):
        """Generator: yields None after the event read and after every few label maps (checkpoints for a
        worker); returns the :class:`KymographData`."""
        t_start = time.perf_counter()
        scene, view = req.frame.scene, req.frame.view
        tc, half = int(view.t_us), int(req.span_us) // 2
        lag_us = int(MAX_LAG_MS * 1000)
        n_ext = -(-(2 * half + 2 * lag_us) // BIN_US)
        t_ext0 = tc - half - lag_us
        ev = self._events(scene, t_ext0, t_ext0 + n_ext * BIN_US)
        yield None
        ann = self._annotator(scene)
        times = slice_times(tc - half, 2 * half + 1, TRACK_SAMPLES, view.grid_origin_us)
        T_co, T_bc, valid = ann.poses(times)
        maps = []
        for i, t in enumerate(times):
            maps.append(self.maps.label_map(ann, int(t), T_co[i], T_bc[i]) if valid[i] else None)
            if i % 8 == 7:
                yield None
        line, auto = self._line(req, ann, times, maps, view)
        data = KymographData(tc, line or KymoLine(0, 0, 0, 0), auto, 2 * half, BIN_US / 1e3, -half / 1e3,
                             np.zeros((0, 0), np.uint16), np.zeros((0, 0), np.uint16), np.zeros((0, 0, 3), np.uint8))
        data.frame_rgb, data.frame_contours = self._frame(scene, view, ev, times, maps)
        if line is not None:
            self._fill(data, scene, view, ev, t_ext0, n_ext, times, maps)
        data.compute_ms = (time.perf_counter() - t_start) * 1e3
        return data

    def _fill(self, data: KymographData, scene, view, ev, t_ext0: int, n_ext: int, times, maps) -> None:
        """The image, tracks and lags of ``data.line`` into ``data``."""
        tc, lag_rows = int(view.t_us), int(MAX_LAG_MS * 1000) // BIN_US
        on, off = bin_events(ev, data.line, t_ext0, n_ext, BIN_US)
        density = contrast_density(on.astype(np.float32) + off)
        r0, r1 = lag_rows, lag_rows + -(-data.span_us // BIN_US)
        data.counts_on, data.counts_off = on[r0:r1], off[r0:r1]
        data.image_rgb = counts_rgb(data.counts_on, data.counts_off)
        data.t_first_ms = (t_ext0 - tc) / 1e3 + r0 * BIN_US / 1e3
        data.n_events = int(data.counts_on.sum() + data.counts_off.sum())
        data.tracks = self._tracks(scene, view, data.line, times, maps, density, t_ext0 - tc, data.n_events)
        data.lag = combine([tr.lag for tr in data.tracks])

    def _frame(self, scene, view, ev, times, maps) -> tuple[np.ndarray, list]:
        """The current window's event image and the shown objects' contours at the track time nearest now."""
        cam = scene.camera
        w = view.window()
        i0, i1 = np.searchsorted(ev.t, [w.t0_us, w.t1_us])
        rgb = represent.to_rgb("polarity", ev[int(i0):int(i1)], cam.width, cam.height, w.t0_us, w.t1_us)
        ok = [i for i, m in enumerate(maps) if m is not None]
        if not ok:
            return rgb, []
        lm = maps[min(ok, key=lambda i: abs(int(times[i]) - int(view.t_us)))]
        contours = [(name, object_color(k), mask_contours(lm == k)) for k, name in enumerate(scene.object_names)
                    if name not in view.hidden]
        return rgb, [c for c in contours if c[2]]

    def _line(self, req: KymographRequest, ann: Annotator, times, maps, view) -> tuple[KymoLine | None, bool]:
        """The requested line clipped to the image, else the default line; and whether it is the default."""
        cam = ann.camera
        if req.line is not None:
            return KymoLine(*(float(c) for c in req.line)).clipped(cam.width, cam.height), False
        ok = [i for i, m in enumerate(maps) if m is not None]
        if not ok:
            return None, True
        tc = int(view.t_us)

        def nearest(t):
            return maps[min(ok, key=lambda i: abs(int(times[i]) - t))]

        names = ann.names
        shown = [k for k, n in enumerate(names) if n not in view.hidden]
        preferred = names.index(view.selected) if view.selected in names and view.selected not in view.hidden else None
        line = default_line(nearest(tc), nearest(tc - MOTION_PROBE_US), nearest(tc + MOTION_PROBE_US), len(names),
                            preferred, shown=shown)
        return line, True

    def _tracks(self, scene, view, line: KymoLine, times, maps, density, t_ext0_rel_us: int,
                n_events: int) -> list[EdgeTrack]:
        """Each shown object's crossings with ``line`` at the track times and the events' lag behind them."""
        names = scene.object_names
        s, uv = line.samples()
        n_cols = density.shape[1]
        d_axis, _ = line.axes()
        cols = np.arange(n_cols, dtype=np.float64)
        uv_cols = np.column_stack([line.u0 + cols * d_axis[0], line.v0 + cols * d_axis[1]])
        crossings: list[list[np.ndarray]] = [[] for _ in names]
        dist: list[list[np.ndarray]] = [[] for _ in names]
        t_ms = []
        for t, lm in zip(times, maps):
            if lm is None:
                continue
            t_ms.append((int(t) - int(view.t_us)) / 1e3)
            at_cols = labels_along(lm, uv_cols)
            for k, c in enumerate(edge_crossings(labels_along(lm, uv), s, len(names))):
                crossings[k].append(c)
                dist[k].append(signed_edge_distance(at_cols == k, c, n_cols))
        tracks = []
        for k, name in enumerate(names):
            if name in view.hidden or not any(len(c) for c in crossings[k]):
                continue
            pt_t = np.concatenate([np.full(len(c), t) for t, c in zip(t_ms, crossings[k])])
            pt_s = np.concatenate(crossings[k])
            segs = link_segments(t_ms, crossings[k])
            lag = estimate_lag(density, t_ext0_rel_us / 1e3, BIN_US / 1e3, t_ms, np.array(dist[k]), n_events,
                               track_travel(segs, len(t_ms)))
            tracks.append(EdgeTrack(name, object_color(k), pt_t, pt_s, segs, lag))
        return tracks
