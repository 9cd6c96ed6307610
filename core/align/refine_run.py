"""The joint refinement of one scene as a command runs it: the fit, what ``--apply`` stores (each part only where
it differs from what is in effect by more than its sigma allows: :func:`~evpose.core.align.apply.plan_joint_result`)
and, with ``apply``, one undo step saved through the checked save path.

``evpose refine SCENE --joint`` and ``evpose dataset refine`` (one task per scene on the Dask workers) both call
:func:`run_refine_joint`, so a dataset's numbers are the single-scene command's, scene by scene.
"""
from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["JointRunOptions", "JointRun", "run_refine_joint", "APPLY_TEXT"]

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
    from evpose.core.align.apply import plan_joint_result, save_applied, store_changes
    from evpose.core.align.joint_fit import refine_joint
    from evpose.core.align.joint_result import JointParams
    from evpose.core.document.history import History

    params = JointParams(clock=opts.clock, objects=opts.objects, hand_eye=opts.hand_eye, n_windows=opts.windows)
    run = JointRun()
    r = run.result = refine_joint(scene, params=params, progress=progress, cancel=cancel)
    data = run.data = r.to_json()
    changes, kept = plan_joint_result(scene, r)
    data["changes"] = [c.to_json() for c in changes]
    data["kept"] = kept
    data["applied"] = bool(opts.apply) and store_changes(History(scene.corrections), changes, APPLY_TEXT)
    if data["applied"]:
        run.saved_line = save_applied(scene, data)
    return run
