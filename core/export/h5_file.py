"""The HDF5 file of the ``h5`` export: creating its datasets and attributes, checking that a partial
file left by an earlier run can be resumed, and bounding the bytes a block of rows adds (for the
free-space check before each write). The layout is documented in :mod:`evpose.core.export.h5`.
"""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from evpose.core.export.fingerprint import evpose_version

__all__ = ["H5_FORMAT", "COUNTS_MAX", "WINDOW_DTYPE", "MARGIN_BYTES", "create_file", "layout_ok", "chunk_layout",
           "need_bytes", "superblock_eoa", "within_end_of_allocation"]

H5_FORMAT = "evpose-h5/1"
COUNTS_MAX = np.iinfo(np.uint16).max
WINDOW_DTYPE = np.dtype([("index", "<i8"), ("t0_us", "<i8"), ("t1_us", "<i8"), ("t_label_us", "<i8"),
                         ("i0", "<i8"), ("i1", "<i8"), ("n_events", "<i8"), ("valid", "?")])
#: Free space kept beyond the estimate of each write (HDF5 metadata, closing the file).
MARGIN_BYTES = 1 << 20
CLOCK_MODEL = "t_pose_us = t_event_us + offset_us + skew_ppm * 1e-6 * (t_event_us - t_ref_us)"


# ------------------------------------------------------------------------------------------- creation
def compression_filter(compression: str | None) -> dict:
    """``create_dataset`` keywords of a compression option ("blosc-lz4", "gzip" or None)."""
    if compression == "blosc-lz4":
        import hdf5plugin

        return dict(hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=hdf5plugin.Blosc.SHUFFLE))
    if compression == "gzip":
        return {"compression": "gzip", "compression_opts": 4, "shuffle": True}
    return {}


def create_file(ctx, part: Path, *, three_channel: bool, compression: str | None):
    """Create ``part`` with every dataset (filled with the "no value" of each) and the root attributes;
    returns the open ``h5py.File``."""
    import h5py

    # no chunk cache: a write reaches the file at once, so a full disk fails that write or the flush after it
    # (an evicted chunk's failure would surface only at close, when HDF5 could no longer close the file)
    f = h5py.File(part, "w", track_order=False, rdcc_nbytes=0)
    _create_datasets(f, ctx, three_channel, compression_filter(compression))
    _write_attributes(f, ctx)
    f.flush()
    return f


def _create_datasets(f, ctx, three_channel: bool, comp_kw: dict) -> None:
    scene = ctx.scene
    cam = scene.camera
    sel = ctx.extra["selected"]
    N, K, H, W = len(sel), len(ctx.names), cam.height, cam.width
    rows = max(1, min(N, 1024))
    small = dict(chunks=True) if N else {}

    def ds(name, shape, dtype, fill=None, chunk=None, comp=False):
        kw = {"chunks": chunk or ((rows,) + shape[1:] if N else None)}
        if comp:
            kw.update(comp_kw)
        if fill is not None:
            kw["fillvalue"] = fill
        return f.create_dataset(name, shape=shape, dtype=dtype, track_times=False,
                                **(kw if N else {}))

    win = np.zeros(N, WINDOW_DTYPE)
    for r, w in enumerate(sel):
        win[r] = (w.index, w.t0_us, w.t1_us, w.t_label_us, w.i0, w.i1, w.n_events, bool(ctx.extra["valid"][r]))
    f.create_dataset("windows", data=win, track_times=False, **small)
    if scene.has_poses:
        _create_label_datasets(f, ds, scene, ctx, (N, K, H, W))
    ds("frames/counts", (N, 2, H, W), "u2", 0, chunk=(1, 2, H, W), comp=True)
    if three_channel:
        ds("frames/three_channel", (N, H, W, 3), "u1", 0, chunk=(1, H, W, 3), comp=True)
    ds("_done", (N,), "u1", 0)


def _create_label_datasets(f, ds, scene, ctx, shape) -> None:
    """The datasets of the labels in ``f`` (none for an event-only scene); ``ds(name, shape, dtype, fill, ...)``
    creates one chunked along windows."""
    N, K, H, W = shape
    ds("T_cam_obj", (N, K, 4, 4), "f8", np.nan)
    ds("T_base_cam", (N, 4, 4), "f8", np.nan)
    ds("bbox_obj", (N, K, 4), "i4", -1)
    ds("bbox_visib", (N, K, 4), "i4", -1)
    ds("keypoints_uv", (N, K, 8, 2), "f8", np.nan)
    ds("corners_cam", (N, K, 8, 3), "f8", np.nan)
    ds("center_uv", (N, K, 2), "f8", np.nan)
    ds("visib_fract", (N, K), "f8", 0.0)
    ds("px_count_all", (N, K), "i8", 0)
    ds("px_count_visib", (N, K), "i8", 0)
    ds("label_map", (N, H, W), "i2", -1, chunk=(1, H, W), comp=True)
    if ctx.extra.get("label_sigma_options") is not None:          # evpose.core.label.uncertainty
        ds("label_sigma", (N, K, 3), "f8", np.nan)
    corners = np.stack([scene.model(n).bbox_corners(ctx.margin_m) for n in ctx.names]) if K else np.zeros((0, 8, 3))
    f.create_dataset("objects/corners_obj", data=corners, track_times=False)


