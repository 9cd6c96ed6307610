"""The published E-POSE per-sequence layout, with correct values (DESIGN section 6).

Per window ``NNNN`` (zero-based window index of the tiling, 4 digits, more when the recording has
more than 10 000 windows), all images in the **raw, distorted** event camera (the pixels of the
events), 346x260 for a DAVIS346:

``NNNN_event_image.png``
    8-bit gray: 255 where the window has at least one event (either polarity), 0 elsewhere.
``NNNN_mask_image.png`` (one exported object)
    1-bit PNG (OpenCV reads 0/255, PIL/MATLAB a logical image): the object's visible mask.
``NNNN_mask_image_all.png`` and ``NNNN_mask_image_obj{K}.png`` (several objects)
    ``_all``: 8-bit label image (16-bit when more than 255 objects), 0 background, ``K`` = 1-based
    position of the object among the exported objects (``object_names`` in the .mat), visible
    (occlusion-resolved) pixels; never saturated. ``_obj{K}``: 1-bit visible mask of object ``K``.
``NNNN_segmented_image.png``
    8-bit gray: 255 where an event falls on the visible mask of an exported object.
    Several objects: also ``NNNN_segmented_image_obj{K}.png``, the same for object ``K`` alone.
``NNNN_three_channel_image.png``
    8-bit RGB: R = ON count / max ON count, G = OFF count / max OFF count, B = latest event time at the
    pixel ``(t_last - t0 + 1) / max`` (:func:`evpose.core.label.event_frames.three_channel.three_channel`, this window's events only).
``NNNN_bbox.txt``
    As the original: one exported object: one line of 8 numbers ``u1 v1 .. u4 v4`` (``%.4f``), the
    distorted pixel coordinates of box corners p1..p4; several: one line per object,
    ``name`` + two spaces + the 8 numbers. ``nan`` for a corner behind the camera.
``NNNN_data.mat`` (MATLAB 5, written last: its presence marks the window complete; never skipped)
    Original fields and shapes, for ``k`` exported objects:
    ``pose`` 4x4k (T_cam_obj side by side), ``keypointprojections`` 8x5k (per object ``[u v X Y Z]`` of
    the 8 box corners in the original corner order p1..p8: (+x+y-z) (+x-y-z) (-x+y-z) (-x-y-z)
    (+x+y+z) (+x-y+z) (-x+y+z) (-x-y+z); ``u v`` distorted pixels, ``X Y Z`` camera frame, metres),
    ``centerInfo`` 1x2k (``u v`` of the object-frame origin, the original's point p9), ``cameraPose``
    3x4 (``T_base_cam[:3, :]`` at this window's label time; the original's shape), ``intrinsicMatrix``
    3x3, ``time`` 1x1 (label time, seconds since the recording's first event, event clock),
    ``events`` Nx4 ``[x y t p]`` (this window's events: 0-based pixel column/row, ``t`` seconds since
    the first event of the recording, ``p`` -1/+1), ``cls_index`` 1xk.
    Added fields: ``T_base_cam`` 4x4, ``t_start_us``/``t_end_us``/``t_label_us``/``t_ref_us`` (int64,
    absolute event clock; ``round(t * 1e6) + t_ref_us`` recovers each event's exact µs),
    ``clock_offset_us`` (int64) / ``clock_skew_ppm``, ``distCoeffs``, ``image_size`` [H W],
    ``object_names`` (cell), ``box_center`` kx5 ``[u v X Y Z]`` of the box centre, ``bbox_obj`` /
    ``bbox_visib`` kx4 ``[x y w h]`` tight boxes of the amodal / visible masks (-1 when empty),
    ``px_count_all`` / ``px_count_visib`` / ``visib_fract`` 1xk; with ``--label-sigma``: ``sigma_t_mm``,
    ``sigma_R_deg``, ``sigma_px`` 1xk, each label's 1-sigma (:mod:`evpose.core.label.uncertainty`).

Beside the windows: ``<object>_box.txt`` (object-frame box corners p1..p8 as 3 rows of 8, metres,
the original's ``*_box.txt``), ``three_channel_image_paths.txt`` (names relative to the folder),
``README.txt`` and ``export_manifest.json``.
"""
from __future__ import annotations

import time

import cv2
import numpy as np

