"""``scene_gt_info.json`` as BOP's ``calc_gt_info`` defines it, for the undistorted BOP camera.

``calc_gt_info`` (``bop_toolkit/scripts/calc_gt_info.py``) renders each object alone on a canvas three
times the image in width and height, the image at offset ``(W, H)``, so that the part of the silhouette
outside the image counts too:

- ``px_count_all``: silhouette pixels on that canvas (in and outside the image);
- ``px_count_visib``: visible pixels in the image; ``visib_fract = px_count_visib / px_count_all``
  (0 when ``px_count_all`` is 0);
- ``bbox_obj``: box of the whole canvas silhouette in image pixel indices (negative or beyond the image
  where the object leaves it), ``bbox_visib``: box of the visible pixels; both
  :func:`~evpose.core.export.bop_conventions.calc_2d_bbox` (``w = x_max - x_min``), both
  ``[-1, -1, -1, -1]`` when no pixel is visible (calc_gt_info computes ``bbox_obj`` only then);
- ``px_count_valid``: calc_gt_info counts in-image silhouette pixels with a depth measurement; there is no
  depth image here, so it counts in-image silhouette pixels whose ray falls on the raw sensor within the
  monotonic distortion radius.

Visibility: a pixel is visible for the object whose surface is nearest along its ray (exact z-buffer,
every scene object occluding); calc_gt_info compares with a depth image with a 15 mm tolerance instead.

The in-image pixels are the export's own masks (``mask/``, ``mask_visib/``); :class:`EnlargedCanvas` adds
the pixels outside the image, rendered with :class:`~evpose.core.label.raster.Rasterizer` in the
image-sized tiles of the canvas around the image, only those the object's projected convex hull reaches
(an object inside the image is not rendered again).
"""
from __future__ import annotations

import numpy as np

from evpose.core.data.camera import CameraModel
from evpose.core.data.geometry import apply_T
from evpose.core.export.bop_conventions import calc_2d_bbox

__all__ = ["CANVAS_FACTOR", "WHOLE_CANVAS_MAX_PX", "CanvasCamera", "EnlargedCanvas", "gt_info"]

#: calc_gt_info's canvas is this many images wide and high, the image in the middle.
CANVAS_FACTOR = 3
#: Canvases of at most this many pixels are rendered whole when an object reaches two tiles or more (one
#: pass over its vertices instead of one per tile; DAVIS346: 0.8 MP, ~32 MB kept, ~90 MB while it is
#: built); larger ones only tile by tile (bounded memory).
WHOLE_CANVAS_MAX_PX = 2**21
#: pixels: a silhouette whose box stays this far inside the outer pixel centres covers none of them
_EDGE_SLACK_PX = 1e-3


