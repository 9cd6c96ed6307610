"""The kymograph (an x-t / y-t slice of the events): the events near a line drawn across an object edge, binned
by position along the line and time, and each object's projected edge track on that line, so that a clock
offset shows as a shift in time between the event streaks and the tracks (and a skew as a slow drift).

A request (:class:`KymographRequest`) is a frame request (the session snapshot) plus the line and the span; the
app computes it on a worker thread with :meth:`KymographComputer.stages` (checkpoints between label maps).
Tracks come from the label maps (one z-buffered render per track time, the poses and clock in effect) sampled
along the line; the maps are cached by time and poses (byte-bounded), so moving the line, or a step in time,
renders only what is new. The readout (:mod:`~evpose.core.views.kymograph_lag`) is the lag of the event
streaks behind the tracks, per object and combined, with its 1σ or the reason it is too weak to read
(:mod:`~evpose.core.views.kymograph_confidence`); the default line is the first of the lines across the shown
objects, by evidence, that reads (:mod:`~evpose.core.views.kymograph_pick`).
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
from evpose.core.views.request import FrameRequest, WindowReader, run_stages
from evpose.core.views.kymograph_confidence import NO_TRACK
from evpose.core.views.kymograph_lag import MAX_LAG_MS, LagEstimate
from evpose.core.views.kymograph_line import KymoLine
from evpose.core.views.kymograph_pick import pick_default_line
from evpose.core.views.kymograph_read import (  # noqa: F401  (bin_events, link_segments: part of this API)
    BIN_US,
    EdgeTrack,
    LineReading,
    SpanData,
    bin_events,
    link_segments,
    read_line,
)
from evpose.core.views.spacetime_slices import SLICE_REQUEST, slice_key, slice_times

#: Edge tracks are sampled at this many times over the span (a step of 4 ms over the default 200 ms).
TRACK_SAMPLES = 50
#: The label maps kept for the tracks (int8, one per track time and pose set): at most this many bytes. A span's 50
#: maps of a DAVIS346 hold 4.4 MB, so this keeps two or three spans (a step back, the pose before a nudge); at 48 MB
#: it was the largest cache at rest after bench_memory's 10-minute session (47.6 MB, full).
LABEL_CACHE_BYTES = 12 << 20
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
    lag: LagEstimate = field(default_factory=lambda: LagEstimate(None, weak=NO_TRACK, judged=True))
    n_events: int = 0
    #: the default line: how many candidate lines were read to pick it (0: the user's line)
    lines_tried: int = 0
    compute_ms: float = 0.0
    #: the current window's event image (H, W, 3) uint8 and the silhouettes' contours at the current time
    #: ``[(name, rgb, [polyline (M, 2)])]``: where the user draws the line
    frame_rgb: np.ndarray | None = None
    frame_contours: list = field(default_factory=list)

    @property
    def lag_ms(self) -> float | None:
        """The combined lag of the events behind the tracks (ms; None: too weak to read, see ``lag.weak``)."""
        return self.lag.lag_ms


class LabelMapCache:
    """Label maps (int8) by :func:`~evpose.core.views.spacetime_slices.slice_key`, least recently used first out
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


def counts_rgb(on: np.ndarray, off: np.ndarray) -> np.ndarray:
    """White where no event, ``ON_RGB`` / ``OFF_RGB`` (darker where both) as the counts grow (uint8 RGB)."""
    img = np.full(on.shape + (3,), 1.0, np.float32)
    for counts, rgb in ((on, ON_RGB), (off, OFF_RGB)):
        a = np.clip(counts.astype(np.float32) / SATURATION_COUNT, 0.0, 1.0)[..., None]
        img *= 1.0 - a * (1.0 - np.asarray(rgb, np.float32) / 255.0)
    return np.round(img * 255.0).astype(np.uint8)


class KymographComputer(WindowReader):
    """Computes :class:`KymographData` from :class:`KymographRequest`; caches the annotator and the label maps
    (use one instance per worker thread).

    Parameters
    ----------
    cache : evpose.core.data.event_cache.EventChunkCache, optional
        Decoded event blocks shared with other computers; without it windows are read from the store.
    """

    def __init__(self, cache=None):
        super().__init__(cache)
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

    def release_caches(self) -> int:
        """Empty the label-map cache and drop the annotator (the view is out of sight and the app idle: both are
        made again on demand, ~30 ms for the annotator). Call on the computer's own thread. Returns the bytes the
        cache held."""
        nb = self.maps.nbytes
        self.maps.clear()
        self._ann = self._ann_key = None          # its rasteriser's per-pixel rays (~3.5 MB)
        return nb

    def stages(self, req: KymographRequest):
        """Generator: yields None after the event read and after every few label maps (checkpoints for a
        worker); returns the :class:`KymographData`."""
        t_start = time.perf_counter()
        scene, view = req.frame.scene, req.frame.view
        tc, half = int(view.t_us), int(req.span_us) // 2
        lag_us = int(MAX_LAG_MS * 1000)
        n_ext = -(-(2 * half + 2 * lag_us) // BIN_US)
        t_ext0 = tc - half - lag_us
        ev = self._window_events(scene, t_ext0, t_ext0 + n_ext * BIN_US)
        yield None
        times = slice_times(tc - half, 2 * half + 1, TRACK_SAMPLES, view.grid_origin_us)
        maps = [None] * len(times)            # an event-only scene: the events along the line, no tracks
        if scene.has_poses:
            ann = self._annotator(scene)
            T_co, T_bc, valid = ann.poses(times)
            for i, t in enumerate(times):
                maps[i] = self.maps.label_map(ann, int(t), T_co[i], T_bc[i]) if valid[i] else None
                if i % 8 == 7:
                    yield None
        span = SpanData(ev, t_ext0, n_ext, tc, times, maps, list(scene.object_names), frozenset(view.hidden))
        data = KymographData(tc, KymoLine(0, 0, 0, 0), req.line is None, 2 * half, BIN_US / 1e3, -half / 1e3,
                             np.zeros((0, 0), np.uint16), np.zeros((0, 0), np.uint16), np.zeros((0, 0, 3), np.uint8))
        data.frame_rgb, data.frame_contours = self._frame(scene, view, ev, times, maps)
        if req.line is not None:
            line = KymoLine(*(float(c) for c in req.line)).clipped(scene.camera.width, scene.camera.height)
            reading = None if line is None else read_line(span, line)
        else:
            reading, data.lines_tried = pick_default_line(span, view)
        if reading is not None:
            self._fill(data, reading)
        data.compute_ms = (time.perf_counter() - t_start) * 1e3
        return data

    @staticmethod
    def _fill(data: KymographData, reading: LineReading) -> None:
        """The image, tracks and lags of ``reading`` into ``data``."""
        lag_rows = int(MAX_LAG_MS * 1000) // BIN_US
        r0, r1 = lag_rows, lag_rows + -(-data.span_us // BIN_US)
        data.line = reading.line
        data.counts_on, data.counts_off = reading.on[r0:r1], reading.off[r0:r1]
        data.image_rgb = counts_rgb(data.counts_on, data.counts_off)
        data.t_first_ms = reading.events.t_first_ms + r0 * BIN_US / 1e3
        data.n_events = int(data.counts_on.sum() + data.counts_off.sum())
        data.tracks = reading.tracks
        data.lag = reading.lag

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
