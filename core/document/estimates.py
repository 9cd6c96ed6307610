"""Accepted estimates into the document: the one path from a clock or pose estimate to corrections.

Automatic estimates (clock sync, clock from edges, pose refinement) produce values *in effect*:
the clock offset and skew the scene should have, an object's base-frame pose correction. The
document stores corrections on top of the scene's prior, so a clock estimate becomes
``offset_us - prior offset`` and ``skew_ppm - prior skew``. The app (through
:class:`~evpose.core.session.model.Session`) and the CLI's ``--apply`` (on a bare scene) both go
through these functions, each edit one undo step of the given history.
"""
from __future__ import annotations

import numpy as np

from evpose.core.document.history import History


def clock_correction_for(scene, offset_us: int, skew_ppm: float | None) -> tuple[int, float]:
    """The corrections ``(offset_us, skew_ppm)`` that make the clock in effect of ``scene`` equal
    ``offset_us`` (event-to-pose offset at the first event, us) and ``skew_ppm``: the estimate minus
    the manifest's prior (``scene.manifest.clock_offset_us``, ``clock_skew_ppm``). ``skew_ppm``
    None keeps the current skew correction (``scene.corrections.skew_ppm``)."""
    off = int(offset_us) - int(scene.manifest.clock_offset_us)
    skew = (float(scene.corrections.skew_ppm) if skew_ppm is None
            else float(skew_ppm) - float(scene.manifest.clock_skew_ppm))
    return off, skew


def apply_clock_estimate(history: History, scene, offset_us: int, skew_ppm: float | None,
                         text: str = "clock estimate") -> None:
    """Make the clock in effect of ``scene`` equal an estimate (:func:`clock_correction_for`) as one
    undo step of ``history`` (which edits ``scene.corrections``)."""
    off, skew = clock_correction_for(scene, offset_us, skew_ppm)
    with history.group(text):
        history.set(("offset_us",), off)
        history.set(("skew_ppm",), skew)


def apply_pose_estimate(history: History, name: str, dT_base, text: str | None = None) -> None:
    """Set the pose correction ``dT_base`` (4x4, base frame: ``T_base_obj' = dT_base @ T_base_obj``)
    of object ``name`` as one undo step."""
    history.set(("object", name), np.asarray(dT_base, dtype=np.float64), text=text or f"refine {name}")
