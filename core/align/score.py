"""Alignment score of a window's events against each object's projected model.

For one window, all objects are rasterised once (one z-buffer, so occlusion between objects is
exact) at the window's label time. Per object, the **edges** are the pixels on either side of
its visible silhouette (label changes between 4-neighbours) and of its depth discontinuities
(self-occlusion: neighbouring pixels of the object whose depths differ by more than
``depth_edge_rel`` of the depth). The measures, on the window's events that fall **near** the
object (within ``near_px`` of its visible mask):

* ``distance_px``: robust mean distance of those events to the edges, each distance truncated
  at ``trunc_px`` (``cv2.distanceTransform`` on a crop around the object);
* ``inside_fraction``: share of them inside the mask dilated by ``inside_px``;
* ``score`` (the one the timeline shows, higher is better): the mean of an edge kernel over the
  events within ``3 sigma_px`` of the silhouette minus its mean for events spread uniformly
  over that band, ``K(u) = g(u) (1 - beta u e^0.5)`` with ``g(u) = exp(-u^2/2)`` and ``u`` the
  signed distance to the silhouette (negative inside, boundary half-way between pixel
  centres) in units of ``sigma_px``: a ridge for events on the silhouette plus an odd step
  detector for the contrast of event density across it (``beta`` in [-1, 1], the share of
  band events inside minus outside, so a textured object on a plain table and the reverse
  both count). 0 means "no better than noise", clipped to [-1, 1].

Why not the edge distance as the score: on textured objects most events come from the texture,
so the mean distance hardly changes with the pose; on the synthetic scenes of ``core.synth``
the kernel score is higher for the true pose than for a 5 mm / 3 degree error in 86-100 % of
10 ms windows, the truncated distance only in about half of them (``bench/accuracy.py``).

The score is **undefined** (masked, never 0 or NaN leaking out) when the label time is outside
the trajectory, the object is out of view or smaller than ``min_pixels`` visible pixels, or
fewer than ``min_events`` events fall near it. Windows with many events are subsampled by a
fixed stride (``max_events``), which keeps the time distribution and makes the cost per window
bounded. Pixels follow DESIGN section 3 (``[v, u]``, centres at integers), distances are in
pixels of the scene's (distorted) camera, where the events are.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from evpose.core.data.events import Cancelled, EventArray
from evpose.core.label.raster import Rasterizer

__all__ = ["ScoreParams", "ScoreTable", "ObjectScore", "score_window", "score_windows", "worst_window",
           "object_edges"]


@dataclass(frozen=True)
class ScoreParams:
    """Parameters of the alignment score (pixels of the scene camera).

    ``near_px`` / ``trunc_px`` default to 3 % of the larger image side (at least 4 px), i.e.
    ~10 px on a DAVIS346 and ~5 px at half resolution; ``sigma_px`` (the width of the score's
    kernel) to ``max(1, fx / 146)``, i.e. 1 px at half and 2 px at full DAVIS346 resolution.
    """

    near_px: float | None = None
    trunc_px: float | None = None
    sigma_px: float | None = None
    inside_px: float = 2.0
    max_events: int = 4000
    min_events: int = 20
    min_pixels: int = 16
    depth_edge_rel: float = 0.03

    def resolved(self, camera) -> "ScoreParams":
        auto = max(4.0, 0.03 * max(camera.width, camera.height))
        near = self.near_px if self.near_px is not None else auto
        trunc = self.trunc_px if self.trunc_px is not None else near
        sigma = self.sigma_px if self.sigma_px is not None else max(1.0, float(camera.K[0, 0]) / 146.0)
        return ScoreParams(float(near), float(trunc), float(sigma), self.inside_px, self.max_events, self.min_events,
                           self.min_pixels, self.depth_edge_rel)


@dataclass
class ObjectScore:
    """Measures of one object in one window (``valid=False``: undefined, values are NaN/0)."""

    valid: bool
    score: float = float("nan")
    distance_px: float = float("nan")
    inside_fraction: float = float("nan")
    n_events_near: int = 0
    n_pixels: int = 0
    reason: str = ""


def object_edges(obj_index: np.ndarray, depth_m: np.ndarray, k: int, depth_edge_rel: float = 0.03) -> np.ndarray:
    """Edge pixels of object ``k``: both sides of its silhouette and its depth discontinuities.

    Parameters
    ----------
    obj_index : (H, W) int
        Per-pixel object index (-1 background), e.g. ``RasterResult.obj_index``.
    depth_m : (H, W) float
        Per-pixel depth, metres (inf where empty).

    Returns
    -------
    (H, W) bool
    """
    m = obj_index == k
    e = np.zeros_like(m)
    # silhouette: label changes between horizontal / vertical neighbours, both pixels marked
    dh = m[:, 1:] != m[:, :-1]
    dv = m[1:, :] != m[:-1, :]
    e[:, 1:] |= dh
    e[:, :-1] |= dh
    e[1:, :] |= dv
    e[:-1, :] |= dv
    # depth discontinuities inside the object (self-occlusion)
    if depth_edge_rel > 0:
        z = np.where(m, depth_m, np.nan).astype(np.float64)
        with np.errstate(invalid="ignore"):
            jh = np.abs(z[:, 1:] - z[:, :-1]) > depth_edge_rel * np.fmin(z[:, 1:], z[:, :-1])
            jv = np.abs(z[1:, :] - z[:-1, :]) > depth_edge_rel * np.fmin(z[1:, :], z[:-1, :])
        e[:, 1:] |= jh
        e[:, :-1] |= jh
        e[1:, :] |= jv
        e[:-1, :] |= jv
    return e


def _crop(mask: np.ndarray, pad: int):
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    H, W = mask.shape
    return (max(int(rows[0]) - pad, 0), min(int(rows[-1]) + pad + 1, H),
            max(int(cols[0]) - pad, 0), min(int(cols[-1]) + pad + 1, W))


def _dt(zero_where: np.ndarray) -> np.ndarray:
    """Euclidean distance (px) of every pixel to the nearest True pixel of ``zero_where``."""
    if not zero_where.any():
        return np.full(zero_where.shape, np.inf, np.float32)
    return cv2.distanceTransform((~zero_where).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


_E05 = math.exp(0.5)


def _kernel_contrast(sd_events: np.ndarray, sd_pixels: np.ndarray, sigma: float) -> float:
    """Mean edge kernel of the events minus its mean over the pixels (uniform events).

    ``K(u) = g(u) (1 - beta u e^0.5)``, ``g(u) = exp(-u^2 / 2)``, ``u = sd / sigma``: a ridge
    on the silhouette plus an odd step detector for the contrast of event density across it
    (``beta`` in [-1, 1] from the events within 3 sigma: the share inside minus outside). Only
    the 3-sigma band around the silhouette counts. NaN when no event is in the band.
    """
    ue = sd_events / sigma
    ue = ue[np.abs(ue) <= 3.0]
    up = sd_pixels / sigma
    up = up[np.abs(up) <= 3.0]
    if len(ue) == 0 or len(up) == 0:
        return float("nan")
    beta = float(np.clip(((ue < 0).sum() - (ue > 0).sum()) / len(ue), -1.0, 1.0))

    def K(u):
        return np.exp(-0.5 * u * u) * (1.0 - beta * u * _E05)

    return float(np.clip(K(ue).mean() - K(up).mean(), -1.0, 1.0))


def score_window(events: EventArray, obj_index: np.ndarray, depth_m: np.ndarray, n_objects: int,
                 params: ScoreParams) -> list[ObjectScore]:
    """Scores of ``n_objects`` objects in one window from its (subsampled) events and the
    rasterised label / depth images. ``params`` must be resolved (see :meth:`ScoreParams.resolved`)."""
    near_px, trunc = float(params.near_px), float(params.trunc_px)
    pad = int(math.ceil(near_px)) + 2
    out = []
    ex = events.x.astype(np.intp) if len(events) else np.zeros(0, np.intp)
    ey = events.y.astype(np.intp) if len(events) else np.zeros(0, np.intp)
    H, W = obj_index.shape
    inb = (ex < W) & (ey < H)
    ex, ey = ex[inb], ey[inb]
    counts = np.bincount(obj_index[obj_index >= 0].ravel().astype(np.intp), minlength=n_objects)
    for k in range(n_objects):
        n_px = int(counts[k]) if k < len(counts) else 0
        if n_px < params.min_pixels:
            out.append(ObjectScore(False, n_pixels=n_px,
                                   reason="out of view" if n_px == 0 else f"only {n_px} visible pixels"))
            continue
        r0, r1, c0, c1 = _crop(obj_index == k, pad)
        oi = obj_index[r0:r1, c0:c1]
        mask = oi == k
        edges = object_edges(oi, depth_m[r0:r1, c0:c1], k, params.depth_edge_rel)
        d_edge = _dt(edges)
        d_mask = _dt(mask)
        near = d_mask <= near_px
        sel = (ey >= r0) & (ey < r1) & (ex >= c0) & (ex < c1)
        yy, xx = ey[sel] - r0, ex[sel] - c0
        is_near = near[yy, xx]
        n_near = int(is_near.sum())
        if n_near < params.min_events:
            out.append(ObjectScore(False, n_events_near=n_near, n_pixels=n_px,
                                   reason=f"only {n_near} events near the object"))
            continue
        yy, xx = yy[is_near], xx[is_near]
        dist = float(np.minimum(d_edge[yy, xx], trunc).mean())
        inside = float((d_mask[yy, xx] <= params.inside_px).mean())
        # signed distance to the silhouette (negative inside), the boundary between pixel centres
        d_in = _dt(~mask)
        sd = np.where(mask, -(d_in - 0.5), d_mask - 0.5)
        score = _kernel_contrast(sd[yy, xx], sd[near], float(params.sigma_px))
        if not math.isfinite(score):
            out.append(ObjectScore(False, n_events_near=n_near, n_pixels=n_px, reason="degenerate edge map"))
            continue
        out.append(ObjectScore(True, score, dist, inside, n_near, n_px))
    return out


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
    windows : list of evpose.core.label.annotate.Window or of (t0_us, t1_us), optional
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
    from evpose.core.label.annotate import time_windows

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
