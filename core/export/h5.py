"""One HDF5 file per sequence for training pipelines that stream (everything chunked along windows).

``OUT/<scene name>.h5`` appears only when complete: it is written as ``OUT/.<scene name>.h5.partial``
(resumable: a rerun with the same configuration continues where the partial file stops) and renamed.

Layout (N = selected windows, in tiling order; K = exported objects; H x W = sensor, raw pixels)::

    windows            (N,) compound: index, t0_us, t1_us, t_label_us, i0, i1, n_events (int64), valid (bool)
    T_cam_obj          (N, K, 4, 4) float64   object poses at the label time (NaN when not valid)
    T_base_cam         (N, 4, 4) float64      camera pose at the label time (NaN when not valid)
    bbox_obj           (N, K, 4) int32        [x, y, w, h] of the amodal mask, -1 when empty or not valid
    bbox_visib         (N, K, 4) int32        [x, y, w, h] of the visible mask
    keypoints_uv       (N, K, 8, 2) float64   distorted pixels of the 8 box corners (NaN behind the camera)
    corners_cam        (N, K, 8, 3) float64   the corners in the camera frame, metres
    center_uv          (N, K, 2) float64      distorted pixel of the box centre
    visib_fract        (N, K) float64         visible / amodal pixels (0 when not in view)
    px_count_all       (N, K) int64, px_count_visib (N, K) int64
    label_map          (N, H, W) int16        exported object index 0..K-1 of the visible surface, -1 background
                                              (pixels of scene objects that are not exported are -1 too)
    frames/counts      (N, 2, H, W) uint16    [0] ON (p=1), [1] OFF (p=0) event counts, saturated at 65535
    frames/three_channel (N, H, W, 3) uint8   optional: evpose.core.label.represent.three_channel as RGB (ON, OFF, time)
    objects/corners_obj (K, 8, 3) float64     box corners in the object frame (corner order: bit a of the
                                              corner index set = max along axis a; x bit 0, y bit 1, z bit 2)
    _done              (N,) uint8             1 when the row is complete (resume bookkeeping)

Image datasets are chunked one window per chunk and compressed with Blosc/LZ4 (``hdf5plugin``; readers
need ``import hdf5plugin``); small datasets are chunked along windows. Root attributes: format,
evpose_version, scene, camera_K, camera_dist, width, height, object_names, class_ids, clock_offset_us,
clock_skew_ppm, clock_t_ref_us, corrections (JSON), window_us / window_events, label_at, margin_m,
counts_saturation, config_sha256.
"""
from __future__ import annotations

import contextlib
import json
import os
import time
from pathlib import Path

import numpy as np

from evpose.core.data.atomic import fsync_dir, write_atomic
from evpose.core.data.os_errors import ensure_free_space, os_error_from_hdf5
from evpose.core.export.common import ExportError, FormatWriter, evpose_version
from evpose.core.label.annotate import Request
from evpose.core.label.represent import polarity_counts, three_channel, three_channel_rgb

H5_FORMAT = "evpose-h5/1"
COUNTS_MAX = np.iinfo(np.uint16).max
_WINDOW_DTYPE = np.dtype([("index", "<i8"), ("t0_us", "<i8"), ("t1_us", "<i8"), ("t_label_us", "<i8"),
                          ("i0", "<i8"), ("i1", "<i8"), ("n_events", "<i8"), ("valid", "?")])
_BLOCK = 32        # rows buffered before one write per dataset
#: Free space kept beyond the estimate of each write (HDF5 metadata, closing the file).
_MARGIN_BYTES = 1 << 20


def _h5_failure(exc: BaseException, path: Path) -> BaseException:
    """An HDF5 failure while writing ``path`` (discarded by then): ``OSError`` naming it when the
    system refused the write (full disk...), else :class:`ExportError`; other exceptions unchanged."""
    err = os_error_from_hdf5(exc, path)
    if isinstance(err, OSError) and err.errno is not None:
        return err
    if isinstance(err, (OSError, RuntimeError, ValueError, KeyError)):
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        return ExportError(f"{path}: HDF5 could not write the file ({first}); it was removed: rerun the same "
                           "command to start it over")
    return err


