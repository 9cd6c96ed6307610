"""Cheap visibility tests of an object's 3D box, so the annotator skips work the scene does not need.

:func:`box_in_view` culls objects outside the image; :func:`projected_box` bounds an object's silhouette
in the normalised image plane, and :func:`rays_in_box` tells whether another object's visible pixels fall
inside that bound: if none does, nothing hides the object and its full (amodal) mask is its visible one.
"""
from __future__ import annotations

import numpy as np

from evpose.core.data.camera import CameraModel


def boxes_overlap(a, b) -> bool:
    """Whether two boxes ``(x0, y0, x1, y1)`` overlap (closed intervals)."""
    return not (a[2] < b[0] or b[2] < a[0] or a[3] < b[1] or b[3] < a[1])


def box_in_view(cam: CameraModel, corners_cam: np.ndarray) -> bool:
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


def rays_in_box(xy: np.ndarray, box) -> bool:
    """Does one of the pixel rays ``xy`` (n, 2) of another object's visible pixels lie inside
    ``box`` (normalised plane, from :func:`projected_box`)? If none does, nothing hides the
    object of ``box``: its full mask is its visible mask."""
    if not np.all(np.isfinite(box)):
        return True
    return bool(np.any((xy[:, 0] >= box[0]) & (xy[:, 0] <= box[2]) & (xy[:, 1] >= box[1]) & (xy[:, 1] <= box[3])))


def projected_box(cam: CameraModel, corners_cam: np.ndarray):
    """Box ``(x0, y0, x1, y1)`` in the normalised image plane that contains the object's
    silhouette: the pinhole projection of a box in front of the camera is the convex hull of its
    projected corners, so the bound is exact whatever the lens distortion. Unbounded when a
    corner is at or behind the near plane."""
    z = corners_cam[:, 2]
    if np.any(z <= cam.near_m):
        return (-np.inf, -np.inf, np.inf, np.inf)
    xy = corners_cam[:, :2] / z[:, None]
    return (xy[:, 0].min(), xy[:, 1].min(), xy[:, 0].max(), xy[:, 1].max())
