"""The frame view's data: the window's event image, then its labels, overlays and scores; pure functions of a
:class:`~evpose.core.views.request.FrameRequest`.

A request is a snapshot (the scene sharing its data, with its own copy of the corrections, and the
view state), so the app computes frames in worker threads while the user keeps editing; stale
results are dropped by their serial. :class:`FrameComputer` caches the rasteriser between calls
(one instance per worker thread). A frame is computed in two stages that the app runs on two workers:
the event image (:meth:`FrameComputer.events_stages` -> :class:`EventFrame`, cheap) and the labels,
overlays and scores (:meth:`FrameComputer.overlay_stages`, the rasterisation), so a view paints the events
at once and the overlays when they are ready; :meth:`FrameComputer.frame` runs both.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from evpose.core.data.events import EventArray
from evpose.core.data.manifest import EVENTS_ONLY
from evpose.core.data.scene import Scene
from evpose.core.label import represent
from evpose.core.label.event_frames.counts import polarity_counts
from evpose.core.label.annotate import Annotator
from evpose.core.label.labels import Request, WindowLabels
from evpose.core.label.windows import Window
from evpose.core.label.overlay import (
    ObjectOverlay,
    axes_segments,
    box_segments,
    compose_masks_rgba,
    mask_contours,
    object_color,
)
from evpose.core.views.overlay_cache import OverlayCache, overlay_key
from evpose.core.views.request import FrameRequest, WindowReader, run_stages

__all__ = ["FrameData", "EventFrame", "FrameComputer", "FrameRequest", "run_stages", "inside_fraction",
           "MAX_PREFETCH_STEP_WINDOWS"]


@dataclass
class FrameData:
    """Everything the frame view draws for one window."""

    window: Window
    n_events: int
    image_rgb: np.ndarray | None         # (H, W, 3) uint8; None from the overlay stage alone
    counts: np.ndarray | None            # (H, W) int64: events per pixel (hover readout); None likewise
    labels: WindowLabels
    mask_rgba: np.ndarray | None         # (H, W, 4) uint8 composite of visible masks
    overlays: list[ObjectOverlay] = field(default_factory=list)
    inside_fraction: float | None = None  # share of the window's events on the (dilated) masks
    scores: dict = field(default_factory=dict)  # name -> evpose.core.align.score alignment score (None: undefined)
    compute_ms: float = 0.0


@dataclass
class EventFrame:
    """The cheap first stage of a frame: the window's event image, shown before the overlays."""

    window: Window
    n_events: int
    image_rgb: np.ndarray                # (H, W, 3) uint8
    counts: np.ndarray                   # (H, W) int64: events per pixel (hover readout)
    compute_ms: float = 0.0


#: :meth:`FrameComputer.prefetch_overlays` follows steps of at most this many windows (stepping, playback);
#: larger jumps (dragging the timeline) are not predicted.
MAX_PREFETCH_STEP_WINDOWS = 4


