"""Pinhole camera with OpenCV lens distortion, with near-plane and fold-back guards.

Pixel convention (DESIGN section 3): pixel ``(u, v)`` has its centre at integer coordinates;
images are indexed ``[v, u]``. The camera frame has OpenCV axes (x right, y down, z forward).

Two guards make projection safe for labels:

* points with ``z <= near_m`` are never projected (no mirrored objects from behind the camera);
* the radial distortion polynomial folds back beyond some radius (its derivative turns negative),
  where far-off-axis points would land *inside* the image; points whose normalised radius is
  beyond :attr:`CameraModel.r_max` are rejected.

Undistortion (pixels to rays) is Newton's method on the distortion model, kept inside ``r_max``
(:mod:`evpose.core.data.undistort_newton`): it converges at every pixel that has a ray, where OpenCV's
fixed-point iteration leaves holes at the image corners of strongly distorted or wide-angle cameras.
"""
from __future__ import annotations

import json
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np

from evpose.core.data.undistort_newton import R_SEARCH, NewtonUndistorter, radial_factor, split_coefficients
from evpose.core.errors import InputError

#: DAVIS346c calibration hard-coded in the E-POSE annotation scripts (OpenCV model, k1 k2 p1 p2 k3);
#: the same values as ``shared/assets/epose/camera_davis346.json``.
DAVIS346_WIDTH = 346
DAVIS346_HEIGHT = 260
DAVIS346_K = ((292.52, 0.0, 172.61), (0.0, 293.19, 130.125), (0.0, 0.0, 1.0))
DAVIS346_DIST = (-0.362, 0.115, 0.0009576, 4.55e-06, 0.13)

_VALID_DIST_LENGTHS = (0, 4, 5, 8, 12, 14)
#: Largest sensor side, px: event pixel coordinates are stored as uint16 (``events/x``, ``events/y``).
MAX_SIDE_PX = 65536
#: Largest sensor area, px (8192 x 8192): per-pixel buffers (rays, z-buffer, remap tables) cost ~40 bytes
#: a pixel, 2.7 GB here; event sensors have at most ~1 MP. A 10**9-pixel width would ask for terabytes.
MAX_AREA_PX = 2**26
#: Focal lengths must lie within [1e-3, 1e4] x the larger sensor side (a field of view between ~0.006
#: degrees and all of it): outside, pixel arithmetic overflows (fx = 1e308) or no ray hits the sensor.
FOCAL_RANGE_PER_SIDE = (1e-3, 1e4)
#: |cx|, |cy| at most this many sensor sides; |distortion coefficient| at most MAX_ABS_DIST.
MAX_CENTRE_PER_SIDE = 100.0
MAX_ABS_DIST = 1e6
#: Point sets at least this share of the sensor's pixels, all at integer pixel centres (events), are undistorted
#: by a lookup in the per-pixel rays (computed once per camera) rather than by Newton's method point by point.
RAY_CACHE_SHARE = 0.125


class CameraError(InputError):
    """Invalid camera parameters; the message names the source and the field."""


