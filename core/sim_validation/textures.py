"""Solid procedural textures: albedo as a function of a 3D point in a surface's own frame (the object frame for
objects), so a texture moves rigidly with its object whatever the mesh's triangulation, as for the published
E-POSE meshes whose texture images are missing.

Perlin's improved gradient noise (2002) on a per-scene permutation table, summed over octaves (fBm), and four
patterns on top of it (:data:`KINDS`). Compiled with numba; called per hit point from
:mod:`evpose.core.sim_validation.shading`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Texture kinds: index in a material's parameter row (:func:`material`).
KINDS = {"plain": 0, "blotches": 1, "stripes": 2, "speckle": 3}
#: Columns of a material row.
MATERIAL_FIELDS = ("kind", "albedo", "contrast", "scale_m", "period_m", "warp", "ax", "ay", "az", "ks", "shininess")


def permutation(rng: np.random.Generator) -> np.ndarray:
    """The noise's lattice hash: a random permutation of 0..255, repeated (512 entries)."""
    p = rng.permutation(256).astype(np.int64)
    return np.concatenate([p, p])


def material(kind: str, albedo: float, contrast: float = 0.0, scale_m: float = 0.02, period_m: float = 0.02,
             warp: float = 0.0, axis=(0.0, 0.0, 1.0), ks: float = 0.0, shininess: float = 16.0) -> np.ndarray:
    """One material row (see :data:`MATERIAL_FIELDS`): a texture kind, the mean albedo (0..1), the texture's
    relative contrast, its noise scale and stripe period (metres), the stripes' warp (radians per unit of
    noise) and direction, and a Blinn-Phong specular weight and exponent."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    return np.array([KINDS[kind], albedo, contrast, scale_m, period_m, warp, a[0], a[1], a[2], ks, shininess])


@njit(cache=True, nogil=True, fastmath=True)
def _fade(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@njit(cache=True, nogil=True, fastmath=True)
def _grad(h, x, y, z):
    h &= 15
    u = x if h < 8 else y
    v = y if h < 4 else (x if h == 12 or h == 14 else z)
    return (u if (h & 1) == 0 else -u) + (v if (h & 2) == 0 else -v)


@njit(cache=True, nogil=True, fastmath=True)
def perlin(perm, x, y, z):
    """Gradient noise at ``(x, y, z)`` (lattice units), in about [-1, 1], zero at lattice points."""
    fx, fy, fz = math.floor(x), math.floor(y), math.floor(z)
    xi, yi, zi = int(fx) & 255, int(fy) & 255, int(fz) & 255
    x, y, z = x - fx, y - fy, z - fz
    u, v, w = _fade(x), _fade(y), _fade(z)
    a = perm[xi] + yi
    aa, ab = perm[a] + zi, perm[a + 1] + zi
    b = perm[xi + 1] + yi
    ba, bb = perm[b] + zi, perm[b + 1] + zi
    x1 = _grad(perm[aa], x, y, z) + u * (_grad(perm[ba], x - 1, y, z) - _grad(perm[aa], x, y, z))
    x2 = _grad(perm[ab], x, y - 1, z) + u * (_grad(perm[bb], x - 1, y - 1, z) - _grad(perm[ab], x, y - 1, z))
    y1 = x1 + v * (x2 - x1)
    x3 = _grad(perm[aa + 1], x, y, z - 1) + u * (_grad(perm[ba + 1], x - 1, y, z - 1)
                                                  - _grad(perm[aa + 1], x, y, z - 1))
    x4 = _grad(perm[ab + 1], x, y - 1, z - 1) + u * (_grad(perm[bb + 1], x - 1, y - 1, z - 1)
                                                      - _grad(perm[ab + 1], x, y - 1, z - 1))
    y2 = x3 + v * (x4 - x3)
    return y1 + w * (y2 - y1)


@njit(cache=True, nogil=True, fastmath=True)
def fbm(perm, x, y, z, octaves):
    """Fractal sum of ``octaves`` noise octaves (frequency x2, amplitude x0.5 each)."""
    total, amp, freq = 0.0, 0.5, 1.0
    for _ in range(octaves):
        total += amp * perlin(perm, x * freq + 17.3, y * freq + 3.1, z * freq + 9.7)
        amp *= 0.5
        freq *= 2.0
    return total


@njit(cache=True, nogil=True, fastmath=True)
def _smooth(e0, e1, x):
    t = min(max((x - e0) / (e1 - e0), 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


@njit(cache=True, nogil=True, fastmath=True)
def albedo(perm, m, x, y, z):
    """Albedo of material row ``m`` at the local point ``(x, y, z)`` (metres), clipped to [0.02, 1]."""
    kind, base, contrast, scale = int(m[0]), m[1], m[2], m[3]
    s = 1.0 / scale
    if kind == 1:        # blotches: printed patches with soft borders
        a = base * (1.0 + contrast * math.tanh(4.0 * fbm(perm, x * s, y * s, z * s, 2)))
    elif kind == 2:      # stripes along an axis, warped by noise (labels, wood grain)
        d = x * m[6] + y * m[7] + z * m[8]
        ph = 2.0 * math.pi * d / m[4] + m[5] * 0.5 * perlin(perm, x * s, y * s, z * s)
        a = base * (1.0 + contrast * (2.0 * _smooth(-0.35, 0.35, math.sin(ph)) - 1.0))
    elif kind == 3:      # speckle: small dots
        n = 0.5 * perlin(perm, x * s + 5.3, y * s + 1.9, z * s + 7.1)
        a = base * (1.0 + contrast * (2.0 * _smooth(0.12, 0.2, n) - 1.0))
    else:                # plain, with a faint low-frequency variation
        a = base * (1.0 + 0.04 * perlin(perm, x * 20.0, y * 20.0, z * 20.0))
    return min(max(a, 0.02), 1.0)
