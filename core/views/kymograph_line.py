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
#: A silhouette centroid moving less than this (px) does not move (for the default line).
MIN_MOTION_PX = 0.5
#: Besides its centre, candidate lines cross an object this share of its half width to either side.
OFFSET_SHARE = 0.5


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
    """The label map's value at the pixel nearest each sample ``uv`` (n, 2) (-1 outside the image); a stack of
    maps (..., H, W) gives (..., n)."""
    H, W = label_map.shape[-2:]
    u = np.rint(uv[:, 0]).astype(np.int64)
    v = np.rint(uv[:, 1]).astype(np.int64)
    ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    out = np.full(label_map.shape[:-2] + (len(uv),), -1, np.int16)
    out[..., ok] = label_map[..., v[ok], u[ok]]
    return out


def crossing_distances(labels: np.ndarray, s: np.ndarray, labels_cols: np.ndarray,
                       k: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Object ``k``'s crossings with the line at each of several times and the signed distance of every column
    to the nearest one.

    ``labels`` (n_t, n_s): the labels at the samples ``s`` (px) along the line per time; ``labels_cols``
    (n_t, n_cols): the labels at the columns (``s = c`` px); at least two samples. Returns the crossings per time
    (the midpoints between consecutive samples whose labels differ, one of them ``k``: an occlusion boundary
    counts for both objects) and (n_t, n_cols) the distance of column ``c`` to the nearest crossing at that time,
    > 0 inside the silhouette (``labels_cols == k``), +-inf without crossings."""
    a, b = labels[:, :-1], labels[:, 1:]
    at = (a != b) & ((a == k) | (b == k))                      # a crossing between samples j and j + 1
    mid = 0.5 * (s[:-1] + s[1:])
    n_j = len(mid)
    j = np.arange(n_j)
    before = np.maximum.accumulate(np.where(at, j, -1), axis=1)                   # last crossing <= j
    after = np.minimum.accumulate(np.where(at, j, n_j)[:, ::-1], axis=1)[:, ::-1]  # first crossing >= j
    c = np.arange(labels_cols.shape[1], dtype=np.float64)
    jl = np.searchsorted(mid, c, side="right") - 1             # the last midpoint at or left of each column
    left = np.where(jl >= 0, before[:, np.clip(jl, 0, n_j - 1)], -1)
    right = np.where(jl + 1 < n_j, after[:, np.clip(jl + 1, 0, n_j - 1)], n_j)
    d = np.minimum(np.where(left >= 0, c - mid[np.clip(left, 0, n_j - 1)], np.inf),
                   np.where(right < n_j, mid[np.clip(right, 0, n_j - 1)] - c, np.inf))
    return [mid[row] for row in at], np.where(labels_cols == k, d, -d)


def mask_extent_along(mask: np.ndarray, centre: np.ndarray, d: np.ndarray) -> float:
    """The farthest reach (px) of ``mask``'s pixels from ``centre`` along the unit direction ``d``, either way."""
    v, u = np.nonzero(mask)
    if len(u) == 0:
        return 0.0
    proj = (u - centre[0]) * d[0] + (v - centre[1]) * d[1]
    return float(np.abs(proj).max())


def silhouette_motion(k: int, label_a: np.ndarray, label_b: np.ndarray) -> np.ndarray:
    """How far (px, ``(du, dv)``) object ``k``'s silhouette centroid moves from ``label_a`` to ``label_b`` (0 when
    it is missing from either)."""
    ma, mb = label_a == k, label_b == k
    if not (ma.any() and mb.any()):
        return np.zeros(2)
    va, ua = np.nonzero(ma)
    vb, ub = np.nonzero(mb)
    return np.array([ub.mean() - ua.mean(), vb.mean() - va.mean()])


def line_through(mask: np.ndarray, p: np.ndarray, d: np.ndarray, margin_px: float) -> KymoLine | None:
    """The line through ``p`` along the unit direction ``d`` reaching ``margin_px`` beyond ``mask`` on both sides
    (clipped to the image)."""
    H, W = mask.shape
    reach = mask_extent_along(mask, p, d) + margin_px
    line = KymoLine(float(p[0] - reach * d[0]), float(p[1] - reach * d[1]),
                    float(p[0] + reach * d[0]), float(p[1] + reach * d[1]))
    return line.clipped(W, H)


def directions(*motions: np.ndarray, min_px: float = MIN_MOTION_PX, min_angle_deg: float = 20.0) -> list:
    """Unit directions of the ``motions`` longer than ``min_px``, without near repeats (either way round);
    ``[(1, 0), (0, 1)]`` (along the rows and the columns) when none is."""
    out = []
    for m in motions:
        n = float(np.hypot(*m))
        if n > min_px:
            d = m / n
            if all(abs(float(d @ e)) < np.cos(np.radians(min_angle_deg)) for e in out):
                out.append(d)
    return out or [np.array([1.0, 0.0]), np.array([0.0, 1.0])]


def candidate_lines(label_now: np.ndarray, label_before: np.ndarray, label_after: np.ndarray,
                    label_first: np.ndarray, label_last: np.ndarray, n_objects: int, preferred: int | None = None,
                    margin_px: float = DEFAULT_LINE_MARGIN_PX, shown=None) -> list[tuple[int, KymoLine]]:
    """Lines across the objects along their image motion, ``[(object, line)]``, the likeliest first.

    Per visible object (only those in ``shown``, indices; default all): along the way its silhouette centroid
    moves now (``label_before`` -> ``label_after``) and over the span (``label_first`` -> ``label_last``), each
    through the centroid in ``label_now`` and through points ``OFFSET_SHARE`` of the silhouette's half width to
    either side, reaching ``margin_px`` beyond the silhouette (clipped to the image). Objects are ordered
    ``preferred`` first, then moving now before still, faster first, larger first; the centre line of an
    object's first direction comes first."""
    ranked = []
    for k in (range(n_objects) if shown is None else shown):
        m = label_now == k
        area = int(m.sum())
        if area < 9:
            continue
        v, u = np.nonzero(m)
        c = np.array([u.mean(), v.mean()])
        now = silhouette_motion(k, label_before, label_after)
        speed = float(np.hypot(*now))
        moving = speed > MIN_MOTION_PX
        key = (k == preferred, moving, speed if moving else 0.0, area)
        ranked.append((key, k, m, c, directions(now, silhouette_motion(k, label_first, label_last))))
    ranked.sort(key=lambda r: r[0], reverse=True)
    out = []
    for _, k, m, c, dirs in ranked:
        for d in dirs:
            across = np.array([-d[1], d[0]])
            half = mask_extent_along(m, c, across)
            for off in (0.0, -OFFSET_SHARE * half, OFFSET_SHARE * half):
                line = line_through(m, c + off * across, d, margin_px)
                if line is not None:
                    out.append((k, line))
    return out


def default_line(label_now: np.ndarray, label_before: np.ndarray, label_after: np.ndarray, n_objects: int,
                 preferred: int | None = None, margin_px: float = DEFAULT_LINE_MARGIN_PX,
                 shown=None) -> KymoLine | None:
    """The likeliest of :func:`candidate_lines` (motion now only): through the centroid of the ``preferred``
    object when visible, else of the one whose centroid moves most (the largest silhouette when none moves more
    than ``MIN_MOTION_PX``), along its motion. None when no candidate is visible."""
    lines = candidate_lines(label_now, label_before, label_after, label_now, label_now, n_objects, preferred,
                            margin_px, shown)
    return lines[0][1] if lines else None
