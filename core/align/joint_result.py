"""The knobs (:class:`JointParams`) and the outcome (:class:`JointResult`) of the joint refinement of clock, object
poses and hand-eye from edges (:mod:`evpose.core.align.joint_fit`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evpose.core.align.refine_result import RefineParams, json_number
from evpose.core.label.windows import DEFAULT_WINDOW_US

__all__ = ["JOINT_SIGMAS_PX", "JointParams", "JointResult", "ObjectFit", "json_number"]

#: Coarse-to-fine kernel widths of the joint fit (px at half DAVIS346 resolution, scaled by fx / 146).
JOINT_SIGMAS_PX = (1.5, 0.8, 0.45, 0.25, 0.14, 0.08)


@dataclass(frozen=True)
class JointParams:
    """What the joint fit estimates, and its knobs.

    ``clock``: fit the offset; ``skew``: ``"auto"`` (fitted, kept when the windows pin it), ``"fit"`` (always
    kept) or ``"fixed"``; ``objects``: names of the objects whose poses are fitted (None: all, empty: none);
    ``hand_eye``: fit a hand-eye correction (camera frame) shared by all objects. With both the hand-eye and
    objects free, the object corrections get a zero-mean prior (``prior_obj_mm`` / ``prior_obj_deg``, worth
    ``prior_weight`` of the associated events) that decides only what the events cannot tell apart.
    """

    clock: bool = True
    skew: str = "auto"
    objects: tuple | None = None
    hand_eye: bool = False
    n_windows: int = 24
    window_us: int = DEFAULT_WINDOW_US
    max_events: int = 12_000
    sigmas_px: tuple | None = None         # px of the scene camera; None: JOINT_SIGMAS_PX scaled by fx / 146
    outer_per_level: int = 4
    step_sigmas: float = 1.0
    band_sigmas: float = 3.0
    spacing_px: float = 0.5
    n_sub: int = 3
    converged_move: float = 0.1
    step_bounds: bool = True
    prior_obj_mm: float = 5.0
    prior_obj_deg: float = 3.0
    prior_weight: float = 0.01
    #: the edge kernel's density-step term (:func:`~evpose.core.align.edges.kernel`'s ``beta``) only at widths of at
    #: least this many px of a camera with fx = 146 (scaled as the widths; 0: at every width): the two coarsest of
    #: JOINT_SIGMAS_PX. Chosen on bench/campaign.py's main-generator family (0: campaign hand-eye -0.6 to -1.8 mm
    #: along the optical axis in 5 of 6 campaigns, 73 % of estimates within 2 sigma; 0.5: 100 %, own fits 90-92 %;
    #: never: own fits 87 %, the slow scenes' own hand-eye median 3.0 mm instead of 1.3), then validated on the
    #: ray-casting family (docs/campaign_bench.txt)
    step_min_sigma_px: float = 0.5

    def __post_init__(self):
        if self.skew not in ("auto", "fit", "fixed"):
            raise ValueError(f"skew: expected 'auto', 'fit' or 'fixed', got {self.skew!r}")
        if self.objects is not None and not isinstance(self.objects, tuple):
            object.__setattr__(self, "objects", tuple(self.objects))

    def sigmas(self, fx: float) -> tuple:
        """The kernel widths, coarse to fine (px of a camera of focal length ``fx``)."""
        return tuple(self.sigmas_px) if self.sigmas_px else tuple(s * fx / 146.0 for s in JOINT_SIGMAS_PX)

    def step_at(self, sigma_px: float, fx: float) -> bool:
        """Whether the kernel's density-step term is used at width ``sigma_px`` (px of a camera of focal length
        ``fx``): the term pulls a sharp edge by ~1.6 beta kernel widths, and at widths below the events' own spread
        about the edge its beta measures the contour's offset itself and holds it there."""
        return sigma_px * 146.0 / fx >= self.step_min_sigma_px * (1 - 1e-9)

    def refine_params(self) -> RefineParams:
        """The shared edge-setup knobs in the form :class:`~evpose.core.align.edges.EdgeSetup` reads."""
        return RefineParams(n_windows=self.n_windows, window_us=self.window_us, max_events=self.max_events,
                            spacing_px=self.spacing_px, band_sigmas=self.band_sigmas, n_sub=self.n_sub)


@dataclass
class ObjectFit:
    """One object's result: the total correction to store (``T_base_obj' = dT_base @ T_base_obj`` of the
    manifest), the change found (rotation deg, displacement of the centre mm) and their standard errors."""

    dT_base: np.ndarray
    dt_mm: float
    dR_deg: float
    std_mm: float
    std_deg: float
    #: A rotation the silhouettes cannot show, held at its start and left out of ``dR_deg`` / ``std_deg`` (e.g.
    #: "spin about its symmetry axis (object frame [0, 0, 1])"), or "".
    held_rotation: str = ""

    def to_json(self) -> dict:
        d = {"dT_base": np.asarray(self.dT_base).tolist(), "dt_mm": float(self.dt_mm),
             "dR_deg": float(self.dR_deg), "dt_std_mm": json_number(self.std_mm), "dR_std_deg": json_number(self.std_deg)}
        if self.held_rotation:
            d["held_rotation"] = self.held_rotation
        return d




