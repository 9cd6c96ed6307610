"""One event window -> every label of every object that needs one.

Products (computed only when requested, see :class:`~evpose.core.label.labels.Request`):

* ``T_cam_obj`` at the window's label time (always);
* the 8 corners of the object's 3D box (optionally enlarged by a margin), in the camera frame
  and projected with the camera's distortion; the projected object centre;
* full (amodal) and visible (modal) masks from the z-buffer rasteriser, a per-pixel label map
  of object indices, pixel counts and the visible fraction, tight 2D boxes of both masks;
* the indices of the window's events that fall on each object's visible mask.

Work left out where the scene does not need it: objects whose 3D box is outside the view are
culled before rasterising; all objects are rasterised once per window (one z-buffer gives every
visible mask); a full mask is needed only for an object that another object actually hides
somewhere: a visible pixel of another object whose ray lies inside the object's projected 3D box
(otherwise full == visible, :mod:`evpose.core.label.visibility`), so a single-object scene or objects
side by side never render twice. ``Rasterizer.render_objects(want_amodal=True)`` (every object's amodal
mask from the z-buffer's pass) was measured and is not used by default: on the 5-object real-mesh scene it
made E-POSE exports slower (9.0 against 11.6 windows/s) although nothing was hidden; rasterisers and
per-object geometry are cached.
Windows whose label time falls outside the trajectory get no label, with the reason.
"""
from __future__ import annotations

import numpy as np

from evpose.core.data.camera import CameraModel
from evpose.core.data.clock import ClockModel
from evpose.core.data.events import EventArray
from evpose.core.data.geometry import apply_T
from evpose.core.label.labels import ObjectLabel, Request, WindowLabels, label_poses, mask_bbox
from evpose.core.label.raster import Rasterizer
from evpose.core.label.visibility import box_in_view, boxes_overlap, projected_box, rays_in_box
from evpose.core.label.windows import Window


