"""Rays through the pixels of a camera with OpenCV's 5-coefficient lens distortion (k1 k2 p1 p2 k3).

Written on its own, without :class:`evpose.core.data.camera.CameraModel`'s projection: the forward model is
evaluated here and inverted by damped Newton iteration on its analytic 2x2 Jacobian, to ~1e-15 in normalised
coordinates (tests compare with ``cv2.projectPoints``). Pixel ``(u, v)`` has its centre at integer
coordinates; a ray is ``(x, y, 1)`` in the camera frame (OpenCV axes), so a hit distance along it is a depth.
"""
from __future__ import annotations

import numpy as np

__all__ = ["coefficients", "distort", "undistort", "monotonic_radius", "pixel_samples", "pixel_rays"]


def coefficients(dist) -> np.ndarray:
    """``(k1, k2, p1, p2, k3)`` from an OpenCV coefficient list (0, 4 or 5 long, or longer with zeros after)."""
    d = np.asarray(dist, dtype=np.float64).ravel()
    if len(d) > 5 and np.any(d[5:] != 0):
        raise ValueError(f"dist: the validation generator models k1 k2 p1 p2 k3 only, got {d.tolist()}")
    out = np.zeros(5)
    out[:min(5, len(d))] = d[:5]
    return out


def _model(x, y, k):
    """Distorted normalised coordinates and the Jacobian ``d(xd, yd) / d(x, y)``."""
    k1, k2, p1, p2, k3 = k
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    g = 2.0 * k1 + r2 * (4.0 * k2 + 6.0 * k3 * r2)          # d radial / d(r2) * 2
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    j11 = radial + g * x * x + 2.0 * p1 * y + 6.0 * p2 * x
    j12 = g * x * y + 2.0 * p1 * x + 2.0 * p2 * y
    j21 = g * x * y + 2.0 * p1 * x + 2.0 * p2 * y
    j22 = radial + g * y * y + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, j11, j12, j21, j22


def distort(xy: np.ndarray, K: np.ndarray, dist) -> np.ndarray:
    """Normalised camera coordinates ``(N, 2)`` to distorted pixels ``(N, 2)``."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    xd, yd, *_ = _model(xy[:, 0], xy[:, 1], coefficients(dist))
    return np.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)


def undistort(uv: np.ndarray, K: np.ndarray, dist, iterations: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Distorted pixels ``(N, 2)`` to normalised coordinates ``(N, 2)`` and whether Newton converged
    (residual below 1e-13 in normalised units, i.e. ~3e-11 px for a 300 px focal length)."""
    k = coefficients(dist)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    td = np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1]], axis=1)
    x, y = td[:, 0].copy(), td[:, 1].copy()
    res = np.full(len(uv), np.inf)
    for _ in range(iterations):
        xd, yd, a, b, c, d = _model(x, y, k)
        ex, ey = xd - td[:, 0], yd - td[:, 1]
        res = np.hypot(ex, ey)
        if res.max(initial=0.0) < 1e-15:
            break
        det = a * d - b * c
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        sx, sy = (d * ex - b * ey) / det, (a * ey - c * ex) / det
        step = 1.0
        for _ in range(6):                           # damping: never accept a step that grows the residual
            xn, yn = x - step * sx, y - step * sy
            xdn, ydn, *_ = _model(xn, yn, k)
            worse = np.hypot(xdn - td[:, 0], ydn - td[:, 1]) > res
            if not worse.any():
                break
            sx, sy = np.where(worse, 0.5 * sx, sx), np.where(worse, 0.5 * sy, sy)
        x, y = x - sx, y - sy
    xd, yd, *_ = _model(x, y, k)
    res = np.hypot(xd - td[:, 0], yd - td[:, 1])
    return np.stack([x, y], axis=1), res < 1e-13


def monotonic_radius(dist) -> float:
    """Normalised radius up to which the radial distortion ``r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` increases
    (``inf`` when it always does): the smallest positive root of ``1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3``, s = r^2."""
    k1, k2, _, _, k3 = coefficients(dist)
    roots = np.roots(np.trim_zeros([7 * k3, 5 * k2, 3 * k1, 1.0], "f"))
    s = [r.real for r in roots if abs(r.imag) < 1e-12 and r.real > 0]
    return float(np.sqrt(min(s))) if s else float("inf")


def pixel_samples(width: int, height: int, supersample: int = 1, rng: np.random.Generator | None = None,
                  jitter: float = 0.5) -> np.ndarray:
    """Sample positions ``(S, H*W, 2)`` in pixels: ``supersample``^2 strata per pixel, each sampled at a fixed
    point drawn uniformly from the central ``jitter`` fraction of its stratum when ``rng`` is given (a pixel's
    photodiode is an area: where in it an edge makes it fire varies from pixel to pixel), else at the centres."""
    s = int(supersample)
    vv, uu = np.mgrid[0:height, 0:width].astype(np.float64)
    base = np.stack([uu.ravel(), vv.ravel()], axis=1)
    out = []
    for i in range(s):
        for j in range(s):
            centre = np.array([(j + 0.5) / s - 0.5, (i + 0.5) / s - 0.5])
            jit = 0.0 if rng is None else rng.uniform(-0.5 * jitter / s, 0.5 * jitter / s, size=base.shape)
            out.append(base + centre + jit)
    return np.stack(out)


def pixel_rays(uv: np.ndarray, K: np.ndarray, dist) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame rays ``(N, 3)`` = ``(x, y, 1)`` through distorted pixel positions ``uv (N, 2)``, and
    which are valid (Newton converged, inside the monotonic radius of the lens model)."""
    xy, ok = undistort(uv, K, dist)
    r_max = monotonic_radius(dist)
    ok &= np.hypot(xy[:, 0], xy[:, 1]) < r_max
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    rays[~ok] = np.nan
    return rays, ok
