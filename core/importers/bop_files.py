"""The files of a BOP scene for ``evpose import bop``: where the scene is, its JSON files, and its event
images read back as events.

A BOP dataset is ``DATASET/{camera.json, models/, SPLIT/SSSSSS/...}``. The source may be the dataset
folder (then ``--scene ID`` picks ``*/SSSSSS``; the scene must be in exactly one split), a split folder
``DATASET/SPLIT`` (``--scene ID``), or the scene folder itself (the one holding ``scene_gt.json``).
The models are in ``DATASET/models`` unless ``--models`` says otherwise.

Event images (:func:`image_events`): evpose's BOP export writes undistorted event-polarity images, red =
ON events, blue = OFF events, green 0 (:mod:`evpose.core.export.bop`). Each pixel whose red (blue)
channel is non-zero becomes one ON (OFF) event, so a pixel with both gives two; counts are not recovered
(the intensity is a clipped count). The events of an image are spread over its window ``[t0, t1)``: in a
fixed pseudo-random pixel order (seeded by the image id, reproducible), event ``k`` of ``n`` at
``t0 + floor(k (t1 - t0) / n)``, so the first is at ``t0`` and every event stays inside the window.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evpose.core.data.input_files import InputFileError, open_regular
from evpose.core.importers.failure import ImportFailure, wrap_errors

__all__ = ["BopScene", "locate_scene", "read_json", "image_events", "image_path", "read_image", "MAX_JSON_BYTES",
           "MAX_IMAGE_BYTES"]

#: scene_gt.json of a long scene (10^5 images x 10 objects ~ 200 MB) fits; a larger file is refused unread.
MAX_JSON_BYTES = 2**30
#: An event image of a megapixel sensor is a few MB.
MAX_IMAGE_BYTES = 256 * 2**20
_IMAGE_SUFFIXES = (".png", ".jpg", ".tif")


@dataclass
class BopScene:
    """Where a BOP scene is: its folder, the dataset root, the split name and the scene id."""

    folder: Path
    root: Path
    split: str
    scene_id: int


def _scene_id(value, where) -> int:
    try:
        sid = int(str(value).strip())
    except (TypeError, ValueError):
        raise ImportFailure(where, "(arguments)", "--scene",
                            f"expected a BOP scene id (integer), got {value!r}") from None
    if sid < 0:
        raise ImportFailure(where, "(arguments)", "--scene", f"expected a scene id >= 0, got {sid}")
    return sid


def locate_scene(sources, scene) -> BopScene:
    """The BOP scene named by the sources and ``--scene`` (see the module docstring)."""
    if len(sources) != 1:
        raise ImportFailure(", ".join(map(str, sources)), "(arguments)", "SRC",
                            "expected one source: BOP_DIR, BOP_DIR/SPLIT or the scene folder")
    src = Path(sources[0])
    if not src.is_dir():
        raise ImportFailure(src, "(arguments)", "SRC",
                            "not a folder (expected BOP_DIR, BOP_DIR/SPLIT or a scene folder)")
    if (src / "scene_gt.json").is_file():
        sid = _scene_id(src.name if scene is None else scene, src)
        return BopScene(src, src.parent.parent, src.parent.name, sid)
    if scene is None:
        raise ImportFailure(src, "(arguments)", "--scene", "which scene? give --scene ID (the SSSSSS folder)")
    sid = _scene_id(scene, src)
    name = f"{sid:06d}"
    if (src / name / "scene_gt.json").is_file():                  # a split folder
        return BopScene(src / name, src.parent, src.name, sid)
    found = sorted(d for d in src.iterdir() if d.is_dir() and (d / name / "scene_gt.json").is_file())
    if not found:
        raise ImportFailure(src, "(arguments)", "--scene", f"no scene {name} (no {name}/scene_gt.json in {src} "
                            "or in a split folder of it)")
    if len(found) > 1:
        raise ImportFailure(src, "(arguments)", "--scene", f"scene {name} is in several splits "
                            f"({', '.join(d.name for d in found)}): give BOP_DIR/SPLIT as the source")
    return BopScene(found[0] / name, src, found[0].name, sid)


def read_json(path: Path, what: str = "-"):
    """A JSON file (a regular file of at most :data:`MAX_JSON_BYTES`); invalid JSON names the line."""
    try:
        with open_regular(path, "rb", max_bytes=MAX_JSON_BYTES) as f:
            with wrap_errors(path, "(file)", what, "cannot read"):
                data = f.read()
    except InputFileError as exc:
        raise ImportFailure(path, "(file)", what, exc.reason) from None
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ImportFailure(path, "(file)", what, f"not UTF-8 text ({exc.reason})") from None
    except json.JSONDecodeError as exc:
        raise ImportFailure(path, f"line {exc.lineno}", what, f"not valid JSON ({exc.msg})") from None
    except RecursionError:
        raise ImportFailure(path, "(file)", what, "JSON nested too deeply") from None


def image_path(folder: Path, im_id: int) -> Path:
    """``rgb/IIIIII.png`` (or ``.jpg``/``.tif``) of an image; the ``.png`` path when none exists."""
    for suf in _IMAGE_SUFFIXES:
        p = folder / "rgb" / f"{im_id:06d}{suf}"
        if p.is_file():
            return p
    return folder / "rgb" / f"{im_id:06d}.png"


def read_image(path: Path, im_id: int, size: tuple[int, int] | None = None) -> np.ndarray:
    """The 8-bit BGR(A) pixels of an event image, of ``size`` ``(width, height)`` when given."""
    import cv2

    rec = f"image {im_id}"
    try:
        with open_regular(path, "rb", max_bytes=MAX_IMAGE_BYTES) as f:
            with wrap_errors(path, rec, "rgb", "cannot read"):
                data = f.read()
    except InputFileError as exc:
        raise ImportFailure(path, rec, "rgb", exc.reason) from None
    with wrap_errors(path, rec, "rgb", "cannot decode"):
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ImportFailure(path, rec, "rgb", "not a readable image (truncated or not PNG/JPEG/TIFF)")
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ImportFailure(path, rec, "rgb", f"expected an 8-bit RGB event image, got {img.dtype} {img.shape}")
    if size is not None and (img.shape[1], img.shape[0]) != tuple(size):
        raise ImportFailure(path, rec, "size", f"{img.shape[1]}x{img.shape[0]} pixels, but the camera is "
                            f"{size[0]}x{size[1]}")
    return img


def image_events(path: Path, im_id: int, t0_us: int, t1_us: int, size: tuple[int, int]):
    """``(x, y, t_us, p)`` of one event image (see the module docstring); ``t1_us > t0_us``."""
    img = read_image(path, im_id, size)
    green = img[..., 1]
    if green.any():
        v, u = np.argwhere(green)[0]
        raise ImportFailure(path, f"image {im_id}", "G", f"non-zero green at pixel ({u}, {v}): not an event-polarity "
                            "image (evpose's BOP export writes R = ON, B = OFF, G = 0)")
    yv_on, xv_on = np.nonzero(img[..., 2])
    yv_off, xv_off = np.nonzero(img[..., 0])
    x = np.concatenate([xv_on, xv_off])
    y = np.concatenate([yv_on, yv_off])
    p = np.concatenate([np.ones(len(xv_on), np.uint8), np.zeros(len(xv_off), np.uint8)])
    n = len(x)
    order = np.random.default_rng(im_id).permutation(n)
    span = int(t1_us) - int(t0_us)
    k = np.arange(n, dtype=np.int64)
    if n and span < (2**62) // n:
        t = int(t0_us) + (k * span) // n
    else:
        t = int(t0_us) + np.floor(k * (span / max(n, 1))).astype(np.int64)
    return x[order], y[order], t, p[order]