def _write_attributes(f, ctx) -> None:
    import h5py

    scene = ctx.scene
    cam = scene.camera
    clock = scene.clock
    fp = ctx.fingerprint
    a = f.attrs
    a["format"] = H5_FORMAT
    a["evpose_version"] = evpose_version()
    a["scene"] = scene.name
    a["camera_K"] = cam.K
    a["camera_dist"] = cam.dist
    a["width"], a["height"] = cam.width, cam.height
    a["object_names"] = np.array(ctx.names, dtype=h5py.string_dtype())
    a["class_ids"] = np.array([scene.manifest.object(n).class_id for n in ctx.names], np.int64)
    a["clock_offset_us"] = np.int64(clock.offset_us)
    a["clock_skew_ppm"] = float(clock.skew_ppm)
    a["clock_t_ref_us"] = np.int64(clock.t_ref_us)
    a["clock_model"] = CLOCK_MODEL
    a["corrections"] = json.dumps(scene.corrections.to_json())
    a["window_us"] = -1 if fp["windows"]["window_us"] is None else fp["windows"]["window_us"]
    a["window_events"] = -1 if fp["windows"]["window_events"] is None else fp["windows"]["window_events"]
    a["label_at"] = ctx.label_at
    a["margin_m"] = float(ctx.margin_m)
    a["counts_saturation"] = int(COUNTS_MAX)
    a["events_only"] = not scene.has_poses        # True: no trajectory, no objects, so no label dataset
    a["config_sha256"] = ctx.sha


# ------------------------------------------------------------------------------------------- resuming
def layout_ok(f, n_rows: int, three_channel: bool, labels: bool = True) -> bool:
    """The partial file has every dataset (``labels`` False: an event-only scene's, without the labels), each with
    one row per selected window."""
    names = ["windows", "_done", "frames/counts"] + (["T_cam_obj", "label_map"] if labels else [])
    if three_channel:
        names.append("frames/three_channel")
    return all(k in f and f[k].shape[:1] == (n_rows,) for k in names) and f["_done"][:].shape == (n_rows,)


def superblock_eoa(path: Path) -> int | None:
    """The end-of-allocation address stored in an HDF5 superblock (versions 0-3, at offset 0), or None."""
    with open(path, "rb") as fh:
        head = fh.read(56)
    if len(head) < 36 or head[:8] != b"\x89HDF\r\n\x1a\n":
        return None
    version = head[8]
    off = {0: 40, 1: 48, 2: 28, 3: 28}.get(version)
    if off is None or len(head) < off + 8:
        return None
    return struct.unpack_from("<Q", head, off)[0]


def within_end_of_allocation(f, path: Path) -> bool:
    """A partial file left by a killed or failed run is sound to resume when HDF5 can walk all of its
    objects and every data chunk lies below the end of allocation its superblock records. (HDF5 can
    evict metadata that points past the recorded end before a crash; resuming such a file fails later
    with ``addr overflow``.) Reads only the chunk index, not the data."""
    import h5py

    eoa = superblock_eoa(path)
    if eoa is None:
        return False
    end = 0

    def info(ci):
        nonlocal end
        end = max(end, ci.byte_offset + ci.size)

    def visit(_name, obj):
        if isinstance(obj, h5py.Dataset) and obj.chunks is not None:
            if hasattr(obj.id, "chunk_iter"):
                obj.id.chunk_iter(info)
            else:  # pragma: no cover - older HDF5
                for i in range(obj.id.get_num_chunks()):
                    info(obj.id.get_chunk_info(i))

    f.visititems(visit)
    return end <= eoa


# ------------------------------------------------------------------------------------------- free space
def chunk_layout(f) -> dict:
    """Per-row dataset: (rows per chunk, bytes per row before compression), for the free-space check."""
    import h5py

    out = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and name != "windows" and obj.ndim >= 1 and obj.chunks is not None:
            out[name] = (int(obj.chunks[0]), int(np.prod(obj.shape[1:], dtype=np.int64)) * obj.dtype.itemsize)

    f.visititems(visit)
    return out


def need_bytes(layout: dict, runs) -> int:
    """An upper bound of the bytes writing rows ``runs`` (list of [a, b)) adds to the file: every chunk
    the rows touch, uncompressed (``layout``: :func:`chunk_layout`), plus a margin."""
    need = MARGIN_BYTES
    for chunk_rows, row_bytes in layout.values():
        for a, b in runs:
            need += ((b - 1) // chunk_rows - a // chunk_rows + 1) * chunk_rows * row_bytes
    return need
