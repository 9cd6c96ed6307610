"""BOP object models: ``models/obj_OOOOOO.ply`` and ``models/models_info.json``.

PLY as ``bop_toolkit_lib.inout.load_ply`` reads it: ``format binary_little_endian 1.0``, one ``vertex``
element with ``float`` x, y, z (mm) and ``float`` nx, ny, nz (unit vertex normals), one ``face`` element
with ``property list uchar int vertex_indices`` (triangles). The toolkit's renderers shade with the
normals (its default Phong rendering fails without them). Normals are the angle-weighted sum of the unit
normals of the faces around a vertex (as BOP computed its models' normals with MeshLab); a vertex where that sum
vanishes (only degenerate faces, opposite faces of a thin fin) or that no face uses takes its neighbours' or the
nearest vertex's normal: never zero (two published YCB models each had one such vertex).

Model origin: the origin of the scene's mesh, unchanged (not moved to the centre of the 3D bounding box,
which BOP's own datasets use): the poses in ``scene_gt.json`` refer to it; ``min_x/y/z`` and
``size_x/y/z`` of ``models_info.json`` say where the box lies.
"""
from __future__ import annotations

import numpy as np

__all__ = ["vertex_normals", "ply_bytes", "models_info_entry"]


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals ``(V, 3)``: for every face corner, the face's unit normal times the corner's
    angle (radians), summed per vertex and normalised; where the sum vanishes, :func:`_fill_zero_normals`."""
    V = np.asarray(vertices, np.float64)
    F = np.asarray(faces, np.int64)
    out = np.zeros_like(V)
    if len(F) == 0:
        return out
    p = V[F]                                                   # (F, 3 corners, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    ln = np.linalg.norm(n, axis=1)
    ok = ln > 0
    n[ok] /= ln[ok, None]
    for c in range(3):
        a = p[:, (c + 1) % 3] - p[:, c]
        b = p[:, (c + 2) % 3] - p[:, c]
        cosang = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1),
                                                            1e-300)
        ang = np.arccos(np.clip(cosang, -1.0, 1.0))
        np.add.at(out, F[:, c], n * ang[:, None])
    ln = np.linalg.norm(out, axis=1)
    ok = ln > 1e-12
    out[ok] /= ln[ok, None]
    if not ok.all():
        _fill_zero_normals(V, F, out, ok)
    return out


def _fill_zero_normals(V: np.ndarray, F: np.ndarray, out: np.ndarray, ok: np.ndarray) -> None:
    """Give every vertex whose angle-weighted normal vanished one (in place): the mean of its face-neighbours'
    normals (repeated while that reaches more of them), else the normal of the nearest vertex that has one, else the
    direction from the model's centre (a renderer shades by these; a zero normal renders black or NaN)."""
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    edges = np.concatenate([edges, edges[:, ::-1]])
    for _ in range(8):
        missing = ~ok
        if not missing.any():
            return
        use = missing[edges[:, 0]] & ok[edges[:, 1]]
        if not use.any():
            break
        acc = np.zeros_like(out)
        np.add.at(acc, edges[use, 0], out[edges[use, 1]])
        ln = np.linalg.norm(acc, axis=1)
        got = missing & (ln > 1e-12)
        out[got] = acc[got] / ln[got, None]
        ok = ok | got
    missing = ~ok
    if missing.any() and ok.any():
        from scipy.spatial import cKDTree

        _, j = cKDTree(V[ok]).query(V[missing])
        out[missing] = out[ok][j]
        return
    if missing.any():
        d = V[missing] - V.mean(axis=0)
        ln = np.linalg.norm(d, axis=1)
        d[ln <= 1e-12] = (0.0, 0.0, 1.0)
        ln[ln <= 1e-12] = 1.0
        out[missing] = d / ln[:, None]


def ply_bytes(vertices_mm: np.ndarray, faces: np.ndarray, normals: np.ndarray, comment: str = "") -> bytes:
    """Binary little-endian PLY of a triangle mesh with vertex normals (see the module docstring)."""
    V = np.asarray(vertices_mm, np.float64)
    F = np.asarray(faces, np.int64)
    if F.ndim != 2 or (len(F) and F.shape[1] != 3):
        raise ValueError(f"ply_bytes: expected (F, 3) triangles, got shape {F.shape}")
    head = ["ply", "format binary_little_endian 1.0"]
    # comments are ASCII header lines: other characters of an object's name are escaped (\xe9), controls dropped
    safe = "".join(c for c in comment if c == "\n" or c.isprintable()).encode("ascii", "backslashreplace").decode()
    head += [f"comment {line}" for line in safe.splitlines() if line]
    head += [f"element vertex {len(V)}"] + [f"property float {a}" for a in ("x", "y", "z", "nx", "ny", "nz")]
    head += [f"element face {len(F)}", "property list uchar int vertex_indices", "end_header"]
    vert = np.empty(len(V), dtype=[("p", "<f4", 6)])
    vert["p"][:, :3] = V
    vert["p"][:, 3:] = normals
    face = np.empty(len(F), dtype=[("n", "u1"), ("i", "<i4", 3)])
    face["n"] = 3
    face["i"] = F
    return ("\n".join(head) + "\n").encode("ascii") + vert.tobytes() + face.tobytes()


def models_info_entry(model) -> dict:
    """``models_info.json`` entry of an object model (metres in, mm out): ``diameter`` (largest distance
    between two vertices), ``min_x/y/z`` and ``size_x/y/z`` of the axis-aligned box, and for a solid of revolution
    ``symmetries_continuous`` (its axis, object frame, through ``offset`` in mm): the fit holds that spin at its start
    since the events cannot see it (issue 23.6), so a label is right only up to it."""
    lo, hi = model.bbox_min_max
    entry = {"diameter": model.diameter_m * 1000.0,
             "min_x": float(lo[0] * 1000.0), "min_y": float(lo[1] * 1000.0), "min_z": float(lo[2] * 1000.0),
             "size_x": float((hi[0] - lo[0]) * 1000.0), "size_y": float((hi[1] - lo[1]) * 1000.0),
             "size_z": float((hi[2] - lo[2]) * 1000.0)}
    kind, axis = model.symmetry
    if kind == "radial":        # the BOP toolkit's MSSD/MSPD count a spin about this axis as no error
        entry["symmetries_continuous"] = [{"axis": [round(float(a), 9) for a in axis],
                                           "offset": [round(float(c) * 1000.0, 6) for c in model.symmetry_centre_m]}]
    return entry
