"""What :class:`~evpose.core.label.annotate.Annotator` computes for a window: the :class:`Request` of
products, and the :class:`ObjectLabel` of each object in the :class:`WindowLabels` of a window.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evpose.core.label.windows import Window


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


def label_poses(scene, t_label_us, names, clock=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(T_cam_obj (N, K, 4, 4), T_base_cam (N, 4, 4), valid (N,))`` of the objects ``names`` at the label times
    ``t_label_us`` (camera clock, µs), the trajectory interpolated once for all of them. ``scene`` is a
    :class:`~evpose.core.data.scene.Scene` or a wrapper of one that overrides ``T_base_cam``; no mesh is loaded
    (the export's driver calls this for every window of a scene)."""
    t = np.atleast_1d(np.asarray(t_label_us, dtype=np.int64))
    T_bc, valid = scene.T_base_cam(t, clock=clock)
    T_co, _ = scene.T_cam_obj(t, names, clock=clock, base_cam=(T_bc, valid))
    return T_co, T_bc, valid