class CameraModel:
    """Intrinsics ``K``, OpenCV distortion ``dist`` and sensor size.

    Parameters
    ----------
    K : (3, 3) array
        Camera matrix in pixels.
    dist : sequence of 0, 4, 5, 8, 12 or 14 floats
        OpenCV distortion coefficients (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1..s4 [tx ty]]]]).
        An empty sequence means no distortion; it is never silently forced to zero.
    width, height : int
        Sensor size in pixels.
    near_m : float
        Near plane in metres; points with ``z <= near_m`` are not projected. Default 1 mm, so
        objects close to the lens do not vanish.
    source : str
        Name used in error messages.
    """

    def __init__(self, K, dist=(), width: int = DAVIS346_WIDTH, height: int = DAVIS346_HEIGHT,
                 *, near_m: float = 1e-3, source: str = "camera"):
        self.source = source
        try:
            K = np.asarray(K, dtype=np.float64)
        except (TypeError, ValueError):
            raise CameraError(f"{source}: K: not a numeric 3x3 matrix") from None
        if K.shape != (3, 3):
            raise CameraError(f"{source}: K: expected a 3x3 matrix, got shape {K.shape}")
        if not np.all(np.isfinite(K)):
            raise CameraError(f"{source}: K: contains NaN or inf")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise CameraError(f"{source}: K: focal lengths must be positive (fx={K[0, 0]}, fy={K[1, 1]})")
        if not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise CameraError(f"{source}: K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
        if K[0, 1] != 0:
            # OpenCV's distortion model has no skew term: projecting with it would silently drop it
            raise CameraError(f"{source}: K: skew K[0][1] = {K[0, 1]} is not supported by the OpenCV "
                              "distortion model; calibrate with zero skew")
        try:
            dist = np.asarray(dist, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise CameraError(f"{source}: dist: not a list of numbers") from None
        if len(dist) not in _VALID_DIST_LENGTHS:
            raise CameraError(f"{source}: dist: OpenCV takes 0, 4, 5, 8, 12 or 14 coefficients, got {len(dist)}")
        if not np.all(np.isfinite(dist)):
            raise CameraError(f"{source}: dist: contains NaN or inf")
        if np.any(np.abs(dist) > MAX_ABS_DIST):
            raise CameraError(f"{source}: dist: coefficients must be at most {MAX_ABS_DIST:g} in magnitude, "
                              f"got {dist.tolist()}")
        try:
            ok_int = int(width) == width and int(height) == height
        except (TypeError, ValueError, OverflowError):
            ok_int = False
        if not ok_int or width <= 0 or height <= 0:
            raise CameraError(f"{source}: width/height: must be positive integers, got {width}x{height}")
        for name, v in (("width", width), ("height", height)):
            if v > MAX_SIDE_PX:
                raise CameraError(f"{source}: {name}: {int(v)} px is more than the {MAX_SIDE_PX} px an event "
                                  "coordinate (uint16) can address")
        if int(width) * int(height) > MAX_AREA_PX:
            raise CameraError(f"{source}: width/height: {int(width)}x{int(height)} = {int(width) * int(height):,} "
                              f"pixels is more than the {MAX_AREA_PX:,} supported (8192 x 8192)")
        side = float(max(width, height))
        lo, hi = FOCAL_RANGE_PER_SIDE[0] * side, FOCAL_RANGE_PER_SIDE[1] * side
        for name, v in (("fx", K[0, 0]), ("fy", K[1, 1])):
            if not lo <= v <= hi:
                raise CameraError(f"{source}: K: {name} = {v:g} px is outside [{lo:g}, {hi:g}] "
                                  f"({FOCAL_RANGE_PER_SIDE[0]:g} to {FOCAL_RANGE_PER_SIDE[1]:g} x the sensor's "
                                  f"larger side of {int(side)} px)")
        for name, v in (("cx", K[0, 2]), ("cy", K[1, 2])):
            if abs(v) > MAX_CENTRE_PER_SIDE * side:
                raise CameraError(f"{source}: K: {name} = {v:g} px is more than {MAX_CENTRE_PER_SIDE:g} sensor "
                                  "sides from the image")
        if not near_m > 0:
            raise CameraError(f"{source}: near_m: must be positive, got {near_m}")
        self.K = K
        self.dist = dist
        self.width = int(width)
        self.height = int(height)
        self.near_m = float(near_m)
        self._maps: dict = {}

    # ------------------------------------------------------------------ construction
    @classmethod
    def davis346(cls, **kwargs) -> "CameraModel":
        """The DAVIS346c calibration used by E-POSE."""
        return cls(DAVIS346_K, DAVIS346_DIST, DAVIS346_WIDTH, DAVIS346_HEIGHT, source="DAVIS346 default", **kwargs)

    @classmethod
    def from_dict(cls, d: dict, source: str = "camera") -> "CameraModel":
        """From a mapping with ``K``, ``dist`` (optional), ``width``, ``height``."""
        for key in ("K", "width", "height"):
            if key not in d:
                raise CameraError(f"{source}: {key}: missing")
        return cls(d["K"], d.get("dist", []), d["width"], d["height"], source=source)

    @classmethod
    def from_json(cls, path) -> "CameraModel":
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise CameraError(f"{path}: cannot read camera JSON ({exc})") from None
        return cls.from_dict(data, source=str(path))

    def to_dict(self) -> dict:
        return {"width": self.width, "height": self.height, "K": self.K.tolist(), "dist": self.dist.tolist()}

    def binned(self, factor: int = 2) -> "CameraModel":
        """The same lens with ``factor x factor`` pixels read as one (``width // factor`` x ``height // factor``):
        focal lengths divided by ``factor``, the principal point on the coarse grid (pixel centres are at integers,
        so ``c`` maps to ``(c + 0.5) / factor - 0.5``), the distortion unchanged (it acts on normalised
        coordinates). E.g. half-resolution DAVIS346 scenes for fast tests and benchmarks."""
        K = self.K.copy()
        K[:2] /= factor
        K[0, 2] = (self.K[0, 2] + 0.5) / factor - 0.5
        K[1, 2] = (self.K[1, 2] + 0.5) / factor - 0.5
        return CameraModel(K, self.dist, self.width // factor, self.height // factor, source=f"{self.source} binned")

    def __repr__(self) -> str:
        return (f"CameraModel({self.width}x{self.height}, fx={self.K[0, 0]:.2f}, fy={self.K[1, 1]:.2f}, "
                f"cx={self.K[0, 2]:.2f}, cy={self.K[1, 2]:.2f}, dist={self.dist.tolist()})")

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.dist != 0))

    # ------------------------------------------------------------------ distortion radius
    @cached_property
    def r_max(self) -> float:
        """Largest normalised radius up to which radial distortion is monotonic (``inf`` if always).

        The radial factor is ``(1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)``;
        ``r_d = r * factor`` must increase with ``r`` (and the denominator stay positive). The search covers
        r up to 20 (87 degrees off-axis) on a grid of 1e-4, and the first radius where it fails is refined
        by bisection to ~1e-15: ``r_max`` is the fold radius itself, not the grid point past it. Tangential
        and prism terms are small and not part of the bound.
        """
        if not self.has_distortion:
            return float("inf")
        d12, _ = split_coefficients(self.dist)

        def monotonic(r):
            radial, dradial, den = radial_factor(r * r, d12)
            return (den > 1e-9) & (radial + 2.0 * r * r * dradial > 0)

        r = np.linspace(0.0, R_SEARCH, 200_001)
        good = monotonic(r)
        if good.all():
            return float("inf")
        i = int(np.argmax(~good))
        lo, hi = float(r[max(i - 1, 0)]), float(r[i])
        for _ in range(64):
            mid = 0.5 * (lo + hi)
            if mid in (lo, hi):
                break
            lo, hi = (mid, hi) if monotonic(np.array(mid)) else (lo, mid)
        return lo

    @cached_property
    def _undistorter(self) -> NewtonUndistorter:
        return NewtonUndistorter(self.K, self.dist, self.r_max)

    # ------------------------------------------------------------------ projection
    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project camera-frame points (metres) to distorted pixel coordinates.

        Returns
        -------
        uv : (N, 2) float64
            Pixel coordinates; NaN where not valid.
        valid : (N,) bool
            ``z > near_m`` and normalised radius within :attr:`r_max`. Points outside the image
            but valid keep their coordinates (use :meth:`in_image`).
        """
        P = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        uv = np.full((len(P), 2), np.nan)
        valid = P[:, 2] > self.near_m
        if valid.any():
            xy = P[valid, :2] / P[valid, 2:3]
            ok = np.einsum("ij,ij->i", xy, xy) <= self.r_max**2
            idx = np.flatnonzero(valid)
            valid[idx[~ok]] = False
            if ok.any():
                uv[idx[ok]] = self.distort_normalized(xy[ok])
        return uv, valid

    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Normalised image coordinates ``(x/z, y/z)`` to distorted pixels: OpenCV's model (radial, rational,
        tangential and thin-prism terms) evaluated in numpy, the same operations as ``cv2.projectPoints`` (which
        is used for the tilted-sensor model, and costs ~0.2 ms per call for the Jacobian it always computes).

        No guard is applied: callers pass points inside :attr:`r_max`.
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if len(xy) == 0:
            return np.zeros((0, 2))
        u, v = self._undistorter.distort_px(xy[:, 0], xy[:, 1])
        return np.stack([u, v], axis=1)

    def undistort_points(self, uv: np.ndarray, K_new: np.ndarray | None = None) -> np.ndarray:
        """Distorted pixels to normalised coordinates (or pixels of ``K_new`` if given); NaN where a pixel has
        no ray (beyond the image of the monotonic disk ``r <= r_max``).

        Newton's method on the distortion model (:class:`~evpose.core.data.undistort_newton.NewtonUndistorter`),
        accurate to ~1e-13 in normalised units. Large sets of integer pixel centres (events) are looked up in
        :meth:`pixel_rays`, which holds the same values.

        Parameters
        ----------
        uv : (N, 2) float
            Distorted pixel coordinates.
        K_new : (3, 3) array, optional
            Camera matrix of the output pixels (applied to ``(x, y, 1)`` as ``cv2.undistortPoints``'s ``P``).
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if len(uv) == 0:
            return np.zeros((0, 2))
        xy = self._cached_rays(uv)
        if xy is None:
            xy = self._undistorter.rays(uv)[0]
        if K_new is None:
            return xy
        P = np.asarray(K_new, dtype=np.float64)
        h = xy @ P[:, :2].T + P[:, 2]
        return h[:, :2] / h[:, 2:3]

    def _cached_rays(self, uv: np.ndarray) -> np.ndarray | None:
        """Rays of ``uv`` from :meth:`pixel_rays` when they are integer pixel centres on the sensor and either
        the rays are computed already or ``uv`` is at least :data:`RAY_CACHE_SHARE` of the sensor; else None."""
        if "_pixel_rays" not in self.__dict__ and len(uv) < RAY_CACHE_SHARE * self.width * self.height:
            return None
        if not np.isfinite(uv).all():
            return None
        iu, iv = uv[:, 0].astype(np.int64), uv[:, 1].astype(np.int64)
        if not (np.array_equal(iu, uv[:, 0]) and np.array_equal(iv, uv[:, 1])
                and iu.min() >= 0 and iv.min() >= 0 and iu.max() < self.width and iv.max() < self.height):
            return None
        return self.pixel_rays()[0][iv, iu]

    def in_image(self, uv: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """True where pixel coordinates fall on the sensor (pixel squares ``[-0.5, W-0.5)``)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        with np.errstate(invalid="ignore"):
            return ((uv[:, 0] >= -0.5 - margin_px) & (uv[:, 0] < self.width - 0.5 + margin_px)
                    & (uv[:, 1] >= -0.5 - margin_px) & (uv[:, 1] < self.height - 0.5 + margin_px))

    # ------------------------------------------------------------------ per-pixel rays and maps
    @cached_property
    def _pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        vv, uu = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        xy, ok = self._undistorter.rays(np.stack([uu.ravel(), vv.ravel()], axis=1))
        xy = xy.reshape(self.height, self.width, 2)
        xy.setflags(write=False)
        ok = ok.reshape(self.height, self.width)
        ok.setflags(write=False)
        return xy, ok

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Normalised ray ``(x, y)`` (ray direction ``(x, y, 1)``) through every pixel centre.

        Computed once per camera (Newton's method, ~0.1 s for a DAVIS346). Returns ``(xy (H, W, 2) float64,
        valid (H, W) bool)``; a pixel is valid exactly when it has a ray: some ``(x, y)`` with radius within
        :attr:`r_max` distorts onto its centre (to 1e-6 px). Invalid pixels hold NaN. The arrays are read-only.
        """
        return self._pixel_rays

    def undistortion_maps(self, K_new: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` maps (two (H, W) float32, pixels) from the undistorted image (intrinsics ``K_new``,
        default ``K``) to this camera's distorted image; cached per ``K_new``.

        The same maps as ``cv2.initUndistortRectifyMap`` (each output pixel's ray distorted forward), except
        that rays beyond :attr:`r_max` map to -1 (outside: ``remap`` fills them with the border value) instead
        of onto the folded-back part of the image."""
        K_new = self.K if K_new is None else np.asarray(K_new, dtype=np.float64)
        key = K_new.tobytes()
        if key not in self._maps:
            vv, uu = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
            h = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], axis=1) @ np.linalg.inv(K_new).T
            xy = h[:, :2] / h[:, 2:3]
            ok = np.einsum("ij,ij->i", xy, xy) <= self.r_max ** 2
            uv = np.full_like(xy, -1.0)
            uv[ok] = self.distort_normalized(xy[ok])
            uv = uv.astype(np.float32).reshape(self.height, self.width, 2)
            self._maps[key] = (np.ascontiguousarray(uv[..., 0]), np.ascontiguousarray(uv[..., 1]))
        return self._maps[key]

    def undistort_image(self, image: np.ndarray, K_new: np.ndarray | None = None,
                        interpolation: int = cv2.INTER_NEAREST) -> np.ndarray:
        """Resample a distorted image (events, masks) into the undistorted camera ``K_new``."""
        if not self.has_distortion and (K_new is None or np.array_equal(K_new, self.K)):
            return image.copy()
        map1, map2 = self.undistortion_maps(K_new)
        return cv2.remap(image, map1, map2, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def undistorted(self, K_new: np.ndarray | None = None) -> "CameraModel":
        """The ideal pinhole camera the undistorted images belong to."""
        return CameraModel(self.K if K_new is None else K_new, (), self.width, self.height,
                           near_m=self.near_m, source=f"{self.source} (undistorted)")
