"""One event window -> every label of every object that needs one.

Products (computed only when requested, see :class:`Request`):

* ``T_cam_obj`` at the window's label time (always);
* the 8 corners of the object's 3D box (optionally enlarged by a margin), in the camera frame
  and projected with the camera's distortion; the projected object centre;
* full (amodal) and visible (modal) masks from the z-buffer rasteriser, a per-pixel label map
  of object indices, pixel counts and the visible fraction, tight 2D boxes of both masks;
* the indices of the window's events that fall on each object's visible mask.

Work left out where the scene does not need it: objects whose 3D box is outside the view are
culled before rasterising; all objects are rasterised once per window (one z-buffer gives every
visible mask); a full mask is rendered separately only for an object that another object
actually hides somewhere: a visible pixel of another object whose ray lies inside the object's
projected 3D box (otherwise full == visible), so a single-object scene or objects side by side
never render twice; rasterisers and per-object geometry are cached.
Windows whose label time falls outside the trajectory get no label, with the reason.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evpose.core.data.camera import CameraModel
from evpose.core.data.events import EventArray
from evpose.core.data.geometry import apply_T
from evpose.core.data.trajectory import ClockModel
from evpose.core.errors import InputError
from evpose.core.label.raster import Rasterizer

LABEL_AT = ("center", "end", "start")
#: Shortest window the command line accepts (``--window-ms``), ms: poses are sampled every few ms, so
#: shorter windows add no label information, while the work and the files grow with the window count
#: (0.1 ms is 10 000 windows per second of recording, 100x the default; 1 µs windows made a 0.8 s scene
#: export run for hours).
MIN_WINDOW_MS = 0.1
#: Most windows one tiling may hold (a Python list of windows; ~17 µs and ~200 bytes each to build):
#: 28 hours of 10 ms windows.
MAX_WINDOWS = 10_000_000


class WindowError(InputError):
    """A window tiling that cannot be built (non-positive length, too many windows)."""


@dataclass(frozen=True)
class Window:
    """An event window ``[t0_us, t1_us)`` on the event clock, with its label time."""

    index: int
    t0_us: int
    t1_us: int
    t_label_us: int
    i0: int = -1  # event index range [i0, i1) when known
    i1: int = -1

    @property
    def n_events(self) -> int:
        return max(self.i1 - self.i0, 0)


def label_time(t0_us: int, t1_us: int, label_at: str = "center") -> int:
    """Label time of ``[t0, t1)``: its centre (default), its end (E-POSE) or its start."""
    if label_at == "center":
        return int(t0_us + (t1_us - t0_us) // 2)
    if label_at == "end":
        return int(t1_us)
    if label_at == "start":
        return int(t0_us)
    raise ValueError(f"label_at must be one of {LABEL_AT}, got {label_at!r}")


def time_windows(store, window_us: int, *, label_at: str = "center", t_start_us=None, t_end_us=None) -> list[Window]:
    """Tile the recording with consecutive half-open windows of ``window_us``.

    The first window starts at the first event (or ``t_start_us``); the last one ends after the
    last event, so every event belongs to exactly one window.
    """
    if window_us <= 0:
        raise WindowError(f"window length must be positive, got {window_us} us")
    if store.t_first_us is None:
        return []
    t_a = store.t_first_us if t_start_us is None else int(t_start_us)
    t_b = store.t_last_us + 1 if t_end_us is None else int(t_end_us)
    if t_b <= t_a:
        return []
    n = -(-(t_b - t_a) // int(window_us))
    if n > MAX_WINDOWS:
        raise WindowError(f"{getattr(store, 'path', 'events')}: window length {window_us} us makes {n:,} windows "
                          f"over {(t_b - t_a) / 1e6:g} s, more than {MAX_WINDOWS:,}; use longer windows")
    edges = np.arange(t_a, t_b, int(window_us), dtype=np.int64)
    edges = np.append(edges, edges[-1] + int(window_us))
    idx = store.indices_of(edges)
    return [Window(k, int(edges[k]), int(edges[k + 1]), label_time(edges[k], edges[k + 1], label_at),
                   int(idx[k]), int(idx[k + 1])) for k in range(len(edges) - 1)]


def count_windows(store, n_events: int, *, label_at: str = "center") -> list[Window]:
    """Consecutive windows of ``n_events`` events each (the last may be shorter).

    Windows are index ranges, so every event belongs to exactly one window; the time span is
    ``[t of first event, t of last event + 1)``.
    """
    if n_events <= 0:
        raise WindowError(f"events per window must be positive, got {n_events}")
    n = store.n_events
    if -(-n // int(n_events)) > MAX_WINDOWS:
        raise WindowError(f"{getattr(store, 'path', 'events')}: {n_events} events per window make "
                          f"{-(-n // int(n_events)):,} windows, more than {MAX_WINDOWS:,}; use longer windows")
    out = []
    starts = np.arange(0, n, int(n_events), dtype=np.int64)
    if len(starts) == 0:
        return out
    ends = np.minimum(starts + n_events, n)
    firsts = [int(store.read(i, i + 1).t[0]) for i in starts]
    lasts = [int(store.read(i - 1, i).t[0]) for i in ends]
    for k, (i0, i1, a, b) in enumerate(zip(starts, ends, firsts, lasts)):
        out.append(Window(k, int(a), int(b) + 1, label_time(int(a), int(b) + 1, label_at), int(i0), int(i1)))
    return out


@dataclass(frozen=True)
class Request:
    """Which products to compute for each window.

    ``margin_m`` enlarges the 3D box on every side. ``amodal`` computes ``px_count_all`` and
    ``bbox_obj`` of the full (amodal) mask, which costs one more rasterisation per object that
    another object hides; views that show only visible masks turn it off (then
    ``px_count_all`` is 0 and ``bbox_obj`` stays ``(-1, -1, -1, -1)`` unless nothing hides the
    object, where the visible mask is the full one). ``camera`` overrides the output camera
    (e.g. the undistorted pinhole camera for BOP); by default labels live in the scene's raw,
    distorted camera, where the events are.
    """

    keypoints: bool = True
    masks_visible: bool = True
    masks_full: bool = False
    label_map: bool = False
    depth: bool = False
    segment_events: bool = False
    margin_m: float = 0.0
    amodal: bool = True

    @property
    def needs_raster(self) -> bool:
        return self.masks_visible or self.masks_full or self.label_map or self.depth or self.segment_events


@dataclass
class ObjectLabel:
    """Labels of one object in one window (pixels in the output camera, metres, camera frame)."""

    name: str
    class_id: int
    T_cam_obj: np.ndarray
    in_view: bool
    corners_cam: np.ndarray | None = None   # (8, 3) metres
    corners_uv: np.ndarray | None = None    # (8, 2) pixels, NaN where not projectable
    center_cam: np.ndarray | None = None    # (3,) box centre, metres
    center_uv: np.ndarray | None = None     # (2,) pixels
    mask_visible: np.ndarray | None = None  # (H, W) bool
    mask_full: np.ndarray | None = None     # (H, W) bool
    px_count_all: int = 0
    px_count_visib: int = 0
    bbox_obj: tuple[int, int, int, int] = (-1, -1, -1, -1)    # x, y, w, h of the full mask
    bbox_visib: tuple[int, int, int, int] = (-1, -1, -1, -1)  # x, y, w, h of the visible mask
    event_indices: np.ndarray | None = None  # indices into the window's events

    @property
    def visib_fract(self) -> float:
        return self.px_count_visib / self.px_count_all if self.px_count_all else 0.0


@dataclass
class WindowLabels:
    window: Window
    valid: bool
    reason: str = ""
    T_base_cam: np.ndarray | None = None
    objects: list[ObjectLabel] = field(default_factory=list)
    label_map: np.ndarray | None = None  # (H, W) int16: object index, -1 background
    depth_m: np.ndarray | None = None    # (H, W) float32: camera-frame z of the nearest object, inf elsewhere

    def object(self, name: str) -> ObjectLabel:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(name)


def mask_bbox(mask: np.ndarray) -> tuple[int, int, int, int]:
    """Tight box ``(x, y, w, h)`` in pixels of a boolean mask; ``(-1, -1, -1, -1)`` if empty."""
    cols = np.flatnonzero(mask.any(axis=0))
    if len(cols) == 0:
        return (-1, -1, -1, -1)
    rows = np.flatnonzero(mask.any(axis=1))
    return (int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1))


def _boxes_overlap(a, b) -> bool:
    return not (a[2] < b[0] or b[2] < a[0] or a[3] < b[1] or b[3] < a[1])


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
    """

    def __init__(self, scene, request: Request = Request(), camera: CameraModel | None = None,
                 objects=None, clock: ClockModel | None = None):
        self.scene = scene
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
            self._raster = Rasterizer(self.camera)
        return self._raster

    def poses(self, t_label_us) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(T_cam_obj (N, K, 4, 4), T_base_cam (N, 4, 4), valid (N,))`` at label times."""
        t = np.atleast_1d(np.asarray(t_label_us, dtype=np.int64))
        T_bc, valid = self.scene.T_base_cam(t, clock=self.clock)          # interpolated once
        T_co, _ = self.scene.T_cam_obj(t, self.names, clock=self.clock, base_cam=(T_bc, valid))
        return T_co, T_bc, valid

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
        cam = self.camera
        labels = WindowLabels(window, True, T_base_cam=T_bc)
        boxes = []
        for k, name in enumerate(self.names):
            model, corners, centre = self._geometry[name]
            T = T_co[k]
            c_cam = apply_T(T, corners)
            uv, ok = cam.project(c_cam)
            # in view unless the whole box is behind the near plane or outside the image
            in_view = _box_in_view(cam, c_cam)
            lab = ObjectLabel(name, model.class_id, T, in_view)
            if req.keypoints:
                lab.corners_cam = c_cam
                lab.corners_uv = uv
                centre_cam = apply_T(T, centre[None])[0]
                lab.center_cam = centre_cam
                cuv, cok = cam.project(centre_cam[None])
                lab.center_uv = cuv[0]
            labels.objects.append(lab)
            boxes.append(_projected_box(cam, c_cam) if in_view else None)

        if not req.needs_raster:
            return labels
        visible = [k for k, lab in enumerate(labels.objects) if lab.in_view]
        H, W = cam.height, cam.width
        label_map = np.full((H, W), -1, np.int16)
        if visible:
            models = [self._geometry[self.names[k]][0] for k in visible]
            res = self.raster.render_objects(models, [T_co[k] for k in visible])
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
                         and _boxes_overlap(boxes[j], boxes[k])
                         and _rays_in_box(rays_of(j), boxes[k])]
            if not occluders:
                full = vis
                lab.px_count_all, lab.bbox_obj = lab.px_count_visib, lab.bbox_visib
            elif req.amodal or req.masks_full:
                full = self.raster.full_mask(self._geometry[lab.name][0], T_co[k])
                lab.px_count_all, lab.bbox_obj = int(np.count_nonzero(full)), mask_bbox(full)
            if req.masks_visible:
                lab.mask_visible = vis
            if req.masks_full:
                lab.mask_full = full if occluders else vis
        if req.label_map:
            labels.label_map = label_map
        if req.segment_events:
            if events is None:
                raise ValueError("segment_events needs the window's events")
            hit = label_map[events.y.astype(np.intp), events.x.astype(np.intp)] if len(events) else np.zeros(0, np.int16)
            for k, lab in enumerate(labels.objects):
                lab.event_indices = np.flatnonzero(hit == k)
        return labels


def _box_in_view(cam: CameraModel, corners_cam: np.ndarray) -> bool:
    """Conservative frustum test of a box given by its 8 camera-frame corners."""
    z = corners_cam[:, 2]
    if np.all(z <= cam.near_m):
        return False
    if np.any(z <= cam.near_m):
        return True  # straddles the camera plane: let the rasteriser clip it
    xy = corners_cam[:, :2] / z[:, None]
    # the image in normalised coordinates lies within the undistorted image corners' box
    lo, hi = _normalised_extent(cam)
    return not (np.all(xy[:, 0] < lo[0]) or np.all(xy[:, 0] > hi[0]) or np.all(xy[:, 1] < lo[1])
                or np.all(xy[:, 1] > hi[1]))


_EXTENT_CACHE: dict = {}


def _normalised_extent(cam: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    key = (cam.K.tobytes(), cam.dist.tobytes(), cam.width, cam.height)
    if key not in _EXTENT_CACHE:
        xy, ok = cam.pixel_rays()
        pts = xy[ok]
        _EXTENT_CACHE[key] = (pts.min(0) - 1e-6, pts.max(0) + 1e-6)
    return _EXTENT_CACHE[key]


def _rays_in_box(xy: np.ndarray, box) -> bool:
    """Does one of the pixel rays ``xy`` (n, 2) of another object's visible pixels lie inside
    ``box`` (normalised plane, from :func:`_projected_box`)? If none does, nothing hides the
    object of ``box``: its full mask is its visible mask."""
    if not np.all(np.isfinite(box)):
        return True
    return bool(np.any((xy[:, 0] >= box[0]) & (xy[:, 0] <= box[2]) & (xy[:, 1] >= box[1]) & (xy[:, 1] <= box[3])))


def _projected_box(cam: CameraModel, corners_cam: np.ndarray):
    """Box ``(x0, y0, x1, y1)`` in the normalised image plane that contains the object's
    silhouette: the pinhole projection of a box in front of the camera is the convex hull of its
    projected corners, so the bound is exact whatever the lens distortion. Unbounded when a
    corner is at or behind the near plane."""
    z = corners_cam[:, 2]
    if np.any(z <= cam.near_m):
        return (-np.inf, -np.inf, np.inf, np.inf)
    xy = corners_cam[:, :2] / z[:, None]
    return (xy[:, 0].min(), xy[:, 1].min(), xy[:, 0].max(), xy[:, 1].max())
