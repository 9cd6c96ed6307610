"""The contour samples of one object in one view, compiled: the hot loop of the edge fits.

:func:`evpose.core.align.contours._edge_samples` picks a mesh's contour generators seen from the camera
(:meth:`~evpose.core.align.mesh_edges.MeshEdges.contour_edges`), keeps those in front of the camera and samples
them every ``spacing_px`` projected pixels. In numpy that is ~15 array passes over all edges and samples, 2.7 ms
per object and window on a 25 k-face YCB mesh: 8.4 s of a 38 s joint fit on a 5-object scene
(``bench/accuracy_validation.py`` scene v20). :func:`edge_samples` does the same in two passes over the edges
(count, fill) and returns the same arrays in the same order; ``tests/core/test_edge_samples_kernel.py`` holds
it to the numpy path. The numpy path stays the reference and the fallback without numba.
"""
from __future__ import annotations

import math

import numpy as np

try:
    from numba import njit
    HAVE_NUMBA = True
except ImportError:                                  # pragma: no cover - numba is a dependency
    HAVE_NUMBA = False

__all__ = ["HAVE_NUMBA", "edge_samples"]

#: At most this many samples per edge (a degenerate projection must not allocate without bound).
MAX_SAMPLES_PER_EDGE = 4096

if HAVE_NUMBA:
    @njit(cache=True, nogil=True)
    def _kernel(V, edges, f1, f2, normals, v0, R, t, cam_obj, fx, fy, cx, cy, near_m, spacing_px, max_n):
        F = normals.shape[0]
        facing = np.empty(F, np.bool_)
        for f in range(F):
            d = 0.0
            for a in range(3):
                d += normals[f, a] * (cam_obj[a] - v0[f, a])
            facing[f] = d > 0.0
        E = edges.shape[0]
        counts = np.zeros(E, np.int64)
        pa = np.empty((E, 2))
        pb = np.empty((E, 2))
        total = 0
        for e in range(E):
            a1 = facing[f1[e]]
            if f2[e] >= 0:
                if a1 == facing[f2[e]]:
                    continue
            elif not a1:                                   # open boundary edge: its face must face the camera
                continue
            ia, ib = edges[e, 0], edges[e, 1]
            za = R[2, 0] * V[ia, 0] + R[2, 1] * V[ia, 1] + R[2, 2] * V[ia, 2] + t[2]
            zb = R[2, 0] * V[ib, 0] + R[2, 1] * V[ib, 1] + R[2, 2] * V[ib, 2] + t[2]
            if not (za > near_m and zb > near_m):
                continue
            xa = R[0, 0] * V[ia, 0] + R[0, 1] * V[ia, 1] + R[0, 2] * V[ia, 2] + t[0]
            ya = R[1, 0] * V[ia, 0] + R[1, 1] * V[ia, 1] + R[1, 2] * V[ia, 2] + t[1]
            xb = R[0, 0] * V[ib, 0] + R[0, 1] * V[ib, 1] + R[0, 2] * V[ib, 2] + t[0]
            yb = R[1, 0] * V[ib, 0] + R[1, 1] * V[ib, 1] + R[1, 2] * V[ib, 2] + t[1]
            za_ = max(za, 1e-6)
            zb_ = max(zb, 1e-6)
            pa[e, 0] = fx * xa / za_ + cx
            pa[e, 1] = fy * ya / za_ + cy
            pb[e, 0] = fx * xb / zb_ + cx
            pb[e, 1] = fy * yb / zb_ + cy
            L = math.hypot(pb[e, 0] - pa[e, 0], pb[e, 1] - pa[e, 1])
            n = max(1, int(math.ceil(L / spacing_px)))
            n = min(n, max_n)
            counts[e] = n
            total += n
        P = np.empty((total, 3))
        Pc = np.empty((total, 3))
        normal = np.empty((total, 2))
        k = 0
        for e in range(E):
            n = counts[e]
            if n == 0:
                continue
            ia, ib = edges[e, 0], edges[e, 1]
            dx, dy = pb[e, 0] - pa[e, 0], pb[e, 1] - pa[e, 1]
            L = max(math.hypot(dx, dy), 1e-12)
            nx, ny = dy / L, -dx / L
            for j in range(n):
                fr = (j + 0.5) / n
                for a in range(3):
                    P[k, a] = V[ia, a] + fr * (V[ib, a] - V[ia, a])
                for a in range(3):
                    Pc[k, a] = R[a, 0] * P[k, 0] + R[a, 1] * P[k, 1] + R[a, 2] * P[k, 2] + t[a]
                normal[k, 0] = nx
                normal[k, 1] = ny
                k += 1
        return P, Pc, normal


def edge_samples(me, T: np.ndarray, cam_obj: np.ndarray, K: np.ndarray, near_m: float, spacing_px: float):
    """Samples every ``spacing_px`` along the contour generators of mesh edges ``me``
    (:class:`~evpose.core.align.mesh_edges.MeshEdges`) in front of the camera (``T``: camera <- object,
    ``cam_obj`` the camera centre in the object frame): ``(P object frame, P camera frame, unit 2D normal)`` or
    None, as :func:`evpose.core.align.contours._edge_samples`. Needs numba (:data:`HAVE_NUMBA`)."""
    T = np.asarray(T, np.float64)
    P, Pc, normal = _kernel(me.V, me.edges, me.f1, me.f2, me.normals, me.v0, np.ascontiguousarray(T[:3, :3]),
                            np.ascontiguousarray(T[:3, 3]), np.asarray(cam_obj, np.float64), float(K[0, 0]),
                            float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), float(near_m), float(spacing_px),
                            MAX_SAMPLES_PER_EDGE)
    return None if len(P) == 0 else (P, Pc, normal)