class CanvasCamera(CameraModel):
    """A distortion-free pinhole camera whose pixel rays are ``((u - cx) / fx, (v - cy) / fy)`` directly
    (the general path undistorts every pixel centre: 1.5 s for a 1038 x 780 canvas)."""

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(xy (H, W, 2), valid (H, W))`` as :meth:`CameraModel.pixel_rays`; not cached (the rasteriser keeps
        its own copy)."""
        K = self.K
        xy = np.empty((self.height, self.width, 2))
        xy[..., 0] = ((np.arange(self.width) - K[0, 2]) / K[0, 0])[None, :]
        xy[..., 1] = ((np.arange(self.height) - K[1, 2]) / K[1, 1])[:, None]
        return xy, np.ones((self.height, self.width), bool)


class EnlargedCanvas:
    """The silhouette of one object outside the image, on calc_gt_info's enlarged canvas.

    Only the tiles the object's projected convex hull reaches are rendered: the 8 image-sized tiles around
    the image (tile ``(dx, dy)``: columns ``dx W .. dx W + W - 1``, rows ``dy H .. dy H + H - 1`` in image
    pixel indices, ``dx, dy`` in {-1, 0, 1} for :data:`CANVAS_FACTOR` 3), each a :class:`CanvasCamera` with
    the principal point moved by ``(-dx W, -dy H)``; an object reaching two tiles or more is rendered once
    on the whole canvas instead when it has at most :data:`WHOLE_CANVAS_MAX_PX` pixels (the cost of a
    render is mostly per vertex). Rasterisers are built on first use: ~40 bytes a pixel (a DAVIS346 tile
    ~3.6 MB, its whole canvas ~32 MB; a 1280 x 720 tile ~37 MB, never its 8.3 MP whole canvas).

    Parameters
    ----------
    camera : CameraModel
        The undistorted (pinhole) output camera of the export, OpenCV pixel convention.
    """

    def __init__(self, camera: CameraModel):
        if camera.has_distortion:
            raise ValueError("EnlargedCanvas: the BOP camera has no distortion")
        self.camera = camera
        self._tiles: dict[tuple[int, int], object] = {}
        self._hulls: dict[int, tuple] = {}
        self._whole = None

    def tile(self, dx: int, dy: int):
        """The :class:`~evpose.core.label.raster.Rasterizer` of tile ``(dx, dy)``."""
        if (dx, dy) not in self._tiles:
            from evpose.core.label.raster import Rasterizer

            cam = self.camera
            K = cam.K.copy()
            K[0, 2] -= dx * cam.width
            K[1, 2] -= dy * cam.height
            self._tiles[dx, dy] = Rasterizer(CanvasCamera(K, (), cam.width, cam.height, near_m=cam.near_m,
                                                          source=f"{cam.source} (BOP canvas tile {dx},{dy})"))
        return self._tiles[dx, dy]

    def hull_points(self, model) -> np.ndarray:
        """The vertices of the model's convex hull (object frame, metres; the 3D box corners when the mesh is
        flat), once per model: their projection bounds the silhouette exactly, for a few hundred points."""
        key = id(model)
        if key not in self._hulls:
            from scipy.spatial import ConvexHull, QhullError

            try:
                pts = model.vertices_m[ConvexHull(model.vertices_m).vertices]
            except (QhullError, ValueError):
                pts = model.bbox_corners()
            self._hulls[key] = (model, pts)          # the model is kept, so its id stays its own
        return self._hulls[key][1]

    def reach(self, model, T_cam_obj: np.ndarray) -> tuple[list[tuple[int, int]], tuple[int, int, int, int]]:
        """``(tiles, (c0, c1, r0, r1))``: the tiles whose pixel centres the object may cover and the columns
        and rows (image pixel indices, inclusive, within the canvas) it may cover: the bounding box of its
        projected convex hull (which contains the silhouette); the whole canvas when the hull crosses the
        near plane; no tile when it ends inside the image."""
        cam = self.camera
        W, H, k = cam.width, cam.height, CANVAS_FACTOR // 2
        ring = [(dx, dy) for dy in range(-k, k + 1) for dx in range(-k, k + 1) if (dx, dy) != (0, 0)]
        P = apply_T(T_cam_obj, self.hull_points(model))
        if np.any(P[:, 2] <= cam.near_m):
            return ring, (-k * W, W - 1 + k * W, -k * H, H - 1 + k * H)
        u = cam.K[0, 0] * P[:, 0] / P[:, 2] + cam.K[0, 2]
        v = cam.K[1, 1] * P[:, 1] / P[:, 2] + cam.K[1, 2]
        s = _EDGE_SLACK_PX
        c0, c1 = max(int(np.ceil(u.min() - s)), -k * W), min(int(np.floor(u.max() + s)), W - 1 + k * W)
        r0, r1 = max(int(np.ceil(v.min() - s)), -k * H), min(int(np.floor(v.max() + s)), H - 1 + k * H)
        tiles = [(dx, dy) for dx, dy in ring
                 if c0 <= dx * W + W - 1 and c1 >= dx * W and r0 <= dy * H + H - 1 and r1 >= dy * H]
        return tiles, (c0, c1, r0, r1)

    def whole(self):
        """The :class:`~evpose.core.label.raster.Rasterizer` of the whole canvas (image at ``(W, H)``)."""
        if self._whole is None:
            from evpose.core.label.raster import Rasterizer

            cam, f = self.camera, CANVAS_FACTOR
            K = cam.K.copy()
            K[0, 2] += cam.width * (f // 2)
            K[1, 2] += cam.height * (f // 2)
            self._whole = Rasterizer(CanvasCamera(K, (), f * cam.width, f * cam.height, near_m=cam.near_m,
                                                  source=f"{cam.source} (BOP canvas)"))
        return self._whole

    def outside(self, model, T_cam_obj: np.ndarray) -> tuple[int, tuple[int, int, int, int] | None]:
        """``(pixels, (x_min, y_min, x_max, y_max) or None)`` of the silhouette on the canvas outside the
        image, in image pixel indices (the object alone; ``model`` in metres, ``T_cam_obj`` its pose)."""
        W, H = self.camera.width, self.camera.height
        tiles, (c0, c1, r0, r1) = self.reach(model, T_cam_obj)
        if len(tiles) > 1 and CANVAS_FACTOR ** 2 * W * H <= WHOLE_CANVAS_MAX_PX:
            parts = [(self.whole(), W * (CANVAS_FACTOR // 2), H * (CANVAS_FACTOR // 2))]
        else:
            parts = [(self.tile(dx, dy), -dx * W, -dy * H) for dx, dy in tiles]
        n, box = 0, None
        for raster, ox, oy in parts:                 # (ox, oy): image pixel (0, 0) in this rasteriser
            x0, x1 = max(c0 + ox, 0), min(c1 + ox, raster.width - 1)
            y0, y1 = max(r0 + oy, 0), min(r1 + oy, raster.height - 1)
            if x1 < x0 or y1 < y0:
                continue
            m = raster.full_mask(model, T_cam_obj)[y0:y1 + 1, x0:x1 + 1]
            # the image itself (its pixels are the export's mask) within this crop
            ix0, ix1 = max(ox - x0, 0), min(ox + W - x0, m.shape[1])
            iy0, iy1 = max(oy - y0, 0), min(oy + H - y0, m.shape[0])
            if ix0 < ix1 and iy0 < iy1:
                m[iy0:iy1, ix0:ix1] = False
            b = _extent(m)
            if b is None:
                continue
            n += int(np.count_nonzero(m))
            b = (b[0] + x0 - ox, b[1] + y0 - oy, b[2] + x0 - ox, b[3] + y0 - oy)
            box = b if box is None else (min(box[0], b[0]), min(box[1], b[1]), max(box[2], b[2]), max(box[3], b[3]))
        return n, box


def _extent(mask: np.ndarray | None) -> tuple[int, int, int, int] | None:
    if mask is None:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    if len(cols) == 0:
        return None
    rows = np.flatnonzero(mask.any(axis=1))
    return int(cols[0]), int(rows[0]), int(cols[-1]), int(rows[-1])


def gt_info(full: np.ndarray | None, visible: np.ndarray | None, valid: np.ndarray,
            outside: tuple[int, tuple | None]) -> dict:
    """One ``scene_gt_info.json`` entry (see the module docstring).

    Parameters
    ----------
    full, visible : (H, W) bool or None
        The amodal and the visible mask in the image (None: nothing in the image).
    valid : (H, W) bool
        Pixels the raw sensor covers.
    outside : (int, box or None)
        :meth:`EnlargedCanvas.outside` of the object.
    """
    n_out, box_out = outside
    n_in = int(np.count_nonzero(full)) if full is not None else 0
    n_vis = int(np.count_nonzero(visible)) if visible is not None else 0
    n_all = n_in + int(n_out)
    bbox_obj = bbox_visib = [-1, -1, -1, -1]
    if n_vis:
        boxes = [b for b in (_extent(full), box_out) if b is not None]
        x0, y0 = min(b[0] for b in boxes), min(b[1] for b in boxes)
        x1, y1 = max(b[2] for b in boxes), max(b[3] for b in boxes)
        bbox_obj = calc_2d_bbox(np.array([x0, x1]), np.array([y0, y1]))
        bx = _extent(visible)
        bbox_visib = calc_2d_bbox(np.array([bx[0], bx[2]]), np.array([bx[1], bx[3]]))
    return {"bbox_obj": bbox_obj, "bbox_visib": bbox_visib, "px_count_all": n_all,
            "px_count_valid": int(np.count_nonzero(full & valid)) if full is not None else 0,
            "px_count_visib": n_vis, "visib_fract": n_vis / n_all if n_all else 0.0}
