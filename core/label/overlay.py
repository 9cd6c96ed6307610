"""Display-ready overlay geometry for one window: contours, box wireframes, axes, centres,
and a composited RGBA mask image. Pixel coordinates are OpenCV's (pixel centres at integers)
in the raw, distorted event image; 3D edges are sampled before projection so they bend with the
lens like the events do.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from evpose.core.data.camera import CameraModel
from evpose.core.data.geometry import apply_T
from evpose.core.data.objects import BBOX_EDGES

#: Qualitative colours (RGB) assigned to objects by their index in the scene. None is red, blue or magenta:
#: those are the events' colours (ON red, OFF blue, both magenta, :data:`EVENT_COLORS`), and objects drawn
#: in them blend into the events. Hues from orange through green to teal, of different lightness.
PALETTE = ((0, 158, 115), (230, 140, 0), (0, 140, 170), (140, 140, 0), (90, 190, 40), (150, 85, 30),
           (0, 95, 70), (200, 170, 60))
#: The event images' colours (:mod:`evpose.core.label.event_frames.display`): ON, OFF, both in one pixel.
EVENT_COLORS = {"ON": (255, 0, 0), "OFF": (0, 0, 255), "both": (255, 0, 255)}
AXIS_COLORS = ((230, 40, 40), (40, 200, 40), (40, 90, 240))  # x red, y green, z blue


def object_color(index: int) -> tuple[int, int, int]:
    return PALETTE[index % len(PALETTE)]


@dataclass
class ObjectOverlay:
    """Overlay primitives of one object (pixels of the raw event image)."""

    name: str
    color: tuple[int, int, int]
    contours: list[np.ndarray] = field(default_factory=list)  # closed polylines (N, 2)
    box_segments: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))  # (M, 2 points, uv)
    axes: list[np.ndarray] = field(default_factory=list)  # 3 polylines (x, y, z), NaN-free segments
    center_uv: np.ndarray | None = None
    #: the label's 1-sigma on the image (px, RMS over its box corners) from the sigmas the applied estimates stored
    #: (:func:`evpose.core.label.uncertainty.stored_label_sigmas`); None: the document stores none
    sigma_px: float | None = None


def mask_contours(mask: np.ndarray, min_points: int = 3) -> list[np.ndarray]:
    """Outer and inner boundaries of a mask as closed polylines of pixel centres (float64)."""
    if mask is None or not mask.any():
        return []
    cs, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
    out = []
    for c in cs:
        c = c.reshape(-1, 2).astype(np.float64)
        if len(c) >= min_points:
            out.append(np.vstack([c, c[:1]]))
    return out


def projected_segments(camera: CameraModel, pts_cam: np.ndarray, pairs) -> np.ndarray:
    """Project 3D polylines given as consecutive point pairs; drop pairs with an unprojectable end."""
    uv, ok = camera.project(pts_cam)
    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    keep = ok[pairs[:, 0]] & ok[pairs[:, 1]]
    return uv[pairs[keep]]


def _sampled_edges(a: np.ndarray, b: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Points along segments a->b (E, 3) with n sub-segments each, and the index pairs."""
    s = np.linspace(0.0, 1.0, n + 1)
    pts = a[:, None, :] + s[None, :, None] * (b - a)[:, None, :]  # (E, n+1, 3)
    E = len(a)
    base = (np.arange(E) * (n + 1))[:, None]
    pairs = np.stack([base + np.arange(n), base + np.arange(1, n + 1)], axis=-1).reshape(-1, 2)
    return pts.reshape(-1, 3), pairs


def box_segments(camera: CameraModel, corners_cam: np.ndarray, samples_per_edge: int = 12) -> np.ndarray:
    """Wireframe of the 3D box (8 camera-frame corners) as projected 2D segments ``(M, 2, 2)``."""
    e = np.asarray(BBOX_EDGES)
    pts, pairs = _sampled_edges(corners_cam[e[:, 0]], corners_cam[e[:, 1]], samples_per_edge)
    return projected_segments(camera, pts, pairs)


def axes_segments(camera: CameraModel, T_cam_obj: np.ndarray, length_m: float, origin_obj=(0, 0, 0),
                  samples: int = 8) -> list[np.ndarray]:
    """The object's x, y, z axes (from ``origin_obj``, ``length_m`` long) as projected segments."""
    o = np.asarray(origin_obj, dtype=np.float64)
    out = []
    for k in range(3):
        tip = o.copy()
        tip[k] += length_m
        pts, pairs = _sampled_edges(apply_T(T_cam_obj, o[None]), apply_T(T_cam_obj, tip[None]), samples)
        out.append(projected_segments(camera, pts, pairs))
    return out


def compose_masks_rgba(label_map: np.ndarray, colors: list[tuple[int, int, int]], alpha: float = 0.35,
                       visible: list[bool] | None = None) -> np.ndarray:
    """One RGBA image (H, W, 4) uint8 of all object masks in their colours (transparent elsewhere)."""
    H, W = label_map.shape
    lut = np.zeros((len(colors) + 1, 4), np.uint8)  # index 0 = background (label -1)
    for k, c in enumerate(colors):
        if visible is None or visible[k]:
            lut[k + 1] = (*c, int(round(255 * alpha)))
    return lut[label_map.astype(np.intp) + 1]


def drawn_objects(names, hidden, selected: str | None, selected_only: bool) -> list[bool]:
    """Which objects the frame draws: those not hidden, and with ``selected_only`` only the selected one
    (all of them when none is selected)."""
    only = selected if selected_only and selected in names else None
    return [n not in hidden and (only is None or n == only) for n in names]


#: The background an event representation is drawn on (:mod:`evpose.core.label.represent`, the app's default).
REPRESENTATION_BACKGROUND = {"three_channel": "black"}


def adjust_contrast(rgb: np.ndarray, contrast: float, background: str = "white") -> np.ndarray:
    """The event image with its faint marks strengthened: a gamma of ``1 / contrast`` on the ink (the
    distance of each channel from the background), so the background and saturated marks stay and faint
    ones darken (white background) or brighten (black). ``contrast`` 1 returns ``rgb`` itself.

    Parameters
    ----------
    rgb : (H, W, 3) uint8
    contrast : float >= 1 (below 1 weakens)
    background : "white" or "black"
    """
    if contrast <= 0:
        raise ValueError(f"contrast must be positive, got {contrast}")
    if contrast == 1.0:
        return rgb
    lut = np.rint(255.0 * (np.arange(256) / 255.0) ** (1.0 / contrast)).astype(np.uint8)
    if background == "white":
        return 255 - lut[255 - rgb]
    return lut[rgb]
