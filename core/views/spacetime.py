"""The space-time view's data: the events around the current time as an (x, y, t) cloud, each event's distance
to the nearest silhouette at its own time (the view's band), and the objects' silhouette tubes and surfaces.

:class:`SpaceTimeComputer` runs as a staged computation on the app's space-time worker (one instance per worker
thread): silhouette slices sit on a fixed time grid and are cached by time and poses
(:mod:`.spacetime_slices`), the band's merged fields and the tubes' surfaces likewise (:mod:`.spacetime_band`,
:mod:`.spacetime_surface`), and the worker's idle time computes the slices of the next steps.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evpose.core.label.annotate import Annotator
from evpose.core.label.overlay import object_color
from evpose.core.data.scene import Scene
from evpose.core.views.request import FrameRequest, WindowReader, run_stages
from evpose.core.views.spacetime_band import MergedFieldCache, events_band
from evpose.core.views.spacetime_slices import SLICE_REQUEST, SliceCache, slice_key, slice_times
from evpose.core.views.spacetime_surface import SurfaceCache, tubes_and_surfaces

__all__ = ["SpaceTimeData", "SpaceTimeComputer", "SPACETIME_PREFETCH_WINDOWS"]


@dataclass
class SpaceTimeData:
    """Events around the current time as an (x, y, t) cloud, and the objects' silhouette tubes.

    ``edge_px`` and ``nearest`` (None when not computed) say how far each event is from the nearest shown
    silhouette at its own time (px; inf: none within reach) and whose it is (index into ``object_colors``, the
    scene's objects in order; -1: none): the view draws the events within its band in their object's colour."""

    t_center_us: int
    points: np.ndarray        # (N, 3) float32: x px, y px, t ms relative to t_center
    polarity: np.ndarray      # (N,) uint8
    n_total: int              # events in the span before decimation
    tubes: list[tuple[str, tuple[int, int, int], list[np.ndarray]]]  # (name, colour, polylines (M, 3))
    span_us: int = 0
    edge_px: np.ndarray | None = None    # (N,) float32
    nearest: np.ndarray | None = None    # (N,) int8
    object_colors: tuple = ()            # (r, g, b) 0-255 per object index
    surfaces: list = field(default_factory=list)  # (name, colour, vertices (V, 3) float32, triangles (F, 3) uint32)



#: :meth:`SpaceTimeComputer.prefetch_spacetime` computes the slices of the span this many windows ahead.
SPACETIME_PREFETCH_WINDOWS = 2


class SpaceTimeComputer(WindowReader):
    """Computes :class:`SpaceTimeData` from requests; caches silhouette slices, the band's fields and the tubes'
    surfaces between calls, each bounded in bytes (one instance per worker thread; ``cache``: see
    :class:`~evpose.core.views.request.WindowReader`)."""

    def __init__(self, cache=None):
        super().__init__(cache)
        #: silhouette slices of the space-time view by time and poses (byte-bounded: ``slice_cache.nbytes``)
        self.slice_cache = SliceCache()
        #: per slice, the objects' merged signed fields (events' band) and the joined contours (tube surfaces)
        self.field_cache = MergedFieldCache()
        self.surface_cache = SurfaceCache()
        self._slice_annotator: Annotator | None = None
        self._slice_scene_key = None
        self._last_spacetime = None   # the last space-time request, for prefetch_spacetime

    def spacetime(self, req: FrameRequest) -> SpaceTimeData:
        """The space-time data at once (:meth:`spacetime_stages` run to its end)."""
        return run_stages(self.spacetime_stages(req))

    def _slices_annotator(self, scene: Scene) -> Annotator:
        """The annotator of the silhouette slices (label map only, :data:`SLICE_REQUEST`), for ``scene``."""
        key = (id(scene.manifest),)
        if self._slice_annotator is None or self._slice_scene_key != key:
            self._slice_annotator = Annotator(scene, SLICE_REQUEST)
            self._slice_scene_key = key
            self.slice_cache.clear()
            self.field_cache.clear()
            self.surface_cache.clear()
        self._slice_annotator.scene = scene
        return self._slice_annotator

    def release_caches(self) -> int:
        """Empty the slice, field and surface caches and drop the slices' annotator (the view is out of sight and
        the app idle: they are made again on demand, ~30 ms for the annotator; the worker prefetches only after the
        next request). Call on the computer's own thread. Returns the bytes the caches held."""
        nb = self.slice_cache.nbytes + self.field_cache.nbytes + self.surface_cache.nbytes
        self.slice_cache.clear()
        self.field_cache.clear()
        self.surface_cache.clear()
        self._slice_annotator = self._slice_scene_key = None      # its rasteriser's per-pixel rays (~3.5 MB)
        return nb

    def spacetime_stages(self, req: FrameRequest):
        """The space-time data as a generator of checkpoints (yields None after the event read and after
        each silhouette slice, so a worker drops a superseded request early) returning :class:`SpaceTimeData`.

        Silhouette slices sit on a fixed grid of ``span / slices`` from the window grid's origin (so a step
        of the current time reuses the slices it still covers) and are cached by their poses: a pose or
        clock change recomputes them, a step recomputes only the new ones (see :attr:`slice_cache` and
        :meth:`prefetch_spacetime`).
        """
        self._last_spacetime = req
        scene, view = req.scene, req.view
        span = int(view.spacetime_span_us)
        t0 = int(view.t_us - span // 2)
        ev = self._window_events(scene, t0, t0 + span)
        self._note_motion(scene, view.t_us, view.window_us)
        yield None
        n = len(ev)
        if n > view.spacetime_budget:
            idx = np.linspace(0, n - 1, view.spacetime_budget).astype(np.int64)
            ev = ev[idx]
        pts = np.empty((len(ev), 3), np.float32)
        pts[:, 0] = ev.x
        pts[:, 1] = ev.y
        pts[:, 2] = (ev.t - view.t_us).astype(np.float32) * 1e-3
        slices = []
        if scene.has_poses:                  # an event-only scene: the cloud alone
            times = slice_times(t0, span, view.spacetime_slices, view.grid_origin_us)
            ann = self._slices_annotator(scene)
            T_co, T_bc, valid = ann.poses(times)
            for i, t in enumerate(times):
                if valid[i]:
                    slices.append((int(t), self.slice_cache.slice(ann, int(t), T_co[i], T_bc[i])))
                yield None
        names = scene.object_names
        colors = tuple(object_color(k) for k in range(len(names)))
        tubes, surfaces = tubes_and_surfaces(slices, names, view.hidden, colors, view.t_us, self.surface_cache)
        edge_px, nearest = events_band(ev, slices, names, view.hidden, scene.camera.width, scene.camera.height,
                                       self.field_cache)
        return SpaceTimeData(int(view.t_us), pts, ev.p.copy(), n, tubes, span, edge_px, nearest, colors, surfaces)

    def prefetch_spacetime(self, should_stop=lambda: False) -> int:
        """Compute into :attr:`slice_cache` the silhouette slices that the span of the last space-time request
        will need after up to :data:`SPACETIME_PREFETCH_WINDOWS` steps of one window in its direction of motion
        (both ways before any motion), for an idle worker: ``should_stop()`` is checked before every slice.
        Returns the slices computed."""
        req = self._last_spacetime
        if req is None or not req.scene.has_poses or self._motion is None or self._motion[0] is not req.scene.events:
            return 0
        scene, view = req.scene, req.view
        span, w = int(view.spacetime_span_us), int(view.window_us)
        direction = self._motion[2]
        ahead = [d * k * w for k in range(1, SPACETIME_PREFETCH_WINDOWS + 1) for d in ((direction,) if direction
                                                                                       else (1, -1))]
        t0 = int(view.t_us - span // 2)
        times = np.unique(np.concatenate([slice_times(t0 + a, span, view.spacetime_slices, view.grid_origin_us)
                                          for a in ahead]))
        if direction < 0:
            times = times[::-1]                  # the nearest first
        ann = self._slices_annotator(scene)
        T_co, T_bc, valid = ann.poses(times)
        n = 0
        for i, t in enumerate(times):
            if should_stop():
                break
            if valid[i] and slice_key(int(t), T_co[i]) not in self.slice_cache:
                value = self.slice_cache.slice(ann, int(t), T_co[i], T_bc[i])
                self.field_cache.merged(value, scene.object_names, view.hidden, scene.camera.height,
                                        scene.camera.width)
                n += 1
        return n