@dataclass
class JointResult:
    """Outcome of :func:`evpose.core.align.joint_fit.refine_joint` (totals, not increments).

    ``offset_us`` / ``skew_ppm``: the clock to use (the start's when not fitted or not accepted);
    ``offset_std_us`` / ``skew_std_ppm`` their standard errors (cluster-robust over windows); ``skew_estimated``:
    the fitted skew was kept. ``objects``: per fitted object an :class:`ObjectFit`; ``held``: objects left at their
    start for lack of evidence, with the reason. ``hand_eye_dT_cam``: the total
    hand-eye correction (``T_base_cam' = T_base_cam @ dT_cam``) with its change and standard errors.
    """

    params: JointParams
    offset_us: int
    skew_ppm: float
    offset_std_us: float | None = None
    skew_std_ppm: float | None = None
    #: The offset's standard error from the windows' spread alone, before the model-error floor of
    #: :mod:`evpose.core.align.uncertainty` (large when the windows disagree: a clock cannot explain them).
    offset_std_data_us: float | None = None
    skew_estimated: bool = False
    #: The fit found a skew beyond :data:`~evpose.core.align.joint_fit.MAX_SKEW_PPM` and dropped it (a note says so).
    skew_implausible: bool = False
    objects: dict = field(default_factory=dict)
    held: dict = field(default_factory=dict)
    hand_eye_dT_cam: np.ndarray | None = None
    hand_eye_dt_mm: float = 0.0
    hand_eye_dR_deg: float = 0.0
    hand_eye_std_mm: float | None = None
    hand_eye_std_deg: float | None = None
    #: the hand-eye's standard errors from the events alone (the object prior's pull left out, the floors in): what
    #: the mounting check tests a change against (:func:`~evpose.core.align.sync_run.mounting_check`)
    hand_eye_std_events_mm: float | None = None
    hand_eye_std_events_deg: float | None = None
    objective_before: float = float("nan")
    objective_after: float = float("nan")
    n_windows: int = 0
    iterations: int = 0
    runtime_s: float = 0.0
    accepted: bool = False
    reason: str = ""
    trace: list = field(default_factory=list)
    #: What the fit decided on its own that the user should know (one sentence each).
    notes: list = field(default_factory=list)
    #: Per fitted object, its alignment score's change on windows the fit did not use
    #: (:mod:`evpose.core.align.joint_check`): ``windows``, ``score_change`` and its ``score_change_std``.
    held_out: dict = field(default_factory=dict)
    #: A clock-and-poses fit's camera-mounting check that did not take the hand-eye fit
    #: (:func:`evpose.core.align.sync_run.mounting_check`): the hand-eye change it saw and its standard errors,
    #: ``dt_mm``, ``dt_std_mm``, ``dR_deg``, ``dR_std_deg`` -- how far the mounting in effect may be off. None: no check.
    mounting_check: dict | None = None

    def to_json(self) -> dict:
        """The result as the CLI prints it: clock at the top, then ``objects`` and ``hand_eye``."""
        p = self.params
        d = {"offset_us": int(self.offset_us), "skew_ppm": float(self.skew_ppm),
             "offset_std_us": json_number(self.offset_std_us), "skew_std_ppm": json_number(self.skew_std_ppm),
             "offset_std_data_us": json_number(self.offset_std_data_us),
             "skew_estimated": bool(self.skew_estimated), "clock_fitted": bool(p.clock),
             "objects": {n: o.to_json() for n, o in self.objects.items()},
             "held": dict(self.held),
             "hand_eye": None if not p.hand_eye else {
                 "dT_cam": None if self.hand_eye_dT_cam is None else np.asarray(self.hand_eye_dT_cam).tolist(),
                 "dt_mm": float(self.hand_eye_dt_mm), "dR_deg": float(self.hand_eye_dR_deg),
                 "dt_std_mm": json_number(self.hand_eye_std_mm), "dR_std_deg": json_number(self.hand_eye_std_deg),
                 "dt_std_events_mm": json_number(self.hand_eye_std_events_mm),
                 "dR_std_events_deg": json_number(self.hand_eye_std_events_deg)},
             "objective_before": json_number(self.objective_before), "objective_after": json_number(self.objective_after),
             "n_windows": int(self.n_windows), "iterations": int(self.iterations),
             "runtime_s": float(self.runtime_s), "accepted": bool(self.accepted), "reason": self.reason,
             "notes": list(self.notes),
             "held_out": {n: {k: json_number(v) if isinstance(v, float) else v for k, v in c.items()}
                          for n, c in self.held_out.items()}}
        if self.mounting_check is not None:
            d["mounting_check"] = {k: json_number(v) for k, v in self.mounting_check.items()}
        return d
