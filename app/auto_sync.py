"""The automatic estimates of the app as proposals: what a job computes, what Accept stores, what the preview shows.

A :class:`Proposal` is the outcome of one estimation job, computed on a snapshot of the scene in a worker thread
(no Qt here):

- **Auto** (:func:`run_auto`): the event-rate stage (:func:`evpose.core.align.estimate.sync_scene`), then, when
  it is reliable, the clock and every object's pose fitted jointly from event edges, started at the rate estimate
  (:func:`evpose.core.align.sync_run.edge_stage`), and again with the hand-eye free (its mounting check: when the
  camera mounting looks off, the proposal carries that fit, hand-eye included). The clock proposed is
  :func:`evpose.core.align.sync_run.final_estimate`'s (the CLI's ``sync --edges`` answer); the poses are the edge
  stage's. An unreliable rate estimate stops the job after the rate stage, and the proposal says why.
- **Clock and poses from edges** and **Refine object** (:func:`run_edges`): the same joint fit
  (:func:`evpose.core.align.joint_fit.refine_joint`) started at the clock in effect; for one object its pose only.

:func:`apply_proposal` stores a proposal as **one** undo step (:meth:`Session.apply_joint_estimate` for the poses,
:meth:`Session.apply_clock_estimate` for the final clock, in one history group); :func:`preview_corrections` runs
the very same function on a throwaway session over a copy of the document, so the preview shows exactly what
Accept would store.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from evpose.core.data.events import Cancelled
from evpose.core.document.review import clock_in_effect

__all__ = ["EDGE_SETUP_SHARE", "RATE_SHARE", "Proposal", "StagedProgress", "apply_proposal", "preview_corrections",
           "run_auto", "run_edges"]

#: Share of Auto's progress bar for the rate stage (about 0.5 s of a 10-20 s run) and for the edge stage's
#: set-up (choosing the windows, sampling the edges: about 2 s) before its first kernel width.
RATE_SHARE = 0.03
EDGE_SETUP_SHARE = 0.12


@dataclass
class Proposal:
    """What one estimation job proposes.

    ``offset_us`` / ``skew_ppm``: the clock to set (totals: prior + correction; ``offset_us`` None keeps the
    clock, ``skew_ppm`` None keeps the skew); ``joint``: the edge fit whose object poses (and hand-eye) Accept
    stores when it was accepted; ``rate``: the event-rate stage (Auto only). ``clock_before``: the clock in effect
    when the job started (``offset_us``, ``skew_ppm``). ``reason``: why nothing, or less than asked, is proposed.
    """

    kind: str                              # "auto", "edges" or "refine"
    title: str
    undo_text: str
    clock_before: tuple
    rate: object = None                    # evpose.core.align.sync_result.SyncResult
    joint: object = None                   # evpose.core.align.joint_result.JointResult
    offset_us: int | None = None
    skew_ppm: float | None = None
    offset_std_us: float | None = None
    skew_std_ppm: float | None = None
    method: str = ""                       # where the clock comes from: "rate", "rate+edges" or "edges"
    reason: str = ""
    runtime_s: float = 0.0

    @property
    def poses(self) -> dict:
        """name -> :class:`~evpose.core.align.joint_result.ObjectFit` that Accept stores ({} without an accepted fit)."""
        return dict(self.joint.objects) if self.joint is not None and self.joint.accepted else {}

    @property
    def held(self) -> dict:
        """name -> why the edge fit kept that object's pose."""
        return dict(self.joint.held) if self.joint is not None else {}

    @property
    def usable(self) -> bool:
        """True when Accept would change something."""
        return self.offset_us is not None or bool(self.poses) or self.hand_eye_fitted

    @property
    def hand_eye_fitted(self) -> bool:
        """True when Accept stores a fitted hand-eye correction."""
        j = self.joint
        return j is not None and j.accepted and j.params.hand_eye and j.hand_eye_dT_cam is not None


class StagedProgress:
    """Maps the stages' ``progress(fraction or None, message)`` onto one bar: the rate stage on
    ``[0, RATE_SHARE)``, the edge stage's set-up up to ``RATE_SHARE + EDGE_SETUP_SHARE``, then its kernel widths.
    Within a width (the edge fit reports None per iteration) the bar advances by iterations of that width's
    share; it never moves back. ``report(fraction, message)`` is the job's progress signal."""

    def __init__(self, report, n_levels: int, iterations_per_level: int, with_rate: bool = True, passes: int = 1):
        self.report = report
        self.passes = max(int(passes), 1)                # edge fits one after the other (sync's mounting check)
        self.rate_share = RATE_SHARE if with_rate else 0.0
        self.n_levels = int(n_levels)
        self.level_share = 1.0 / (n_levels + 1)         # refine_joint reports level / (n_levels + 1)
        self.iterations = max(int(iterations_per_level), 1)
        self.fraction = 0.0
        self._level_start, self._steps = 0.0, 0

    def _emit(self, fraction: float, message: str) -> None:
        self.fraction = min(max(self.fraction, float(fraction)), 1.0)
        self.report(self.fraction, message)

    def rate(self, f, message: str = "") -> None:
        if f is not None:
            self._emit(self.rate_share * float(f), f"event rate: {message}")

    def edge_setup(self) -> None:
        self._emit(self.rate_share, "edges: choosing windows and sampling the objects' edges")

    def edges(self, f, message: str = "") -> None:
        start = self.rate_share + EDGE_SETUP_SHARE
        if f is not None:
            self._level_start, self._steps = float(f), 0
        else:
            self._steps += 1
        within = min(self._steps, self.iterations) / (self.iterations + 1) * self.level_share / self.passes
        edge_f = 1.0 if f is not None and f >= 1.0 else self._level_start + within
        local = self._level_start * self.passes             # which fit, and how far into it
        in_pass = local - min(int(local), self.passes - 1)
        level = min(int(round(in_pass / self.level_share)) + 1, self.n_levels)
        stage = "finishing" if edge_f >= 1.0 else f"kernel width {level} of {self.n_levels}"
        self._emit(start + (1.0 - start) * edge_f, f"edges, {stage}: {message}")


