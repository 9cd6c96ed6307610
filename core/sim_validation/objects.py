"""The validation scenes' objects: E-POSE's YCB meshes (or procedural stand-ins of their size when the meshes are
absent), resting on a table in poses drawn from their convex hull's stable faces, and distractors (clutter)
that the manifest does not list."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.transform import Rotation

from evpose.core.data.objects import ObjectModel
from evpose.core.sim_validation.config import ASSETS

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb")
#: Stand-ins (box extents or cylinder radius/height, metres) for the YCB objects of E-POSE and the built-ins.
STAND_INS = {
    "sugar_box": ("box", (0.038, 0.089, 0.175)), "cracker_box": ("box", (0.06, 0.158, 0.21)),
    "mustard_bottle": ("box", (0.058, 0.095, 0.19)), "bleach_cleanser": ("box", (0.065, 0.098, 0.25)),
    "potted_meat_can": ("box", (0.05, 0.097, 0.082)), "drill": ("box", (0.05, 0.15, 0.185)),
    "nine_hole_peg": ("box", (0.16, 0.16, 0.04)), "timer": ("cylinder", (0.045, 0.05)),
    "wood_block": ("box", (0.085, 0.085, 0.2)), "rubiks_cube": ("box", (0.057, 0.057, 0.057)),
    "hammer": ("box", (0.03, 0.13, 0.33)), "scissors": ("box", (0.2, 0.09, 0.015)),
    "wrench": ("box", (0.2, 0.05, 0.015)), "box": ("box", (0.09, 0.06, 0.15)),
    "flatbox": ("box", (0.15, 0.10, 0.045)), "cylinder": ("cylinder", (0.035, 0.12)),
}


def _procedural(name: str, kind: str, size) -> ObjectModel:
    import trimesh

    mesh = (trimesh.creation.box(extents=size) if kind == "box"
            else trimesh.creation.cylinder(radius=size[0], height=size[1], sections=64))
    v, f = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, 0.02)   # small triangles for the labeller
    return ObjectModel(name, v, f, source=f"procedural {kind} {tuple(size)}")


def load_object(name: str, mesh_dir: str | None) -> ObjectModel:
    """``<mesh_dir>/<name>.*`` when ``mesh_dir`` is given; else the E-POSE mesh of that name when the assets
    exist; else a procedural stand-in (:data:`STAND_INS`, the base name before any digits)."""
    folders = [Path(mesh_dir)] if mesh_dir is not None else [ASSETS / "models"]
    for folder in folders:
        found = [folder / f"{name}{s}" for s in MESH_SUFFIXES if (folder / f"{name}{s}").is_file()]
        if found:
            return ObjectModel.from_file(found[0], name=name)
    if mesh_dir is not None:
        raise FileNotFoundError(f"{mesh_dir}: no mesh named {name} ({'/'.join(MESH_SUFFIXES)})")
    key = name.rstrip("0123456789")
    if key not in STAND_INS:
        raise ValueError(f"objects: {name!r} is neither a mesh in {folders[0]} nor a stand-in "
                         f"({', '.join(sorted(STAND_INS))}); give --mesh-dir")
    return _procedural(name, *STAND_INS[key])


def resting_rotations(vertices: np.ndarray, max_poses: int = 6) -> list[tuple[np.ndarray, float]]:
    """Rotations ``R`` (object -> table frame, z up) that rest the object on a stable face of its convex hull,
    with weights (the supporting polygon's area). A face is stable when the hull's centroid projects inside it."""
    hull = ConvexHull(vertices)
    pts = vertices[hull.vertices]
    com = _hull_centroid(vertices, hull)
    tri = vertices[hull.simplices]
    areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    normals, totals = [], []                      # hull facets: faces grouped by normal (3 degrees)
    left = np.ones(len(areas), bool)
    while left.any() and len(normals) < 200:
        k = int(np.argmax(np.where(left, areas, -1.0)))
        group = left & (hull.equations[:, :3] @ hull.equations[k, :3] > np.cos(np.radians(3)))
        normals.append(hull.equations[k, :3])
        totals.append(float(areas[group].sum()))
        left &= ~group
    out = []
    for j in np.argsort(-np.asarray(totals)):
        n = normals[j]
        d = -float(np.max(pts @ n))
        support = pts[np.abs(pts @ n + d) < 1e-3]
        R = Rotation.align_vectors([[0.0, 0.0, -1.0]], [n])[0].as_matrix()
        area = _inside_area((support @ R.T)[:, :2], (com @ R.T)[:2])
        if area > 0:
            out.append((R, area))
        if len(out) >= max_poses:
            break
    return out or [(np.eye(3), 1.0)]


def _hull_centroid(vertices: np.ndarray, hull: ConvexHull) -> np.ndarray:
    c0 = vertices[hull.vertices].mean(axis=0)
    tet = vertices[hull.simplices] - c0
    vol = np.abs(np.einsum("ij,ij->i", tet[:, 0], np.cross(tet[:, 1], tet[:, 2]))) / 6
    cent = c0 + tet.sum(axis=1) / 4
    return (cent * vol[:, None]).sum(axis=0) / max(vol.sum(), 1e-18)


def _inside_area(poly: np.ndarray, c: np.ndarray) -> float:
    """Area of the convex hull of ``poly`` when ``c`` lies inside it (with a 2 mm margin), else 0."""
    if len(poly) < 3:
        return 0.0
    try:
        h = ConvexHull(poly)
    except QhullError:
        return 0.0
    return float(h.volume) if np.all(h.equations[:, :2] @ c + h.equations[:, 2] < -0.002) else 0.0


def place(models, centre: np.ndarray, table_z: float, rng: np.random.Generator, taken=None,
          ring=(0.0, 0.16)) -> tuple[list[np.ndarray], list]:
    """Resting poses ``T_base_obj`` on the table at ``table_z`` within ``ring`` (min, max metres) of ``centre``,
    their footprints not overlapping each other nor the discs in ``taken`` (updated and returned)."""
    taken = [] if taken is None else taken
    poses = []
    for m in models:
        rests = resting_rotations(np.asarray(m.vertices_m))
        w = np.array([a for _, a in rests])
        yaw = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_matrix()
        R = yaw @ rests[rng.choice(len(rests), p=w / w.sum())][0]
        v = m.vertices_m @ R.T
        lo, hi = v.min(axis=0), v.max(axis=0)
        radius = 0.5 * float(np.hypot(*(hi - lo)[:2]))
        for attempt in range(4000):
            grow = 1.0 + attempt / 400
            r = rng.uniform(ring[0], ring[1] * grow)
            a = rng.uniform(-np.pi, np.pi)
            xy = centre[:2] + r * np.array([np.cos(a), np.sin(a)])
            if all(np.hypot(*(xy - c)) >= radius + rr + 0.008 for c, rr in taken):
                break
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = [xy[0] - (lo[0] + hi[0]) / 2, xy[1] - (lo[1] + hi[1]) / 2, table_z - lo[2]]
        poses.append(T)
        taken.append((xy, radius))
    return poses, taken


def clutter_models(n: int, exclude, rng: np.random.Generator) -> list[ObjectModel]:
    """``n`` distractors: E-POSE meshes not among ``exclude`` (when the assets exist) and procedural shapes."""
    import trimesh

    spare = sorted(p for p in (ASSETS / "models").glob("*") if p.suffix in MESH_SUFFIXES
                   and p.stem not in set(exclude)) if (ASSETS / "models").is_dir() else []
    out = []
    for i in range(n):
        if spare and rng.uniform() < 0.4:
            out.append(ObjectModel.from_file(spare[rng.integers(len(spare))], name=f"clutter{i}"))
            continue
        kind = rng.choice(["box", "cylinder", "sphere", "capsule"])
        s = rng.uniform(0.03, 0.11, 3)
        mesh = {"box": lambda: trimesh.creation.box(extents=s),
                "cylinder": lambda: trimesh.creation.cylinder(radius=s[0] / 2, height=s[1], sections=40),
                "sphere": lambda: trimesh.creation.icosphere(subdivisions=3, radius=s[0] / 2),
                "capsule": lambda: trimesh.creation.capsule(height=s[1], radius=s[0] / 3)}[kind]()
        out.append(ObjectModel(f"clutter{i}", np.asarray(mesh.vertices), np.asarray(mesh.faces),
                               source=f"clutter {kind}"))
    return out
