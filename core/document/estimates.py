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
                         text: str = "clock estimate", offset_std_us: float | None = None,
                         skew_std_ppm: float | None = None) -> None:
    """Make the clock in effect of ``scene`` equal an estimate (:func:`clock_correction_for`) as one
    undo step of ``history`` (which edits ``scene.corrections``), with the estimate's standard errors (µs, ppm: kept
    in the document's ``sigmas``, where the label sigma starts from; a skew the estimate kept is not its own)."""
    off, skew = clock_correction_for(scene, offset_us, skew_ppm)
    kept_skew = (scene.corrections.sigma("clock") or {}).get("skew_ppm") if skew == scene.corrections.skew_ppm else None
    with history.group(text):
        history.set(("offset_us",), off)
        history.set(("skew_ppm",), skew)
        # a skew the estimate kept keeps the sigma it had (the offset's change dropped the clock's sigmas)
        _store_sigma(history, "clock", offset_us=offset_std_us,
                     skew_ppm=kept_skew if skew_ppm is None or skew_std_ppm is None else skew_std_ppm)


def apply_pose_estimate(history: History, name: str, dT_base, text: str | None = None,
                        std_mm: float | None = None, std_deg: float | None = None) -> None:
    """Set the pose correction ``dT_base`` (4x4, base frame: ``T_base_obj' = dT_base @ T_base_obj``)
    of object ``name`` as one undo step, with the estimate's standard errors (mm of its centre, degrees)."""
    text = text or f"refine {name}"
    with history.group(text):
        history.set(("object", name), np.asarray(dT_base, dtype=np.float64), text=text)
        _store_sigma(history, f"object:{name}", mm=std_mm, deg=std_deg)


def apply_hand_eye_estimate(history: History, dT_cam, text: str = "hand-eye estimate",
                            std_mm: float | None = None, std_deg: float | None = None) -> None:
    """Set the hand-eye correction ``dT_cam`` (4x4, camera frame: ``T_base_cam' = T_base_cam @ dT_cam``) as one
    undo step, with the estimate's standard errors (mm of the camera's origin, degrees)."""
    with history.group(text):
        history.set(("hand_eye",), np.asarray(dT_cam, dtype=np.float64), text=text)
        _store_sigma(history, "hand_eye", mm=std_mm, deg=std_deg)


def _store_sigma(history: History, part: str, **values) -> None:
    """Store the finite, positive standard errors of ``values`` as ``part``'s sigmas (nothing when none is:
    an estimate without a sigma leaves the part without one -- its value's change cleared the old)."""
    import math

    known = {k: float(v) for k, v in values.items() if v is not None and math.isfinite(v) and v > 0}
    if known:
        history.set(("sigma", part), known)
