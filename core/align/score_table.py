"""Alignment scores of a whole sequence: every window scored for every object, as one table.

One render per window for all objects (so occlusion between them is exact), the window's events
subsampled by a fixed stride, each object scored by :func:`evpose.core.align.score.score_window`.
The table keeps undefined scores masked (never 0 or NaN leaking into a mean), says why each is
undefined, and names the worst window of each object, which is where a reviewer looks first.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from evpose.core.align.score import ScoreParams, score_window
from evpose.core.data.events import Cancelled
from evpose.core.label.raster import Rasterizer

__all__ = ["ScoreTable", "score_windows", "worst_window"]


@dataclass
class ScoreTable:
    """Scores of every window and object.

    ``score``, ``distance_px`` and ``inside_fraction`` map an object name to a masked array
    ``(N,)`` whose mask is ``~valid[name]`` (the hidden data is NaN, so it never leaks into a
    masked mean). ``n_events_near`` is an int array (0 where undefined).
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

    def __len__(self) -> int:
        return len(self.t_label_us)

    def mean_score(self, name: str) -> float | None:
        v = self.score[name].compressed()
        return float(v.mean()) if len(v) else None

    def to_json(self) -> dict:
        def val(a, i):
            return None if np.ma.is_masked(a[i]) else float(a[i])

        windows = []
        for i in range(len(self)):
            windows.append({"index": i, "t0_us": int(self.t0_us[i]), "t1_us": int(self.t1_us[i]),
                            "t_label_us": int(self.t_label_us[i]),
                            "objects": {n: {"score": val(self.score[n], i), "distance_px": val(self.distance_px[n], i),
                                            "inside_fraction": val(self.inside_fraction[n], i),
                                            "n_events_near": int(self.n_events_near[n][i]),
                                            "valid": bool(self.valid[n][i]),
                                            "reason": self.reasons.get(n, {}).get(i)} for n in self.objects}})
        summary = {}
        for n in self.objects:
            w = worst_window(self, n)
            summary[n] = {"mean_score": self.mean_score(n), "n_valid": int(self.valid[n].sum()),
                          "worst_window": w, "worst_t_label_us": None if w is None else int(self.t_label_us[w])}
        return {"n_windows": len(self), "objects": list(self.objects), "runtime_s": float(self.runtime_s),
                "summary": summary, "windows": windows, "unlabeled": len(self.unlabeled),
                "unlabeled_reasons": self.unlabeled_reasons()}

    def unlabeled_reasons(self) -> dict:
        """reason -> number of windows without a pose (so without any score)."""
        out: dict = {}
        for r in self.unlabeled.values():
            out[r] = out.get(r, 0) + 1
        return out


def worst_window(table: ScoreTable, name: str) -> int | None:
    """Index of the window with the lowest valid score of ``name`` (None if none is valid)."""
    s = table.score[name]
    if s.count() == 0:
        return None
    return int(np.ma.argmin(s))


def score_windows(scene, windows=None, objects=None, *, window_us: int = 10_000, clock=None,
                  params: ScoreParams = ScoreParams(), poses=None, raster: Rasterizer | None = None,
                  progress=None, cancel=None) -> ScoreTable:
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
    progress : callable, optional
        ``progress(fraction, message)``.
    cancel : callable, optional
        ``cancel() -> bool``; True raises :class:`evpose.core.data.events.Cancelled`.
    """
    from evpose.core.data.geometry import inv_T
    from evpose.core.label.windows import time_windows

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
            if len(ev) > p.max_events:
                ev = ev[::int(math.ceil(len(ev) / p.max_events))]
            for k, sc in enumerate(score_window(ev, res.obj_index, res.depth_m, K, p)):
                if sc.valid:
                    valid[k, i] = True
                    data["score"][k, i], data["dist"][k, i], data["inside"][k, i] = \
                        sc.score, sc.distance_px, sc.inside_fraction
                else:
                    reasons[names[k]][i] = sc.reason
                n_near[k, i] = sc.n_events_near
            if progress is not None and (i % 20 == 0 or i == N - 1):
                progress((i + 1) / N, f"scored {i + 1}/{N} windows")

    def masked(a, k):
        return np.ma.MaskedArray(a[k], mask=~valid[k])

    return ScoreTable(names, t0, t1, t_label,
                      {n: masked(data["score"], k) for k, n in enumerate(names)},
                      {n: masked(data["dist"], k) for k, n in enumerate(names)},
                      {n: masked(data["inside"], k) for k, n in enumerate(names)},
                      {n: n_near[k] for k, n in enumerate(names)},
                      {n: valid[k].copy() for k, n in enumerate(names)},
                      reasons, time.perf_counter() - t_start, p,
                      {i: r for i, r in enumerate(no_pose) if r is not None})
