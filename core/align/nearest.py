"""Nearest point within a radius, for many query points against one small 2D point set.

The edge stage asks, per event window and sub-window, which projected contour sample (a few thousand, re-projected
at every trial pose) is nearest to each event within the band of the kernel (a few pixels). A k-d tree per call
spends most of its time building the tree it then queries once (scipy's ``cKDTree``: 5.8 ms build + 6.4 ms query
per call on a 5-object scene, 8.6 k samples and 3.1 k events; 29 of the joint fit's 52 s of CPU). A uniform grid
with cells at least the radius wide needs one counting sort and a 3 x 3 cell look per query, compiled by numba.

:func:`nearest_within` returns what ``cKDTree(points).query(queries, distance_upper_bound=radius)`` returns
(distance, index; ``inf`` and ``len(points)`` where none is within ``radius``), and falls back to that call when
numba cannot be imported. Points are pixels (any finite values); queries must be finite.
"""
from __future__ import annotations

import math

import numpy as np

try:
    from numba import njit
    HAVE_NUMBA = True
except ImportError:                                  # pragma: no cover - numba is a dependency
    HAVE_NUMBA = False

__all__ = ["HAVE_NUMBA", "nearest_within"]

#: The grid has at most this many cells per point and query (wider cells beyond), so a far-flung point set or a
#: tiny radius never allocates in proportion to the image area.
MAX_CELLS_PER_ITEM = 4

if HAVE_NUMBA:
    @njit(cache=True, nogil=True)
    def _grid_nearest(P, Q, radius, x0, y0, cell, nx, ny, dist, idx):
        M = P.shape[0]
        cell_of = np.full(M, -1, np.int64)
        counts = np.zeros(nx * ny + 1, np.int64)
        for k in range(M):
            fx = (P[k, 0] - x0) / cell
            fy = (P[k, 1] - y0) / cell
            if fx >= 0.0 and fy >= 0.0 and fx < nx and fy < ny:       # also False for NaN
                c = int(fy) * nx + int(fx)
                cell_of[k] = c
                counts[c + 1] += 1
        for c in range(nx * ny):
            counts[c + 1] += counts[c]                                 # start of each cell
        fill = counts[:-1].copy()
        order = np.empty(counts[nx * ny], np.int64)
        for k in range(M):                                             # stable: ascending index within a cell
            c = cell_of[k]
            if c >= 0:
                order[fill[c]] = k
                fill[c] += 1
        r2 = radius * radius
        for q in range(Q.shape[0]):
            qx, qy = Q[q, 0], Q[q, 1]
            cx = int(math.floor((qx - x0) / cell))
            cy = int(math.floor((qy - y0) / cell))
            best = r2
            bi = M
            for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
                for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
                    c = gy * nx + gx
                    for o in range(counts[c], counts[c + 1]):
                        k = order[o]
                        dx = P[k, 0] - qx
                        dy = P[k, 1] - qy
                        d2 = dx * dx + dy * dy
                        if d2 < best or (d2 == best and bi < M and k < bi):
                            best = d2
                            bi = k
            if bi < M:
                dist[q] = math.sqrt(best)
                idx[q] = bi
            else:
                dist[q] = np.inf
                idx[q] = M


def nearest_within(points: np.ndarray, queries: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """For each query (N, 2) the nearest of ``points`` (M, 2) closer than ``radius``: ``(distance, index)``, with
    ``inf`` and ``M`` where none is (scipy's ``cKDTree.query(..., distance_upper_bound=radius)`` convention; of
    points at equal distance the lower index)."""
    P = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
    Q = np.ascontiguousarray(queries, dtype=np.float64).reshape(-1, 2)
    M, N = len(P), len(Q)
    dist = np.full(N, np.inf)
    idx = np.full(N, M, np.intp)
    if M == 0 or N == 0 or not radius > 0:
        return dist, idx
    if not HAVE_NUMBA:                                             # pragma: no cover - numba is a dependency
        from scipy.spatial import cKDTree

        return cKDTree(P).query(Q, distance_upper_bound=radius)
    # the grid spans the queries plus the radius: points outside it are farther than the radius from every query
    x0, y0 = float(Q[:, 0].min() - radius), float(Q[:, 1].min() - radius)
    w, h = float(Q[:, 0].max() + radius) - x0, float(Q[:, 1].max() + radius) - y0
    cell = float(radius)
    limit = MAX_CELLS_PER_ITEM * (M + N) + 64
    if (w / cell + 1.0) * (h / cell + 1.0) > limit:                # wider cells (still >= radius: 3 x 3 suffice)
        cell = max(cell, math.sqrt(w * h / limit) * 1.01 + 1e-9)
    nx, ny = int(w / cell) + 1, int(h / cell) + 1
    _grid_nearest(P, Q, float(radius), x0, y0, cell, nx, ny, dist, idx)
    return dist, idx
