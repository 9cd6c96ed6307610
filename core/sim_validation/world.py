"""Everything a validation scene holds before anything moves: camera, objects and their true poses, clutter,
a textured table in a room, materials (:mod:`~evpose.core.sim_validation.textures`) and lights, drawn from
one random generator in a fixed order."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from evpose.core.data.camera import CameraModel
from evpose.core.data.objects import ObjectModel
from evpose.core.sim_validation.config import ASSETS, ValidationConfig
from evpose.core.sim_validation.objects import clutter_models, load_object, place
from evpose.core.sim_validation.textures import material, permutation

#: Table top centre in the robot base frame (metres): E-POSE's objects stand about 0.8 m in front of the base.
TABLE_CENTRE = np.array([0.02, -0.78, -0.015])


@dataclass
class Surface:
    """One mesh of the ray-casting scene, in the base frame, with its shading normals and material; texture
    coordinates are points in its own frame ``T_local_base @ p_base``."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    material: np.ndarray
    T_local_base: np.ndarray


@dataclass
class World:
    camera: CameraModel
    models: list[ObjectModel]
    T_true: list[np.ndarray]
    clutter: list[tuple[str, np.ndarray]]     # distractor names and poses (not in the manifest)
    surfaces: list[Surface]
    light: np.ndarray                         # see :func:`lighting`
    target: np.ndarray                        # where the camera looks, base frame
    perm: np.ndarray
    table_z: float
    table_index: int                          # index of the table top in ``surfaces``

    @property
    def obstacles(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Bounding boxes (base frame) of the objects and distractors."""
        return [(s.vertices.min(axis=0), s.vertices.max(axis=0)) for s in self.surfaces[:self.table_index]]


def scene_camera(cfg: ValidationConfig) -> CameraModel:
    if cfg.camera:
        return CameraModel.from_dict(cfg.camera, source="validation camera")
    path = ASSETS / "camera_davis346.json"
    return CameraModel.from_json(path) if path.is_file() else CameraModel.davis346()


def lighting(rng: np.random.Generator, target: np.ndarray) -> np.ndarray:
    """``[point light xyz, its power, fill direction xyz, fill, ambient]``: a lamp 0.9-1.4 m above the table
    scaled to give 0.85 on a white surface facing it at the target, a weak directional fill, ambient."""
    pos = target + np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(0.9, 1.4)])
    power = 0.85 * float(np.sum((pos - target) ** 2))
    fill = Rotation.from_euler("zy", [rng.uniform(-np.pi, np.pi), rng.uniform(0.3, 1.2)]).apply([0, 0, 1.0])
    return np.r_[pos, power, fill, rng.uniform(0.12, 0.25), rng.uniform(0.06, 0.12)]


def object_material(rng: np.random.Generator) -> np.ndarray:
    kind = rng.choice(["blotches", "stripes", "speckle", "plain"], p=[0.35, 0.35, 0.2, 0.1])
    return material(str(kind), rng.uniform(0.25, 0.8), rng.uniform(0.25, 0.6), rng.uniform(0.012, 0.04),
                    rng.uniform(0.012, 0.04), rng.uniform(0.0, 3.0), rng.normal(size=3), rng.uniform(0.0, 0.3),
                    rng.uniform(8, 48))


def _surface(name, vertices, faces, T_base_local, mat) -> Surface:
    import trimesh

    mesh = trimesh.graph.smooth_shade(trimesh.Trimesh(vertices, faces, process=False), angle=np.radians(35))
    v = np.asarray(mesh.vertices) @ T_base_local[:3, :3].T + T_base_local[:3, 3]
    n = np.asarray(mesh.vertex_normals) @ T_base_local[:3, :3].T
    return Surface(name, v, np.asarray(mesh.faces), n, mat, np.linalg.inv(T_base_local))


def _slab(extents, centre) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    box = trimesh.creation.box(extents=extents)
    return np.asarray(box.vertices) + centre, np.asarray(box.faces)


def build_world(cfg: ValidationConfig, rng: np.random.Generator) -> World:
    """Objects resting on the table (class ids by position), clutter around them, table, room, lights."""
    camera = scene_camera(cfg)
    models = [load_object(n, cfg.mesh_dir) for n in cfg.objects]
    for i, m in enumerate(models):
        m.class_id = i + 1
    table_z = float(TABLE_CENTRE[2])
    T_true, taken = place(models, TABLE_CENTRE, table_z, rng, ring=(0.0, 0.03 + 0.05 * (len(models) > 1)
                                                                     + 0.02 * len(models)))
    extra = clutter_models(cfg.clutter, cfg.objects, rng)
    T_clutter, _ = place(extra, TABLE_CENTRE, table_z, rng, taken, ring=(0.17, 0.32))
    target = np.r_[np.mean([T[:2, 3] for T in T_true], axis=0), table_z + 0.05]
    surfaces = [_surface(m.name, m.vertices_m, m.faces, T, object_material(rng)) for m, T in zip(models, T_true)]
    surfaces += [_surface(m.name, m.vertices_m, m.faces, T, object_material(rng)) for m, T in zip(extra, T_clutter)]
    grain = material("stripes", rng.uniform(0.35, 0.55), rng.uniform(0.06, 0.18), rng.uniform(0.05, 0.12),
                     rng.uniform(0.015, 0.04), rng.uniform(2.0, 5.0), [1.0, rng.uniform(-0.1, 0.1), 0.0], 0.05, 10)
    v, f = _slab((1.4, 1.0, 0.03), TABLE_CENTRE - [0, 0, 0.015])
    table_index = len(surfaces)
    surfaces.append(_surface("table", v, f, np.eye(4), grain))
    v, f = _slab((6.0, 6.0, 3.5), TABLE_CENTRE + [0, 0, 1.0])
    surfaces.append(_surface("room", v, f, np.eye(4), material("blotches", 0.3, 0.3, 0.4)))
    light = lighting(rng, target)
    return World(camera, models, T_true, [(m.name, T) for m, T in zip(extra, T_clutter)], surfaces, light,
                 target, permutation(rng), table_z, table_index)
