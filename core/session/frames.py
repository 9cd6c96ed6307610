"""Frame and space-time computation for the views: pure functions of a :class:`FrameRequest`.

A request is a snapshot (the scene sharing its data, with its own copy of the corrections, and the
view state), so the app computes frames in worker threads while the user keeps editing; stale
results are dropped by their serial. :class:`FrameComputer` caches the rasteriser between calls
(one instance per worker thread).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from evpose.core.data.events import EventArray
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
from evpose.core.session.view_state import ViewState


@dataclass
class FrameData:
    """Everything the frame view draws for one window."""

    window: Window
    n_events: int
    image_rgb: np.ndarray                # (H, W, 3) uint8
    counts: np.ndarray                   # (H, W) int64: events per pixel (hover readout)
    labels: WindowLabels
    mask_rgba: np.ndarray | None         # (H, W, 4) uint8 composite of visible masks
    overlays: list[ObjectOverlay] = field(default_factory=list)
    inside_fraction: float | None = None  # share of the window's events on the (dilated) masks
    scores: dict = field(default_factory=dict)  # name -> evpose.core.align.score alignment score (None: undefined)
    compute_ms: float = 0.0


@dataclass
class SpaceTimeData:
    """Events around the current time as an (x, y, t) cloud, and the objects' silhouette tubes."""

    t_center_us: int
    points: np.ndarray        # (N, 3) float32: x px, y px, t ms relative to t_center
    polarity: np.ndarray      # (N,) uint8
    n_total: int              # events in the span before decimation
    tubes: list[tuple[str, tuple[int, int, int], list[np.ndarray]]]  # (name, colour, polylines (M, 3))
    span_us: int = 0


@dataclass(frozen=True)
class FrameRequest:
    """What to compute: a snapshot of the session (see :meth:`Session.request`); ``serial`` orders
    the requests so a late result of an older one is dropped."""

    scene: Scene       # a snapshot: shares data, owns a copy of the corrections
    view: ViewState
    serial: int = 0


class FrameComputer:
    """Computes :class:`FrameData` and :class:`SpaceTimeData` from requests; caches the
    rasteriser and per-object geometry between calls (use one instance per worker thread)."""

    def __init__(self):
        self._annotator: Annotator | None = None
        self._key = None
        self._score_params = None

    def _annotator_for(self, scene: Scene) -> Annotator:
        key = (id(scene.manifest),)
        if self._annotator is None or self._key != key:
            self._annotator = Annotator(scene, Request(keypoints=True, masks_visible=True, label_map=True, depth=True,
                                                               amodal=False))   # views show visible masks only
            self._key = key
        self._annotator.scene = scene
        return self._annotator

    def frame(self, req: FrameRequest) -> FrameData:
        t_start = time.perf_counter()
        scene, view = req.scene, req.view
        cam = scene.camera
        w = view.window()
        ev = scene.events.window(w.t0_us, w.t1_us)
        image = represent.to_rgb(view.representation, ev, cam.width, cam.height, w.t0_us, w.t1_us)
        pos, neg = polarity_counts(ev, cam.width, cam.height)
        counts = pos + neg
        ann = self._annotator_for(scene)
        labels = ann.annotate(w)
        overlays, mask_rgba, inside = [], None, None
        names = scene.object_names
        if labels.valid:
            shown = [n not in view.hidden for n in names]
            if "mask" in view.overlays:
                mask_rgba = compose_masks_rgba(labels.label_map, [object_color(k) for k in range(len(names))],
                                               view.mask_alpha, shown)
            for k, o in enumerate(labels.objects):
                if not shown[k]:
                    continue
                ov = ObjectOverlay(o.name, object_color(k))
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
        return FrameData(w, len(ev), image, counts, labels, mask_rgba, overlays, inside, scores,
                         (time.perf_counter() - t_start) * 1e3)

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

    def spacetime(self, req: FrameRequest) -> SpaceTimeData:
        scene, view = req.scene, req.view
        span = int(view.spacetime_span_us)
        t0 = int(view.t_us - span // 2)
        ev = scene.events.window(t0, t0 + span)
        n = len(ev)
        if n > view.spacetime_budget:
            idx = np.linspace(0, n - 1, view.spacetime_budget).astype(np.int64)
            ev = ev[idx]
        pts = np.empty((len(ev), 3), np.float32)
        pts[:, 0] = ev.x
        pts[:, 1] = ev.y
        pts[:, 2] = (ev.t - view.t_us).astype(np.float32) * 1e-3
        tubes = []
        n_slices = max(int(view.spacetime_slices), 2)
        times = t0 + (np.arange(n_slices) + 0.5) * (span / n_slices)
        times = np.rint(times).astype(np.int64)
        ann = self._annotator_for(scene)
        T_co, T_bc, valid = ann.poses(times)
        per_obj: dict[str, list[np.ndarray]] = {name: [] for name in scene.object_names}
        for i, t in enumerate(times):
            if not valid[i]:
                continue
            lab = ann.annotate(Window(-1, int(t), int(t) + 1, int(t)), pose=(T_co[i], T_bc[i], True))
            for o in lab.objects:
                if o.name in view.hidden or not o.in_view:
                    continue
                for c in mask_contours(o.mask_visible):
                    poly = np.empty((len(c), 3), np.float32)
                    poly[:, :2] = c
                    poly[:, 2] = (t - view.t_us) * 1e-3
                    per_obj[o.name].append(poly)
        for k, name in enumerate(scene.object_names):
            if per_obj[name]:
                tubes.append((name, object_color(k), per_obj[name]))
        return SpaceTimeData(int(view.t_us), pts, ev.p.copy(), n, tubes, span)


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
