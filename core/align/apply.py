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
from dataclasses import dataclass, field
from typing import Callable

from evpose.core.align.refine_result import RefineResult
from evpose.core.align.sync_result import SyncResult
from evpose.core.document.estimates import apply_clock_estimate, clock_correction_for

__all__ = ["APPLY_SIGMAS", "PlannedChange", "apply_joint_result", "apply_offset_result", "apply_sync", "clock_correction",
           "clock_differs", "plan_joint_result", "plan_sync", "save_applied", "store_changes"]

#: An estimate replaces what is in effect only where it differs by more than this many of its standard errors.
APPLY_SIGMAS = 2.0


def _beyond(change: float, std, k: float = APPLY_SIGMAS) -> bool:
    """``|change| > k * std`` with a finite, positive standard error (None, NaN or inf: never)."""
    return std is not None and math.isfinite(std) and std > 0 and abs(change) > k * std


def _num(x, scale: float, digits: int) -> str:
    """``x * scale`` with ``digits`` decimals; "n/a" for None."""
    return "n/a" if x is None else f"{x * scale:.{digits}f}"


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
    as one undo step (:func:`plan_sync`); returns whether applied."""
    return store_changes(history, plan_sync(scene, result), text)


def apply_offset_result(history, scene, result: RefineResult, text: str = "clock from edges") -> bool:
    """Store an accepted offset refinement (offset and skew) as clock corrections through
    ``history``, as one undo step; returns whether applied."""
    if result.kind != "offset" or not result.accepted or result.offset_us is None:
        return False
    if not clock_differs(scene, result.offset_us, result.skew_ppm, result.offset_std_us,
                         getattr(result, "skew_std_ppm", None)):
        return False
    apply_clock_estimate(history, scene, result.offset_us, result.skew_ppm, text, result.offset_std_us,
                         getattr(result, "skew_std_ppm", None))
    return True


@dataclass
class PlannedChange:
    """One part of an estimate that ``--apply`` stores (or a dry run would): ``part`` (``"clock"``, ``"object"``,
    ``"hand-eye"``), ``name`` (the object's), a one-line ``text`` with the change and its sigma, ``values`` (JSON
    numbers: the change and its standard errors, units in the keys) and ``store(history, text)`` that stores it."""

    part: str
    name: str
    text: str
    values: dict
    store: Callable = field(repr=False, default=None)

    def to_json(self) -> dict:
        return {"part": self.part, "name": self.name, "text": self.text, **self.values}


def _clock_change(scene, offset_us, skew_ppm, offset_std_us, skew_std_ppm) -> tuple[str, dict]:
    """The line and the JSON values of a planned clock change from the clock in effect to ``offset_us`` (and
    ``skew_ppm`` when not None), with their standard errors."""
    now = scene.clock
    d_us = float(offset_us - now.offset_us)
    text = f"clock: offset {d_us / 1e3:+.3f} ms (+- {_num(offset_std_us, 1e-3, 3)})"
    vals = {"offset_from_us": int(now.offset_us), "offset_to_us": int(offset_us), "offset_change_us": d_us,
            "offset_std_us": offset_std_us}
    if skew_ppm is not None:
        text += f", skew {now.skew_ppm:+.1f} -> {skew_ppm:+.1f} ppm"
        if skew_std_ppm is not None:
            text += f" (+- {_num(skew_std_ppm, 1.0, 1)})"
        vals.update(skew_from_ppm=float(now.skew_ppm), skew_to_ppm=float(skew_ppm), skew_std_ppm=skew_std_ppm)
    return text, vals


def plan_joint_result(scene, result, *, clock: bool = True, poses: bool = True) -> tuple[list, list]:
    """What :func:`apply_joint_result` would store of an accepted joint refinement, without storing anything:
    ``(changes, kept)`` -- the :class:`PlannedChange` of each part that differs from what is in effect by more
    than :data:`APPLY_SIGMAS` of its standard errors, and one line per part left as it is and why. Nothing for a
    fit that was not accepted."""
    from evpose.core.document.estimates import apply_hand_eye_estimate, apply_pose_estimate

    changes, kept = [], []
    if not result.accepted:
        return changes, [f"not accepted: {result.reason}"]
    p = result.params
    if clock and p.clock:
        skew = result.skew_ppm if result.skew_estimated else None
        if clock_differs(scene, result.offset_us, skew, result.offset_std_us, result.skew_std_ppm):
            text, vals = _clock_change(scene, result.offset_us, skew, result.offset_std_us, result.skew_std_ppm)

            def store_clock(history, text_, r=result):
                # the total clock the fit used: its own skew, or the start's it kept (for sync, the rate estimate's)
                apply_clock_estimate(history, scene, r.offset_us, r.skew_ppm, text_, r.offset_std_us,
                                     r.skew_std_ppm if r.skew_estimated else None)
            changes.append(PlannedChange("clock", "", text, vals, store_clock))
        else:
            kept.append(f"clock: within {APPLY_SIGMAS:g} sigma of the clock in effect")
            changes += _kept_sigma(scene, "clock", "clock",
                                   offset_us=(result.offset_us - scene.clock.offset_us, result.offset_std_us),
                                   skew_ppm=(result.skew_ppm - scene.clock.skew_ppm, result.skew_std_ppm)
                                   if result.skew_estimated else (0.0, None))
    if not poses:
        return changes, kept
    for name, o in result.objects.items():
        if _beyond(o.dt_mm, o.std_mm) or _beyond(o.dR_deg, o.std_deg):
            def store_pose(history, text_, name=name, o=o):
                apply_pose_estimate(history, name, o.dT_base, text_, o.std_mm, o.std_deg)
            changes.append(PlannedChange(
                "object", name, f"{name}: {o.dt_mm:.2f} mm (+- {o.std_mm:.2f}), {o.dR_deg:.2f} deg (+- {o.std_deg:.2f})",
                {"dt_mm": o.dt_mm, "std_mm": o.std_mm, "dR_deg": o.dR_deg, "std_deg": o.std_deg}, store_pose))
        else:
            kept.append(f"{name}: its change ({o.dt_mm:.2f} mm, {o.dR_deg:.2f} deg) is within {APPLY_SIGMAS:g} sigma")
            changes += _kept_sigma(scene, f"object:{name}", name, mm=(o.dt_mm, o.std_mm), deg=(o.dR_deg, o.std_deg))
    if p.hand_eye and result.hand_eye_dT_cam is not None:
        r = result
        if _beyond(r.hand_eye_dt_mm, r.hand_eye_std_mm) or _beyond(r.hand_eye_dR_deg, r.hand_eye_std_deg):
            def store_hand_eye(history, text_, H=r.hand_eye_dT_cam):
                apply_hand_eye_estimate(history, H, text_, r.hand_eye_std_mm, r.hand_eye_std_deg)
            changes.append(PlannedChange(
                "hand-eye", "", f"hand-eye: {r.hand_eye_dt_mm:.2f} mm (+- {r.hand_eye_std_mm:.2f}), "
                                f"{r.hand_eye_dR_deg:.3f} deg (+- {r.hand_eye_std_deg:.3f})",
                {"dt_mm": r.hand_eye_dt_mm, "std_mm": r.hand_eye_std_mm, "dR_deg": r.hand_eye_dR_deg,
                 "std_deg": r.hand_eye_std_deg}, store_hand_eye))
        else:
            kept.append(f"hand-eye: its change is within {APPLY_SIGMAS:g} sigma")
            changes += _kept_sigma(scene, "hand_eye", "hand-eye", mm=(r.hand_eye_dt_mm, r.hand_eye_std_mm),
                                   deg=(r.hand_eye_dR_deg, r.hand_eye_std_deg))
    elif result.mounting_check is not None:       # the mounting kept: how far it may be off, as the check saw it
        m = result.mounting_check
        changes += _kept_sigma(scene, "hand_eye", "hand-eye (mounting check)", mm=(m["dt_mm"], m["dt_std_mm"]),
                               deg=(m["dR_deg"], m["dR_std_deg"]))
    return changes, kept


#: Units of each sigma field in a kept part's line.
_SIGMA_UNITS = {"offset_us": ("ms", 1e-3, 3), "skew_ppm": ("ppm", 1.0, 1), "mm": ("mm", 1.0, 2), "deg": ("deg", 1.0, 3)}


def _kept_sigma(scene, part: str, label: str, **pairs) -> list:
    """A part an estimate confirms (within :data:`APPLY_SIGMAS` of what is in effect): its value is kept, and when
    the document stores no sigma for it yet, how far the value in effect may be off -- the estimate's standard error
    and its distance from that value in quadrature -- is stored beside it (where the label sigma starts from;
    :attr:`~evpose.core.document.corrections.Corrections.sigmas`). ``pairs``: field -> (distance, standard error).
    A list of zero or one :class:`PlannedChange` (part ``"sigma"``, name the document's part)."""
    if scene.corrections.sigma(part) is not None:
        return []
    sigma = {k: math.hypot(float(d), float(s)) for k, (d, s) in pairs.items()
             if s is not None and math.isfinite(s) and s > 0 and math.isfinite(d)}
    if not sigma:
        return []
    shown = ", ".join(f"{v * _SIGMA_UNITS[k][1]:.{_SIGMA_UNITS[k][2]}f} {_SIGMA_UNITS[k][0]}" for k, v in sigma.items())

    def store(history, text_):
        history.set(("sigma", part), sigma, text=text_)
    values = {"sigma": sigma, "offset_std_us": sigma.get("offset_us"), "std_mm": sigma.get("mm"),
              "std_deg": sigma.get("deg")}
    return [PlannedChange("sigma", part, f"{label}: kept; its sigma stored (+- {shown})",
                          {k: v for k, v in values.items() if v is not None}, store)]


def apply_joint_result(history, scene, result, text: str = "refine clock and poses from edges", *,
                       clock: bool = True, poses: bool = True, kept: list | None = None) -> bool:
    """Store an accepted joint refinement (:class:`~evpose.core.align.joint_result.JointResult`) through
    ``history`` as one undo step: its clock (when fitted, and ``clock``), every fitted object's pose correction
    and the hand-eye correction (when fitted; both with ``poses``) -- each only where it differs from what is in
    effect by more than :data:`APPLY_SIGMAS` of its standard errors (:func:`plan_joint_result`); ``kept`` (a list)
    receives one line per part left as it was and why. Returns whether anything was applied."""
    changes, why = plan_joint_result(scene, result, clock=clock, poses=poses)
    if kept is not None and result.accepted:
        kept.extend(why)
    return store_changes(history, changes, text)


def store_changes(history, changes: list, text: str) -> bool:
    """Store planned changes (:func:`plan_joint_result`) through ``history`` as one undo step."""
    if not changes:
        return False
    with history.group(text):
        for c in changes:
            c.store(history, text)
    return True


def plan_sync(scene, result: SyncResult) -> list:
    """What :func:`apply_sync` would store of a rate estimate: the clock when reliable and beyond
    :data:`APPLY_SIGMAS` of its standard errors from the clock in effect; within them, its sigma when the document
    has none for the clock (:func:`_kept_sigma`); an empty list otherwise."""
    if result.offset_us is None or not result.reliable:
        return []
    skew_std = getattr(result, "skew_std_ppm", None)
    if not clock_differs(scene, result.offset_us, result.skew_ppm, result.offset_std_us, skew_std):
        return _kept_sigma(scene, "clock", "clock", offset_us=(result.offset_us - scene.clock.offset_us,
                                                               result.offset_std_us))
    text, vals = _clock_change(scene, result.offset_us, result.skew_ppm, result.offset_std_us, skew_std)

    def store(history, text_):
        apply_clock_estimate(history, scene, result.offset_us, result.skew_ppm, text_, result.offset_std_us,
                             skew_std)
    return [PlannedChange("clock", "", text, vals, store)]


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
