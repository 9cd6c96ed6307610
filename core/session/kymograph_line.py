"""The kymograph's line: a segment the user draws across an object edge in the event image, the events near it,
the objects' silhouette crossings along it, and a default line across the selected or fastest object.

Coordinates are pixels of the raw (distorted) event image, OpenCV convention (pixel centres at integers);
``s`` is the position along the line from its first end (px), ``n`` the signed distance across it (px).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Labels along the line are sampled this often (px): finer than a pixel, so a crossing is located at the
#: boundary between two pixels of the label map (the raster samples pixel centres: the true edge lies there
#: on average).
SAMPLE_STEP_PX = 0.25
#: The default line reaches this far beyond the object's silhouette on both sides (px).
DEFAULT_LINE_MARGIN_PX = 14.0


@dataclass(frozen=True)
class KymoLine:
    """The segment from ``(u0, v0)`` to ``(u1, v1)`` (px)."""

    u0: float
    v0: float
    u1: float
    v1: float

    @property
    def length(self) -> float:
        return math.hypot(self.u1 - self.u0, self.v1 - self.v0)

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors along the line and across it (90° clockwise in the image, rows down)."""
        d = np.array([self.u1 - self.u0, self.v1 - self.v0], np.float64) / max(self.length, 1e-9)
        return d, np.array([-d[1], d[0]])

    def project(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(s, n)`` of pixels ``(u, v)``: position along the line and signed distance across it, px."""
        d, nrm = self.axes()
        du = np.asarray(u, np.float64) - self.u0
        dv = np.asarray(v, np.float64) - self.v0
        return du * d[0] + dv * d[1], du * nrm[0] + dv * nrm[1]

    def samples(self, step_px: float = SAMPLE_STEP_PX) -> tuple[np.ndarray, np.ndarray]:
        """Points along the line every ``step_px``: ``(s (n,), uv (n, 2))``."""
        s = np.arange(0.0, self.length + 1e-9, step_px)
        d, _ = self.axes()
        return s, np.column_stack([self.u0 + s * d[0], self.v0 + s * d[1]])

    def clipped(self, width: int, height: int) -> "KymoLine | None":
        """The part of the line inside the image (pixel centres ``0..width-1``, ``0..height-1``), or None."""
        p0 = np.array([self.u0, self.v0])
        d = np.array([self.u1 - self.u0, self.v1 - self.v0])
        lo, hi = 0.0, 1.0
        for axis, top in ((0, width - 1.0), (1, height - 1.0)):
            if abs(d[axis]) < 1e-12:
                if not 0.0 <= p0[axis] <= top:
                    return None
                continue
            a, b = (0.0 - p0[axis]) / d[axis], (top - p0[axis]) / d[axis]
            lo, hi = max(lo, min(a, b)), min(hi, max(a, b))
        if hi - lo <= 0 or (hi - lo) * self.length < 2.0:
            return None
        q0, q1 = p0 + lo * d, p0 + hi * d
        return KymoLine(float(q0[0]), float(q0[1]), float(q1[0]), float(q1[1]))

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.u0, self.v0, self.u1, self.v1)


def labels_along(label_map: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The label map's value at the pixel nearest each sample ``uv`` (n, 2) (-1 outside the image)."""
    H, W = label_map.shape
    u = np.rint(uv[:, 0]).astype(np.int64)
    v = np.rint(uv[:, 1]).astype(np.int64)
    ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    out = np.full(len(uv), -1, np.int16)
    out[ok] = label_map[v[ok], u[ok]]
    return out


def edge_crossings(labels: np.ndarray, s: np.ndarray, n_objects: int) -> list[np.ndarray]:
    """Per object, the positions ``s`` (px) where the line enters or leaves its visible silhouette: the midpoints
    between consecutive samples whose labels differ (an occlusion boundary counts for both objects)."""
    labels = np.asarray(labels)
    i = np.nonzero(labels[1:] != labels[:-1])[0]
    mid = 0.5 * (s[i] + s[i + 1])
    a, b = labels[i], labels[i + 1]
    return [mid[(a == k) | (b == k)] for k in range(n_objects)]


def mask_extent_along(mask: np.ndarray, centre: np.ndarray, d: np.ndarray) -> float:
    """The farthest reach (px) of ``mask``'s pixels from ``centre`` along the unit direction ``d``, either way."""
    v, u = np.nonzero(mask)
    if len(u) == 0:
        return 0.0
    proj = (u - centre[0]) * d[0] + (v - centre[1]) * d[1]
    return float(np.abs(proj).max())


def default_line(label_now: np.ndarray, label_before: np.ndarray, label_after: np.ndarray, n_objects: int,
                 preferred: int | None = None, margin_px: float = DEFAULT_LINE_MARGIN_PX,
                 shown=None) -> KymoLine | None:
    """A line across an object along its image motion: through the centroid of its visible silhouette in
    ``label_now``, in the direction its centroid moves from ``label_before`` to ``label_after``, reaching
    ``margin_px`` beyond the silhouette on both sides (clipped to the image). The object is ``preferred``
    when visible, else the one whose centroid moves most (the largest silhouette when none moves more than
    0.5 px). Only the objects in ``shown`` (indices; default all) are candidates: a hidden object has no track.
    None when no candidate is visible."""
    H, W = label_now.shape
    best, best_key = None, None
    for k in (range(n_objects) if shown is None else shown):
        m = label_now == k
        area = int(m.sum())
        if area < 9:
            continue
        v, u = np.nonzero(m)
        c = np.array([u.mean(), v.mean()])
        motion = np.zeros(2)
        mb, ma = label_before == k, label_after == k
        if mb.any() and ma.any():
            vb, ub = np.nonzero(mb)
            va, ua = np.nonzero(ma)
            motion = np.array([ua.mean() - ub.mean(), va.mean() - vb.mean()])
        speed = float(np.hypot(*motion))
        moving = speed > 0.5
        key = (k == preferred, moving, speed if moving else 0.0, area)
        if best_key is None or key > best_key:
            best, best_key = (k, c, motion, m), key
    if best is None:
        return None
    _, c, motion, m = best
    norm = float(np.hypot(*motion))
    d = motion / norm if norm > 0.5 else np.array([1.0, 0.0])
    reach = mask_extent_along(m, c, d) + margin_px
    line = KymoLine(float(c[0] - reach * d[0]), float(c[1] - reach * d[1]),
                    float(c[0] + reach * d[0]), float(c[1] + reach * d[1]))
    return line.clipped(W, H)