class Annotator:
    """Computes :class:`WindowLabels` for windows of one scene; caches what windows share.

    Parameters
    ----------
    scene : evpose.core.data.scene.Scene
    request : Request
    camera : CameraModel, optional
        Output camera (default: the scene's raw camera).
    objects : list of str, optional
        Objects to label (default: all).
    clock : ClockModel, optional
        Clock override (default: the scene's clock in effect).
    raster_threads : int
        Threads of the rasteriser per window (:class:`~evpose.core.label.raster.Rasterizer`; default 1).
    """

    def __init__(self, scene, request: Request = Request(), camera: CameraModel | None = None,
                 objects=None, clock: ClockModel | None = None, raster_threads: int = 1):
        self.scene = scene
        self.raster_threads = raster_threads
        self.request = request
        self.camera = camera or scene.camera
        self.names = list(objects) if objects is not None else scene.object_names
        self.clock = clock
        self._raster: Rasterizer | None = None
        self._geometry = {}
        for n in self.names:
            m = scene.raster_model(n)
            corners = m.bbox_corners(request.margin_m)
            self._geometry[n] = (m, corners, m.bbox_center_m)

    @property
    def raster(self) -> Rasterizer:
        if self._raster is None:
            self._raster = Rasterizer(self.camera, threads=self.raster_threads)
        return self._raster

    def poses(self, t_label_us) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(T_cam_obj (N, K, 4, 4), T_base_cam (N, 4, 4), valid (N,))`` at label times."""
        return label_poses(self.scene, t_label_us, self.names, self.clock)

    def no_label_reason(self, t_label_us: int) -> str:
        """Why there is no label at ``t_label_us``: outside the trajectory or in a hole of it."""
        reasons = getattr(self.scene, "unlabeled_reasons", None)
        r = reasons(np.array([t_label_us], np.int64), self.clock)[0] if reasons is not None else None
        return r or "label time outside the trajectory (no extrapolation)"

    def annotate(self, window: Window, events: EventArray | None = None, *,
                 pose: tuple[np.ndarray, np.ndarray, bool] | None = None) -> WindowLabels:
        """Labels of one window. ``events`` are needed only for ``segment_events``.

        ``pose`` (``T_cam_obj (K, 4, 4)``, ``T_base_cam``, ``valid``) may be passed when the
        caller already interpolated poses for many windows at once.
        """
        if pose is None:
            T_co, T_bc, valid = self.poses([window.t_label_us])
            T_co, T_bc, valid = T_co[0], T_bc[0], bool(valid[0])
        else:
            T_co, T_bc, valid = pose
        if not valid:
            return WindowLabels(window, False, self.no_label_reason(window.t_label_us))
        req = self.request
        labels = WindowLabels(window, True, T_base_cam=T_bc)
        boxes = self._box_labels(labels, T_co)
        if not req.needs_raster:
            return labels
        visible = [k for k, lab in enumerate(labels.objects) if lab.in_view]
        # amodal masks from the z-buffer's pass only on request: with the real YCB meshes (tile path) that pass
        # costs a full mask per object, more than rendering the few hidden ones (bench_export, ycb_5obj_5s)
        label_map, counts, amodal = self._label_map(labels, visible, T_co, False)
        self._mask_labels(labels, visible, T_co, boxes, label_map, counts, amodal)
        if req.label_map:
            labels.label_map = label_map
        if req.segment_events:
            self._segment_events(labels, label_map, events)
        return labels

    def _box_labels(self, labels: WindowLabels, T_co: np.ndarray) -> list:
        """One :class:`ObjectLabel` per object (pose, whether its 3D box is in view, and the box corners and
        centre in the camera and in pixels when keypoints are requested) appended to ``labels``; returns each
        object's silhouette bound in the normalised plane (:func:`projected_box`; None when out of view).
        The corners and centres of all objects are projected in one call (the projection is per point)."""
        req, cam = self.request, self.camera
        boxes, cams = [], []
        for k, name in enumerate(self.names):
            model, corners, centre = self._geometry[name]
            T = T_co[k]
            c_cam = apply_T(T, corners)
            # in view unless the whole box is behind the near plane or outside the image
            in_view = box_in_view(cam, c_cam)
            lab = ObjectLabel(name, model.class_id, T, in_view)
            if req.keypoints:
                lab.corners_cam = c_cam
                lab.center_cam = apply_T(T, centre[None])[0]
                cams += [c_cam, lab.center_cam[None]]
            labels.objects.append(lab)
            boxes.append(projected_box(cam, c_cam) if in_view else None)
        if cams:
            uv = cam.project(np.concatenate(cams))[0].reshape(len(self.names), 9, 2)
            for lab, uv_k in zip(labels.objects, uv):
                lab.corners_uv, lab.center_uv = uv_k[:8], uv_k[8]
        return boxes

    def _label_map(self, labels: WindowLabels, visible: list[int], T_co: np.ndarray,
                   want_amodal: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """One z-buffered render of the objects in view: the ``(H, W)`` int16 map of object indices (-1:
        background), the visible pixel count per object and, with ``want_amodal``, the ``(len(visible), H, W)``
        amodal masks of the same pass (else None); sets ``labels.depth_m`` when depth is requested."""
        req, cam = self.request, self.camera
        H, W = cam.height, cam.width
        label_map = np.full((H, W), -1, np.int16)
        amodal = None
        if visible:
            models = [self._geometry[self.names[k]][0] for k in visible]
            res = self.raster.render_objects(models, [T_co[k] for k in visible], want_amodal=want_amodal)
            amodal = res.amodal
            obj = res.obj_index
            lut = np.asarray(visible, dtype=np.int16)
            covered = obj >= 0
            label_map[covered] = lut[obj[covered]]
            counts = np.bincount(label_map[covered].ravel().astype(np.int64), minlength=len(self.names))
            if req.depth:
                labels.depth_m = res.depth_m
        else:
            counts = np.zeros(len(self.names), np.int64)
            if req.depth:
                labels.depth_m = np.full((H, W), np.inf, np.float32)
        return label_map, counts, amodal

    def _mask_labels(self, labels: WindowLabels, visible: list[int], T_co: np.ndarray, boxes: list,
                     label_map: np.ndarray, counts: np.ndarray, amodal: np.ndarray | None = None) -> None:
        """Visible and full masks, pixel counts and 2D boxes of the objects in view; a full mask is
        needed only for an object that another object really hides (see the module docstring): taken
        from ``amodal`` (the label map's own pass, one per visible object) when given, else rendered."""
        req, cam = self.request, self.camera
        ray_cache: dict[int, np.ndarray] = {}

        def rays_of(j: int) -> np.ndarray:
            """Normalised rays (n, 2) of object j's visible pixels, once per window."""
            if j not in ray_cache:
                v, u = np.nonzero(label_map == j)
                ray_cache[j] = cam.pixel_rays()[0][v, u]
            return ray_cache[j]

        for k, lab in enumerate(labels.objects):
            if not lab.in_view:
                continue
            vis = label_map == k
            lab.px_count_visib = int(counts[k])
            lab.bbox_visib = mask_bbox(vis)
            # is this object hidden anywhere? only where another object's visible pixel lies inside
            # our silhouette's bound (exact test, ~0.1 ms; was: any overlap of the projected boxes)
            occluders = [j for j in visible if j != k and boxes[j] is not None and boxes[k] is not None
                         and boxes_overlap(boxes[j], boxes[k])
                         and rays_in_box(rays_of(j), boxes[k])]
            if not occluders:
                full = vis
                lab.px_count_all, lab.bbox_obj = lab.px_count_visib, lab.bbox_visib
            elif req.amodal or req.masks_full:
                full = (amodal[visible.index(k)] if amodal is not None
                        else self.raster.full_mask(self._geometry[lab.name][0], T_co[k]))
                lab.px_count_all, lab.bbox_obj = int(np.count_nonzero(full)), mask_bbox(full)
            if req.masks_visible:
                lab.mask_visible = vis
            if req.masks_full:
                lab.mask_full = full if occluders else vis

    @staticmethod
    def _segment_events(labels: WindowLabels, label_map: np.ndarray, events: EventArray | None) -> None:
        """The indices of the window's events on each object's visible mask."""
        if events is None:
            raise ValueError("segment_events needs the window's events")
        hit = label_map[events.y.astype(np.intp), events.x.astype(np.intp)] if len(events) else np.zeros(0, np.int16)
        for k, lab in enumerate(labels.objects):
            lab.event_indices = np.flatnonzero(hit == k)
