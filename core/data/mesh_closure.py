"""Is a mesh a closed, consistently oriented surface? Then back faces never show (exact culling).

For a closed oriented surface that bounds its volume (every directed edge ``a -> b`` used as often
as its reverse ``b -> a``; each connected piece encloses a positive volume with outward normals),
a ray from a point outside the volume enters it before it can leave it: its first hit is a
*front* face (normal towards the ray's origin). The rasteriser therefore skips back-facing
triangles of such a mesh when the camera is certainly outside it (every vertex beyond the near
plane, so the camera is outside the convex hull and no triangle is clipped) without changing any
pixel of the z-buffer (nearest hit) or of the amodal mask (any hit). It halves the triangles
that reach the pixel tests of a closed mesh.

Closedness is decided on topology after merging vertices with identical coordinates (OBJ files
split vertices along texture seams) and ignoring faces that repeat a vertex (they cover
nothing). Meshes with holes, open boundaries, inconsistent winding or a piece of negative volume
(inside-out) are never culled. Of the E-POSE YCB meshes all 13 pass (the STL meshes have one
edge shared by four faces, still balanced).

Sign convention: a triangle ``(a, b, c)`` with vertices ``(x, y) = (X/Z, Y/Z)`` in the
normalised image plane (``Z > 0``) has the signed area ``(x_b - x_a)(y_c - y_a) - (y_b - y_a)(x_c - x_a)
= a . ((b - a) x (c - a)) / (Z_a Z_b Z_c)``: negative exactly when the face's normal points towards
the camera. So for an outward-oriented mesh (:func:`cull_sign` ``+1``) faces with a positive area
are back faces; for an inward-oriented one (``-1``) those with a negative area.
"""
from __future__ import annotations

import threading
import weakref

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = ["cull_sign", "cached_cull_sign"]

_CACHE: dict[int, tuple[weakref.ref, int]] = {}
_LOCK = threading.Lock()


def cached_cull_sign(vertices_m: np.ndarray, faces: np.ndarray) -> int:
    """:func:`cull_sign`, remembered per read-only face array while it lives (shared by every
    rasteriser; 20-70 ms for a 65 k-face YCB mesh, so :class:`~evpose.core.data.scene.Scene` computes
    it when it loads a model, not the first frame). Topology and coincident vertices do not change
    with a rigid pose, so any posed copy of the vertices gives the same answer. Writable face arrays
    (their content may change) get 0: never culled."""
    if faces.flags.writeable:
        return 0
    key = id(faces)
    with _LOCK:
        hit = _CACHE.get(key)
    if hit is not None and hit[0]() is faces:
        return hit[1]
    sign = cull_sign(vertices_m, faces)
    try:
        ref = weakref.ref(faces)
    except TypeError:                               # not weak-referenceable: do not cache
        return sign
    with _LOCK:
        for k in [k for k, (r, _) in _CACHE.items() if r() is None]:
            del _CACHE[k]
        _CACHE[key] = (ref, sign)
    return sign


def cull_sign(vertices_m: np.ndarray, faces: np.ndarray) -> int:
    """Back-face culling sign of a mesh: ``+1`` closed with outward normals, ``-1`` closed with
    inward normals (all pieces), ``0`` not provably closed (never cull).

    Parameters
    ----------
    vertices_m : (V, 3) float
        Vertices in any rigid frame (metres).
    faces : (F, 3) int
        Vertex indices.

    Returns
    -------
    int
        ``s`` such that a face whose normalised-plane signed area ``A`` has ``s * A > 0`` faces away
        from a camera outside the mesh.
    """
    V = np.asarray(vertices_m, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    if len(F) == 0 or len(V) == 0:
        return 0
    _, merged = np.unique(V, axis=0, return_inverse=True)
    G = merged.ravel()[F]
    G = G[(G[:, 0] != G[:, 1]) & (G[:, 1] != G[:, 2]) & (G[:, 0] != G[:, 2])]
    if not len(G):
        return 0
    n = int(G.max()) + 1
    head = np.concatenate([G[:, 0], G[:, 1], G[:, 2]])
    tail = np.concatenate([G[:, 1], G[:, 2], G[:, 0]])
    fwd = np.sort(head * n + tail)
    rev = np.sort(tail * n + head)
    if not np.array_equal(fwd, rev):           # an edge without a matching reverse use
        return 0
    # signed volume of every connected piece (divergence theorem; the origin cancels out)
    n_comp, comp = connected_components(coo_matrix((np.ones(len(head)), (head, tail)), shape=(n, n)),
                                        directed=False)
    Vm = np.zeros((n, 3))
    Vm[merged.ravel()] = V
    P = Vm[G]
    det = np.einsum("ij,ij->i", P[:, 0], np.cross(P[:, 1], P[:, 2]))
    piece = comp[G[:, 0]]
    vol = np.bincount(piece, weights=det, minlength=n_comp)[np.unique(piece)]
    if (vol > 0).all():
        return 1
    if (vol < 0).all():
        return -1
    return 0