def _superblock_eoa(path: Path) -> int | None:
    """The end-of-allocation address stored in an HDF5 superblock (versions 0-3, at offset 0), or None."""
    import struct

    with open(path, "rb") as fh:
        head = fh.read(56)
    if len(head) < 36 or head[:8] != b"\x89HDF\r\n\x1a\n":
        return None
    version = head[8]
    off = {0: 40, 1: 48, 2: 28, 3: 28}.get(version)
    if off is None or len(head) < off + 8:
        return None
    return struct.unpack_from("<Q", head, off)[0]


def _within_end_of_allocation(f, path: Path) -> bool:
    """A partial file left by a killed or failed run is sound to resume when HDF5 can walk all of its
    objects and every data chunk lies below the end of allocation its superblock records. (HDF5 can
    evict metadata that points past the recorded end before a crash; resuming such a file fails later
    with ``addr overflow``.) Reads only the chunk index, not the data."""
    import h5py

    eoa = _superblock_eoa(path)
    if eoa is None:
        return False
    end = 0

    def visit(_name, obj):
        nonlocal end
        if isinstance(obj, h5py.Dataset) and obj.chunks is not None:
            def info(ci):
                nonlocal end
                end = max(end, ci.byte_offset + ci.size)

            if hasattr(obj.id, "chunk_iter"):
                obj.id.chunk_iter(info)
            else:  # pragma: no cover - older HDF5
                for i in range(obj.id.get_num_chunks()):
                    info(obj.id.get_chunk_info(i))

    f.visititems(visit)
    return end <= eoa


