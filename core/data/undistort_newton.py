"""OpenCV's lens distortion and its inverse by Newton's method, vectorised, converging wherever a pixel has a ray.

``cv2.undistortPoints`` inverts the distortion by the fixed-point iteration ``x <- (x_d - tangential(x)) /
radial(x)``. It contracts only where the radial factor changes slowly: with strong distortion (k1 = -0.6,
k3 = +0.4) or a short focal length (fx = 20 px, rays ~60 degrees off-axis) it oscillates at the image corners,
and pixels that do have a ray come back unconverged (tracker issue 23.7: 23 to 134 holes in a DAVIS346 mask).

Here the distortion ``D(x, y)`` (pixels) is inverted by Newton's method with the analytic 2 x 2 Jacobian,
started from the exact inverse of the radial part (a monotonic table of ``r -> r_d`` on ``[0, r_max]``,
interpolated), and kept inside the disk ``r <= r_max`` where the radial distortion is monotonic
(:attr:`evpose.core.data.camera.CameraModel.r_max`), so it can never converge onto a folded-back root. A
point has a ray when the iteration ends within :data:`ACCEPT_PX` of it; otherwise it has none (it lies
beyond the image of the monotonic disk) and comes back NaN.

Models: radial ``k1 k2 k3``, rational ``k4 k5 k6``, tangential ``p1 p2`` and thin prism ``s1..s4`` are
evaluated in NumPy (the same operations as ``cv2.projectPoints``); the tilted-sensor model (coefficients
13 and 14 non-zero) is evaluated by ``cv2.projectPoints``, whose Jacobian with respect to the translation
is, at zero rotation, the Jacobian with respect to the point.
"""
from __future__ import annotations

import cv2
import numpy as np

#: Samples of the radial table ``r -> r_d`` that gives the initial guess (its interpolation error, ~1e-5
#: in r, is what the first Newton step removes).
N_TABLE = 4097
#: Upper end of the radial table when the distortion is monotonic everywhere (``r_max = inf``): the range
#: ``CameraModel.r_max`` searches (87 degrees off-axis). Newton may go beyond it.
R_SEARCH = 20.0
#: Newton iterations at most. Points with a ray converge quadratically in 2 to 5 (60 leaves room for the
#: linear convergence right at the fold radius); points without one use them all.
MAX_ITER = 60
#: A point stops iterating when its Newton step is below this, in normalised units times ``1 + r``.
STEP_TOL = 1e-13
#: A point has a ray when ``D(x, y)`` lands within this many pixels of it (in either coordinate).
ACCEPT_PX = 1e-6


def split_coefficients(dist) -> tuple[np.ndarray, bool]:
    """``(d12, tilted)``: the first 12 OpenCV coefficients zero-padded (k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4),
    and whether the tilted-sensor coefficients (13, 14) are non-zero."""
    dist = np.asarray(dist, dtype=np.float64).ravel()
    d12 = np.zeros(12)
    d12[:min(len(dist), 12)] = dist[:12]
    return d12, bool(len(dist) > 12 and np.any(dist[12:]))


