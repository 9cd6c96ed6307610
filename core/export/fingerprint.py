"""The configuration fingerprint of an export: everything its bytes depend on.

Two runs with equal fingerprints write identical files, so a rerun into the same folder resumes
(:mod:`evpose.core.export.out_folder`); anything else must not be mixed into one folder. The fingerprint
holds the format and its options, the windows, the review filter, the camera, the clock in effect, the
poses of every object (exported or occluding) and digests of the files read (events by size,
trajectory and meshes by sha256).
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

__all__ = ["EXPORT_LAYOUT_VERSION", "evpose_version", "file_digest", "T_list", "export_fingerprint", "fingerprint_sha"]

#: Version of the output layouts; part of the fingerprint and of every manifest. 2 (issue 22): PNGs deflated
#: run-length (other bytes, same pixels), HDF5 files in a canonical order, no run statistics in the manifest.
EXPORT_LAYOUT_VERSION = 2


def evpose_version() -> str:
    """The installed evpose version (written into every export)."""
    try:
        from importlib.metadata import version

        return version("evpose")
    except Exception:  # pragma: no cover - not installed
        return "unknown"


def file_digest(path) -> dict:
    """Name, size and sha256 of a file (the content an export depends on)."""
    path = Path(path)
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return {"file": path.name, "size": path.stat().st_size, "sha256": h.hexdigest()}


def T_list(T) -> list:
    """A 4x4 transform as nested lists of floats (JSON)."""
    return [[float(v) for v in row] for row in np.asarray(T, np.float64)]


def export_fingerprint(scene, names, *, fmt, format_options, window_us, window_events, label_at,
                       only_verified, margin_m, include_stale=False) -> dict:
    """Everything the exported bytes depend on (JSON-able). Two runs with equal fingerprints write
    identical files, so a rerun may resume; anything else must not be mixed into one folder."""
    m = scene.manifest
    clock = scene.clock
    ev = scene.events
    objects = []
    for n in names:
        spec = m.object(n)
        objects.append({"name": n, "class_id": int(spec.class_id), "T_base_obj": T_list(scene.T_base_obj(n)),
                        "mesh": file_digest(spec.mesh), "mesh_scale": float(spec.mesh_scale)})
    occluders = [{"name": n, "T_base_obj": T_list(scene.T_base_obj(n)), "mesh": file_digest(m.object(n).mesh)}
                 for n in scene.object_names if n not in names]
    doc = {
        "layout": EXPORT_LAYOUT_VERSION,
        "format": fmt,
        "format_options": format_options,
        "windows": {"window_us": None if window_events is not None else int(window_us),
                    "window_events": None if window_events is None else int(window_events),
                    "label_at": label_at},
        "only_verified": bool(only_verified),
        "reviews": [r.to_json() for r in scene.corrections.reviews] if only_verified else None,
        "margin_m": float(margin_m),
        "scene": scene.name,
        "camera": m.camera.to_dict(),
        "events": {"file": Path(m.events_path).name, "size": Path(m.events_path).stat().st_size,
                   "n_events": int(ev.n_events), "t_first_us": ev.t_first_us, "t_last_us": ev.t_last_us},
        "trajectory": None if m.trajectory_path is None else {     # None: an event-only scene
            **file_digest(m.trajectory_path), "frame": m.trajectory_frame,
            "hand_eye": None if m.hand_eye is None else T_list(m.hand_eye),
            "hand_eye_delta": T_list(scene.corrections.hand_eye_delta),
            # an explicit max gap changes the holes; the default follows from the file digest
            **({} if getattr(m, "trajectory_max_gap_us", None) is None
               else {"max_gap_us": int(m.trajectory_max_gap_us)})},
        "clock": {"offset_us": int(clock.offset_us), "skew_ppm": float(clock.skew_ppm), "t_ref_us": int(clock.t_ref_us)},
        "objects": objects,
        "occluders": occluders,
    }
    if only_verified and include_stale:
        doc["include_stale"] = True       # absent otherwise: fingerprints of earlier exports stay valid
    return doc


def fingerprint_sha(doc: dict) -> str:
    """The sha256 of a fingerprint (canonical JSON): the name of a configuration."""
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()