from evpose.core.data.atomic import AtomicBatch, write_atomic
from evpose.core.export.encode import encode_png, savemat_bytes
from evpose.core.export.epose_readme import readme_text
from evpose.core.export.options import ExportError
from evpose.core.export.writer import FormatWriter
from evpose.core.label.labels import Request

#: Original E-POSE corner order p1..p8 as indices into :func:`evpose.core.data.objects.ObjectModel.bbox_corners`
#: (whose corner i takes the max along axis a when bit a of i is set).
EPOSE_CORNER_ORDER = np.array([3, 1, 2, 0, 7, 5, 6, 4])


def three_channel_image(ev, width: int, height: int, t0_us: int, spike: np.ndarray) -> np.ndarray:
    """``three_channel_rgb(three_channel(ev, width, height, t0_us, t1_us))`` as RGB ``uint8 (H, W, 3)``,
    bit-identical (tested against evpose.core.label.event_frames), with the float
    conversions done only at the pixels that have events (``spike`` > 0, flat ``(H*W,)``); the image is
    zero elsewhere. Same arithmetic: channel = float32(value / max) (float64 division), then
    rint(float64(channel) * 255). 0.6 ms instead of 4 ms CPU for a 16 k-event DAVIS346 window.
    """
    HW = width * height
    out = np.zeros((HW, 3), np.uint8)
    if len(ev) == 0:
        return out.reshape(height, width, 3)
    key = ev.y.astype(np.intp)
    key *= width
    key += ev.x
    kp = ev.p.astype(np.intp)
    kp *= HW
    kp += key                                   # OFF in [0, HW), ON in [HW, 2 HW)
    counts = np.bincount(kp, minlength=2 * HW)
    last = np.zeros(HW, np.int64)                # t_last - t0 + 1 per pixel (either polarity)
    np.maximum.at(last, key, ev.t - (int(t0_us) - 1))
    idx = np.flatnonzero(spike)
    for ch, a in ((0, counts[HW:][idx]), (1, counts[:HW][idx]), (2, last[idx])):
        m = a.max()
        if m > 0:
            v = (a / float(m)).astype(np.float32).astype(np.float64)
            v *= 255.0
            np.rint(v, out=v)
            out[idx, ch] = v
    return out.reshape(height, width, 3)


def window_stem(index: int, n_digits: int) -> str:
    return f"{index:0{n_digits}d}"


#: Per-window products a user may leave out (``skip`` option, ``--skip``), by name: the files each removes.
#: The ``.mat`` (labels, events, completion mark) is always written. Files per window with ``k`` objects: all
#: products ``4 + 2 (k + 1)`` for ``k > 1`` (5 objects: 16), ``6`` for one; see :meth:`EposeWriter.window_files`.
SKIPPABLE = ("event_image", "masks", "segmented", "three_channel", "bbox")


def check_skip(skip) -> tuple[str, ...]:
    """``skip`` (names from :data:`SKIPPABLE`, any order, or a comma-separated string) as a sorted tuple."""
    if isinstance(skip, str):
        skip = [s.strip() for s in skip.split(",") if s.strip()]
    names = tuple(sorted(set(skip or ())))
    bad = [n for n in names if n not in SKIPPABLE]
    if bad:
        raise ValueError(f"skip: unknown product {', '.join(map(repr, bad))} (E-POSE products: "
                         f"{', '.join(SKIPPABLE)}; the .mat is always written)")
    return names


