"""The joint refinement of one scene as a command runs it: the fit, what ``--apply`` stores (each part only where
it differs from what is in effect by more than its sigma allows: :func:`~evpose.core.align.apply.plan_joint_result`)
and, with ``apply``, one undo step saved through the checked save path.

``evpose refine SCENE --joint`` and ``evpose dataset refine`` (one task per scene on the Dask workers) both call
:func:`run_refine_joint`, so a dataset's numbers are the single-scene command's, scene by scene.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evpose.core.errors import InputError

__all__ = ["JointRunOptions", "JointRun", "ProposalError", "run_refine_joint", "plan_and_store", "apply_proposal",
           "APPLY_TEXT"]

#: The undo step's text of an applied joint refinement (the app's Undo names it).
APPLY_TEXT = "refine clock and poses from edges"


@dataclass(frozen=True)
class JointRunOptions:
    """What to fit and whether to store it: ``clock`` (offset and, when pinned, skew), ``hand_eye``, ``objects``
    (names; None: all), ``windows`` (event windows of the fit), ``apply``."""

    clock: bool = True
    hand_eye: bool = False
    objects: tuple | None = None
    windows: int = 24
    apply: bool = False


@dataclass
class JointRun:
    """``data``: the ``--json`` document (the fit's, plus ``changes``: what ``--apply`` stores or stored, ``kept``:
    the parts left as they are and why, ``applied``, and ``saved``/``revision`` when saved); ``result``: the
    :class:`~evpose.core.align.joint_result.JointResult`; ``saved_line``: "applied and saved to ..." or ""."""

    data: dict = field(default_factory=dict)
    result: object = None
    saved_line: str = ""


def run_refine_joint(scene, opts: JointRunOptions, *, progress=None, cancel=None) -> JointRun:
    """Fit (:func:`~evpose.core.align.joint_fit.refine_joint`), plan and, with ``opts.apply``, store and save.

    A clock-and-poses fit of every object (no hand-eye) gets the camera-mounting check of ``evpose sync --edges``
    (:func:`~evpose.core.align.sync_run.mounting_check`): when it shows what a mounting error does, the fit runs again
    with the hand-eye free, and when the mounting is off beyond its sigma that fit is the answer -- the hand-eye is
    proposed (and stored with ``apply``) instead of a clock and object poses bent to absorb it."""
    from evpose.core.align.joint_fit import refine_joint
    from evpose.core.align.joint_result import JointParams
    from evpose.core.align.sync_run import (MOUNTING_MIN_TURN_DEG, _halves, camera_turn_deg, mounting_check,
                                            mounting_suspected)

    if not getattr(scene, "has_poses", True):
        scene.require_poses("pose refinement")
    params = JointParams(clock=opts.clock, objects=opts.objects, hand_eye=opts.hand_eye, n_windows=opts.windows)
    check = opts.clock and not opts.hand_eye and opts.objects is None
    first, second = _halves(progress) if check else (progress, None)
    r = refine_joint(scene, params=params, progress=first, cancel=cancel)
    if check and mounting_suspected(r):
        alt = refine_joint(scene, params=JointParams(clock=True, hand_eye=True, n_windows=opts.windows),
                           progress=second, cancel=cancel)
        r = mounting_check(r, alt, turns=camera_turn_deg(scene) >= MOUNTING_MIN_TURN_DEG)
    elif check and progress is not None:
        progress(1.0, "done (no sign of a camera-mounting error)")
    return plan_and_store(scene, r, opts.apply, APPLY_TEXT)


def plan_and_store(scene, r, apply: bool, text: str) -> JointRun:
    """The document of a joint result ``r`` for ``scene`` (its JSON, ``planned_on``, ``changes``: each part beyond
    its sigma of what is in effect, ``kept``) and, with ``apply``, the changes stored as one undo step named
    ``text`` and saved."""
    from evpose.core.align.apply import plan_joint_result, save_applied, store_changes
    from evpose.core.document.history import History

    run = JointRun(result=r)
    data = run.data = r.to_json()
    changes, kept = plan_joint_result(scene, r)
    data["planned_on"] = scene.corrections.digest()
    data["changes"] = [c.to_json() for c in changes]
    data["kept"] = kept
    data["applied"] = bool(apply) and store_changes(History(scene.corrections), changes, text)
    if data["applied"]:
        run.saved_line = save_applied(scene, data)
    return run


class ProposalError(InputError):
    """A dry run's proposal that cannot be applied (nothing to apply, or the corrections changed since)."""


def apply_proposal(scene, doc: dict) -> str:
    """Store the ``changes`` of a dry run's document ``doc`` (:func:`run_refine_joint` without ``apply``) into
    ``scene``'s corrections as one undo step and save them; the same corrections ``--apply`` would have stored.

    Refused (:class:`ProposalError`) when the corrections in effect are not the ones the proposal was planned on
    (``doc["planned_on"]``): a change judged against other corrections (another save meanwhile, an earlier apply)
    is never stored. Returns the "applied and saved to ..." line."""
    from evpose.core.align.apply import save_applied
    from evpose.core.document.estimates import apply_clock_estimate, apply_hand_eye_estimate, apply_pose_estimate
    from evpose.core.document.history import History

    where = scene.corrections_path
    changes = doc.get("changes") or []
    if not changes:
        raise ProposalError(f"{where}: changes: the proposal has nothing to apply")
    if doc.get("planned_on") != scene.corrections.digest():
        raise ProposalError(f"{where}: planned_on: the corrections changed since the proposal was made; "
                            "run the refinement again")
    history = History(scene.corrections)
    with history.group(APPLY_TEXT):
        for c in changes:
            if c["part"] == "clock":
                apply_clock_estimate(history, scene, doc["offset_us"], doc["skew_ppm"], APPLY_TEXT,
                                     doc.get("offset_std_us"), doc.get("skew_std_ppm") if doc.get("skew_estimated")
                                     else None)
            elif c["part"] == "object":
                o = doc["objects"][c["name"]]
                apply_pose_estimate(history, c["name"], np.asarray(o["dT_base"]), APPLY_TEXT, o.get("dt_std_mm"),
                                    o.get("dR_std_deg"))
            elif c["part"] == "hand-eye":
                he = doc["hand_eye"]
                apply_hand_eye_estimate(history, np.asarray(he["dT_cam"], np.float64), APPLY_TEXT, he.get("dt_std_mm"),
                                        he.get("dR_std_deg"))
            elif c["part"] == "sigma":             # a part the estimate confirmed: its sigma beside the kept value
                history.set(("sigma", c["name"]), c["sigma"], text=APPLY_TEXT)
            else:
                raise ProposalError(f"{where}: changes: unknown part {c['part']!r}")
    out = dict(doc, applied=True)
    line = save_applied(scene, out)
    doc.update(applied=True, saved=out["saved"], revision=out["revision"])
    return line
