"""Helpers shared by tests (a uniquely named module: every test folder has its own conftest)."""
from __future__ import annotations


def half_davis_camera() -> dict:
    """DAVIS346 calibration at half resolution (173x130): same lens, 4x fewer pixels, fast tests."""
    from evpose.core.data.camera import CameraModel

    return CameraModel.davis346().binned(2).to_dict()


#: The shared synthetic scene: 3 objects, trajectory B at 0.5 m/s, clock offset and pose error injected.
TINY_SCENE = dict(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5, duration_s=0.8,
                  offset_us=20_000, skew_ppm=0.0, pose_error_mm=5.0, pose_error_deg=3.0, seed=3)


def msidx_cache_file(path):
    """Where EventStore caches the index and validation of an event file (the user cache dir)."""
    import hashlib
    from pathlib import Path

    from evpose.core.data.event_index import default_cache_dir

    return default_cache_dir() / f"{hashlib.sha1(str(Path(path).resolve()).encode()).hexdigest()}.npz"


def describe_file_differences(got: dict, ref: dict, root_got=None, root_ref=None) -> list[str]:
    """The names whose contents differ between two ``{name: bytes}`` trees (or, with ``root_got`` / ``root_ref``,
    two ``{name: digest}`` snapshots of those folders), each with what differs: for a PNG whether the decoded
    pixels are equal (only the deflate stream differs) or how many pixels of which channels differ; so that a
    rare byte difference says where it comes from when it happens."""
    from pathlib import Path

    import cv2
    import numpy as np

    out = []
    for name in sorted(k for k in got if k in ref and got[k] != ref[k]):
        a, b = got[name], ref[name]
        if root_got is not None:
            a, b = (Path(root_got) / name).read_bytes(), (Path(root_ref) / name).read_bytes()
        note = f"{len(a)} vs {len(b)} bytes"
        if name.endswith(".png"):
            ia = cv2.imdecode(np.frombuffer(a, np.uint8), cv2.IMREAD_UNCHANGED)
            ib = cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_UNCHANGED)
            if ia is None or ib is None or ia.shape != ib.shape:
                note += ", undecodable or of another shape"
            elif np.array_equal(ia, ib):
                same_raw = _png_scanlines(a) == _png_scanlines(b)
                note += (", same pixels and same scanlines (only the deflate stream differs)" if same_raw else
                         ", same pixels but other scanline bytes (filter bytes or padding differ)")
            else:
                diff = (ia != ib).reshape(ia.shape[0], ia.shape[1], -1)
                where = np.argwhere(diff.any(axis=2))
                chans = np.flatnonzero(diff.any(axis=(0, 1))).tolist()
                r, c = where[0]
                note += (f", {len(where)} pixels differ (channels {chans} in OpenCV's BGR order; first at row {r}, "
                         f"column {c}: {ia[r, c].tolist()} vs {ib[r, c].tolist()})")
        out.append(f"{name}: {note}")
    return out


def _png_scanlines(png: bytes) -> bytes | None:
    """The inflated IDAT data of a PNG (filter byte + row per scanline), or None when it cannot be read."""
    import struct
    import zlib

    pos, idat = 8, b""
    try:
        while pos < len(png):
            n, kind = struct.unpack(">I4s", png[pos:pos + 8])
            if kind == b"IDAT":
                idat += png[pos + 8:pos + 8 + n]
            pos += 12 + n
        return zlib.decompress(idat)
    except (struct.error, zlib.error):
        return None