def radial_factor(r2: np.ndarray, d12: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(radial, d radial / d r^2, denominator)`` of the rational radial model at squared radii ``r2``."""
    k1, k2, _, _, k3, k4, k5, k6 = d12[:8]
    num = 1.0 + ((k3 * r2 + k2) * r2 + k1) * r2
    den = 1.0 + ((k6 * r2 + k5) * r2 + k4) * r2
    dnum = (3.0 * k3 * r2 + 2.0 * k2) * r2 + k1
    dden = (3.0 * k6 * r2 + 2.0 * k5) * r2 + k4
    radial = num / den
    return radial, (dnum - radial * dden) / den, den


def distort_xy(x: np.ndarray, y: np.ndarray, d12: np.ndarray, jacobian: bool = False):
    """Normalised coordinates ``(x, y)`` to distorted normalised coordinates ``(x_d, y_d)``.

    Returns
    -------
    xd, yd : ndarray
    J : tuple of four ndarrays, only with ``jacobian``
        ``(dxd/dx, dxd/dy, dyd/dx, dyd/dy)``, dimensionless.
    """
    _, _, p1, p2, _, _, _, _, s1, s2, s3, s4 = d12
    r2 = x * x + y * y
    radial, dradial, _ = radial_factor(r2, d12)
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x) + (s1 + s2 * r2) * r2
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2 + (s3 + s4 * r2) * r2
    if not jacobian:
        return xd, yd
    # d/dx of f(r2) is 2 x f'(r2): the radial, prism and tangential terms
    gx, gy = 2.0 * dradial * x, 2.0 * dradial * y
    px, py = 2.0 * (s1 + 2.0 * s2 * r2), 2.0 * (s3 + 2.0 * s4 * r2)
    J = (radial + gx * x + 2.0 * p1 * y + 6.0 * p2 * x + px * x,
         gy * x + 2.0 * p1 * x + 2.0 * p2 * y + px * y,
         gx * y + 2.0 * p1 * x + 2.0 * p2 * y + py * x,
         radial + gy * y + 6.0 * p1 * y + 2.0 * p2 * x + py * y)
    return xd, yd, J


class NewtonUndistorter:
    """Distorted pixels to normalised rays of one camera.

    Parameters
    ----------
    K : (3, 3) array
        Camera matrix, pixels (zero skew).
    dist : sequence of float
        OpenCV distortion coefficients (any length OpenCV takes).
    r_max : float
        Normalised radius up to which the radial distortion is monotonic (``inf`` if always); rays are
        searched only inside it.
    """

    def __init__(self, K, dist, r_max: float):
        self.K = np.asarray(K, dtype=np.float64)
        self.dist = np.asarray(dist, dtype=np.float64).ravel()
        self.d12, self.tilted = split_coefficients(self.dist)
        self.r_max = float(r_max)
        self.identity = not np.any(self.dist)
        r_hi = min(self.r_max, R_SEARCH)
        r = np.linspace(0.0, r_hi, N_TABLE)
        self._r_table = r
        self._rd_table = np.maximum.accumulate(r * radial_factor(r * r, self.d12)[0])

    def distort_px(self, x: np.ndarray, y: np.ndarray, jacobian: bool = False):
        """Normalised coordinates to distorted pixels ``(u, v)``, with the Jacobian ``d(u, v)/d(x, y)``
        (pixels per normalised unit, four arrays) if asked."""
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        if self.tilted:
            pts = np.stack([x, y, np.ones_like(x)], axis=1)
            uv, jac = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.K, self.dist)
            uv = uv.reshape(-1, 2)
            if not jacobian:
                return uv[:, 0], uv[:, 1]
            d = jac[:, 3:5].reshape(-1, 2, 2)          # d(u, v)/d(tx, ty) = d(u, v)/d(x, y) at zero rotation
            return uv[:, 0], uv[:, 1], (d[:, 0, 0], d[:, 0, 1], d[:, 1, 0], d[:, 1, 1])
        out = distort_xy(x, y, self.d12, jacobian)
        u, v = fx * out[0] + cx, fy * out[1] + cy
        if not jacobian:
            return u, v
        a, b, c, d = out[2]
        return u, v, (fx * a, fx * b, fy * c, fy * d)

    def initial_guess(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The exact inverse of the radial part (tangential, prism and tilt terms ignored), normalised."""
        xd = (u - self.K[0, 2]) / self.K[0, 0]
        yd = (v - self.K[1, 2]) / self.K[1, 1]
        rd = np.hypot(xd, yd)
        r = np.interp(rd, self._rd_table, self._r_table)
        scale = np.divide(r, rd, out=np.ones_like(rd), where=rd > 0)
        return xd * scale, yd * scale

    def rays(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised rays ``(x, y)`` (direction ``(x, y, 1)``) of distorted pixels ``uv`` (N, 2).

        Returns
        -------
        xy : (N, 2) float64
            NaN where the pixel has no ray.
        ok : (N,) bool
            The pixel has a ray: Newton ended within :data:`ACCEPT_PX` of it, at a radius within ``r_max``.
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        u, v = uv[:, 0], uv[:, 1]
        if self.identity:
            xy = np.stack([(u - self.K[0, 2]) / self.K[0, 0], (v - self.K[1, 2]) / self.K[1, 1]], axis=1)
            return xy, np.all(np.isfinite(xy), axis=1)
        x, y = self.initial_guess(u, v)
        active = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
        for _ in range(MAX_ITER):
            if not len(active):
                break
            active = self._newton_step(x, y, u, v, active)
        ex, ey = self.distort_px(x, y)
        with np.errstate(invalid="ignore"):
            ok = ((np.abs(ex - u) <= ACCEPT_PX) & (np.abs(ey - v) <= ACCEPT_PX)
                  & (x * x + y * y <= self.r_max ** 2))
        xy = np.stack([x, y], axis=1)
        xy[~ok] = np.nan
        return xy, ok

    def _newton_step(self, x, y, u, v, active: np.ndarray) -> np.ndarray:
        """One Newton step on the points ``active`` (in place on ``x``, ``y``); returns those still moving."""
        xa, ya = x[active], y[active]
        eu, ev, (a, b, c, d) = self.distort_px(xa, ya, jacobian=True)
        ru, rv = u[active] - eu, v[active] - ev
        with np.errstate(divide="ignore", invalid="ignore"):
            det = a * d - b * c
            nx = xa + (d * ru - b * rv) / det
            ny = ya + (a * rv - c * ru) / det
            bad = ~(np.isfinite(nx) & np.isfinite(ny))          # a singular Jacobian (at the fold): stop there
            nx, ny = np.where(bad, xa, nx), np.where(bad, ya, ny)
            r_old = np.hypot(xa, ya)
            r_new = np.hypot(nx, ny)
            # outside the monotonic disk: go halfway from the old radius to its rim, along the new direction
            over = r_new > self.r_max
            shrink = np.where(over, 0.5 * (r_old + self.r_max) / r_new, 1.0)
            nx, ny = nx * shrink, ny * shrink
            step = np.maximum(np.abs(nx - xa), np.abs(ny - ya))
            moving = ~bad & (step > STEP_TOL * (1.0 + r_new))
        x[active], y[active] = nx, ny
        return active[moving]