class EposeWriter(FormatWriter):
    """E-POSE layout writer (see the module docstring for every encoding). ``skip``: products of
    :data:`SKIPPABLE` not written (fewer files per window; part of the export's configuration)."""

    fmt = "epose"

    def __init__(self, png_compression: int = 1, skip=()):
        self.png_compression = int(png_compression)
        self.skip = check_skip(skip)

    def options(self) -> dict:
        # "skip" only when set: an export without it keeps the configuration hash of earlier versions
        return {"png_compression": self.png_compression, **({"skip": list(self.skip)} if self.skip else {})}

    def request(self, margin_m: float) -> Request:
        # one rasterisation gives the label map; every mask and the segmentation derive from it
        return Request(keypoints=True, masks_visible=False, masks_full=False, label_map=True,
                       segment_events=False, margin_m=margin_m)

    # ------------------------------------------------------------------ names
    def window_files(self, index: int, n_digits: int, k: int) -> list[str]:
        """The files of window ``index`` with ``k`` exported objects, in write order (the ``.mat`` last)."""
        s, skip = window_stem(index, n_digits), self.skip
        files = [] if "event_image" in skip else [f"{s}_event_image.png"]
        if k == 1:
            files += [] if "masks" in skip else [f"{s}_mask_image.png"]
            files += [] if "segmented" in skip else [f"{s}_segmented_image.png"]
        else:
            if "masks" not in skip:
                files += [f"{s}_mask_image_all.png"] + [f"{s}_mask_image_obj{j}.png" for j in range(1, k + 1)]
            if "segmented" not in skip:
                files += [f"{s}_segmented_image.png"] + [f"{s}_segmented_image_obj{j}.png" for j in range(1, k + 1)]
        files += [] if "three_channel" in skip else [f"{s}_three_channel_image.png"]
        files += [] if "bbox" in skip else [f"{s}_bbox.txt"]
        return files + [f"{s}_data.mat"]

    def last_file(self, ctx, index):
        return ctx.out_dir / f"{window_stem(index, ctx.n_digits)}_data.mat"

    # ------------------------------------------------------------------ parent
    def begin(self, ctx) -> None:
        scene = ctx.scene
        for n in ctx.names:
            c = scene.model(n).bbox_corners(ctx.margin_m)[EPOSE_CORNER_ORDER]     # (8, 3)
            text = "".join(" ".join(f"{v:.6f}" for v in row) + "\n" for row in c.T)
            write_atomic(ctx.out_dir / f"{n}_box.txt", text.encode(), ctx.fsync, ctx.owned)
        write_atomic(ctx.out_dir / "README.txt", self.readme(ctx).encode(), ctx.fsync, ctx.owned)

    def finish(self, ctx, records) -> list[str]:
        k = len(ctx.names)
        written = sorted(i for i, r in records.items() if r.get("status") == "written")
        files = [f"{n}_box.txt" for n in ctx.names]
        if "three_channel" not in self.skip:
            paths = "".join(f"{window_stem(i, ctx.n_digits)}_three_channel_image.png\n" for i in written)
            write_atomic(ctx.out_dir / "three_channel_image_paths.txt", paths.encode(), ctx.fsync, ctx.owned)
            files.append("three_channel_image_paths.txt")
        files.append("README.txt")
        per = [f for i in written for f in self.window_files(i, ctx.n_digits, k)]
        ctx.extra["n_window_files"] = len(per)
        patterns = [f.replace("0" * ctx.n_digits, f"{{index:0{ctx.n_digits}d}}", 1)
                    for f in self.window_files(0, ctx.n_digits, k)]
        return files + per, patterns

    # ------------------------------------------------------------------ worker
    def setup_worker(self, wctx) -> dict:
        scene = wctx.scene
        cam = wctx.camera
        n_all = len(scene.object_names)
        k = len(wctx.sel)
        lut = np.zeros(n_all + 1, np.uint8 if k <= 255 else np.uint16)   # label_map + 1 -> exported label
        lut[wctx.sel + 1] = np.arange(1, k + 1)
        lut256 = np.zeros(256, np.uint8)
        if len(lut) <= 256 and lut.dtype == np.uint8:
            lut256[:len(lut)] = lut
        class_ids = np.array([scene.model(n).class_id for n in wctx.names], np.float64)
        return {"lut": lut, "lut256": lut256, "t_ref": int(scene.clock.t_ref_us), "clock": scene.clock,
                "class_ids": class_ids, "K": np.asarray(cam.K, np.float64),
                "dist": np.asarray(cam.dist, np.float64), "names": np.array(wctx.names, dtype=object),
                "spike": np.zeros(cam.height * cam.width, np.uint8)}

    def process(self, wctx, task, ev, labels):
        w = task.window
        stem = window_stem(w.index, wctx.spec.n_digits)
        objs = [labels.objects[i] for i in wctx.sel]
        t0 = time.perf_counter()
        spike = _event_pixels(wctx, w.index, ev)
        blobs = self._images(wctx, stem, ev, spike, labels.label_map, w.t0_us)
        keypoints = _keypoints(wctx.camera, objs)
        if "bbox" not in self.skip:
            blobs.append((f"{stem}_bbox.txt", _bbox_text(objs, wctx.names).encode()))
        t1 = time.perf_counter()
        mat = savemat_bytes(_mat_fields(wctx, task, ev, objs, keypoints))
        t2 = time.perf_counter()
        with AtomicBatch(wctx.fsync_files, wctx.owned) as batch:
            for name, data in blobs:
                batch.add(wctx.out_dir / name, data)
            batch.add(wctx.out_dir / f"{stem}_data.mat", mat)           # last: marks the window complete
        t3 = time.perf_counter()
        tm = wctx.timings
        tm["images"] += t1 - t0
        tm["mat"] += t2 - t1
        tm["write"] += t3 - t2
        return {"i": w.index, "status": "written", "n_events": len(ev)}, None

    def _images(self, wctx, stem: str, ev, spike: np.ndarray, label_map: np.ndarray, t0_us: int) -> list:
        """``(file name, PNG bytes)`` of the window's images: events, masks, segmentation, three-channel."""
        st = wctx.state
        H, W = wctx.camera.height, wctx.camera.width
        k = len(wctx.sel)
        lab = _exported_labels(st, label_map)                          # flat: 0 bg, 1..k
        on_obj = lab > 0
        seg = spike * on_obj                                           # uint8: 255 * 1 or 0
        comp = self.png_compression
        skip = self.skip
        blobs = [] if "event_image" in skip else [(f"{stem}_event_image.png",
                                                   encode_png(spike.reshape(H, W), compression=comp))]
        masks = [lab == j for j in range(1, k + 1)] if k > 1 else [on_obj]
        if "masks" not in skip:
            if k == 1:
                blobs.append((f"{stem}_mask_image.png", encode_png(on_obj.view(np.uint8).reshape(H, W), bilevel=True)))
            else:
                blobs.append((f"{stem}_mask_image_all.png", encode_png(lab.reshape(H, W), compression=comp)))
                for j, m in enumerate(masks, 1):
                    blobs.append((f"{stem}_mask_image_obj{j}.png",
                                  encode_png(m.view(np.uint8).reshape(H, W), bilevel=True)))
        if "segmented" not in skip:
            blobs.append((f"{stem}_segmented_image.png", encode_png(seg.reshape(H, W), compression=comp)))
            if k > 1:
                for j, m in enumerate(masks, 1):
                    blobs.append((f"{stem}_segmented_image_obj{j}.png",
                                  encode_png((spike * m).reshape(H, W), compression=comp)))
        if "three_channel" not in skip:
            rgb = three_channel_image(ev, W, H, t0_us, spike)
            blobs.append((f"{stem}_three_channel_image.png", encode_png(rgb, compression=comp)))
        return blobs

    # ------------------------------------------------------------------ README
    def readme(self, ctx) -> str:
        return readme_text(ctx)


