"""Log-intensity rendering of a synthetic scene (table and objects) for a camera pose."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from evpose.core.data.camera import CameraModel
from evpose.core.data.geometry import apply_T, inv_T
from evpose.core.data.objects import ObjectModel
from evpose.core.label.raster import Rasterizer
from evpose.core.sim.synth_objects import TABLE_CENTRE_BASE


def _checker(p: np.ndarray, cell_m: float) -> np.ndarray:
    """0/1 checkerboard of cubes (or squares) of side ``cell_m`` over points ``(N, D)``."""
    return (np.floor(p * np.float32(1.0 / cell_m)).astype(np.int32).sum(axis=1) & 1).astype(np.float32)


class SceneRenderer:
    """Renders log intensity of the table and objects for a camera pose.

    Objects have a base albedo with a 3D checker texture (two scales), the table a coarser,
    lower-contrast checker; Lambertian shading under a fixed directional light in the base frame.
    ``texture`` varies the objects' texture: ``"checker"`` (default), ``"fine"`` (cells a third of the size,
    many more texture events inside the silhouettes) or ``"plain"`` (no checker: shading only).
    """

    TEXTURES = ("checker", "fine", "plain")

    def __init__(self, camera: CameraModel, models: list[ObjectModel], T_base_obj: list[np.ndarray],
                 rng: np.random.Generator, light_base=(0.3, 0.5, 1.0), texture: str = "checker"):
        if texture not in self.TEXTURES:
            raise ValueError(f"texture: expected one of {self.TEXTURES}, got {texture!r}")
        self.texture = texture
        self.camera = camera
        self.raster = Rasterizer(camera)
        xy = camera.pixel_rays()[0].reshape(-1, 2)
        self.rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1).astype(np.float32)  # (x, y, 1) per pixel
        self.models = models
        self.T_base_obj = [np.asarray(T) for T in T_base_obj]
        half = 1.2
        c = TABLE_CENTRE_BASE
        self.table_v = np.array([[c[0] - half, c[1] - half, 0], [c[0] + half, c[1] - half, 0],
                                 [c[0] + half, c[1] + half, 0], [c[0] - half, c[1] + half, 0]])
        self.table_f = np.array([[0, 1, 2], [0, 2, 3]])
        self.light = np.asarray(light_base, dtype=np.float64) / np.linalg.norm(light_base)
        self.normals = []
        for m in models:
            v = m.vertices_m[m.faces]
            n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
            self.normals.append((n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-15)).astype(np.float32))
        self.tex = [dict(albedo=rng.uniform(0.35, 0.7), cell=rng.uniform(0.018, 0.03), phase=rng.uniform(0, 0.05, 3),
                         R=Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()) for _ in models]

    def render(self, T_base_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Log intensity ``(H, W) float32`` and depth ``(H, W) float32`` (inf where empty)."""
        T_cam_base = inv_T(T_base_cam)
        T_cam_obj = [T_cam_base @ T for T in self.T_base_obj]
        meshes = [(apply_T(T, m.vertices_m), m.faces) for T, m in zip(T_cam_obj, self.models)]
        meshes.append((apply_T(T_cam_base, self.table_v), self.table_f))
        res = self.raster.render(meshes, want_faces=True)
        H, W = res.depth_m.shape
        intensity = np.full(H * W, 0.08, dtype=np.float32)
        obj = res.obj_index.ravel()
        depth = res.depth_m.ravel()
        face = res.face_index.ravel()
        light_cam = (T_cam_base[:3, :3] @ self.light).astype(np.float32)
        R_cb = T_cam_base[:3, :3].astype(np.float32)
        t_cb = T_cam_base[:3, 3].astype(np.float32)
        for k in range(len(meshes)):
            pix = np.flatnonzero(obj == k)
            if len(pix) == 0:
                continue
            ray = self.rays[pix]
            p_cam = ray * depth[pix, None]
            if k < len(self.models):
                T = T_cam_obj[k].astype(np.float32)
                tex = self.tex[k]
                p_obj = (p_cam - T[:3, 3]) @ T[:3, :3]  # inv(T_cam_obj) applied to camera points
                p_tex = p_obj @ tex["R"].T.astype(np.float32) + tex["phase"].astype(np.float32)
                cell = tex["cell"] / 3.0 if self.texture == "fine" else tex["cell"]
                if self.texture == "plain":
                    albedo = np.full(len(pix), tex["albedo"], dtype=np.float32)
                else:
                    albedo = tex["albedo"] * (0.55 + 0.9 * _checker(p_tex, cell)) * (
                        0.9 + 0.2 * _checker(p_tex, cell / 3.1))
                n = self.normals[k][face[pix]] @ T[:3, :3].T
                lambert = n @ light_cam
                # visible back faces of open meshes: flip the normal towards the camera
                lambert = np.where(np.einsum("ij,ij->i", n, ray) > 0, -lambert, lambert)
            else:
                p_base_xy = ((p_cam - t_cb) @ R_cb)[:, :2]
                albedo = 0.4 * (0.8 + 0.4 * _checker(p_base_xy, 0.06))
                n_table = R_cb[:, 2]  # the table normal (base z) in the camera frame
                lambert = float(abs(n_table @ light_cam))
            intensity[pix] = albedo * (0.3 + 0.7 * np.clip(lambert, 0.0, None))
        return np.log(intensity + 0.02).reshape(H, W), res.depth_m
