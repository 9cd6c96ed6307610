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
so the mean distance hardly changes with the pose; the kernel score tells a 5 mm / 3 degree
error from the true pose far more often (measured in ``docs/refine.md``).

The score is **undefined** (never 0 or NaN leaking out) when the object is out of view or smaller
than ``min_pixels`` visible pixels, or fewer than ``min_events`` events fall near it. A defined score
also carries its evidence, ``n_edge_events`` (events within ``near_px`` of the edges): how much a
window can show is judged in :mod:`evpose.core.align.score_evidence`. Pixels
follow DESIGN section 3 (``[v, u]``, centres at integers), distances are in pixels of the scene's
(distorted) camera, where the events are. Scoring a whole sequence: :mod:`evpose.core.align.score_table`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from evpose.core.data.events import EventArray

__all__ = ["ObjectScore", "ScoreParams", "object_edges", "score_window"]


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

    def resolved(self, camera) -> ScoreParams:
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
    #: events within ``near_px`` of the object's edges (of the events given: a subsample scales it)
    n_edge_events: int = 0


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
        n_edge = int((d_edge[yy, xx] <= near_px).sum())
        if n_near < params.min_events:
            out.append(ObjectScore(False, n_events_near=n_near, n_pixels=n_px,
                                   reason=f"only {n_near} events near the object", n_edge_events=n_edge))
            continue
        yy, xx = yy[is_near], xx[is_near]
        dist = float(np.minimum(d_edge[yy, xx], trunc).mean())
        inside = float((d_mask[yy, xx] <= params.inside_px).mean())
        # signed distance to the silhouette (negative inside), the boundary between pixel centres
        d_in = _dt(~mask)
        sd = np.where(mask, -(d_in - 0.5), d_mask - 0.5)
        score = _kernel_contrast(sd[yy, xx], sd[near], float(params.sigma_px))
        if not math.isfinite(score):
            out.append(ObjectScore(False, n_events_near=n_near, n_pixels=n_px, reason="degenerate edge map",
                                   n_edge_events=n_edge))
            continue
        out.append(ObjectScore(True, score, dist, inside, n_near, n_px, n_edge_events=n_edge))
    return out
