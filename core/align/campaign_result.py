"""The outcome of a campaign fit (:mod:`evpose.core.align.campaign_fit`): each shared unit's estimate with its
standard errors, and each scene's view of it as a :class:`~evpose.core.align.joint_result.JointResult`, so that
what ``--apply`` stores in a scene is planned and stored by the single scene's code
(:func:`evpose.core.align.apply.plan_joint_result`)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from evpose.core.align import uncertainty as U
from evpose.core.align.joint_model import HAND_EYE_RADIUS_M
from evpose.core.align.joint_result import JointParams, JointResult, ObjectFit, json_number
from evpose.core.align.pose_refine import _pose_change
from evpose.core.data.geometry import inv_T

__all__ = ["UnitFit", "CampaignResult", "unit_fits", "scene_result"]


@dataclass
class UnitFit:
    """One shared term: a hand-eye unit's increment (``T``: camera frame, on top of each scene's correction in
    effect) or one object of a placement unit (``T``: its base-frame pose), the change from the start (``dt_mm``:
    of the origin for the hand-eye, of the edge centre for an object; ``dR_deg``), its standard errors, the scenes
    that share it and whether it was fitted (else kept at its start, ``reason`` says why)."""

    scenes: list
    T: np.ndarray
    dt_mm: float = 0.0
    dR_deg: float = 0.0
    std_mm: float = math.inf
    std_deg: float = math.inf
    fitted: bool = False
    reason: str = ""

    def to_json(self) -> dict:
        return {"scenes": list(self.scenes), "T": np.asarray(self.T).tolist(), "dt_mm": float(self.dt_mm),
                "dR_deg": float(self.dR_deg), "dt_std_mm": json_number(self.std_mm),
                "dR_std_deg": json_number(self.std_deg), "fitted": bool(self.fitted), "reason": self.reason}


@dataclass
class CampaignResult:
    """``hand_eye``: per hand-eye unit a :class:`UnitFit`; ``placements``: per placement unit, per object a
    :class:`UnitFit`; ``per_scene``: each scene's :class:`JointResult` (its clock, the shared terms as totals for
    its corrections); the summed objective's before / after per scene; ``trace``: one entry per trial step."""

    params: JointParams
    scenes: list
    hand_eye: dict = field(default_factory=dict)
    placements: dict = field(default_factory=dict)
    per_scene: dict = field(default_factory=dict)
    objective_before: dict = field(default_factory=dict)
    objective_after: dict = field(default_factory=dict)
    accepted: bool = False
    reason: str = ""
    notes: list = field(default_factory=list)
    trace: list = field(default_factory=list)
    runtime_s: float = 0.0
    #: the kernel width the standard errors were computed at (:func:`~evpose.core.align.campaign_fit.fit_campaign`)
    covariance_sigma_px: float = math.nan
    #: per scene, the digest of the corrections the fit started from (its share is stored only on those)
    planned_on: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"scenes": list(self.scenes), "accepted": bool(self.accepted), "reason": self.reason,
                "notes": list(self.notes), "hand_eye_fitted": bool(self.params.hand_eye),
                "hand_eye": {u: f.to_json() for u, f in self.hand_eye.items()},
                "placements": {u: {nm: f.to_json() for nm, f in objs.items()} for u, objs in self.placements.items()},
                "objective_before": {n: json_number(v) for n, v in self.objective_before.items()},
                "objective_after": {n: json_number(v) for n, v in self.objective_after.items()},
                "steps": len(self.trace), "covariance_sigma_px": json_number(self.covariance_sigma_px),
                "runtime_s": float(self.runtime_s), "trace": list(self.trace)}


def _stds(sd: np.ndarray, cols: list) -> tuple[np.ndarray, bool]:
    s = sd[cols]
    return s, bool(np.all(np.isfinite(s)))


