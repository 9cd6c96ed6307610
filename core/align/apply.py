"""Accepting a clock estimate: the corrections it stands for, stored through the History.

The estimates hold *total* clocks (prior + correction); the scene stores corrections on top of
the manifest's prior. This module converts one into the other and applies an accepted estimate
as one undo step, for the CLI's ``--apply`` (the app goes through
:meth:`evpose.core.session.model.Session.apply_clock_estimate`); both end in
:mod:`evpose.core.document.estimates`, the one place that turns an estimate into corrections.
"""
from __future__ import annotations

from evpose.core.align.refine_result import RefineResult
from evpose.core.align.sync_result import SyncResult
from evpose.core.document.estimates import apply_clock_estimate, clock_correction_for

__all__ = ["apply_joint_result", "apply_offset_result", "apply_sync", "clock_correction", "save_applied"]


def clock_correction(scene, result: SyncResult) -> tuple[int, float] | None:
    """The corrections (``offset_us``, ``skew_ppm``) that make the scene's clock equal the
    estimate: total minus the manifest prior. None when the result has no offset. The skew
    correction is the current one when the skew was not estimated."""
    if result.offset_us is None:
        return None
    return clock_correction_for(scene, result.offset_us, result.skew_ppm)


def apply_sync(history, scene, result: SyncResult, text: str = "clock sync") -> bool:
    """Apply a reliable result through ``history`` as one undo step; returns whether applied."""
    if result.offset_us is None or not result.reliable:
        return False
    apply_clock_estimate(history, scene, result.offset_us, result.skew_ppm, text)
    return True


def apply_offset_result(history, scene, result: RefineResult, text: str = "clock from edges") -> bool:
    """Store an accepted offset refinement (offset and skew) as clock corrections through
    ``history``, as one undo step; returns whether applied."""
    if result.kind != "offset" or not result.accepted or result.offset_us is None:
        return False
    apply_clock_estimate(history, scene, result.offset_us, result.skew_ppm, text)
    return True


def apply_joint_result(history, scene, result, text: str = "refine clock and poses from edges", *,
                       clock: bool = True, poses: bool = True) -> bool:
    """Store an accepted joint refinement (:class:`~evpose.core.align.joint_result.JointResult`) through
    ``history`` as one undo step: its clock (when fitted, and ``clock``), every fitted object's pose correction
    and the hand-eye correction (when fitted; both with ``poses``). Returns whether anything was applied."""
    from evpose.core.document.estimates import apply_pose_estimate

    if not result.accepted:
        return False
    p = result.params
    changed = False
    with history.group(text):
        if clock and p.clock:
            # the total clock the fit used: its own skew, or the start's it kept (for sync, the rate estimate's)
            apply_clock_estimate(history, scene, result.offset_us, result.skew_ppm, text)
            changed = True
        if poses:
            for name, o in result.objects.items():
                apply_pose_estimate(history, name, o.dT_base, text)
                changed = True
            if p.hand_eye and result.hand_eye_dT_cam is not None:
                history.set(("hand_eye",), result.hand_eye_dT_cam, text=text)
                changed = True
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
