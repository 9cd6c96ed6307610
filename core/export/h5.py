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
    label_sigma        (N, K, 3) float64      with --label-sigma: each label's 1-sigma [t mm, rotation deg, contour px]
                                              (evpose.core.label.uncertainty; NaN when not valid)
    label_map          (N, H, W) int16        exported object index 0..K-1 of the visible surface, -1 background
                                              (pixels of scene objects that are not exported are -1 too)
    frames/counts      (N, 2, H, W) uint16    [0] ON (p=1), [1] OFF (p=0) event counts, saturated at 65535
    frames/three_channel (N, H, W, 3) uint8   optional: evpose.core.label.event_frames.three_channel as RGB (ON, OFF, time)
    objects/corners_obj (K, 8, 3) float64     box corners in the object frame (corner order: bit a of the
                                              corner index set = max along axis a; x bit 0, y bit 1, z bit 2)
    _done              (N,) uint8             1 when the row is complete (resume bookkeeping)

An event-only scene (no trajectory, no objects: ``scene.toml`` without ``[trajectory]``) gives the same file without
the labels: ``windows`` (``valid`` false in every row), ``frames/counts``, the optional ``frames/three_channel`` and
``_done``; no ``T_cam_obj``, ``T_base_cam``, ``bbox_*``, ``keypoints_uv``, ``corners_cam``, ``center_uv``,
``visib_fract``, ``px_count_*``, ``label_map`` or ``objects/``; the root attribute ``events_only`` is true (false in a
labelled export) and ``object_names`` / ``class_ids`` are empty. The events themselves stay in the scene's
``events.h5``: ``windows`` ``i0``/``i1`` index them there.

