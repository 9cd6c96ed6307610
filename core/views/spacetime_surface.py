"""Silhouette tubes as surfaces: each object's contours at consecutive slice times joined into a triangle band,
so the space-time view can draw the tube as a translucent skin around the events it should enclose.

Contours of two consecutive slices are paired by their centroids (the nearest, if it is near enough for the
contours' size), both resampled to ``RING_POINTS`` points evenly along their length, given the same winding,
and the second one rotated to the start that best matches the first; the band between them is two triangles
per point. Coordinates are the space-time view's data coordinates ``(x px, y px, t ms)``.
"""
from __future__ import annotations

from collections import OrderedDict

import numpy as np

from evpose.core.views.spacetime_band import derived_nbytes, drop_dead, value_ref

#: Points per resampled contour ring.
RING_POINTS = 48
#: Contours shorter than this (px) are not joined (specks).
MIN_RING_LENGTH_PX = 6.0
#: Bytes of joined slice pairs kept by :class:`SurfaceCache` (a pair of five YCB objects' rings: 1-4 kB; a span has
#: ``slices - 1`` pairs per object).
SURFACE_CACHE_BYTES = 2 << 20


def resample_ring(contour: np.ndarray, n: int = RING_POINTS) -> np.ndarray | None:
    """A closed polyline (M, 2) resampled to ``n`` points evenly spaced along its length, counter-clockwise in
    the image's (u, v) axes; None when shorter than ``MIN_RING_LENGTH_PX``."""
    c = np.asarray(contour, np.float64)
    if len(c) < 3:
        return None
    if not np.array_equal(c[0], c[-1]):
        c = np.vstack([c, c[:1]])
    seg = np.hypot(*np.diff(c, axis=0).T)
    total = float(seg.sum())
    if total < MIN_RING_LENGTH_PX:
        return None
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.linspace(0.0, total, n, endpoint=False)
    ring = np.column_stack([np.interp(s, arc, c[:, 0]), np.interp(s, arc, c[:, 1])])
    x, y = ring[:, 0], ring[:, 1]
    area2 = float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))
    return ring[::-1].copy() if area2 < 0 else ring