def run_auto(scene, n_windows: int = 24, *, progress=None, cancel=None) -> Proposal:
    """Auto on ``scene`` (a snapshot): the rate stage, then clock and poses jointly from edges (see the module)."""
    from evpose.core.align.estimate import sync_scene
    from evpose.core.align.joint_result import JOINT_SIGMAS_PX, JointParams
    from evpose.core.align.sync_run import edge_stage, final_estimate

    t0 = time.perf_counter()
    bar = StagedProgress(progress or (lambda f, m: None), len(JOINT_SIGMAS_PX), JointParams().outer_per_level,
                         passes=2)                   # the clock-and-poses fit, then the mounting check
    p = Proposal("auto", "Automatic estimate", "automatic clock and poses (rate, then edges)", clock_in_effect(scene))
    rate = p.rate = sync_scene(scene, progress=bar.rate, cancel=cancel)
    if not rate.reliable or rate.offset_us is None:
        p.reason = f"no reliable clock from the event rate: {rate.reason or 'no clear peak'}; edges not run"
        p.runtime_s = time.perf_counter() - t0
        return p
    if cancel is not None and cancel():
        raise Cancelled("automatic estimate cancelled")
    bar.edge_setup()
    if scene.object_names:
        p.joint = edge_stage(scene, rate, n_windows, progress=bar.edges, cancel=cancel)
        if not p.joint.accepted:
            p.reason = f"edges: {p.joint.reason}; the event-rate clock is proposed alone"
    else:
        p.reason = "the scene has no objects: the event-rate clock is proposed alone"
    final = final_estimate(rate, p.joint)
    p.offset_us, p.skew_ppm, p.method = int(final["offset_us"]), final["skew_ppm"], final["method"]
    p.offset_std_us, p.skew_std_ppm = final["offset_std_us"], final["skew_std_ppm"]
    p.runtime_s = time.perf_counter() - t0
    return p


def run_edges(scene, params, kind: str, title: str, undo_text: str, *, progress=None, cancel=None) -> Proposal:
    """The joint edge fit (:func:`~evpose.core.align.joint_fit.refine_joint`) from the clock in effect, as a
    proposal: the clock when ``params.clock`` and the fit was accepted (its skew only when the windows pinned it),
    and the fitted objects' poses."""
    from evpose.core.align.joint_fit import refine_joint
    from evpose.core.align.joint_result import JOINT_SIGMAS_PX

    t0 = time.perf_counter()
    levels = len(params.sigmas_px or JOINT_SIGMAS_PX)
    bar = StagedProgress(progress or (lambda f, m: None), levels, params.outer_per_level, with_rate=False)
    p = Proposal(kind, title, undo_text, clock_in_effect(scene))
    bar.edge_setup()
    j = p.joint = refine_joint(scene, params=params, progress=bar.edges, cancel=cancel)
    if not j.accepted:
        p.reason = j.reason or "the fit did not improve the alignment"
    elif params.clock:
        p.offset_us, p.offset_std_us, p.method = int(j.offset_us), j.offset_std_us, "edges"
        p.skew_ppm = float(j.skew_ppm) if j.skew_estimated else None
        p.skew_std_ppm = j.skew_std_ppm
    p.runtime_s = time.perf_counter() - t0
    return p


def apply_proposal(session, p: Proposal) -> bool:
    """Store ``p`` in ``session``'s document as one undo step: the fitted poses (and hand-eye), then the clock.
    Returns whether anything was stored."""
    if not p.usable:
        return False
    with session.history.group(p.undo_text):
        if p.poses or p.hand_eye_fitted:
            session.apply_joint_estimate(p.joint, p.undo_text, clock=False, poses=True)
        if p.offset_us is not None:
            session.apply_clock_estimate(p.offset_us, p.skew_ppm, p.undo_text, p.offset_std_us, p.skew_std_ppm)
    return True


def preview_corrections(session, p: Proposal):
    """The corrections the document would hold after Accept (the document itself is untouched)."""
    from evpose.core.session.model import Session

    scratch = Session(session.scene.with_corrections(session.scene.corrections.copy()))
    apply_proposal(scratch, p)
    return scratch.scene.corrections