def unit_fits(scenes, infos, index: dict, state0, end, sd: np.ndarray, accepted: bool,
              params: JointParams) -> tuple[dict, dict]:
    """``(hand_eye, placements)`` of :class:`UnitFit`: the end state's value of every unit with its standard errors
    (``sd``: global layout; ``index``: parameter key -> column); a unit whose direction the events leave flat (an
    infinite standard error) or a fit not ``accepted`` keeps its start."""
    hand_eye, placements = {}, {}
    for cs in scenes:
        if params.hand_eye:
            hand_eye.setdefault(cs.hand_eye, UnitFit([], np.eye(4))).scenes.append(cs.name)
        info = infos[cs.name]
        objs = placements.setdefault(cs.placement, {})
        for nm in info.names:
            if ("object", cs.placement, nm, 0) not in index:       # held in this scene (or not fitted)
                continue
            objs.setdefault(nm, UnitFit([], state0.T[(cs.placement, nm)].copy())).scenes.append(cs.name)
    for unit, f in hand_eye.items():
        s, ok = _stds(sd, [index[("hand-eye", unit, j)] for j in range(6)])
        if not (ok and accepted):
            f.reason = "not accepted" if not accepted else "the events do not pin it (a flat direction); kept"
            continue
        f.T, f.fitted = end.H[unit].copy(), True
        f.dR_deg, f.dt_mm = _pose_change(f.T, np.zeros(3))
        f.std_mm = U.with_floor(float(np.sqrt(np.sum(s[:3] ** 2))), U.HAND_EYE_FLOOR_MM)
        f.std_deg = U.with_floor(float(np.sqrt(np.sum(s[3:] ** 2))) * math.degrees(1e-3 / HAND_EYE_RADIUS_M),
                                 U.HAND_EYE_FLOOR_DEG)
    radius = {}
    for cs in scenes:
        for nm in infos[cs.name].names:
            radius.setdefault((cs.placement, nm), (infos[cs.name].radius_m[nm], infos[cs.name].centre_obj[nm]))
    for unit, objs in placements.items():
        for nm, f in objs.items():
            s, ok = _stds(sd, [index[("object", unit, nm, j)] for j in range(6)])
            if not (ok and accepted):
                f.reason = ("not accepted" if not accepted else
                            "the campaign's events do not pin its pose (a direction of it is flat); pose kept")
                continue
            r, c_obj = radius[(unit, nm)]
            T0 = state0.T[(unit, nm)]
            f.T, f.fitted = end.T[(unit, nm)].copy(), True
            f.dR_deg, f.dt_mm = _pose_change(f.T @ inv_T(T0), T0[:3, :3] @ c_obj + T0[:3, 3])
            f.std_mm = U.with_floor(float(np.sqrt(np.sum(s[:3] ** 2))), U.POSE_FLOOR_MM)
            f.std_deg = U.with_floor(float(np.sqrt(np.sum(s[3:] ** 2))) * math.degrees(1e-3 / r), U.POSE_FLOOR_DEG)
    return hand_eye, placements


def scene_result(cs, info, offset_us: float, offset_std_us: float, campaign: CampaignResult,
                 params: JointParams) -> JointResult:
    """Scene ``cs``'s view of the campaign: its clock, its placement's object poses as corrections of its manifest
    (changes and standard errors against its own poses in effect; also for an object this scene alone would hold,
    e.g. mostly out of its view, when the placement's other scenes fitted it), and its hand-eye unit's increment on
    top of its own correction in effect."""
    p = JointParams(clock=params.clock, skew="fixed", objects=params.objects, hand_eye=params.hand_eye,
                    n_windows=params.n_windows)
    clock_ok = campaign.accepted and math.isfinite(offset_std_us)
    r = JointResult(params=p, offset_us=int(round(offset_us)) if clock_ok else int(info.offset_us),
                    skew_ppm=float(info.skew_ppm), offset_std_us=offset_std_us if params.clock else None,
                    accepted=campaign.accepted, reason=campaign.reason, n_windows=info.n_windows,
                    objective_before=campaign.objective_before.get(cs.name, math.nan),
                    objective_after=campaign.objective_after.get(cs.name, math.nan),
                    hand_eye_dT_cam=np.asarray(info.hand_eye).copy())
    r.held = dict(info.held)
    for nm, f in campaign.placements.get(cs.placement, {}).items():
        if nm not in info.names:
            continue
        if not f.fitted:
            r.held.setdefault(nm, f.reason)
            continue
        if nm in r.held:          # one T_base_obj per placement: what the group's other scenes pinned goes here too
            r.notes.append(f"{nm}: held in this scene ({r.held.pop(nm)}); the pose its placement's other scenes "
                           "fitted is stored here too")
        T0 = np.asarray(info.T_start[nm])
        ang, moved = _pose_change(f.T @ inv_T(T0), T0[:3, :3] @ info.centre_obj[nm] + T0[:3, 3])
        r.objects[nm] = ObjectFit(dT_base=f.T @ inv_T(np.asarray(info.T_manifest[nm])), dt_mm=moved, dR_deg=ang,
                                  std_mm=f.std_mm, std_deg=f.std_deg)
    he = campaign.hand_eye.get(cs.hand_eye)
    if he is not None and he.fitted:
        r.hand_eye_dT_cam = np.asarray(info.hand_eye) @ he.T
        r.hand_eye_dt_mm, r.hand_eye_dR_deg = he.dt_mm, he.dR_deg
        r.hand_eye_std_mm, r.hand_eye_std_deg = he.std_mm, he.std_deg
    r.notes.append(f"campaign fit of {len(campaign.scenes)} scenes: hand-eye {cs.hand_eye}, placement {cs.placement}")
    return r
