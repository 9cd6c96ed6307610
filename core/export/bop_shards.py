"""BOP-webdataset shards of a BOP export (``--bop-shards N``, issue 27.4): fewer, larger files.

The layout is bop_toolkit's ``bop_webdataset`` (the format of BOP's large training sets, written by its
``convert_imagewise_to_webdataset``)::

    OUT/SPLIT_web/shard-NNNNNN.tar       the images of windows [N*S, (N+1)*S) of the tiling (S = --bop-shards)
    OUT/SPLIT_web/key_to_shard.json      {KEY: N} for every image
    shard-NNNNNN.tar: KEY.rgb.png, KEY.camera.json, KEY.gt.json, KEY.gt_info.json, KEY.mask.json, KEY.mask_visib.json

``KEY`` is ``{scene_id:06d}_{image_id:06d}`` (``image_id``: the window index, as in the scene-wise layout).
``KEY.camera.json`` is the image's entry of ``scene_camera.json``, ``KEY.gt.json`` / ``KEY.gt_info.json`` its lists
of ``scene_gt.json`` / ``scene_gt_info.json``, and ``KEY.mask.json`` / ``KEY.mask_visib.json`` map each instance
(position in ``gt``, as a string) to its mask in bop_toolkit's ``pycoco_utils.binary_mask_to_rle`` encoding:
uncompressed COCO RLE, ``{"counts": [...], "size": [H, W]}``, runs in column-major (Fortran) order starting with
a run of zeros. ``bop_imagewise.load_image_data`` reads these members as written.

Shards are not shuffled: shard ``N`` holds windows ``[N*S, (N+1)*S)`` so that a shard is one contiguous task of the
export (a worker writes it whole, atomically, at the end of the task), the output does not depend on how the work
was cut, and a resumed export redoes at most the shards it had not finished. A shard whose windows are all
unlabeled (or left out) is not written: shard numbers may have gaps; ``key_to_shard.json`` lists what exists.

Tars are byte-reproducible: POSIX ustar, members in key order then the order above, mode 0644, owner 0:0 without
names, modification time 0.
"""
from __future__ import annotations

import io
import json
import tarfile

import numpy as np

__all__ = ["KEY_TO_SHARD", "SHARD_MEMBERS", "DEFAULT_SHARD_WINDOWS", "MAX_SHARD_WINDOWS", "check_shard_windows",
           "image_key", "json_member", "mask_rle", "shard_name", "shard_tar", "web_dir_name"]

#: Images a shard holds by default: ~5 s of one worker's CPU on a 5-object DAVIS346 scene (one task of the
#: cluster export); BOP's own converter uses at most 1000.
DEFAULT_SHARD_WINDOWS = 200
#: The largest shard accepted (a worker holds a shard's members in memory until it writes it: ~40 kB a window).
MAX_SHARD_WINDOWS = 5000
#: The map of image keys to shard numbers, beside the shards.
KEY_TO_SHARD = "key_to_shard.json"
#: Members of one image, in the order they are written.
SHARD_MEMBERS = ("rgb.png", "camera.json", "gt.json", "gt_info.json", "mask.json", "mask_visib.json")


def check_shard_windows(n) -> int:
    """``n`` images a shard (0: no shards), an integer in ``0 .. MAX_SHARD_WINDOWS``."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 0 <= n <= MAX_SHARD_WINDOWS:
        raise ValueError(f"shard_windows: must be an integer from 1 to {MAX_SHARD_WINDOWS} (0: no shards), got {n!r}")
    return int(n)


def web_dir_name(split: str) -> str:
    """The shards' folder of a split: ``SPLIT_web`` (bop_toolkit's naming, e.g. ``train_pbr_web``)."""
    return f"{split}_web"


def shard_name(n: int) -> str:
    return f"shard-{int(n):06d}.tar"


def image_key(scene_id: int, image_id: int) -> str:
    return f"{int(scene_id):06d}_{int(image_id):06d}"


def mask_rle(mask: np.ndarray | None, shape: tuple[int, int]) -> dict:
    """``mask`` (H x W bool, or None: empty) as bop_toolkit's uncompressed RLE: run lengths over the column-major
    pixels, the first run counting zeros (0 when the first pixel is set)."""
    H, W = shape
    if mask is None or not mask.any():
        return {"counts": [H * W], "size": [H, W]}
    flat = np.asarray(mask, bool).ravel(order="F")
    edges = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    bounds = np.concatenate(([0], edges, [flat.size]))
    runs = np.diff(bounds).tolist()
    if flat[0]:
        runs.insert(0, 0)
    return {"counts": runs, "size": [H, W]}


def shard_tar(images: list[tuple[str, dict[str, bytes]]]) -> bytes:
    """The bytes of a shard holding ``images`` = ``[(key, {member: bytes})]`` (sorted by key here)."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.USTAR_FORMAT) as tar:
        for key, members in sorted(images, key=lambda kv: kv[0]):
            for ext in SHARD_MEMBERS:
                data = members[ext]
                info = tarfile.TarInfo(f"{key}.{ext}")
                info.size = len(data)
                info.mtime = 0
                info.mode = 0o644
                info.uid = info.gid = 0
                info.uname = info.gname = ""
                tar.addfile(info, io.BytesIO(data))
    return buf.getvalue()


def json_member(obj) -> bytes:
    """The JSON bytes of a mask member or of ``key_to_shard.json`` (compact: keys in the order given)."""
    return json.dumps(obj, separators=(",", ":")).encode()
