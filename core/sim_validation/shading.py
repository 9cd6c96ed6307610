"""Shading of ray hits: normals interpolated from the vertices (smooth shading, creases kept by the mesh), solid
textures (:mod:`evpose.core.sim_validation.textures`), a point lamp with inverse-square fall-off and a Blinn-Phong
highlight, a directional fill light, ambient light, the table's soft shadows (a precomputed map) and the lens's
cos^4 vignetting. One numba kernel over all rays of a frame."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from evpose.core.sim_validation.textures import albedo


@njit(cache=True, nogil=True, fastmath=True)
def _shadow(shadow, meta, x, y):
    """Bilinear lookup of the shadow map (1 = lit) at base-frame ``(x, y)``; 1 outside it."""
    fx, fy = (x - meta[0]) / meta[2], (y - meta[1]) / meta[2]
    i, j = int(math.floor(fy)), int(math.floor(fx))
    if i < 0 or j < 0 or i >= shadow.shape[0] - 1 or j >= shadow.shape[1] - 1:
        return 1.0
    a, b = fy - i, fx - j
    return ((1 - a) * ((1 - b) * shadow[i, j] + b * shadow[i, j + 1])
            + a * ((1 - b) * shadow[i + 1, j] + b * shadow[i + 1, j + 1]))


@njit(cache=True, nogil=True, fastmath=True)
def bake_table(perm, m, light, shadow, shadow_meta, x0, y0, cell, z, out):
    """The table top's view-independent radiance (textured albedo under ambient, lamp with soft shadow and
    fill; normal +z) on the grid ``out[i, j]`` at ``(x0 + j cell, y0 + i cell, z)``: looked up per pixel
    instead of evaluating the texture, as the table covers most of the image."""
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            px, py = x0 + j * cell, y0 + i * cell
            lx, ly, lz = light[0] - px, light[1] - py, light[2] - z
            d2 = lx * lx + ly * ly + lz * lz
            lamp = light[3] / d2 * _shadow(shadow, shadow_meta, px, py)
            diff = max(0.0, lz / math.sqrt(d2)) * lamp
            out[i, j] = albedo(perm, m, px, py, z) * (light[8] + diff + max(0.0, light[6]) * light[7])


@njit(cache=True, nogil=True, fastmath=True)
def make_rays(rays_cam, R, t, out):
    """Base-frame rays ``out (N, 6) float32`` = origin ``t``, direction ``R @ ray`` for camera rays ``(N, 3)``."""
    for i in range(len(rays_cam)):
        x, y, z = rays_cam[i, 0], rays_cam[i, 1], rays_cam[i, 2]
        out[i, 0], out[i, 1], out[i, 2] = t[0], t[1], t[2]
        out[i, 3] = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z
        out[i, 4] = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z
        out[i, 5] = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z


@njit(cache=True, nogil=True, fastmath=True)
def shade(t_hit, gid, pid, puv, rays, normals, faces, face_off, T_local, mats, perm, light, shadow,
          shadow_meta, table_gid, baked, baked_meta, vignette, out):
    """Radiance of every ray into ``out``. ``rays (N, 6)`` base-frame origins and directions, open3d's
    hit arrays (distance along the direction, geometry, triangle, barycentric ``(u, v)`` of vertices 1 and 2);
    ``faces`` index the concatenated ``normals``, geometry ``g``'s triangles start at ``face_off[g]``;
    ``T_local[g]`` (3x4) maps base-frame points to its texture frame; ``mats[g]`` its material row;
    ``baked``: the table's radiance map (:func:`bake_table`, grid origin and cell in ``baked_meta``)."""
    origin = rays[0, :3]
    for i in range(len(t_hit)):
        t = t_hit[i]
        if not np.isfinite(t):
            out[i] = 0.0
            continue
        dx, dy, dz = rays[i, 3], rays[i, 4], rays[i, 5]
        px, py, pz = origin[0] + t * dx, origin[1] + t * dy, origin[2] + t * dz
        g = gid[i]
        f = face_off[g] + pid[i]
        u, v = puv[i, 0], puv[i, 1]
        w = 1.0 - u - v
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        nx = w * normals[a, 0] + u * normals[b, 0] + v * normals[c, 0]
        ny = w * normals[a, 1] + u * normals[b, 1] + v * normals[c, 1]
        nz = w * normals[a, 2] + u * normals[b, 2] + v * normals[c, 2]
        nn = math.sqrt(nx * nx + ny * ny + nz * nz) + 1e-30
        dn = math.sqrt(dx * dx + dy * dy + dz * dz)
        vx, vy, vz = -dx / dn, -dy / dn, -dz / dn
        nx, ny, nz = nx / nn, ny / nn, nz / nn
        if nx * vx + ny * vy + nz * vz < 0.0:        # double-sided: face the viewer
            nx, ny, nz = -nx, -ny, -nz
        m = mats[g]
        lx, ly, lz = light[0] - px, light[1] - py, light[2] - pz
        d2 = lx * lx + ly * ly + lz * lz
        dl = math.sqrt(d2)
        lx, ly, lz = lx / dl, ly / dl, lz / dl
        lamp = light[3] / d2
        if g == table_gid:
            lamp *= _shadow(shadow, shadow_meta, px, py)
        spec = 0.0
        if m[9] > 0.0:
            hx, hy, hz = lx + vx, ly + vy, lz + vz
            cos_h = (nx * hx + ny * hy + nz * hz) / (math.sqrt(hx * hx + hy * hy + hz * hz) + 1e-30)
            if cos_h > 1e-6:
                spec = m[9] * math.exp(m[10] * math.log(cos_h)) * lamp
        bi, bj = (py - baked_meta[1]) / baked_meta[2], (px - baked_meta[0]) / baked_meta[2]
        if g == table_gid and 0.0 <= bi < baked.shape[0] - 1 and 0.0 <= bj < baked.shape[1] - 1 and nz > 0.5:
            i0, j0 = int(bi), int(bj)
            wa, wb = bi - i0, bj - j0
            diffuse = ((1 - wa) * ((1 - wb) * baked[i0, j0] + wb * baked[i0, j0 + 1])
                       + wa * ((1 - wb) * baked[i0 + 1, j0] + wb * baked[i0 + 1, j0 + 1]))
        else:
            T = T_local[g]
            qx = T[0, 0] * px + T[0, 1] * py + T[0, 2] * pz + T[0, 3]
            qy = T[1, 0] * px + T[1, 1] * py + T[1, 2] * pz + T[1, 3]
            qz = T[2, 0] * px + T[2, 1] * py + T[2, 2] * pz + T[2, 3]
            diff = max(0.0, nx * lx + ny * ly + nz * lz) * lamp
            fill = max(0.0, nx * light[4] + ny * light[5] + nz * light[6]) * light[7]
            diffuse = albedo(perm, m, qx, qy, qz) * (light[8] + diff + fill)
        out[i] = (diffuse + spec) * vignette[i]