Image datasets are chunked one window per chunk and compressed with Blosc/LZ4 (``hdf5plugin``; readers
need ``import hdf5plugin``); small datasets are chunked along windows. The finished file is written once more in
a canonical order (:mod:`evpose.core.export.h5_canonical`): equal inputs give byte-identical files across runs,
``--jobs``, Dask workers and resumes. Root attributes: format,
evpose_version, scene, camera_K, camera_dist, width, height, object_names, class_ids, clock_offset_us,
clock_skew_ppm, clock_t_ref_us, corrections (JSON), window_us / window_events, label_at, margin_m,
counts_saturation, events_only, config_sha256.
"""
from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

import numpy as np

from evpose.core.data.atomic import fsync_dir, fsync_path, write_atomic
from evpose.core.data.os_errors import ensure_free_space, os_error_from_hdf5
from evpose.core.data.temp_files import temp_path_for
from evpose.core.export.fingerprint import evpose_version
from evpose.core.export.h5_canonical import canonical_copy
from evpose.core.export.h5_file import (
    COUNTS_MAX,
    MARGIN_BYTES,
    WINDOW_DTYPE,
    chunk_layout,
    create_file,
    layout_ok,
    need_bytes,
    within_end_of_allocation,
)
from evpose.core.export.epose import three_channel_image
from evpose.core.export.options import ExportError
from evpose.core.export.writer import FormatWriter
from evpose.core.label.event_frames.counts import polarity_counts
from evpose.core.label.labels import Request

#: Rows buffered before one write per dataset.
_BLOCK = 32


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


def _is_complete(final: Path, sha: str) -> bool:
    """``final`` is a finished export of the configuration ``sha``."""
    import h5py

    try:
        with h5py.File(final, "r") as f:
            return f.attrs.get("config_sha256") == sha
    except OSError:
        return False


def _safe_name(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "scene"


class H5Writer(FormatWriter):
    """HDF5 writer (see the module docstring)."""

    fmt = "h5"
    process_unlabeled = True        # frames and the windows row are written for unlabeled windows too
    events_only_ok = True           # an event-only scene: events and event frames, no label dataset

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

    # ------------------------------------------------------------------ parent
    def begin(self, ctx) -> None:
        final, part = self.paths(ctx)
        ctx.extra["h5"] = None
        ctx.extra["h5_buffer"] = {}
        write_atomic(ctx.out_dir / "README.txt", self.readme(ctx).encode(), ctx.fsync, ctx.owned)
        if final.exists():
            if _is_complete(final, ctx.sha):
                ctx.extra["h5_complete"] = True
                part.unlink(missing_ok=True)     # a run killed after its rename left it
                return
            final.unlink()
        ctx.extra["h5_complete"] = False
        f = self._resume(ctx, part) if part.exists() else None
        if f is None:
            f = self._create(ctx, part)
        ctx.extra["h5"] = f
        ctx.extra["h5_layout"] = chunk_layout(f)

    def _resume(self, ctx, part: Path):
        """The partial file of an earlier run of this configuration, open for writing, when it is sound
        to resume; else None (the file is removed)."""
        import h5py

        f = None
        try:
            f = h5py.File(part, "r+", rdcc_nbytes=0)
            if (f.attrs.get("config_sha256") != ctx.sha
                    or not layout_ok(f, len(ctx.extra["selected"]), self.three_channel, ctx.scene.has_poses)
                    or not within_end_of_allocation(f, part)):
                f.close()
                f = None
        except Exception:      # a crash left it unreadable: start over  # noqa: BLE001
            if f is not None:
                ctx.extra["h5"] = f
                self._discard(ctx)
            f = None
        if f is None:
            part.unlink(missing_ok=True)
        return f

    def _create(self, ctx, part: Path):
        """A new partial file (after a free-space check), logged before it exists."""
        ensure_free_space(part, MARGIN_BYTES + len(ctx.extra["selected"]) * WINDOW_DTYPE.itemsize,
                          "a new HDF5 file")
        ctx.owned.partial(part)          # logged before it exists (evpose.core.data.owned_log)
        try:
            return create_file(ctx, part, three_channel=self.three_channel, compression=self.compression)
        except Exception as exc:
            self._discard(ctx)
            raise _h5_failure(exc, part) from None

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

    def completed(self, ctx) -> dict[int, dict]:
        sel = ctx.extra["selected"]
        written = ctx.extra["valid"] | (not ctx.scene.has_poses)     # an event-only scene's rows are all written
        if ctx.extra.get("h5_complete"):
            return {w.index: {"i": w.index, "status": "written" if v else "unlabeled"}
                    for w, v in zip(sel, written)}
        f = ctx.extra["h5"]
        done = f["_done"][:] if len(sel) else np.zeros(0, np.uint8)
        return {w.index: {"i": w.index, "status": "written" if v else "unlabeled"}
                for w, v, d in zip(sel, written, done) if d}

    def accept(self, ctx, record, payload, line=None) -> None:
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
        ensure_free_space(part, need_bytes(ctx.extra.get("h5_layout", {}), [(run[0], run[-1] + 1) for run in runs]),
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
            self._finish_canonical(ctx, part, final)
        return [final.name, "README.txt"], []

    @staticmethod
    def _finish_canonical(ctx, part: Path, final: Path) -> None:
        """The final file: the complete partial file rewritten in the canonical order
        (:func:`evpose.core.export.h5_canonical.canonical_copy`, so equal data gives equal bytes whatever the
        order the rows were written in, resumes included), fsynced, logged, renamed into place; then the partial
        file is removed. A kill before the rename leaves the partial file (the rerun finishes from it) and a
        temporary file (removed by the rerun)."""
        ensure_free_space(part, os.stat(part).st_size + MARGIN_BYTES, "the finished HDF5 file")
        tmp = temp_path_for(final)
        try:
            canonical_copy(part, tmp)
            if ctx.durable != "none":
                fsync_path(tmp)
        except BaseException as exc:
            with contextlib.suppress(OSError):
                tmp.unlink()
            if isinstance(exc, Exception):
                raise _h5_failure(exc, final) from None
            raise
        st = os.stat(tmp)                    # the final name is logged before it appears (same size, mtime)
        ctx.owned.files([(final, st.st_size, st.st_mtime_ns)])
        os.replace(tmp, final)
        part.unlink()
        if ctx.durable != "none":
            fsync_dir(final.parent)

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
        if self.three_channel:      # three_channel_rgb(three_channel(...)) computed at the event pixels only
            p["frames/three_channel"] = three_channel_image(ev, W, H, w.t0_us, (pos | neg).ravel())
        if not wctx.scene.has_poses:        # an event-only scene: the frames are the whole row
            wctx.timings["images"] += time.perf_counter() - t0
            return {"i": w.index, "status": "written"}, p
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
            if task.sigma is not None:
                p["label_sigma"] = np.asarray(task.sigma, np.float64)
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