def _exported_labels(st: dict, label_map: np.ndarray) -> np.ndarray:
    """Flat ``(H*W,)`` exported label of every pixel (0 background, ``K`` = 1-based position among the
    exported objects) from the annotator's ``label_map`` (scene object index, -1 background), through the
    worker's table ``st["lut"]`` (label_map + 1 -> exported label); with at most 255 scene objects by
    OpenCV's 8-bit table lookup (0.1 instead of 0.3 ms per DAVIS346 frame)."""
    lut = st["lut"]
    if len(lut) <= 256 and lut.dtype == np.uint8:
        idx = np.add(label_map.ravel(), 1, dtype=np.int16).astype(np.uint8)
        return cv2.LUT(idx, st["lut256"]).ravel()
    return lut[label_map.ravel().astype(np.intp) + 1]


def _event_pixels(wctx, index: int, ev) -> np.ndarray:
    """The worker's flat ``(H*W,)`` uint8 buffer set to 255 at every pixel with an event of the window
    (either polarity), 0 elsewhere; an event off the sensor is refused naming the event file."""
    H, W = wctx.camera.height, wctx.camera.width
    spike = wctx.state["spike"]
    spike[:] = 0
    if len(ev):
        if int(ev.x.max()) >= W or int(ev.y.max()) >= H:
            raise ExportError(f"{wctx.scene.manifest.events_path}: events/x, events/y: an event of window "
                              f"{index} lies outside the {W}x{H} sensor of scene.toml [camera]")
        key = ev.y.astype(np.intp)
        key *= W
        key += ev.x
        spike[key] = 255
    return spike


