"""The contour generators of a mesh: the edges where its silhouette can be, seen from a point.

The edge refinement fits events to the object's edges taken from the mesh itself, not from a
rasterised mask: a rasterised boundary is biased half a pixel inwards, which at half DAVIS
resolution is a ~2.5 % scale, i.e. ~10 mm of depth. An edge is a contour generator when one of
its faces faces the camera and the other does not (open boundary edges count when their face
does); the topology is built once per mesh and the test per view is one dot product per face.
"""
from __future__ import annotations

import numpy as np

__all__ = ["MeshEdges"]


class MeshEdges:
    """Edge topology of a mesh: unique edges, their (up to two) faces, face normals."""

    def __init__(self, model):
        V = np.asarray(model.vertices_m, dtype=np.float64)
        F = np.asarray(model.faces, dtype=np.int64)
        e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        fid = np.tile(np.arange(len(F)), 3)
        es = np.sort(e, axis=1)
        key = es[:, 0] * len(V) + es[:, 1]
        order = np.argsort(key, kind="stable")
        ks = key[order]
        _, start, counts = np.unique(ks, return_index=True, return_counts=True)
        self.edges = es[order[start]]
        self.f1 = fid[order[start]]
        nxt = np.minimum(start + 1, len(order) - 1)
        self.f2 = np.where(counts >= 2, fid[order[nxt]], -1)
        self.V = V
        self.normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        self.v0 = V[F[:, 0]]
        lo, hi = V.min(0), V.max(0)
        self.centre = 0.5 * (lo + hi)
        self.radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)

    def contour_edges(self, cam_pos_obj: np.ndarray) -> np.ndarray:
        """Indices of contour-generator and open boundary edges seen from ``cam_pos_obj``."""
        facing = np.einsum("ij,ij->i", self.normals, cam_pos_obj - self.v0) > 0
        f1 = facing[self.f1]
        f2 = np.where(self.f2 >= 0, facing[np.maximum(self.f2, 0)], ~f1)
        boundary = self.f2 < 0
        return np.flatnonzero((f1 != f2) & (~boundary | f1))

