"""Frames of a validation scene: open3d ``RaycastingScene`` ray casting through the distorted lens
(:mod:`~evpose.core.sim_validation.rays`), shaded by :mod:`~evpose.core.sim_validation.shading`, as log intensity.

The BVH is built once (the world is static; only the camera moves). Each pixel casts ``supersample``^2 rays at
fixed jittered points of its area; their radiance is averaged before the logarithm, as a photodiode integrates.
"""
from __future__ import annotations

import numpy as np

from evpose.core.sim_validation.rays import pixel_rays, pixel_samples
from evpose.core.sim_validation.shading import bake_table, make_rays, shade
from evpose.core.sim_validation.world import World

#: Table shadow map: half size (m), cell (m), lamp radius (m) and samples on it (soft shadows).
SHADOW_HALF_M, SHADOW_CELL_M, LAMP_RADIUS_M, LAMP_SAMPLES = 0.45, 0.002, 0.04, 4
#: The table's baked radiance: half size (m); its cell is what a pixel sees of the table 0.3 m away (DAVIS346: 1 mm).
BAKE_HALF_M, BAKE_DEPTH_M = 0.6, 0.3


class Raycaster:
    """Renders ``world`` for camera poses ``T_base_cam``.

    Parameters
    ----------
    world : World
    supersample : int
        Rays per pixel side.
    rng : numpy.random.Generator
        Draws the fixed sub-pixel sample points.
    dark_level : float
        Added to the radiance before the logarithm (the sensor's dark current).
    shadows : bool
        Soft shadows of the objects on the table.
    """

    def __init__(self, world: World, supersample: int, rng: np.random.Generator, dark_level: float,
                 shadows: bool = True):
        import open3d as o3d

        cam = world.camera
        self.world, self.dark = world, float(dark_level)
        self.width, self.height, self.s2 = cam.width, cam.height, int(supersample) ** 2
        uv = pixel_samples(cam.width, cam.height, supersample, rng).reshape(-1, 2)
        rays, ok = pixel_rays(uv, cam.K, cam.dist)
        rays[~ok] = [0.0, 0.0, 1.0]
        self.rays_cam = rays.astype(np.float32)
        self.vignette = np.where(ok, 1.0 / np.einsum("ij,ij->i", rays, rays) ** 2, 0.0)   # cos^4 of the angle
        self.scene = o3d.t.geometry.RaycastingScene()
        offs, faces, normals, n_v = [0], [], [], 0
        for s in world.surfaces:
            self.scene.add_triangles(o3d.core.Tensor(s.vertices.astype(np.float32)),
                                     o3d.core.Tensor(s.faces.astype(np.uint32)))
            faces.append(s.faces + n_v)
            normals.append(s.normals)
            n_v += len(s.vertices)
            offs.append(offs[-1] + len(s.faces))
        self.faces = np.concatenate(faces).astype(np.int64)
        self.normals = np.concatenate(normals).astype(np.float64)
        self.face_off = np.asarray(offs[:-1], np.int64)
        self.T_local = np.stack([s.T_local_base[:3] for s in world.surfaces]).astype(np.float64)
        self.mats = np.stack([s.material for s in world.surfaces]).astype(np.float64)
        self.shadow, self.shadow_meta = self._shadow_map(world, rng) if shadows else (np.ones((2, 2)),
                                                                                       np.array([0.0, 0.0, 1.0]))
        c = world.target
        cell = BAKE_DEPTH_M / float(cam.K[0, 0])
        n = int(2 * BAKE_HALF_M / cell) + 1
        self.baked = np.empty((n, n), np.float32)
        self.baked_meta = np.array([c[0] - BAKE_HALF_M, c[1] - BAKE_HALF_M, cell])
        bake_table(world.perm, self.mats[world.table_index], world.light, self.shadow, self.shadow_meta,
                   self.baked_meta[0], self.baked_meta[1], cell, world.table_z, self.baked)
        self._rays = np.empty((len(self.rays_cam), 6), np.float32)
        step = max(1, int(round(min(cam.width, cam.height) / 40)))
        grid = np.zeros((cam.height, cam.width), bool)
        grid[::step, ::step] = True
        self._probe = np.flatnonzero(grid.ravel())          # pixels whose hit points steer the frame rate

    def _shadow_map(self, world: World, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        import open3d as o3d

        c = world.target
        n = int(2 * SHADOW_HALF_M / SHADOW_CELL_M) + 1
        x0, y0 = c[0] - SHADOW_HALF_M, c[1] - SHADOW_HALF_M
        yy, xx = np.mgrid[0:n, 0:n] * SHADOW_CELL_M
        p = np.stack([xx.ravel() + x0, yy.ravel() + y0, np.full(n * n, world.table_z + 1e-4)], axis=1)
        lit = np.zeros(n * n)
        for _ in range(LAMP_SAMPLES):
            lamp = world.light[:3] + rng.uniform(-LAMP_RADIUS_M, LAMP_RADIUS_M, 3)
            rays = np.concatenate([p, lamp - p], axis=1).astype(np.float32)
            lit += ~self.scene.test_occlusions(o3d.core.Tensor(rays), tnear=1e-4, tfar=1.0).numpy()
        return (lit / LAMP_SAMPLES).reshape(n, n), np.array([x0, y0, SHADOW_CELL_M])

    def render(self, T_base_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Log intensity ``(H, W) float32`` and a sparse grid of the frame's hit points ``(M, 3)`` (base frame)."""
        import open3d as o3d

        t = np.ascontiguousarray(T_base_cam[:3, 3], dtype=np.float64)
        make_rays(self.rays_cam, np.ascontiguousarray(T_base_cam[:3, :3], dtype=np.float64), t, self._rays)
        hit = self.scene.cast_rays(o3d.core.Tensor.from_numpy(self._rays))
        t_hit = hit["t_hit"].numpy()
        out = np.empty(len(self._rays))
        shade(t_hit, hit["geometry_ids"].numpy(), hit["primitive_ids"].numpy(), hit["primitive_uvs"].numpy(),
              self._rays, self.normals, self.faces, self.face_off, self.T_local, self.mats, self.world.perm,
              self.world.light, self.shadow, self.shadow_meta, self.world.table_index, self.baked, self.baked_meta,
              self.vignette, out)
        radiance = out.reshape(self.s2, -1).mean(axis=0)
        log = np.log(radiance + self.dark).astype(np.float32).reshape(self.height, self.width)
        th = t_hit[self._probe]
        ok = np.isfinite(th)
        points = t + th[ok, None].astype(np.float64) * self._rays[self._probe[ok], 3:]
        return log, points
