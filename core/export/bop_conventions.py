"""The BOP conventions an export must follow to be read by the BOP toolkit (``thodan/bop_toolkit``) as
BOP data: the pixel origin of ``cam_K``, the 2D boxes of ``calc_gt_info``, the split folder and the test
targets.

Pixel origin. evpose (and OpenCV) put the centre of pixel ``(u, v)`` at integer coordinates. The BOP
toolkit's renderers turn ``cam_K`` into an OpenGL projection whose window coordinates start at the
*corner* of the top-left pixel, so pixel ``i`` is sampled at ``u = i + 0.5``; the official BOP masks come
from those renderers. A point that evpose projects to ``u`` is at ``u + 0.5`` there, hence
``cam_K = K_opencv`` with ``cx + 0.5`` and ``cy + 0.5`` (:func:`bop_K`; :func:`opencv_K` undoes it).

Boxes (``bop_toolkit_lib.misc.calc_2d_bbox``): ``[x_min, y_min, x_max - x_min, y_max - y_min]`` over the
pixel indices of a silhouette, not clipped to the image; ``[-1, -1, -1, -1]`` when there is none.

Targets: ``test_targets_bop19.json`` (6D localisation) lists per image and ``obj_id`` the number of
instances whose ``visib_fract`` is at least :data:`VISIB_GT_MIN` (``inout.get_im_targets``);
``test_targets_bop24.json`` (6D detection) lists every image (``scripts/create_test_targets.py``).
"""
from __future__ import annotations

import re

import numpy as np

from evpose.core.export.options import ExportError

__all__ = ["PIXEL_ORIGIN_SHIFT", "VISIB_GT_MIN", "DEFAULT_SPLIT", "bop_K", "opencv_K", "calc_2d_bbox",
           "check_split", "targets_bop19", "targets_bop24", "TARGETS_BOP19", "TARGETS_BOP24"]

#: ``cx_bop - cx_opencv`` and ``cy_bop - cy_opencv`` (pixels).
PIXEL_ORIGIN_SHIFT = 0.5
#: BOP's minimum visible fraction of a localisation target (``visib_gt_min`` of the toolkit).
VISIB_GT_MIN = 0.1
#: The split folder of an export unless the user chooses another.
DEFAULT_SPLIT = "test"
TARGETS_BOP19 = "test_targets_bop19.json"
TARGETS_BOP24 = "test_targets_bop24.json"
_SPLIT = re.compile(r"^(train|val|test)(_[A-Za-z0-9]+)?$")


def bop_K(K_opencv) -> np.ndarray:
    """BOP's ``cam_K`` (pixel origin at the top-left corner) of an OpenCV camera matrix (pixel centres at
    integers): ``cx + 0.5``, ``cy + 0.5``; focal lengths unchanged. ``(3, 3)`` float64, pixels."""
    K = np.array(K_opencv, dtype=np.float64).reshape(3, 3)
    K[0, 2] += PIXEL_ORIGIN_SHIFT
    K[1, 2] += PIXEL_ORIGIN_SHIFT
    return K


def opencv_K(K_bop) -> np.ndarray:
    """The OpenCV camera matrix of BOP's ``cam_K`` (inverse of :func:`bop_K`)."""
    K = np.array(K_bop, dtype=np.float64).reshape(3, 3)
    K[0, 2] -= PIXEL_ORIGIN_SHIFT
    K[1, 2] -= PIXEL_ORIGIN_SHIFT
    return K


def calc_2d_bbox(xs: np.ndarray, ys: np.ndarray) -> list[int]:
    """BOP's box ``[x, y, w, h]`` of pixel indices (``w = x_max - x_min``, not clipped);
    ``[-1, -1, -1, -1]`` for no pixel."""
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    x0, y0 = int(np.min(xs)), int(np.min(ys))
    return [x0, y0, int(np.max(xs)) - x0, int(np.max(ys)) - y0]


def check_split(split) -> str:
    """The split folder name: ``train``, ``val`` or ``test``, optionally with a ``_TYPE`` suffix (BOP's
    ``split_type``, e.g. ``test_davis346``)."""
    if not isinstance(split, str) or not _SPLIT.match(split):
        raise ExportError(f"split: expected train, val or test (optionally with a _TYPE suffix), got {split!r}")
    return split


def targets_bop19(scene_id: int, images: dict[int, tuple[list, list]]) -> list[dict]:
    """``test_targets_bop19.json`` entries: ``images`` maps image id -> (scene_gt list, scene_gt_info list);
    per image and ``obj_id`` (ascending) the count of instances with ``visib_fract >= VISIB_GT_MIN``."""
    out = []
    for im_id in sorted(images):
        gt, info = images[im_id]
        counts: dict[int, int] = {}
        for g, i in zip(gt, info):
            if i["visib_fract"] >= VISIB_GT_MIN:
                counts[int(g["obj_id"])] = counts.get(int(g["obj_id"]), 0) + 1
        out += [{"im_id": int(im_id), "inst_count": n, "obj_id": o, "scene_id": int(scene_id)}
                for o, n in sorted(counts.items())]
    return out


def targets_bop24(scene_id: int, image_ids) -> list[dict]:
    """``test_targets_bop24.json`` entries: every image of the scene."""
    return [{"im_id": int(i), "scene_id": int(scene_id)} for i in sorted(image_ids)]