def _safe_name(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "scene"


class H5Writer(FormatWriter):
    """HDF5 writer (see the module docstring)."""

    fmt = "h5"
    process_unlabeled = True        # frames and the windows row are written for unlabeled windows too

    def __init__(self, three_channel: bool = False, compression: str | None = "blosc-lz4"):
        if compression not in ("blosc-lz4", "gzip", None):
            raise ExportError(f"compression: expected 'blosc-lz4', 'gzip' or None, got {compression!r}")
        self.three_channel = bool(three_channel)
        self.compression = compression

    def options(self) -> dict:
        return {"three_channel": self.three_channel, "compression": self.compression}

    def request(self, margin_m: float) -> Request:
        return Request(keypoints=True, masks_visible=False, masks_full=False, label_map=True, margin_m=margin_m)

    def paths(self, ctx) -> tuple[Path, Path]:
        name = _safe_name(ctx.scene.name)
        return ctx.out_dir / f"{name}.h5", ctx.out_dir / f".{name}.h5.partial"

    def _comp(self) -> dict:
        if self.compression == "blosc-lz4":
            import hdf5plugin

            return dict(hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=hdf5plugin.Blosc.SHUFFLE))
        if self.compression == "gzip":
            return {"compression": "gzip", "compression_opts": 4, "shuffle": True}
        return {}

    # ------------------------------------------------------------------ parent
    def begin(self, ctx) -> None:
        import h5py

        final, part = self.paths(ctx)
        ctx.extra["h5"] = None
        ctx.extra["h5_buffer"] = {}
        write_atomic(ctx.out_dir / "README.txt", self.readme(ctx).encode(), ctx.fsync, ctx.owned)
        if final.exists():
            try:
                with h5py.File(final, "r") as f:
                    if f.attrs.get("config_sha256") == ctx.sha:
                        ctx.extra["h5_complete"] = True
                        return
            except OSError:
                pass
            final.unlink()
        ctx.extra["h5_complete"] = False
        f = None
        if part.exists():
            try:
                f = h5py.File(part, "r+", rdcc_nbytes=0)
                if (f.attrs.get("config_sha256") != ctx.sha or not self._layout_ok(ctx, f)
                        or not _within_end_of_allocation(f, part)):
                    f.close()
                    f = None
            except Exception:      # a crash left it unreadable: start over  # noqa: BLE001
                if f is not None:
                    ctx.extra["h5"] = f
                    self._discard(ctx)
                f = None
            if f is None:
                part.unlink(missing_ok=True)
        if f is None:
            ensure_free_space(part, _MARGIN_BYTES + len(ctx.extra["selected"]) * _WINDOW_DTYPE.itemsize,
                              "a new HDF5 file")
            ctx.owned.partial(part)          # logged before it exists (evpose.core.data.owned_files)
            try:
                f = self._create(ctx, part)
            except Exception as exc:
                self._discard(ctx)
                raise _h5_failure(exc, part) from None
        ctx.extra["h5"] = f
        ctx.extra["h5_layout"] = self._layout(f)

    def _layout_ok(self, ctx, f) -> bool:
        """The partial file has every dataset, each with one row per selected window."""
        n = len(ctx.extra["selected"])
        names = ["windows", "_done", "T_cam_obj", "label_map", "frames/counts"]
        if self.three_channel:
            names.append("frames/three_channel")
        return all(k in f and f[k].shape[:1] == (n,) for k in names) and f["_done"][:].shape == (n,)

    @staticmethod
    def _layout(f) -> dict:
        """Per-row dataset: (rows per chunk, bytes per row before compression), for the free-space check."""
        out = {}

        def visit(name, obj):
            import h5py

            if isinstance(obj, h5py.Dataset) and name != "windows" and obj.ndim >= 1 and obj.chunks is not None:
                out[name] = (int(obj.chunks[0]), int(np.prod(obj.shape[1:], dtype=np.int64)) * obj.dtype.itemsize)

        f.visititems(visit)
        return out

    def _need_bytes(self, ctx, runs) -> int:
        """An upper bound of the bytes writing rows ``runs`` (list of [a, b)) adds to the file: every chunk
        the rows touch, uncompressed, plus a margin."""
        need = _MARGIN_BYTES
        for chunk_rows, row_bytes in ctx.extra.get("h5_layout", {}).values():
            for a, b in runs:
                need += ((b - 1) // chunk_rows - a // chunk_rows + 1) * chunk_rows * row_bytes
        return need

    def _discard(self, ctx) -> None:
        """Throw the partial file away after a failed HDF5 write (a full disk): truncated first, so that
        HDF5 can close it (its close writes metadata; a file it cannot close crashes the interpreter at
        exit), then removed. The rerun starts it over."""
        _, part = self.paths(ctx)
        f = ctx.extra.get("h5")
        ctx.extra["h5"] = None
        ctx.extra["h5_buffer"] = {}
        with contextlib.suppress(OSError):
            os.truncate(part, 0)
        if f is not None:
            with contextlib.suppress(Exception):
                f.close()
        with contextlib.suppress(OSError):
            part.unlink()

    def _create(self, ctx, part: Path):
        import h5py

        scene = ctx.scene
        cam = scene.camera
        sel = ctx.extra["selected"]
        N, K, H, W = len(sel), len(ctx.names), cam.height, cam.width
        # no chunk cache: a write reaches the file at once, so a full disk fails that write or the flush after it
        # (an evicted chunk's failure would surface only at close, when HDF5 could no longer close the file)
        f = h5py.File(part, "w", track_order=False, rdcc_nbytes=0)
        rows = max(1, min(N, 1024))
        small = dict(chunks=True) if N else {}

        def ds(name, shape, dtype, fill=None, chunk=None, comp=False):
            kw = {"chunks": chunk or ((rows,) + shape[1:] if N else None)}
            if comp:
                kw.update(self._comp())
            if fill is not None:
                kw["fillvalue"] = fill
            return f.create_dataset(name, shape=shape, dtype=dtype, track_times=False,
                                    **(kw if N else {}))

        win = np.zeros(N, _WINDOW_DTYPE)
        for r, w in enumerate(sel):
            win[r] = (w.index, w.t0_us, w.t1_us, w.t_label_us, w.i0, w.i1, w.n_events, bool(ctx.extra["valid"][r]))
        f.create_dataset("windows", data=win, track_times=False, **small)
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
        ds("frames/counts", (N, 2, H, W), "u2", 0, chunk=(1, 2, H, W), comp=True)
        if self.three_channel:
            ds("frames/three_channel", (N, H, W, 3), "u1", 0, chunk=(1, H, W, 3), comp=True)
        ds("_done", (N,), "u1", 0)
        corners = np.stack([scene.model(n).bbox_corners(ctx.margin_m) for n in ctx.names]) if K else np.zeros((0, 8, 3))
        f.create_dataset("objects/corners_obj", data=corners, track_times=False)
        clock = scene.clock
        fp = ctx.fingerprint
        a = f.attrs
        a["format"] = H5_FORMAT
        a["evpose_version"] = evpose_version()
        a["scene"] = scene.name
        a["camera_K"] = cam.K
        a["camera_dist"] = cam.dist
        a["width"], a["height"] = W, H
        a["object_names"] = np.array(ctx.names, dtype=h5py.string_dtype())
        a["class_ids"] = np.array([scene.manifest.object(n).class_id for n in ctx.names], np.int64)
        a["clock_offset_us"] = np.int64(clock.offset_us)
        a["clock_skew_ppm"] = float(clock.skew_ppm)
        a["clock_t_ref_us"] = np.int64(clock.t_ref_us)
        a["clock_model"] = "t_pose_us = t_event_us + offset_us + skew_ppm * 1e-6 * (t_event_us - t_ref_us)"
        a["corrections"] = json.dumps(scene.corrections.to_json())
        a["window_us"] = -1 if fp["windows"]["window_us"] is None else fp["windows"]["window_us"]
        a["window_events"] = -1 if fp["windows"]["window_events"] is None else fp["windows"]["window_events"]
        a["label_at"] = ctx.label_at
        a["margin_m"] = float(ctx.margin_m)
        a["counts_saturation"] = int(COUNTS_MAX)
        a["config_sha256"] = ctx.sha
        f.flush()
        return f

    def completed(self, ctx) -> dict[int, dict]:
        sel = ctx.extra["selected"]
        if ctx.extra.get("h5_complete"):
            return {w.index: {"i": w.index, "status": "written" if v else "unlabeled"}
                    for w, v in zip(sel, ctx.extra["valid"])}
        f = ctx.extra["h5"]
        done = f["_done"][:] if len(sel) else np.zeros(0, np.uint8)
        return {w.index: {"i": w.index, "status": "written" if v else "unlabeled"}
                for w, v, d in zip(sel, ctx.extra["valid"], done) if d}

    def accept(self, ctx, record, payload) -> None:
        buf = ctx.extra["h5_buffer"]
        buf[payload["row"]] = payload
        if len(buf) >= _BLOCK:
            self._write_buffer(ctx)

    def _write_buffer(self, ctx) -> None:
        buf = ctx.extra["h5_buffer"]
        f = ctx.extra.get("h5")
        if not buf or f is None:
            return
        t_start = time.perf_counter()
        rows = sorted(buf)
        # contiguous runs -> one slice write per dataset and run
        runs, start = [], 0
        for j in range(1, len(rows) + 1):
            if j == len(rows) or rows[j] != rows[j - 1] + 1:
                runs.append(rows[start:j])
                start = j
        keys = [k for k in buf[rows[0]] if k != "row"]
        _, part = self.paths(ctx)
        # a full disk must stop us here, before HDF5 runs into it: the file stays whole and resumable
        ensure_free_space(part, self._need_bytes(ctx, [(run[0], run[-1] + 1) for run in runs]),
                          f"{len(rows)} windows")
        try:
            for run in runs:
                a, b = run[0], run[-1] + 1
                for k in keys:
                    f[k][a:b] = np.stack([buf[r][k] for r in run])
            for run in runs:        # flags last: a row is complete only after its data
                f["_done"][run[0]:run[-1] + 1] = 1
            buf.clear()
            f.flush()
        except Exception as exc:     # the file can no longer be trusted
            self._discard(ctx)
            raise _h5_failure(exc, part) from None
        ctx.extra["parent_write_s"] = ctx.extra.get("parent_write_s", 0.0) + time.perf_counter() - t_start

    def flush(self, ctx) -> None:
        self._write_buffer(ctx)
        f = ctx.extra.get("h5")
        if f is not None and ctx.durable != "none":
            fsync_dir(f.filename)

    def finish(self, ctx, records) -> list[str]:
        final, part = self.paths(ctx)
        f = ctx.extra.get("h5")
        if f is not None:
            self._write_buffer(ctx)
            try:
                done = f["_done"][:]
                f.close()
            except Exception as exc:
                self._discard(ctx)
                raise _h5_failure(exc, part) from None
            ctx.extra["h5"] = None
            if not done.all():      # pragma: no cover - every selected window goes through process()
                raise ExportError(f"{part}: {int((done == 0).sum())} rows were not written")
            if ctx.durable != "none":
                fsync_dir(part)
            st = os.stat(part)               # the final name is logged before it appears (same size, mtime)
            ctx.owned.files([(final, st.st_size, st.st_mtime_ns)])
            os.replace(part, final)
            if ctx.durable != "none":
                fsync_dir(final.parent)
        return [final.name, "README.txt"], []

    def abort(self, ctx) -> None:
        f = ctx.extra.get("h5")
        if f is not None:
            with contextlib.suppress(Exception):
                self._write_buffer(ctx)      # a full disk: refused before writing, the file stays resumable
            f = ctx.extra.get("h5")
            if f is not None:
                try:
                    f.close()
                except Exception:  # noqa: BLE001 - it cannot be closed: it cannot be trusted either
                    self._discard(ctx)
            ctx.extra["h5"] = None

    # ------------------------------------------------------------------ worker
    def setup_worker(self, wctx) -> dict:
        n_all = len(wctx.scene.object_names)
        lut = np.full(n_all + 1, -1, np.int16)
        lut[wctx.sel + 1] = np.arange(len(wctx.sel))
        return {"lut": lut}

    def process(self, wctx, task, ev, labels):
        cam = wctx.camera
        H, W = cam.height, cam.width
        w = task.window
        K = len(wctx.sel)
        t0 = time.perf_counter()
        pos, neg = polarity_counts(ev, W, H)
        counts = np.empty((2, H, W), np.uint16)
        np.minimum(pos, COUNTS_MAX, out=counts[0], casting="unsafe")
        np.minimum(neg, COUNTS_MAX, out=counts[1], casting="unsafe")
        p = {"row": task.row, "frames/counts": counts}
        if self.three_channel:
            p["frames/three_channel"] = three_channel_rgb(three_channel(ev, W, H, w.t0_us, w.t1_us))
        if labels is not None:
            objs = [labels.objects[k] for k in wctx.sel]
            p["T_cam_obj"] = np.stack([o.T_cam_obj for o in objs])
            p["T_base_cam"] = task.T_base_cam
            p["bbox_obj"] = np.array([o.bbox_obj for o in objs], np.int32).reshape(K, 4)
            p["bbox_visib"] = np.array([o.bbox_visib for o in objs], np.int32).reshape(K, 4)
            p["keypoints_uv"] = np.stack([o.corners_uv for o in objs])
            p["corners_cam"] = np.stack([o.corners_cam for o in objs])
            p["center_uv"] = np.stack([o.center_uv for o in objs])
            p["visib_fract"] = np.array([o.visib_fract for o in objs], np.float64)
            p["px_count_all"] = np.array([o.px_count_all for o in objs], np.int64)
            p["px_count_visib"] = np.array([o.px_count_visib for o in objs], np.int64)
            p["label_map"] = wctx.state["lut"][labels.label_map.astype(np.intp) + 1]
        else:
            p["T_cam_obj"] = np.full((K, 4, 4), np.nan)
            p["T_base_cam"] = np.full((4, 4), np.nan)
            p["bbox_obj"] = np.full((K, 4), -1, np.int32)
            p["bbox_visib"] = np.full((K, 4), -1, np.int32)
            p["keypoints_uv"] = np.full((K, 8, 2), np.nan)
            p["corners_cam"] = np.full((K, 8, 3), np.nan)
            p["center_uv"] = np.full((K, 2), np.nan)
            p["visib_fract"] = np.zeros(K)
            p["px_count_all"] = np.zeros(K, np.int64)
            p["px_count_visib"] = np.zeros(K, np.int64)
            p["label_map"] = np.full((H, W), -1, np.int16)
        wctx.timings["images"] += time.perf_counter() - t0
        return {"i": w.index, "status": "written" if labels is not None else "unlabeled"}, p

    def readme(self, ctx) -> str:
        from evpose.core.export import h5 as mod

        return (f"HDF5 export of scene \"{ctx.scene.name}\" written by evpose {evpose_version()}; "
                "see export_manifest.json for the configuration.\n" + (mod.__doc__ or ""))
