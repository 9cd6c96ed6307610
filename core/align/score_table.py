"""Alignment scores of a whole sequence: every window scored for every object, as one table.

One render per window for all objects (so occlusion between them is exact), the window's events
subsampled by a fixed stride, each object scored by :func:`evpose.core.align.score.score_window`.
The table keeps undefined scores masked (never 0 or NaN leaking into a mean), says why each is
undefined, and names the worst window of each object, which is where a reviewer looks first.

Each defined score carries its evidence (:mod:`evpose.core.align.score_evidence`: events near the
object's edges, its image motion, how much of it is in view). A window with too little is **low
evidence**: its score is kept and reported, but the worst window is only ever one with evidence, where
a human can see what is wrong.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from evpose.core.align.score import ScoreParams, score_window
from evpose.core.align.score_evidence import (
    STATE_LOW,
    STATE_OK,
    STATE_UNDEFINED,
    EvidenceParams,
    box_points,
    image_motion_px_s,
    in_view_fraction,
    low_evidence_reason,
)
from evpose.core.data.events import Cancelled
from evpose.core.label.raster import Rasterizer
from evpose.core.label.windows import DEFAULT_WINDOW_US

__all__ = ["ScoreTable", "score_windows", "worst_note", "worst_window"]


@dataclass
class ScoreTable:
    """Scores of every window and object.

    ``score``, ``distance_px`` and ``inside_fraction`` map an object name to a masked array
    ``(N,)`` whose mask is ``~valid[name]`` (the hidden data is NaN, so it never leaks into a
    masked mean). ``n_events_near`` is an int array (0 where undefined).

    Evidence, per object name (see :mod:`evpose.core.align.score_evidence`): ``n_edge_events`` (int,
    whole window), ``motion_px_s`` (float, px/s, NaN unknown), ``in_view_fraction`` (float, NaN without
    a pose), ``low_evidence`` (bool, only where ``valid``) with the reason in ``evidence_reasons[name][i]``.
    """

    objects: list
    t0_us: np.ndarray
    t1_us: np.ndarray
    t_label_us: np.ndarray
    score: dict
    distance_px: dict
    inside_fraction: dict
    n_events_near: dict
    valid: dict
    reasons: dict = field(default_factory=dict)
    runtime_s: float = 0.0
    params: ScoreParams | None = None
    #: window index -> why it has no pose (outside the trajectory or in a hole): no score for any object
    unlabeled: dict = field(default_factory=dict)
    n_edge_events: dict = field(default_factory=dict)
    motion_px_s: dict = field(default_factory=dict)
    in_view_fraction: dict = field(default_factory=dict)
    low_evidence: dict = field(default_factory=dict)
    evidence_reasons: dict = field(default_factory=dict)
    evidence: EvidenceParams | None = None

    def __len__(self) -> int:
        return len(self.t_label_us)

    def informative(self, name: str) -> np.ndarray:
        """(N,) bool: the score of ``name`` is defined and backed by evidence (state "ok")."""
        low = self.low_evidence.get(name)
        return self.valid[name] & (False if low is None else ~low)

    def state(self, name: str) -> np.ndarray:
        """(N,) str per window: ``"ok"``, ``"low_evidence"`` (a score without evidence) or ``"undefined"``."""
        out = np.full(len(self), STATE_UNDEFINED, dtype=object)
        out[self.valid[name]] = STATE_LOW
        out[self.informative(name)] = STATE_OK
        return out

    def mean_score(self, name: str) -> float | None:
        v = self.score[name].compressed()
        return float(v.mean()) if len(v) else None

    def to_json(self) -> dict:
        states = {n: self.state(n) for n in self.objects}
        windows = [{"index": i, "t0_us": int(self.t0_us[i]), "t1_us": int(self.t1_us[i]),
                    "t_label_us": int(self.t_label_us[i]),
                    "objects": {n: self._window_json(n, i, str(states[n][i])) for n in self.objects}}
                   for i in range(len(self))]
        summary = {}
        for n in self.objects:
            w = worst_window(self, n)
            summary[n] = {"mean_score": self.mean_score(n), "n_valid": int(self.valid[n].sum()),
                          "n_ok": int((states[n] == STATE_OK).sum()),
                          "n_low_evidence": int((states[n] == STATE_LOW).sum()),
                          "worst_window": w, "worst_t_label_us": None if w is None else int(self.t_label_us[w]),
                          "worst_note": worst_note(self, n)}
        ev = self.evidence
        return {"n_windows": len(self), "objects": list(self.objects), "runtime_s": float(self.runtime_s),
                "summary": summary, "windows": windows, "unlabeled": len(self.unlabeled),
                "unlabeled_reasons": self.unlabeled_reasons(),
                "evidence": None if ev is None else {"min_edge_events": int(ev.min_edge_events),
                                                     "min_motion_px": float(ev.min_motion_px),
                                                     "min_in_view": float(ev.min_in_view)}}

    def _window_json(self, n: str, i: int, state: str) -> dict:
        """One object in one window: its measures (None where undefined), evidence and state."""
        def val(a):
            return None if np.ma.is_masked(a[i]) else float(a[i])

        def num(d):
            a = d.get(n)
            return None if a is None or not np.isfinite(a[i]) else float(a[i])

        edge = self.n_edge_events.get(n)
        return {"score": val(self.score[n]), "distance_px": val(self.distance_px[n]),
                "inside_fraction": val(self.inside_fraction[n]), "n_events_near": int(self.n_events_near[n][i]),
                "valid": bool(self.valid[n][i]), "reason": self.reasons.get(n, {}).get(i),
                "n_edge_events": 0 if edge is None else int(edge[i]), "motion_px_s": num(self.motion_px_s),
                "in_view_fraction": num(self.in_view_fraction), "state": state,
                "evidence_reason": self.evidence_reasons.get(n, {}).get(i)}

    def unlabeled_reasons(self) -> dict:
        """reason -> number of windows without a pose (so without any score)."""
        out: dict = {}
        for r in self.unlabeled.values():
            out[r] = out.get(r, 0) + 1
        return out


def worst_window(table: ScoreTable, name: str) -> int | None:
    """Index of the window with the lowest score of ``name`` among those backed by evidence (state
    "ok"); None when there is none (:func:`worst_note` says why). Low-evidence windows never count."""
    ok = table.informative(name)
    if not ok.any():
        return None
    return int(np.argmin(np.where(ok, np.ma.getdata(table.score[name]), np.inf)))


def worst_note(table: ScoreTable, name: str) -> str | None:
    """Why ``name`` has no worst window (None when it has one)."""
    if table.informative(name).any():
        return None
    n_low = int(table.low_evidence[name].sum()) if name in table.low_evidence else 0
    if n_low == 0:
        return "no window has a score"
    counts: dict = {}
    for r in table.evidence_reasons.get(name, {}).values():
        for part in r.split("; "):
            key = part.split(" (")[0]
            counts[key] = counts.get(key, 0) + 1
    why = ", ".join(f"{k}: {v}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1]))
    return f"no window has enough evidence: {n_low} low-evidence windows ({why})"


def score_windows(scene, windows=None, objects=None, *, window_us: int = DEFAULT_WINDOW_US, clock=None,
                  params: ScoreParams = ScoreParams(), poses=None, raster: Rasterizer | None = None,
                  evidence: EvidenceParams = EvidenceParams(), progress=None, cancel=None) -> ScoreTable:
    """Score every window (default: the recording tiled with ``window_us`` windows) and object.

    Parameters
    ----------
    scene : evpose.core.data.scene.Scene
    windows : list of evpose.core.label.windows.Window or of (t0_us, t1_us), optional
        Label time is the window centre.
    objects : list of str, optional
        Default all.
    clock : ClockModel, optional
        Clock override (default: the scene's clock in effect).
    poses : dict name -> (4, 4) T_base_obj, optional
        Object pose overrides (e.g. a candidate correction).
    evidence : EvidenceParams
        When a defined score is low evidence (:mod:`evpose.core.align.score_evidence`).
    progress : callable, optional
        ``progress(fraction, message)``.
    cancel : callable, optional
        ``cancel() -> bool``; True raises :class:`evpose.core.data.events.Cancelled`.
    """
    from evpose.core.data.geometry import inv_T
    from evpose.core.label.windows import time_windows

    if not getattr(scene, "has_poses", True):        # an event-only scene: one line, not an empty table
        scene.require_poses("alignment scores")
    t_start = time.perf_counter()
    names = scene.object_names if objects is None else list(objects)
    p = params.resolved(scene.camera)
    if windows is None:
        windows = time_windows(scene.events, window_us)
    bounds = np.array([(w.t0_us, w.t1_us) if hasattr(w, "t0_us") else (int(w[0]), int(w[1])) for w in windows],
                      dtype=np.int64).reshape(-1, 2)
    N, K = len(bounds), len(names)
    t0, t1 = bounds[:, 0], bounds[:, 1]
    t_label = t0 + (t1 - t0) // 2
    data = {k: np.full((K, N), np.nan) for k in ("score", "dist", "inside")}
    n_near = np.zeros((K, N), np.int64)
    n_edge = np.zeros((K, N), np.int64)
    motion = np.full((K, N), np.nan)
    in_view = np.full((K, N), np.nan)
    valid = np.zeros((K, N), bool)
    reasons = {n: {} for n in names}
    no_pose = []
    if N and K:
        T_bc, pose_ok = scene.T_base_cam(t_label, clock=clock)
        no_pose = [None] * N                     # outside the trajectory or in a hole: no score
        if not pose_ok.all():
            bad = np.flatnonzero(~pose_ok)
            for i, r in zip(bad, scene.unlabeled_reasons(t_label[bad], clock)):
                no_pose[i] = r
        T_cb = inv_T(T_bc)
        T_bo = np.stack([np.asarray(poses[n]) if poses and n in poses else scene.T_base_obj(n) for n in names])
        models = [scene.raster_model(n) for n in names]
        raster = raster or Rasterizer(scene.camera)
        motion, in_view = _motion_and_view(scene, names, T_bo, t0, t1, T_cb, pose_ok, clock)
        for i in range(N):
            if cancel is not None and cancel():
                raise Cancelled("scoring cancelled")
            if not pose_ok[i]:
                why = no_pose[i] or "label time outside the trajectory"
                for n in names:
                    reasons[n][i] = why
                continue
            T_co = [T_cb[i] @ T_bo[k] for k in range(K)]
            res = raster.render_objects(models, T_co)
            ev = scene.events.window(int(t0[i]), int(t1[i]))
            stride = int(math.ceil(len(ev) / p.max_events)) if len(ev) > p.max_events else 1
            ev = ev[::stride]
            for k, sc in enumerate(score_window(ev, res.obj_index, res.depth_m, K, p)):
                if sc.valid:
                    valid[k, i] = True
                    data["score"][k, i], data["dist"][k, i], data["inside"][k, i] = \
                        sc.score, sc.distance_px, sc.inside_fraction
                else:
                    reasons[names[k]][i] = sc.reason
                n_near[k, i] = sc.n_events_near
                n_edge[k, i] = sc.n_edge_events * stride
            if progress is not None and (i % 20 == 0 or i == N - 1):
                progress((i + 1) / N, f"scored {i + 1}/{N} windows")

    def masked(a, k):
        return np.ma.MaskedArray(a[k], mask=~valid[k])

    low, why = _low_evidence(names, valid, n_edge, motion, in_view, evidence,
                             evidence.min_motion_px_s(float(scene.camera.K[0, 0]), t1 - t0))
    return ScoreTable(names, t0, t1, t_label,
                      {n: masked(data["score"], k) for k, n in enumerate(names)},
                      {n: masked(data["dist"], k) for k, n in enumerate(names)},
                      {n: masked(data["inside"], k) for k, n in enumerate(names)},
                      {n: n_near[k] for k, n in enumerate(names)},
                      {n: valid[k].copy() for k, n in enumerate(names)},
                      reasons, time.perf_counter() - t_start, p,
                      {i: r for i, r in enumerate(no_pose) if r is not None},
                      {n: n_edge[k] for k, n in enumerate(names)}, {n: motion[k] for k, n in enumerate(names)},
                      {n: in_view[k] for k, n in enumerate(names)}, {n: low[k] for k, n in enumerate(names)},
                      why, evidence)


def _motion_and_view(scene, names, T_bo, t0, t1, T_cb, pose_ok, clock) -> tuple[np.ndarray, np.ndarray]:
    """Image motion (px/s; NaN where a window end has no pose) and in-view share (NaN without a pose at
    the label time), ``(K, N)`` each."""
    from evpose.core.data.geometry import inv_T

    T_s, ok_s = scene.T_base_cam(t0, clock=clock)
    T_e, ok_e = scene.T_base_cam(t1, clock=clock)
    T_cs, T_ce = inv_T(T_s), inv_T(T_e)
    motion = np.full((len(names), len(t0)), np.nan)
    view = np.full((len(names), len(t0)), np.nan)
    for k, n in enumerate(names):
        pts = box_points(scene.model(n))
        m = image_motion_px_s(scene.camera, pts, T_cs @ T_bo[k], T_ce @ T_bo[k], t1 - t0)
        motion[k] = np.where(ok_s & ok_e, m, np.nan)
        view[k] = np.where(pose_ok, in_view_fraction(scene.camera, pts, T_cb @ T_bo[k]), np.nan)
    return motion, view


def _low_evidence(names, valid, n_edge, motion, in_view, evidence: EvidenceParams, min_motion_px_s):
    """``(K, N)`` bool (only where valid) and name -> {window: reason}."""
    low = np.zeros_like(valid)
    why: dict = {n: {} for n in names}
    for k, i in zip(*np.nonzero(valid)):
        r = low_evidence_reason(int(n_edge[k, i]), float(motion[k, i]), float(in_view[k, i]),
                                float(min_motion_px_s[i]), evidence)
        if r:
            low[k, i] = True
            why[names[k]][int(i)] = r
    return low, why
