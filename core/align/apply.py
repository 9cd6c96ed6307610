"""Accepting a clock estimate: the corrections it stands for, stored through the History.

The estimates hold *total* clocks (prior + correction); the scene stores corrections on top of
the manifest's prior. This module converts one into the other and applies an accepted estimate
as one undo step, for the CLI's ``--apply``.
"""
from __future__ import annotations

from evpose.core.align.refine_result import RefineResult
from evpose.core.align.sync_result import SyncResult

__all__ = ["apply_offset_result", "apply_sync", "clock_correction"]


def clock_correction(scene, result: SyncResult) -> tuple[int, float] | None:
    """The corrections (``offset_us``, ``skew_ppm``) that make the scene's clock equal the
    estimate: total minus the manifest prior. None when the result has no offset. The skew
    correction is the current one when the skew was not estimated."""
    if result.offset_us is None:
        return None
    off = int(result.offset_us) - int(scene.manifest.clock_offset_us)
    skew = (float(result.skew_ppm) - float(scene.manifest.clock_skew_ppm)) if result.skew_ppm is not None \
        else float(scene.corrections.skew_ppm)
    return off, skew


def apply_sync(history, scene, result: SyncResult, text: str = "clock sync") -> bool:
    """Apply a reliable result through ``history`` as one undo step; returns whether applied."""
    corr = clock_correction(scene, result)
    if corr is None or not result.reliable:
        return False
    with history.group(text):
        history.set(("offset_us",), corr[0])
        history.set(("skew_ppm",), corr[1])
    return True


def apply_offset_result(history, scene, result: RefineResult, text: str = "clock from edges") -> bool:
    """Store an accepted offset refinement (offset and skew) as clock corrections through
    ``history``, as one undo step; returns whether applied."""
    if result.kind != "offset" or not result.accepted or result.offset_us is None:
        return False
    skew = scene.clock.skew_ppm if result.skew_ppm is None else float(result.skew_ppm)
    with history.group(text):
        history.set(("offset_us",), int(result.offset_us) - int(scene.manifest.clock_offset_us))
        history.set(("skew_ppm",), skew - float(scene.manifest.clock_skew_ppm))
    return True