def _keypoints(cam, objs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``keypointprojections`` (8, 5k), ``centerInfo`` (2k,) and ``box_center`` (k, 5) of the .mat."""
    k = len(objs)
    kp = np.empty((8, 5 * k))
    centre = np.empty(2 * k)
    box_c = np.empty((k, 5))
    if k:
        centre[:] = cam.project(np.stack([o.T_cam_obj[:3, 3] for o in objs]))[0].ravel()   # per point: one call
    for j, o in enumerate(objs):
        kp[:, 5 * j:5 * j + 2] = o.corners_uv[EPOSE_CORNER_ORDER]
        kp[:, 5 * j + 2:5 * j + 5] = o.corners_cam[EPOSE_CORNER_ORDER]
        box_c[j, :2] = o.center_uv
        box_c[j, 2:] = o.center_cam
    return kp, centre, box_c


def _bbox_text(objs, names) -> str:
    """``NNNN_bbox.txt``: the distorted pixels of corners p1..p4 (one object: one line; several: one line
    per object after its name)."""
    rows = [" ".join(f"{v:.4f}" for v in o.corners_uv[EPOSE_CORNER_ORDER[:4]].ravel()) for o in objs]
    if len(objs) == 1:
        return rows[0] + "\n"
    return "".join(f"{n}  {r}\n" for n, r in zip(names, rows))


def _mat_fields(wctx, task, ev, objs, keypoints) -> dict:
    """The fields of ``NNNN_data.mat`` (see the module docstring), in file order."""
    st = wctx.state
    cam = wctx.camera
    w = task.window
    k = len(objs)
    kp, centre, box_c = keypoints
    t_ref = st["t_ref"]
    evm = np.empty((len(ev), 4), order="F")     # column-major, as the .mat stores it: written without a copy
    evm[:, 0] = ev.x
    evm[:, 1] = ev.y
    np.multiply(ev.t - t_ref, 1e-6, out=evm[:, 2])
    np.multiply(ev.p, 2.0, out=evm[:, 3])
    evm[:, 3] -= 1.0
    T_bc = task.T_base_cam
    clock = st["clock"]
    sigma = {}
    if task.sigma is not None:         # --label-sigma: each label's 1-sigma (evpose.core.label.uncertainty)
        sig = np.asarray(task.sigma, np.float64)
        sigma = {"sigma_t_mm": sig[None, :, 0], "sigma_R_deg": sig[None, :, 1], "sigma_px": sig[None, :, 2]}
    return {
        "pose": np.concatenate([o.T_cam_obj for o in objs], axis=1),
        "keypointprojections": kp,
        "centerInfo": centre[None, :],
        "cameraPose": T_bc[:3, :].copy(),
        "intrinsicMatrix": st["K"],
        "time": np.array([[(w.t_label_us - t_ref) * 1e-6]]),
        "events": evm,
        "cls_index": st["class_ids"][None, :],
        "T_base_cam": T_bc,
        "t_start_us": np.array([[w.t0_us]], np.int64),
        "t_end_us": np.array([[w.t1_us]], np.int64),
        "t_label_us": np.array([[w.t_label_us]], np.int64),
        "t_ref_us": np.array([[t_ref]], np.int64),
        "clock_offset_us": np.array([[clock.offset_us]], np.int64),
        "clock_skew_ppm": np.array([[clock.skew_ppm]], np.float64),
        "distCoeffs": st["dist"][None, :],
        "image_size": np.array([[cam.height, cam.width]], np.float64),
        "object_names": st["names"],
        "box_center": box_c,
        "bbox_obj": np.array([o.bbox_obj for o in objs], np.float64).reshape(k, 4),
        "bbox_visib": np.array([o.bbox_visib for o in objs], np.float64).reshape(k, 4),
        "px_count_all": np.array([[o.px_count_all for o in objs]], np.float64),
        "px_count_visib": np.array([[o.px_count_visib for o in objs]], np.float64),
        "visib_fract": np.array([[o.visib_fract for o in objs]], np.float64),
        **sigma,
    }