class FrameComputer(WindowReader):
    """Computes :class:`FrameData` (and its cheap first stage, :class:`EventFrame`) from requests; caches the
    rasteriser and per-object geometry between calls (use one instance per worker thread).

    Parameters
    ----------
    cache : evpose.core.data.event_cache.EventChunkCache, optional
        Decoded event blocks shared with other computers (thread-safe); windows are read through it
        and :meth:`prefetch` fills it ahead of the motion. Without it, windows are read from the store.
    raster_threads : int
        Threads of the frame's rasteriser (default 1; see :class:`~evpose.core.label.raster.Rasterizer`).
    """

    def __init__(self, cache=None, raster_threads: int = 1):
        super().__init__(cache)
        self.raster_threads = raster_threads
        self._annotator: Annotator | None = None
        self._key = None
        self._score_params = None
        self._last_events = None   # (store, t0, t1, representation) of the last event stage
        self.overlays_ahead = OverlayCache()   # overlay results of prefetch_overlays
        self._last_overlay = None  # (request, step_us) of the last overlay stage, for prefetch_overlays

    def _annotator_for(self, scene: Scene) -> Annotator:
        key = (id(scene.manifest),)
        if self._annotator is None or self._key != key:
            self._annotator = Annotator(scene, Request(keypoints=True, masks_visible=True, label_map=True, depth=True,
                                                               amodal=False),   # views show visible masks only
                                         raster_threads=self.raster_threads)
            self._key = key
        self._annotator.scene = scene
        return self._annotator

    def frame(self, req: FrameRequest) -> FrameData:
        """The whole frame at once: the event stage and the overlay stage, one :class:`FrameData`."""
        ev_frame = self.events_frame(req)
        data = run_stages(self.overlay_stages(req))
        return replace(data, image_rgb=ev_frame.image_rgb, counts=ev_frame.counts,
                       compute_ms=data.compute_ms + ev_frame.compute_ms)

    def events_frame(self, req: FrameRequest) -> EventFrame:
        """The event stage of ``req`` (always computed, never reused)."""
        self._last_events = None
        return run_stages(self.events_stages(req))

    def events_stages(self, req: FrameRequest):
        """The event stage (cheap: read, image, counts) for a worker that shows the events before the overlays.

        A generator (see :class:`~evpose.app.workers.LatestWorker`): yields None after reading the events (a
        checkpoint: a request superseded by then stops there) and returns the :class:`EventFrame`, or None
        when the window, representation and store equal the previous call's (a pose nudge: the view
        already shows these events)."""
        t_start = time.perf_counter()
        scene, view = req.scene, req.view
        cam = scene.camera
        w = view.window()
        self._note_motion(scene, view.t_us, view.window_us)
        key = (scene.events, w.t0_us, w.t1_us, view.representation)   # the store itself: ids are reused
        if self._last_events == key:
            return None
        ev = self._window_events(scene, w.t0_us, w.t1_us)
        yield None
        image = represent.to_rgb(view.representation, ev, cam.width, cam.height, w.t0_us, w.t1_us)
        pos, neg = polarity_counts(ev, cam.width, cam.height)
        self._last_events = key
        return EventFrame(w, len(ev), image, pos + neg, (time.perf_counter() - t_start) * 1e3)

    def overlay_stages(self, req: FrameRequest):
        """The overlay stage (the expensive part: rasterised labels, masks, contours, boxes, scores).

        A generator yielding None after the rasterisation (a checkpoint) and returning a
        :class:`FrameData` without the event image (``image_rgb`` and ``counts`` are None: the event
        stage provides them). A result that :meth:`prefetch_overlays` computed ahead for exactly this
        request (same scene, corrections, window and overlay settings) is returned at once."""
        prev, step_us = self._last_overlay or (None, 0)
        if prev is not None and prev.scene.events is req.scene.events and req.view.t_us != prev.view.t_us:
            step_us = req.view.t_us - prev.view.t_us
        self._last_overlay = (req, step_us)
        ahead = self.overlays_ahead.get(overlay_key(req)) if len(self.overlays_ahead) else None
        if ahead is not None:                  # computed ahead of the user: the same request's result
            return ahead
        data = yield from self._overlays(req)
        return data

    def _overlays(self, req: FrameRequest):
        """The overlay stage's computation (a generator, see :meth:`overlay_stages`)."""
        t_start = time.perf_counter()
        scene, view = req.scene, req.view
        cam = scene.camera
        w = view.window()
        ev = self._window_events(scene, w.t0_us, w.t1_us)
        if not scene.has_poses:                # an event-only scene: events, no labels (and no rasteriser)
            return FrameData(w, len(ev), None, None, WindowLabels(w, False, EVENTS_ONLY), None,
                             compute_ms=(time.perf_counter() - t_start) * 1e3)
        ann = self._annotator_for(scene)
        labels = ann.annotate(w)
        yield None
        overlays, mask_rgba, inside = [], None, None
        names = scene.object_names
        sigma_px = _label_sigma_px(scene, w.t_label_us, names) if labels.valid else None
        if labels.valid:
            shown = [n not in view.hidden for n in names]
            if "mask" in view.overlays:
                mask_rgba = compose_masks_rgba(labels.label_map, [object_color(k) for k in range(len(names))],
                                               view.mask_alpha, shown)
            for k, o in enumerate(labels.objects):
                if not shown[k]:
                    continue
                ov = ObjectOverlay(o.name, object_color(k))
                if sigma_px is not None and np.isfinite(sigma_px[k]):
                    ov.sigma_px = float(sigma_px[k])
                if o.in_view:
                    if "contour" in view.overlays:
                        ov.contours = mask_contours(o.mask_visible)
                    if "box" in view.overlays and o.corners_cam is not None:
                        ov.box_segments = box_segments(cam, o.corners_cam)
                    if "axes" in view.overlays:
                        model = scene.model(o.name)
                        ov.axes = axes_segments(cam, o.T_cam_obj, 0.5 * model.diameter_m, model.bbox_center_m)
                    if "center" in view.overlays and o.center_uv is not None and np.all(np.isfinite(o.center_uv)):
                        ov.center_uv = o.center_uv
                overlays.append(ov)
            inside = inside_fraction(ev, labels.label_map)
        scores = self._scores(scene, ev, labels)
        return FrameData(w, len(ev), None, None, labels, mask_rgba, overlays, inside, scores,
                         (time.perf_counter() - t_start) * 1e3)

    def release_prefetched(self) -> int:
        """Drop the overlays computed ahead (:attr:`overlays_ahead`; the worker computes more only after the next
        request). Call on the computer's own thread. Returns the bytes they held."""
        nb = self.overlays_ahead.nbytes
        self.overlays_ahead.clear()
        return nb

    def prefetch_overlays(self, should_stop=lambda: False) -> bool:
        """Compute the overlays of the next window in the direction and step of the last two requests
        (at most :data:`MAX_PREFETCH_STEP_WINDOWS` windows away) into :attr:`overlays_ahead`, for an idle
        worker: ``should_stop()`` is checked between stages and the work abandoned when it turns True.
        Returns True when a result was stored."""
        if self._last_overlay is None:
            return False
        req, step_us = self._last_overlay
        if not req.scene.has_poses or step_us == 0 or abs(step_us) > MAX_PREFETCH_STEP_WINDOWS * req.view.window_us:
            return False
        t_next = req.view.t_us + step_us
        store = req.scene.events
        if store.t_first_us is None or not store.t_first_us <= t_next <= store.t_last_us:
            return False
        nxt = replace(req, view=replace(req.view, t_us=int(t_next)))
        key = overlay_key(nxt)
        if key in self.overlays_ahead:
            return False
        gen = self._overlays(nxt)
        try:
            while True:
                if should_stop():
                    gen.close()
                    return False
                next(gen)
        except StopIteration as stop:
            self.overlays_ahead.put(key, stop.value)
            return True

    def _scores(self, scene: Scene, ev: EventArray, labels: WindowLabels) -> dict:
        """The window's alignment score per object (:mod:`core.score`, higher is better), from the
        label and depth images the frame already has: no second rasterisation."""
        from evpose.core.align.score import ScoreParams, score_window

        names = scene.object_names
        if not labels.valid or labels.label_map is None or labels.depth_m is None:
            return {n: None for n in names}
        if self._score_params is None or self._score_params[0] is not scene.camera:
            self._score_params = (scene.camera, ScoreParams().resolved(scene.camera))
        p = self._score_params[1]
        if len(ev) > p.max_events:
            ev = ev[::int(np.ceil(len(ev) / p.max_events))]
        res = score_window(ev, labels.label_map, labels.depth_m, len(names), p)
        return {n: (float(r.score) if r.valid else None) for n, r in zip(names, res)}

def _label_sigma_px(scene: Scene, t_label_us: int, names) -> np.ndarray | None:
    """Each object's label sigma on the image at ``t_label_us`` (px) from the document's stored sigmas; None when
    it stores none (no estimate with a sigma applied: nothing to show)."""
    if not scene.corrections.sigmas:
        return None
    from evpose.core.label.uncertainty import stored_label_sigmas

    return stored_label_sigmas(scene, np.array([t_label_us], np.int64), names).sigma_px[0]


def inside_fraction(ev: EventArray, label_map: np.ndarray, dilate_px: int = 2) -> float | None:
    """Share of the events that fall on any object's mask dilated by ``dilate_px`` pixels
    (None for an empty window)."""
    if len(ev) == 0 or label_map is None:
        return None
    import cv2

    mask = (label_map >= 0).astype(np.uint8)
    if dilate_px > 0:
        mask = cv2.dilate(mask, np.ones((2 * dilate_px + 1, 2 * dilate_px + 1), np.uint8))
    return float(mask[ev.y, ev.x].mean())
