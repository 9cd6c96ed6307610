"""Accepting a clock estimate: the corrections it stands for, stored through the History.

The estimates hold *total* clocks (prior + correction); the scene stores corrections on top of
the manifest's prior. This module converts one into the other and applies an accepted estimate
as one undo step -- only the parts that differ from what is in effect by more than :data:`APPLY_SIGMAS` of their
standard errors (:func:`clock_differs`): a value the estimate cannot tell from the one in effect is kept, so a right
clock or pose is never replaced by a noisier copy of itself, and an estimate without a standard error changes
nothing --  for the CLI's ``--apply`` (the app goes through
:meth:`evpose.core.session.model.Session.apply_clock_estimate`); both end in
:mod:`evpose.core.document.estimates`, the one place that turns an estimate into corrections.
"""
from __future__ import annotations

import math

from evpose.core.align.refine_result import RefineResult
from evpose.core.align.sync_result import SyncResult
from evpose.core.document.estimates import apply_clock_estimate, clock_correction_for

__all__ = ["APPLY_SIGMAS", "apply_joint_result", "apply_offset_result", "apply_sync", "clock_correction", "clock_differs",
           "save_applied"]

#: An estimate replaces what is in effect only where it differs by more than this many of its standard errors.
APPLY_SIGMAS = 2.0


def _beyond(change: float, std, k: float = APPLY_SIGMAS) -> bool:
    """``|change| > k * std`` with a finite, positive standard error (None, NaN or inf: never)."""
    return std is not None and math.isfinite(std) and std > 0 and abs(change) > k * std


def clock_differs(scene, offset_us, skew_ppm, offset_std_us, skew_std_ppm=None) -> bool:
    """Whether an estimated clock (totals: ``offset_us`` at the first event, ``skew_ppm`` or None when not
    estimated) differs from the clock in effect of ``scene`` by more than :data:`APPLY_SIGMAS` of its standard
    errors, in the offset or (when estimated) in the skew."""
    now = scene.clock
    if offset_us is None:
        return False
    if _beyond(float(offset_us) - float(now.offset_us), offset_std_us):
        return True
    return skew_ppm is not None and _beyond(float(skew_ppm) - float(now.skew_ppm), skew_std_ppm)


def clock_correction(scene, result: SyncResult) -> tuple[int, float] | None:
    """The corrections (``offset_us``, ``skew_ppm``) that make the scene's clock equal the
    estimate: total minus the manifest prior. None when the result has no offset. The skew
    correction is the current one when the skew was not estimated."""
    if result.offset_us is None:
        return None
    return clock_correction_for(scene, result.offset_us, result.skew_ppm)


def apply_sync(history, scene, result: SyncResult, text: str = "clock sync") -> bool:
    """Apply a reliable result that differs from the clock in effect (:func:`clock_differs`) through ``history``
    as one undo step; returns whether applied."""
    if result.offset_us is None or not result.reliable:
        return False
    if not clock_differs(scene, result.offset_us, result.skew_ppm, result.offset_std_us,
                         getattr(result, "skew_std_ppm", None)):
        return False
    apply_clock_estimate(history, scene, result.offset_us, result.skew_ppm, text)
    return True


def apply_offset_result(history, scene, result: RefineResult, text: str = "clock from edges") -> bool:
    """Store an accepted offset refinement (offset and skew) as clock corrections through
    ``history``, as one undo step; returns whether applied."""
    if result.kind != "offset" or not result.accepted or result.offset_us is None:
        return False
    if not clock_differs(scene, result.offset_us, result.skew_ppm, result.offset_std_us,
                         getattr(result, "skew_std_ppm", None)):
        return False
    apply_clock_estimate(history, scene, result.offset_us, result.skew_ppm, text)
    return True


def apply_joint_result(history, scene, result, text: str = "refine clock and poses from edges", *,
                       clock: bool = True, poses: bool = True, kept: list | None = None) -> bool:
    """Store an accepted joint refinement (:class:`~evpose.core.align.joint_result.JointResult`) through
    ``history`` as one undo step: its clock (when fitted, and ``clock``), every fitted object's pose correction
    and the hand-eye correction (when fitted; both with ``poses``) -- each only where it differs from what is in
    effect by more than :data:`APPLY_SIGMAS` of its standard errors; ``kept`` (a list) receives one line per part
    left as it was and why. Returns whether anything was applied."""
    from evpose.core.document.estimates import apply_pose_estimate

    if not result.accepted:
        return False
    p = result.params
    kept = [] if kept is None else kept
    changed = False
    with history.group(text):
        if clock and p.clock:
            skew = result.skew_ppm if result.skew_estimated else None
            if clock_differs(scene, result.offset_us, skew, result.offset_std_us, result.skew_std_ppm):
                # the total clock the fit used: its own skew, or the start's it kept (for sync, the rate estimate's)
                apply_clock_estimate(history, scene, result.offset_us, result.skew_ppm, text)
                changed = True
            else:
                kept.append(f"clock: within {APPLY_SIGMAS:g} sigma of the clock in effect")
        if poses:
            for name, o in result.objects.items():
                if _beyond(o.dt_mm, o.std_mm) or _beyond(o.dR_deg, o.std_deg):
                    apply_pose_estimate(history, name, o.dT_base, text)
                    changed = True
                else:
                    kept.append(f"{name}: its change ({o.dt_mm:.2f} mm, {o.dR_deg:.2f} deg) is within "
                                f"{APPLY_SIGMAS:g} sigma")
            if p.hand_eye and result.hand_eye_dT_cam is not None:
                if (_beyond(result.hand_eye_dt_mm, result.hand_eye_std_mm)
                        or _beyond(result.hand_eye_dR_deg, result.hand_eye_std_deg)):
                    history.set(("hand_eye",), result.hand_eye_dT_cam, text=text)
                    changed = True
                else:
                    kept.append(f"hand-eye: its change is within {APPLY_SIGMAS:g} sigma")
    return changed


def save_applied(scene, data: dict) -> str:
    """Save the applied corrections through the one checked save path (revision check, merge with
    another program's edits saved meanwhile, or a refusal naming the conflict: raised as
    ``CorrectionsConflict``, an ``InputError``). Fills ``data["saved"]``, ``data["revision"]`` and
    ``data["merged_from_disk"]``; returns the line that says so."""
    path = scene.save_corrections()
    report = scene.corrections.last_save
    data["saved"] = str(path)
    data["revision"] = report.revision
    data["merged_from_disk"] = list(report.from_disk)
    line = f"applied and saved to {path} (revision {report.revision})"
    if report.from_disk:
        line += f"; kept {', '.join(report.from_disk)} saved meanwhile by another program"
    return line
