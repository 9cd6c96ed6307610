"""``export_manifest.json``: the record of what an export holds and how it was made.

Written last, after every other file: the format, evpose version, configuration fingerprint, the clock
and hand-eye correction in effect, camera, the exported objects with their poses (manifest, correction,
result), every window of the tiling with its status (``written``, ``unlabeled``, ``missing``,
``filtered_unverified``), why windows have no label, the files, and the per-window file patterns.
``events_only`` is true for an event-only scene (no trajectory, no objects: an ``h5`` export of its event frames,
whose windows are ``written`` without labels).

Nothing of the run itself (run time, ``--jobs``, windows written now or skipped as already complete): equal
inputs give a byte-identical manifest, as every other file of an export, however the export was run or resumed.
The run's numbers are in :class:`evpose.core.export.summary.ExportSummary` (the command prints them).
"""
from __future__ import annotations

from pathlib import Path

from evpose.core.data.atomic import write_atomic
from evpose.core.export.encode import json_text
from evpose.core.export.fingerprint import EXPORT_LAYOUT_VERSION, T_list, evpose_version
from evpose.core.export.out_folder import MANIFEST_NAME

__all__ = ["CLOCK_MODEL", "write_manifest"]

CLOCK_MODEL = "t_pose_us = t_event_us + offset_us + skew_ppm * 1e-6 * (t_event_us - t_ref_us)"


def _windows_table(ctx, records, selected, valid) -> dict:
    """Every window of the tiling, column-wise, with its status in this export."""
    status = {}
    events_only = not ctx.scene.has_poses           # its windows have event frames, never labels
    for w, v in zip(selected, valid):
        v = v or events_only
        status[w.index] = "written" if (w.index in records and v) else ("unlabeled" if not v else "missing")
    win = {"index": [], "t0_us": [], "t1_us": [], "t_label_us": [], "i0": [], "i1": [], "status": []}
    sigma_out = ctx.extra.get("label_sigma_left_out", set())
    for w in ctx.windows:
        win["index"].append(w.index)
        win["t0_us"].append(w.t0_us)
        win["t1_us"].append(w.t1_us)
        win["t_label_us"].append(w.t_label_us)
        win["i0"].append(w.i0)
        win["i1"].append(w.i1)
        win["status"].append(status.get(w.index, "filtered_label_sigma" if w.index in sigma_out
                                        else "filtered_unverified"))
    return win


def _objects(ctx) -> list[dict]:
    """The exported objects: class, index among the scene's objects, poses in the base frame."""
    scene = ctx.scene
    corr = scene.corrections
    objs = []
    for k, n in zip(ctx.sel, ctx.names):
        spec = scene.manifest.object(n)
        objs.append({"name": n, "class_id": int(spec.class_id), "index": int(k),
                     "T_base_obj_manifest": T_list(spec.T_base_obj),
                     "dT_base": T_list(corr.object_delta(n)),
                     "T_base_obj": T_list(scene.T_base_obj(n)),
                     **ctx.extra.get("object_extra", {}).get(n, {})})
    return objs


def _clock(scene) -> dict:
    """The clock in effect, the scene's prior and the user's correction."""
    m, clock, corr = scene.manifest, scene.clock, scene.corrections
    return {"offset_us": int(clock.offset_us), "skew_ppm": float(clock.skew_ppm), "t_ref_us": int(clock.t_ref_us),
            "prior_offset_us": int(m.clock_offset_us), "prior_skew_ppm": float(m.clock_skew_ppm),
            "correction_offset_us": int(corr.offset_us), "correction_skew_ppm": float(corr.skew_ppm),
            "model": CLOCK_MODEL}


def write_manifest(ctx, summary, records, selected, valid, unlabeled) -> None:
    """Write ``OUT/export_manifest.json`` (atomically, logged) for the export of ``ctx``.

    ``records``: window index -> record of every complete window; ``selected`` / ``valid``: the selected
    windows and whether each has a label; ``unlabeled``: :func:`evpose.core.export.windows.unlabeled_windows`.
    """
    scene = ctx.scene
    m = scene.manifest
    fp = ctx.fingerprint
    doc = {
        "format": ctx.writer.fmt,
        "evpose_version": evpose_version(),
        "layout": EXPORT_LAYOUT_VERSION,
        "config_sha256": ctx.sha,
        "scene": {"name": scene.name, "path": str(Path(m.path).resolve())},
        "windows_config": fp["windows"],
        "only_verified": fp["only_verified"],
        "margin_m": ctx.margin_m,
        "format_options": fp["format_options"],
        "clock": _clock(scene),
        "events_only": not scene.has_poses,
        "hand_eye": {"trajectory_frame": m.trajectory_frame if scene.has_poses else None,
                     "hand_eye": None if m.hand_eye is None else T_list(m.hand_eye),
                     "dT_cam": T_list(scene.corrections.hand_eye_delta)},
        "camera": m.camera.to_dict(),
        "objects": _objects(ctx),
        "occluders_not_exported": [n for n in scene.object_names if n not in ctx.names],
        "counts": {"windows_total": summary.windows_total, "selected": summary.selected,
                   "labeled": int(valid.sum()), "unlabeled": summary.unlabeled,
                   "filtered_unverified": summary.filtered_unverified,
                   "filtered_label_sigma": summary.filtered_label_sigma},
        "unlabeled": unlabeled,
        "unlabeled_reasons": summary.unlabeled_reasons,
        "windows": _windows_table(ctx, records, selected, valid),
        "files": ctx.extra["top_files"],
        "window_files": ctx.extra["window_file_patterns"],
        "extra": ctx.extra.get("manifest_extra", {}),
    }
    write_atomic(ctx.out_dir / MANIFEST_NAME, json_text(doc).encode(), ctx.fsync, ctx.owned)
