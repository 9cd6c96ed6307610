"""The options of an export, checked before anything is written, and :class:`ExportError`.

Every check raises :class:`ExportError` naming the option and the value at fault. The window options
are checked by :func:`evpose.core.export.windows.build_windows`, the format options by each writer.
"""
from __future__ import annotations

import math

import numpy as np

from evpose.core.errors import InputError

__all__ = ["FORMATS", "ExportError", "durability_mode", "export_objects", "check_events_only", "check_margin",
           "check_jobs"]

FORMATS = ("epose", "bop", "h5")


class ExportError(InputError):
    """A user-facing export error; the message names the file or the option at fault."""


def durability_mode(durable) -> str:
    """``True``/"batch" -> "batch", "file" -> "file", ``False``/"none" -> "none"."""
    if durable is True or durable == "batch":
        return "batch"
    if durable == "file":
        return "file"
    if durable is False or durable == "none" or durable is None:
        return "none"
    raise ExportError(f"durable: expected True, False, 'batch', 'file' or 'none', got {durable!r}")


def export_objects(scene, objects) -> tuple[list[str], np.ndarray]:
    """The exported object names in the scene's order (``objects`` None: all) and their indices among
    the scene's objects."""
    names = list(scene.object_names) if objects is None else list(objects)
    for n in names:
        if n not in scene.object_names:
            raise ExportError(f"objects: no object named {n!r} in {scene.manifest.path} "
                              f"(objects: {', '.join(scene.object_names)})")
    if not names:
        raise ExportError("objects: at least one object must be exported")
    names = [n for n in scene.object_names if n in names]           # scene order
    sel = np.array([scene.object_names.index(n) for n in names], np.intp)
    return names, sel


def check_events_only(scene, writer, objects, only_verified: bool) -> bool:
    """True when ``scene`` is event-only (no trajectory, no objects: ``scene.has_poses`` False), after refusing
    what such a scene cannot give, in one line each: a format that writes labels (every format but ``h5``, whose
    writer sets ``events_only_ok``), ``objects``, and ``only_verified`` (review marks are made on labels)."""
    if getattr(scene, "has_poses", True):
        return False
    from evpose.core.data.manifest import ADD_TRAJECTORY_HINT, EVENTS_ONLY

    path = scene.manifest.path
    if not getattr(writer, "events_only_ok", False):
        raise ExportError(f"{path}: [trajectory]: missing table: --format {writer.fmt} writes labels, and labels need "
                          f"a trajectory; this scene holds {EVENTS_ONLY} (--format h5 exports its events and event "
                          f"frames; {ADD_TRAJECTORY_HINT})")
    if objects:
        raise ExportError(f"objects: {path} has no objects ({EVENTS_ONLY})")
    if only_verified:
        raise ExportError(f"only_verified: {path} has no labels to verify ({EVENTS_ONLY})")
    return True


def check_margin(margin_m) -> None:
    """The box margin: a finite number of metres >= 0."""
    if not (isinstance(margin_m, (int, float)) and math.isfinite(margin_m) and margin_m >= 0):
        raise ExportError(f"margin: must be a finite number >= 0 (metres), got {margin_m!r}")


def check_jobs(jobs) -> int:
    """The number of worker processes, a positive integer."""
    if isinstance(jobs, bool) or int(jobs) != jobs or jobs < 1:
        raise ExportError(f"jobs: must be a positive integer, got {jobs!r}")
    return int(jobs)