def aligned(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``b`` rotated (cyclically) to the start that minimises the squared distances to ``a``'s points."""
    n = len(a)
    shifts = (np.arange(n)[:, None] + np.arange(n)[None, :]) % n          # shift k: b[(i + k) % n]
    cost = ((b[shifts] - a[None, :, :]) ** 2).sum(axis=(1, 2))
    return b[shifts[int(np.argmin(cost))]]


def ring_bands(a: np.ndarray, b: np.ndarray, ta: np.ndarray, tb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (2 P n, 3) float32 and triangles (2 P n, 3) uint32 of the bands between the rings ``a[p]`` at
    ``ta[p]`` and ``b[p]`` at ``tb[p]`` (``a``, ``b``: (P, n, 2) with matching starts)."""
    P, n = a.shape[:2]
    verts = np.empty((P, 2 * n, 3), np.float32)
    verts[:, :n, :2], verts[:, n:, :2] = a, b
    verts[:, :n, 2] = np.asarray(ta, np.float32)[:, None]
    verts[:, n:, 2] = np.asarray(tb, np.float32)[:, None]
    i = np.arange(n)
    j = (i + 1) % n
    one = np.concatenate([np.stack([i, j, n + i], 1), np.stack([j, n + j, n + i], 1)])      # (2n, 3)
    tri = one[None, :, :] + (2 * n * np.arange(P))[:, None, None]
    return verts.reshape(-1, 3), tri.reshape(-1, 3).astype(np.uint32)


def pair_rings(rings_a: list, rings_b: list) -> list[tuple[int, int]]:
    """Index pairs of the rings of two consecutive slices: each ring of ``a`` with the ring of ``b`` whose
    centroid is nearest, when nearer than half the rings' mean radius plus 4 px."""
    if not rings_a or not rings_b:
        return []
    ca = np.array([r.mean(axis=0) for r in rings_a])
    cb = np.array([r.mean(axis=0) for r in rings_b])
    ra = np.array([np.hypot(*(r - c).T).mean() for r, c in zip(rings_a, ca)])
    rb = np.array([np.hypot(*(r - c).T).mean() for r, c in zip(rings_b, cb)])
    d = np.hypot(*(ca[:, None, :] - cb[None, :, :]).transpose(2, 0, 1))
    pairs = []
    for i in range(len(rings_a)):
        j = int(np.argmin(d[i]))
        if d[i, j] <= 0.5 * (ra[i] + rb[j]) / 2 + 4.0:
            pairs.append((i, j))
    return pairs


def joined_rings(contours_a: list, contours_b: list) -> tuple[np.ndarray, np.ndarray]:
    """The paired, resampled and aligned rings of two consecutive slices' contours: (P, n, 2) each."""
    ra = [r for r in (resample_ring(c) for c in contours_a) if r is not None]
    rb = [r for r in (resample_ring(c) for c in contours_b) if r is not None]
    pairs = pair_rings(ra, rb)
    if not pairs:
        return np.zeros((0, RING_POINTS, 2)), np.zeros((0, RING_POINTS, 2))
    return (np.stack([ra[i] for i, _ in pairs]), np.stack([aligned(ra[i], rb[j]) for i, j in pairs]))


class SurfaceCache:
    """:func:`joined_rings` by the two slices' values (the cached slice lists: the same objects for the same
    times and poses; recognised by identity, not kept alive: the rings of a slice the slice cache dropped go
    with it) and the object; least recently used first out beyond ``max_bytes`` (:attr:`nbytes`)."""

    def __init__(self, max_bytes: int = SURFACE_CACHE_BYTES):
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict = OrderedDict()
        self.nbytes = 0

    def __len__(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        self._items.clear()
        self.nbytes = 0

    def joined(self, value_a: list, value_b: list, name: str, contours_a: list, contours_b: list):
        key = (id(value_a), id(value_b), name)
        hit = self._items.get(key)
        if hit is not None and hit[0][0]() is value_a and hit[0][1]() is value_b:
            self._items.move_to_end(key)
            return hit[1]
        rings = joined_rings(contours_a, contours_b)
        self.nbytes -= drop_dead(self._items)             # rings of slices the slice cache dropped
        old = self._items.pop(key, None)                  # reused ids of dead values
        if old is not None:
            self.nbytes -= derived_nbytes(old[1])
        nb = derived_nbytes(rings)
        if nb <= self.max_bytes:
            self._items[key] = ((value_ref(value_a), value_ref(value_b)), rings)   # not kept alive by this cache
            self.nbytes += nb
        while self.nbytes > self.max_bytes:
            self.nbytes -= derived_nbytes(self._items.popitem(last=False)[1][1])
        return rings


def tube_surface(slices: list[tuple[float, list[np.ndarray]]]) -> tuple[np.ndarray, np.ndarray]:
    """One object's tube surface from its contours per slice ``[(t ms, [contour (M, 2)])]`` in time order:
    ``(vertices (V, 3) float32, triangles (F, 3) uint32)`` (empty arrays when no two slices join)."""
    parts = [(joined_rings(ca, cb), ta, tb) for (ta, ca), (tb, cb) in zip(slices[:-1], slices[1:])]
    return surface_of(parts)


def surface_of(parts: list) -> tuple[np.ndarray, np.ndarray]:
    """The bands of ``[((rings_a, rings_b), ta, tb)]`` as one mesh (see :func:`ring_bands`)."""
    parts = [(rings, ta, tb) for rings, ta, tb in parts if len(rings[0])]
    if not parts:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32)
    a = np.concatenate([r[0] for r, _, _ in parts])
    b = np.concatenate([r[1] for r, _, _ in parts])
    ta = np.concatenate([np.full(len(r[0]), t) for r, t, _ in parts])
    tb = np.concatenate([np.full(len(r[0]), t) for r, _, t in parts])
    return ring_bands(a, b, ta, tb)


def tubes_and_surfaces(slices: list, names: list, hidden, colors, t_center_us: int,
                       cache: SurfaceCache | None = None) -> tuple[list, list]:
    """The space-time view's tubes (``[(name, rgb, [polyline (M, 3)])]``: every contour at its slice time) and
    surfaces (``[(name, rgb, vertices (V, 3) float32, triangles (F, 3) uint32)]``) of the objects not
    ``hidden``, from the slices ``[(t_us, [(name, in_view, contours, field)])]`` in time order; ``colors[k]``
    is object ``k``'s colour, t is in ms from ``t_center_us``; joined slices come from (and go to) ``cache``."""
    cache = cache if cache is not None else SurfaceCache()
    tubes, surfaces = [], []
    t_ms = [(int(t) - int(t_center_us)) * 1e-3 for t, _ in slices]
    for k, name in enumerate(names):
        if name in hidden:
            continue
        per_slice = [(value, o[2] if o[1] else []) for _, value in slices for o in value if o[0] == name]
        polys = []
        for t, (_, contours) in zip(t_ms, per_slice):
            for c in contours:
                poly = np.empty((len(c), 3), np.float32)
                poly[:, :2] = c
                poly[:, 2] = t
                polys.append(poly)
        if not polys:
            continue
        tubes.append((name, colors[k], polys))
        parts = [(cache.joined(va, vb, name, ca, cb), ta, tb)
                 for (va, ca), (vb, cb), ta, tb in zip(per_slice[:-1], per_slice[1:], t_ms[:-1], t_ms[1:])]
        v, f = surface_of(parts)
        if len(f):
            surfaces.append((name, colors[k], v, f))
    return tubes, surfaces
