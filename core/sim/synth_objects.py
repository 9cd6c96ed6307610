"""The objects of a synthetic scene: built-in shapes or meshes, resting on the table in non-overlapping
poses, and the pose error injected into the manifest."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from evpose.core.data.geometry import make_T
from evpose.core.data.objects import ObjectModel, box_model, cylinder_model

#: Where the objects stand, in the robot base frame (metres), as in E-POSE's scenes.
TABLE_CENTRE_BASE = np.array([0.0, -0.75, 0.0])
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf")


def _builtin(name: str) -> ObjectModel | None:
    if name.startswith("box"):
        return box_model(name, (0.09, 0.06, 0.15))
    if name.startswith("flatbox"):
        return box_model(name, (0.15, 0.10, 0.045))
    if name.startswith("cylinder"):
        return cylinder_model(name, radius_m=0.035, height_m=0.12)
    return None


BUILTIN_OBJECTS = ("box", "cylinder", "flatbox")


def load_objects(names, mesh_dir=None) -> list[ObjectModel]:
    """Built-in procedural objects (``box``, ``cylinder``, ``flatbox`` and numbered variants such as
    ``box2``) or meshes ``<mesh_dir>/<name>.<obj|stl|ply|...>`` in metres."""
    models = []
    for i, name in enumerate(names):
        if mesh_dir is not None:
            cands = [Path(mesh_dir) / f"{name}{s}" for s in MESH_SUFFIXES]
            found = [p for p in cands if p.is_file()]
            if not found:
                raise FileNotFoundError(f"{mesh_dir}: no mesh named {name} ({'/'.join(MESH_SUFFIXES)})")
            m = ObjectModel.from_file(found[0], name=name)
        else:
            m = _builtin(name)
            if m is None:
                raise ValueError(f"objects: unknown built-in object {name!r} (built-ins: {', '.join(BUILTIN_OBJECTS)};"
                                 " or give --mesh-dir)")
        m.class_id = i + 1
        models.append(m)
    return models


def _resting_rotation(model: ObjectModel, yaw_rad: float) -> np.ndarray:
    """Rotation that lays the object on its largest bounding-box face, then turns it by ``yaw``."""
    lo, hi = model.bbox_min_max
    up_axis = int(np.argmin(hi - lo))
    align = {0: Rotation.from_euler("y", -90, degrees=True), 1: Rotation.from_euler("x", 90, degrees=True),
             2: Rotation.identity()}[up_axis]
    return (Rotation.from_euler("z", yaw_rad) * align).as_matrix()


def place_objects(models: list[ObjectModel], rng: np.random.Generator) -> list[np.ndarray]:
    """Non-overlapping resting poses ``T_base_obj`` on the table (z = 0) around the table centre."""
    poses, discs = [], []
    for m in models:
        R = _resting_rotation(m, rng.uniform(-np.pi, np.pi))
        v = m.vertices_m @ R.T
        lo, hi = v.min(0), v.max(0)
        radius = 0.5 * float(np.hypot(*(hi - lo)[:2]))
        for attempt in range(2000):
            spread = 0.02 + 0.0002 * attempt
            xy = TABLE_CENTRE_BASE[:2] + rng.normal(scale=spread + 0.04 * (len(models) > 1), size=2)
            if all(np.hypot(*(xy - c)) >= radius + r + 0.01 for c, r in discs):
                break
        centre_xy = (lo[:2] + hi[:2]) / 2
        t = np.array([xy[0] - centre_xy[0], xy[1] - centre_xy[1], -lo[2]])
        poses.append(make_T(R, t))
        discs.append((xy, radius))
    return poses


def inject_pose_error(T_base_obj: np.ndarray, error_mm: float, error_deg: float, rng) -> np.ndarray:
    """``dT_base`` with a translation of ``error_mm`` and a rotation of ``error_deg`` about the
    object's origin, in random directions."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    R_err = Rotation.from_rotvec(axis * math.radians(error_deg)).as_matrix()
    o = T_base_obj[:3, 3]
    # rotate about the object origin, then translate: T' = dT @ T with dT = Trans(o + e) Rot Trans(-o)
    return make_T(R_err, o + direction * error_mm * 1e-3 - R_err @ o)
