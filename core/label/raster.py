"""Z-buffered triangle rasterisation of posed meshes in the *distorted* camera image.

Every pixel centre ``(u, v)`` (integer coordinates, DESIGN section 3) has a ray ``(x_n, y_n, 1)``
in the camera frame, from :meth:`CameraModel.pixel_rays` (undistortion of the pixel centre). A
pixel is covered by a triangle exactly when its ray hits the triangle, i.e. when ``(x_n, y_n)``
lies inside the triangle projected to the normalised plane ``z = 1`` (points ``(x/z, y/z)``:
a triangle in front of the camera keeps straight edges there). This is what a ray caster
computes, so masks line up with raw (distorted) event frames, and occlusion between objects is
exact: the nearest surface along each pixel-centre ray wins.

Algorithm (vectorised; Python loops only over meshes and a few triangle classes)
--------------------------------------------------------------------------------
1. Meshes outside the view frustum (the cone of valid pixel rays beyond the near plane) are
   culled: :meth:`Rasterizer.render_objects` tests the 8 corners of the model's bounding box
   before transforming anything; every mesh is also culled when its distorted vertices lie
   off the image by more than the distortion bend bound.
2. Vertices are projected to the normalised plane and distorted to pixels (the OpenCV model
   evaluated in numpy, same formula as ``cv2.projectPoints``, ~30x faster). Each vertex gets
   the integer range ``[ceil(u - m0), floor(u + m0)]`` (same for ``v``) packed in four 16-bit
   lanes of a uint64, so one gather and one lane-wise minimum per vertex of a triangle give its
   candidate pixel box, and one addition gives both box sizes.
3. Most triangles of dense meshes are smaller than a pixel: their box holds no pixel centre
   (dropped: 61 % of the 147k triangles of nine_hole_peg + wrench + mustard_bottle at
   0.36-0.55 m) or exactly one (24 %), two or a 2 x 2 block: those pixels are the
   candidates, taken straight from the integer boxes. Larger boxes are recomputed with the margin
   ``c * (du^2 + dv^2)`` pixels for a box of ``du x dv`` pixels, ``c`` measured per camera
   from the first and second derivatives of the distortion map (:func:`_distortion_bounds`):
   it bounds how far distortion bends a straight edge, so no covered pixel is missed. ``m0``
   is that bound for boxes of at most 2 x 2 pixels.
4. Triangles with a vertex at or behind the near plane (``z <= near_m``) are clipped against
   it (never dropped, never projected from behind); they and triangles reaching outside the
   disc where the distortion is well conditioned take a *tile path*: the image is cut into
   16 x 16 tiles whose exact normalised-ray bounding boxes are precomputed, a separating-axis
   test in the normalised plane finds the tiles a triangle may cover, tiles entirely inside
   are filled without per-pixel edge tests, the others are tested pixel by pixel.
5. Candidates of all meshes are tested together, one batch per candidate layout (1, 2, 4, 6
   or 9 pixels per triangle): an edge-function test in normalised coordinates (float32,
   relative to the triangle's first vertex) and, if covered, the depth from barycentric
   interpolation of ``1/z`` (exact for a plane). The z-buffer keeps, per pixel, the minimum
   of the uint64 key ``(float32 z bits << 32) | triangle id`` via ``np.minimum.at``: the
   nearest surface wins; exact depth ties go to the lower id (earlier mesh, lower face).
   Triangles whose box is longer than 3 pixels (coarse meshes: procedural boxes, CAD with
   long faces) test every pixel of their box against edge coefficients computed once per
   triangle and repeated to its pixels (:meth:`Rasterizer._eval_boxes`), same test and result.

Tie rule: triangles are *closed* (``>= 0`` edge tests), so a pixel centre exactly on an edge
shared by two triangles of a mesh is covered (the z-buffer picks one of them); there is no
strict top-left rule, so a centre within float32 rounding (~1e-5 px) of an edge may be decided
either way, as in a float32 ray caster. Triangles with zero area in the normalised plane
(degenerate, or seen exactly edge-on) cover nothing. Pixels whose ray is invalid (undistortion
fold-back) get nothing.

Accuracy: coverage is decided at the pixel-centre ray, so masks agree with open3d's
``RaycastingScene`` except for pixels within float32 rounding of an edge (where open3d itself
errs: 0-1 pixel per test scene); depth agrees to ~1e-7 m on real meshes (float32 keys; down to
~1e-4 relative on extreme grazing slivers, like open3d).

Threads: a :class:`Rasterizer` may be shared; per-render state is local and the caches are
locked. On the 2-core development machine threads gave no speed-up (the cores do not run
numpy in parallel), so rendering is single-threaded.

Units: metres for vertices and depths, camera frame with OpenCV axes (x right, y down,
z forward); images are ``(H, W)`` indexed ``[v, u]``.
"""
from __future__ import annotations

import sys
import threading
import time
import weakref
from dataclasses import dataclass
from typing import NamedTuple, Sequence

import numpy as np

from evpose.core.data.camera import CameraModel
from evpose.core.data.objects import ObjectModel
from evpose.core.label import raster_kernels as _kern
from evpose.core.data.mesh_closure import cached_cull_sign

__all__ = ["RasterResult", "Rasterizer", "warm_up"]

_EMPTY_KEY = np.uint64(0xFFFFFFFFFFFFFFFF)
_LITTLE_ENDIAN = sys.byteorder == "little"
#: Pixels added to every candidate box on top of the distortion bound: covers the 1e-4 px
#: round-trip tolerance of :meth:`CameraModel.pixel_rays` and float32 rounding of ``(u, v)``.
_EPS_PX = 2e-3
#: Tile edge in pixels for the tile path.
_TILE = 16
#: Number of (triangle, tile) tests per chunk in the tile path (memory bound).
_TILE_CHUNK = 1 << 20
#: Largest number of (triangle, pixel) pairs tested in one batch (memory bound, ~100 MB).
_PAIR_CHUNK = 1 << 21
#: Offset of the 16-bit packed pixel boxes (see :meth:`Rasterizer._vertex_stage`): pixel
#: coordinates handled by the fast path must lie in ``(-_BOX_OFF, _BOX_OFF)``.
_BOX_OFF = 16384
_LANE_MASK = np.uint64(0x80008000)      # bit 15 of both lanes of the packed box sizes
_U64_LOW32 = np.uint64(0xFFFFFFFF)
_SHIFT32 = np.uint64(32)
_NO_MASK = np.zeros(0, dtype=bool)          # kernel argument: depth mode
_NO_ZBUF = np.zeros(0, dtype=np.uint64)     # kernel argument: mask mode
_NO_FACE = np.zeros(0, dtype=np.int32)      # kernel argument: no face index wanted
#: Below this many triangles in a render, extra threads cost more (hand-off, a z-buffer each, the merge:
#: ~0.1 ms) than they save (~10 ns per triangle).
_PARALLEL_MIN_FACES = 20_000


#: Bytes of derived mesh arrays kept by :data:`MESH_ARRAYS` (5 YCB meshes, raster-friendly: ~8 MB).
MESH_CACHE_BYTES = 48 << 20


class MeshArrayCache:
    """Arrays derived from read-only mesh arrays (transposed faces, homogeneous float32 vertices), by kind and the
    source array's identity while it lives, least recently used first out beyond ``max_bytes``.

    One instance (:data:`MESH_ARRAYS`) serves every :class:`Rasterizer` of the process: the app's views each have
    an annotator of the same scene meshes (the frame, the space-time slices, the kymograph, the residual sweep),
    and the derived arrays depend on the mesh only, not on the camera. An entry goes when its source array is
    freed (weak reference), so a closed scene's arrays are not kept. Thread-safe."""

    def __init__(self, max_bytes: int = MESH_CACHE_BYTES):
        self.max_bytes = int(max_bytes)
        self._items: dict = {}          # (kind, id(arr)) -> (weakref, value, nbytes), insertion = recency order
        self._lock = threading.RLock()  # a weakref callback may run inside a locked section (gc on allocation)
        self.nbytes = 0

    def __len__(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self.nbytes = 0

    def _drop(self, key, ref=None) -> None:
        with self._lock:
            item = self._items.get(key)
            if item is not None and (ref is None or item[0] is ref):
                del self._items[key]
                self.nbytes -= item[2]

    def get(self, arr: np.ndarray, kind: str, make):
        """``make(arr)``, from the cache when ``arr`` is read-only and weak-referenceable, else computed."""
        if arr.flags.writeable:
            return make(arr)
        key = (kind, id(arr))
        with self._lock:
            hit = self._items.get(key)
            if hit is not None and hit[0]() is arr:
                self._items[key] = self._items.pop(key)          # most recently used
                return hit[1]
        val = make(arr)
        try:
            ref = weakref.ref(arr, lambda r, key=key: self._drop(key, r))
        except TypeError:                       # not weak-referenceable: do not cache
            return val
        nb = _derived_nbytes(val)
        if nb > self.max_bytes:
            return val
        with self._lock:
            self._drop(key)
            self._items[key] = (ref, val, nb)
            self.nbytes += nb
            while self.nbytes > self.max_bytes:
                self._drop(next(iter(self._items)))
        return val


def _derived_nbytes(val) -> int:
    if isinstance(val, np.ndarray):
        return int(val.nbytes)
    if isinstance(val, tuple):
        return sum(_derived_nbytes(v) for v in val)
    return 0


#: The process's one :class:`MeshArrayCache`.
MESH_ARRAYS = MeshArrayCache()


# ---------------------------------------------------------------------------- result
@dataclass
class RasterResult:
    """Per-pixel output of :meth:`Rasterizer.render` (distorted image, ``[v, u]`` indexing).

    Attributes
    ----------
    depth_m : (H, W) float32
        Camera-frame ``z`` in metres of the nearest surface along the pixel-centre ray;
        ``np.inf`` where nothing is hit.
    obj_index : (H, W) int16
        Index of the winning mesh in the sequence given to the renderer; ``-1`` where empty.
    face_index : (H, W) int32 or None
        Index of the winning face within that mesh; ``-1`` where empty. ``None`` unless
        ``want_faces`` was set.
    amodal : (n, H, W) bool or None
        Amodal (full) mask of each mesh, as if it were alone in the scene (the same as
        :meth:`Rasterizer.full_masks`), from the same pass as the z-buffer. ``None`` unless
        ``want_amodal`` was set.
    """

    depth_m: np.ndarray
    obj_index: np.ndarray
    face_index: np.ndarray | None = None
    amodal: np.ndarray | None = None

    def mask(self, k: int) -> np.ndarray:
        """Visible (modal) mask of mesh ``k``: bool ``(H, W)``."""
        return self.obj_index == k

    def visible_pixel_counts(self, n: int) -> np.ndarray:
        """Number of visible pixels of each of the ``n`` meshes: int64 ``(n,)``."""
        idx = self.obj_index[self.obj_index >= 0].astype(np.intp)
        return np.bincount(idx, minlength=n)[:n].astype(np.int64)


# ---------------------------------------------------------------------------- distortion
def _distort_fn(camera: CameraModel):
    """Return ``f(x, y) -> (u, v)``: normalised coordinates to distorted pixels (float64).

    The formula of ``cv2.projectPoints`` (like it, uses ``fx, fy, cx, cy`` of ``K`` and no
    skew), about 20 times faster than it for tens of thousands of points. Falls back to OpenCV
    for the tilted-sensor model (coefficients 13 and 14 non-zero).
    """
    K = camera.K
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    k = np.zeros(14)
    k[: len(camera.dist)] = camera.dist
    if k[12] != 0 or k[13] != 0:
        def f_cv(x, y):
            x = np.asarray(x, dtype=np.float64)
            uv = camera.distort_normalized(np.stack([x.ravel(), np.asarray(y, np.float64).ravel()], axis=1))
            return uv[:, 0].reshape(x.shape), uv[:, 1].reshape(x.shape)
        return f_cv
    if not np.any(k):
        def f_pinhole(x, y):
            return x * fx + cx, y * fy + cy
        return f_pinhole
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = (float(c) for c in k[:12])
    rational = bool(k4 or k5 or k6)
    prism = bool(s1 or s2 or s3 or s4)

    def f(x, y):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        if rational:
            radial = radial / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xy2 = 2.0 * x * y
        xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
        if prism:
            r4 = r2 * r2
            xd = xd + s1 * r2 + s2 * r4
            yd = yd + s3 * r2 + s4 * r4
        return xd * fx + cx, yd * fy + cy

    return f


def _distort32_fn(camera: CameraModel, fallback):
    """Return ``f(x, y, r2) -> (u, v)``: the OpenCV distortion of :func:`_distort_fn` on float32
    arrays with few temporaries (``r2 = x^2 + y^2`` is passed in). Falls back to ``fallback``
    for the tilted-sensor model."""
    K = camera.K
    f32 = np.float32
    fx, fy, cx, cy = f32(K[0, 0]), f32(K[1, 1]), f32(K[0, 2]), f32(K[1, 2])
    k = np.zeros(14)
    k[: len(camera.dist)] = camera.dist
    if k[12] != 0 or k[13] != 0:
        return lambda x, y, r2: tuple(np.asarray(a, np.float32) for a in fallback(x, y))
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = (f32(c) for c in k[:12])
    radial_on = bool(k1 or k2 or k3)
    rational = bool(k4 or k5 or k6)
    tangential = bool(p1 or p2)
    prism = bool(s1 or s2 or s3 or s4)

    def f(x, y, r2):
        if radial_on or rational:
            rad = k3 * r2
            rad += k2
            rad *= r2
            rad += k1
            rad *= r2
            rad += f32(1.0)
            if rational:
                den = k6 * r2
                den += k5
                den *= r2
                den += k4
                den *= r2
                den += f32(1.0)
                rad /= den
            u = x * rad
            v = y * rad
        else:
            u, v = x.copy(), y.copy()
        if tangential:
            xy2 = x * y
            xy2 *= f32(2.0)
            t = x * x                           # u += 2 p1 x y + p2 (r2 + 2 x^2)
            t *= f32(2.0)
            t += r2
            t *= p2
            u += t
            u += p1 * xy2
            np.multiply(y, y, out=t)            # v += p1 (r2 + 2 y^2) + 2 p2 x y
            t *= f32(2.0)
            t += r2
            t *= p1
            v += t
            v += p2 * xy2
        if prism:
            r4 = r2 * r2
            u += s1 * r2 + s2 * r4
            v += s3 * r2 + s4 * r4
        u *= fx
        u += cx
        v *= fy
        v += cy
        return u, v

    return f


def _kernel_distortion(camera: CameraModel):
    """Parameters of :func:`raster_kernels.vertex_stage` for ``camera``: float32 ``(16,)``
    ``k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, fx, fy, cx, cy`` and bool ``(4,)`` flags (radial,
    rational, tangential, thin prism), as :func:`_distort32_fn` uses them; None for the tilted-sensor
    model (the numpy vertex stage then runs)."""
    k = np.zeros(14)
    k[: len(camera.dist)] = camera.dist
    if k[12] != 0 or k[13] != 0:
        return None
    K = camera.K
    prm = np.array(list(k[:12]) + [K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dtype=np.float32)
    flags = np.array([np.any(k[[0, 1, 4]] != 0), np.any(k[5:8] != 0), np.any(k[2:4] != 0),
                      np.any(k[8:12] != 0)], dtype=bool)
    return prm, flags


def _distortion_bounds(distort, fx: float, fy: float, r_lim: float) -> tuple[float, float]:
    """Derivative bounds of the distortion map ``D`` (normalised -> pixels) on ``|p| <= r_lim``.

    Returns
    -------
    M2 : float
        Bound on ``|D''(p)[w, w]| / |w|^2`` in pixels per squared normalised unit (the spectral
        norms of the two Hessians combined), so a straight segment ``a -> b`` in the normalised
        plane maps to a curve within ``M2 |b - a|^2 / 8`` pixels of its chord.
    s : float
        Smallest eigenvalue of the symmetric part of the dimensionless Jacobian
        ``diag(1/fx, 1/fy) D'``; then ``|D(b) - D(a)| >= min(fx, fy) s |b - a|`` for any
        segment inside the disc (the mean Jacobian along it has the same lower bound).

    Both are evaluated by finite differences on a polar grid including the rim, with safety
    factors (1.25 on ``M2``, 0.9 on ``s``) for the grid spacing.
    """
    r = np.linspace(0.0, r_lim, 96)
    a = np.linspace(0.0, 2 * np.pi, 192, endpoint=False)
    R, A = np.meshgrid(r, a)
    x = (R * np.cos(A)).ravel()
    y = (R * np.sin(A)).ravel()
    h1 = 1e-6
    h2 = 1e-4

    def D(px, py):
        u, v = distort(px, py)
        return np.stack([np.asarray(u, np.float64), np.asarray(v, np.float64)])

    jx = (D(x + h1, y) - D(x - h1, y)) / (2 * h1)
    jy = (D(x, y + h1) - D(x, y - h1)) / (2 * h1)
    a11, a12, a21, a22 = jx[0] / fx, jy[0] / fx, jx[1] / fy, jy[1] / fy
    sym = (a12 + a21) / 2
    lam_min = (a11 + a22) / 2 - np.sqrt(((a11 - a22) / 2) ** 2 + sym**2)
    d0 = D(x, y)
    dxx = (D(x + h2, y) - 2 * d0 + D(x - h2, y)) / h2**2
    dyy = (D(x, y + h2) - 2 * d0 + D(x, y - h2)) / h2**2
    dxy = (D(x + h2, y + h2) - D(x + h2, y - h2) - D(x - h2, y + h2) + D(x - h2, y - h2)) / (4 * h2**2)
    hnorm = np.abs((dxx + dyy) / 2) + np.sqrt(((dxx - dyy) / 2) ** 2 + dxy**2)   # (2, N)
    M2 = float(np.sqrt((hnorm**2).sum(axis=0)).max()) * 1.25
    s = float(lam_min.min()) * 0.9
    return M2, s


# ---------------------------------------------------------------------------- helpers
# ---------------------------------------------------------------------------- helpers
_CORNER_BITS = np.array([[(i >> a) & 1 for a in range(3)] for i in range(8)], dtype=bool)


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The 8 corners ``(8, 3)`` of the axis-aligned box ``[lo, hi]``."""
    return np.where(_CORNER_BITS, hi, lo)


def _clip_near(P: np.ndarray, near: float) -> tuple[np.ndarray, np.ndarray]:
    """Clip triangles against the plane ``z = near`` keeping the part with ``z >= near``.

    Parameters
    ----------
    P : (n, 3, 3) float64
        Triangle vertices in the camera frame (metres), ``P[i, j]`` vertex ``j`` of triangle i.

    Returns
    -------
    tris : (m, 3, 3) float64
        Clipped triangles (a triangle with two vertices in front becomes two triangles).
    src : (m,) intp
        Index into ``P`` of the triangle each output came from. Triangles entirely at or
        behind the plane produce nothing.
    """
    s = P[:, :, 2] - near                      # signed distance to the plane
    inside = s > 0
    n_in = inside.sum(axis=1)
    out_t, out_src = [], []
    keep3 = np.flatnonzero(n_in == 3)
    if len(keep3):
        out_t.append(P[keep3])
        out_src.append(keep3)
    for count in (1, 2):
        idx = np.flatnonzero(n_in == count)
        if not len(idx):
            continue
        # roll the vertices so that vertex 0 is the lone inside (count 1) or lone outside (count 2)
        lone = inside[idx] if count == 1 else ~inside[idx]
        r = np.argmax(lone, axis=1)
        order = (r[:, None] + np.arange(3)[None, :]) % 3
        Q = P[idx[:, None], order]            # (k, 3, 3), winding preserved
        sq = s[idx[:, None], order]           # (k, 3)

        def cut(i, j):                        # point on edge i -> j at the plane
            t = sq[:, i] / (sq[:, i] - sq[:, j])
            p = Q[:, i] + t[:, None] * (Q[:, j] - Q[:, i])
            p[:, 2] = near                    # exact, avoids z = near - 1 ulp
            return p

        if count == 1:                        # vertex 0 in front: one smaller triangle
            out_t.append(np.stack([Q[:, 0], cut(0, 1), cut(0, 2)], axis=1))
            out_src.append(idx)
        else:                                 # vertex 0 behind: quad (p01, 1, 2, p20) -> 2 triangles
            p01, p20 = cut(1, 0), cut(2, 0)
            out_t.append(np.stack([p01, Q[:, 1], Q[:, 2]], axis=1))
            out_t.append(np.stack([p01, Q[:, 2], p20], axis=1))
            out_src += [idx, idx]
    if not out_t:
        return np.zeros((0, 3, 3)), np.zeros(0, dtype=np.intp)
    return np.concatenate(out_t), np.concatenate(out_src)


def _tile_rows(tris: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-triangle coefficients of the tile path (origin-referenced, unit edges).

    Parameters
    ----------
    tris : (n, 3, 3) float64
        Vertices in the camera frame (metres), all with ``z >= near``.
    q : (n, 3, 2) float64
        The same vertices in the normalised plane ``(x/z, y/z)``; they may lie far outside the
        image (vertices close to the near plane).

    Returns
    -------
    rows : (12, n) float64
        ``A0, B0, C0, A1, B1, C1, A2, B2, C2, R, P, Q``: edge functions
        ``E_i = A_i x + B_i y + C_i`` of the pixel ray ``(x, y)``, scaled to signed distances
        (normalised units, positive inside) so that float32 evaluates them accurately near the
        image, and the inverse depth ``1/z = R + P x + Q y`` (the triangle's plane, 1/metres;
        evaluated in float64: large, grazing triangles).
    keep : (n,) bool
        False for triangles of zero area in the normalised plane (they cover nothing).
    """
    rows = np.empty((12, len(q)), dtype=np.float64)
    q0, q1, q2 = q[:, 0], q[:, 1], q[:, 2]
    for e, (qa, qb) in enumerate(((q0, q1), (q1, q2), (q2, q0))):
        A = qa[:, 1] - qb[:, 1]
        B = qb[:, 0] - qa[:, 0]
        rows[3 * e] = A
        rows[3 * e + 1] = B
        rows[3 * e + 2] = -(A * qa[:, 0] + B * qa[:, 1])
    area = rows[1] * (q2[:, 1] - q0[:, 1]) + rows[0] * (q2[:, 0] - q0[:, 0])
    P0, P1, P2 = tris[:, 0], tris[:, 1], tris[:, 2]
    n = np.cross(P1 - P0, P2 - P0)
    d = np.einsum("ij,ij->i", n, P0)                  # plane n . p = d; d = 0 through the camera
    keep = (area != 0) & (d != 0) & np.isfinite(area)
    sign = np.where(area > 0, 1.0, -1.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for e in range(3):
            norm = np.hypot(rows[3 * e], rows[3 * e + 1])
            rows[3 * e: 3 * e + 3] *= sign / np.where(norm > 0, norm, 1.0)
        inv_d = 1.0 / np.where(d != 0, d, 1.0)
        rows[9] = n[:, 2] * inv_d
        rows[10] = n[:, 0] * inv_d
        rows[11] = n[:, 1] * inv_d
    return rows, keep


# ---------------------------------------------------------------------------- rasteriser
def _edge_coefficients(xy: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Edge functions of the triangles ``idx`` ((3, n) vertex indices into ``xy``, complex64
    normalised coordinates): float32 ``(7, n)`` rows ``ax, ay, C0, C1, C2, C3, |S|`` with
    ``E0 = C0 dx + C1 dy`` and ``E2 = C2 dx + C3 dy`` for ``d = p - a`` (see
    :meth:`Rasterizer._eval_tris`); ``|S| = -1`` for zero-area triangles (never inside)."""
    P3 = xy.take(idx)                                            # (3, n) complex64
    X3, Y3 = P3.real, P3.imag
    coef = np.empty((7, idx.shape[1]), dtype=np.float32)
    coef[0] = X3[0]
    coef[1] = Y3[0]
    np.subtract(Y3[0], Y3[1], out=coef[2])
    np.subtract(X3[1], X3[0], out=coef[3])
    np.subtract(Y3[2], Y3[0], out=coef[4])
    np.subtract(X3[0], X3[2], out=coef[5])
    area = coef[3] * coef[4]
    area -= coef[2] * coef[5]
    coef[2:6] *= np.sign(area)
    aa = np.abs(area)
    aa[area == 0] = -1.0
    coef[6] = aa
    return coef


def _edge_test(D: np.ndarray, coef: np.ndarray):
    """``(E0, E2, inside)`` of pixel rays ``D`` (complex64) against edge coefficients whose rows
    broadcast against ``D``: inside the closed triangle iff ``E0 >= 0``, ``E2 >= 0`` and
    ``E0 + E2 <= |S|``."""
    dx = D.real - coef[0]
    dy = D.imag - coef[1]
    e0 = coef[2] * dx
    e0 += coef[3] * dy
    e2 = coef[4] * dx
    e2 += coef[5] * dy
    ins = e0 >= 0
    ins &= e2 >= 0
    s = e0 + e2
    ins &= s <= coef[6]
    return e0, e2, ins


def _depth_keys(iz, idx, ti, p, e0, e2, aa):
    """z-buffer keys ``float32(z) bits << 32`` of covered pairs: ``1/z`` interpolated with the
    barycentric weights ``e2 / |S|`` (vertex b) and ``e0 / |S|`` (vertex c); pairs with
    ``1/z <= 0`` are dropped. ``e0`` and ``e2`` are overwritten. Returns ``(ti, p, key)``."""
    I3 = iz.take(idx.take(ti, axis=1))                          # (3, m)
    w_b = e2
    w_b *= I3[1] - I3[0]
    w_c = e0
    w_c *= I3[2] - I3[0]
    w_b += w_c
    w_b /= aa
    w_b += I3[0]                                                 # 1/z
    pos = w_b > 0
    if not pos.all():
        ti, p, w_b = ti[pos], p[pos], w_b[pos]
    key = (np.float32(1.0) / w_b).view(np.uint32).astype(np.uint64) << _SHIFT32
    return ti, p, key


class _VertexStage(NamedTuple):
    """Per-vertex data of one mesh (see :meth:`Rasterizer._vertex_stage`)."""

    V: np.ndarray            #: (N, 3) float32 or float64 vertices, camera frame, metres
    FT: np.ndarray           #: (3, F) intp faces
    u: np.ndarray            #: (N,) distorted pixel column
    v: np.ndarray            #: (N,) distorted pixel row
    rec: np.ndarray          #: (N,) uint64 packed integer boxes
    bad: np.ndarray | None   #: (N,) bool, vertex outside the fast path (None: all fine)
    xy: np.ndarray | None = None   #: (N,) complex64 normalised ``x/z + i y/z`` (numpy path)


class Rasterizer:
    """Z-buffered rasteriser for one camera (distorted image, exact pixel-centre rays).

    Parameters
    ----------
    camera : CameraModel
        Intrinsics, distortion, sensor size and near plane. Per-camera data (pixel rays, tile
        boxes, distortion bounds) are computed once here (about 0.1 s for a DAVIS346).
    backend : {"auto", "numba", "numpy"}
        ``"numba"``: the compiled kernels of :mod:`raster_kernels` for the vertex stage, the
        candidate boxes, pixel tests, z-buffer and decoding (~5x faster); ``"numpy"``: the
        vectorised numpy pipeline described above. Both give identical results. ``"auto"``
        (default) takes numba when it can be imported.
    threads : int
        Threads the compiled pipeline may use per render (default 1: the calling thread only). With
        more, the meshes are split into groups of about equal triangle counts, each rasterised into a
        z-buffer of its own by a thread of a shared pool (the kernels release the GIL), then the buffers
        are merged by their minimum key: the same result as one thread, whatever the split. Worth it
        where a core is otherwise idle (the app's frame worker), not in export workers that already
        fill every core.

    Attributes
    ----------
    timings : dict[str, float]
        Seconds accumulated per stage over all renders (profiling aid; clear it freely).
    r_lim : float
        Radius of the disc of the normalised plane handled by the fast path.
    """

    def __init__(self, camera: CameraModel, backend: str = "auto", threads: int = 1):
        if backend not in ("auto", "numba", "numpy"):
            raise ValueError(f"backend must be 'auto', 'numba' or 'numpy', got {backend!r}")
        if backend == "numba" and not _kern.HAVE_NUMBA:
            raise ValueError("backend 'numba': numba cannot be imported")
        #: "numba" or "numpy": the pipeline :meth:`render` runs
        self.backend = "numba" if backend != "numpy" and _kern.HAVE_NUMBA else "numpy"
        #: threads of the compiled pipeline per render (see the class docstring)
        self.threads = max(1, int(threads))
        self.camera = camera
        W, H = camera.width, camera.height
        self.width, self.height = W, H
        self.near_m = camera.near_m
        xy, valid = camera.pixel_rays()
        # pixel rays, flat, plus one dummy NaN pixel at index H*W (padding: never covered)
        X = np.full(H * W + 1, np.nan, dtype=np.float32)
        Y = np.full(H * W + 1, np.nan, dtype=np.float32)
        X[:-1] = np.where(valid, xy[..., 0], np.nan).ravel()
        Y[:-1] = np.where(valid, xy[..., 1], np.nan).ravel()
        self._X, self._Y = X, Y
        self._X64 = np.append(np.where(valid, xy[..., 0], np.nan).ravel(), np.nan)   # tile-path depth
        self._Y64 = np.append(np.where(valid, xy[..., 1], np.nan).ravel(), np.nan)
        self._XY = (X + 1j * Y).astype(np.complex64)         # both in one 8-byte gather
        self._ray = self._XY.view(np.float32)                # the same, interleaved (kernels)
        self._kparams = _kernel_distortion(camera)
        self._any_valid = bool(valid.any())
        if self._any_valid:
            xs, ys = xy[..., 0][valid], xy[..., 1][valid]
            #: normalised bounding box of all valid rays (the frustum): xmin, xmax, ymin, ymax
            self._frustum = (float(xs.min()), float(xs.max()), float(ys.min()), float(ys.max()))
            r_valid = float(np.sqrt(xs**2 + ys**2).max())
        else:
            self._frustum = (0.0, 0.0, 0.0, 0.0)
            r_valid = 1.0
        #: float32 box of the valid rays widened by 1e-4 (~0.03 px): a triangle in front of the near plane
        #: whose normalised bounding box misses it covers no pixel (tile-path faces are dropped by it)
        fx32, fy32 = X[np.isfinite(X)], Y[np.isfinite(Y)]
        m = 1e-4
        self._fbox32 = (np.array([fx32.min() - m, fx32.max() + m, fy32.min() - m, fy32.max() + m], dtype=np.float32)
                        if len(fx32) else np.zeros(4, dtype=np.float32))
        self._distort = _distort_fn(camera)
        self._distort32 = _distort32_fn(camera, self._distort)
        self._setup_disc(r_valid)
        self._setup_tiles()
        #: pixel offsets of candidate blocks (rows x columns), as (k, 1) columns
        self._offsets = {s: (np.arange(s)[:, None] * W + np.arange(s)[None, :]).reshape(-1, 1) for s in (2, 3)}
        self._offsets["3x2"] = (np.arange(2)[:, None] * W + np.arange(3)[None, :]).reshape(-1, 1)
        self._offsets["2x3"] = (np.arange(3)[:, None] * W + np.arange(2)[None, :]).reshape(-1, 1)
        #: the derived mesh arrays, shared by every rasteriser of the process (:class:`MeshArrayCache`)
        self._cache = MESH_ARRAYS
        self.timings: dict[str, float] = {}
        self._timings_lock = threading.Lock()

    # ------------------------------------------------------------------ per-camera setup
    def _setup_disc(self, r_valid: float) -> None:
        """Choose the disc ``|p| <= r_lim`` of the normalised plane handled by the fast path and
        the margin constants ``c`` and ``m0`` (pixels) that make its candidate boxes safe."""
        cam = self.camera
        if max(self.width, self.height) >= _BOX_OFF // 2:
            raise ValueError(f"{cam.source}: sensors wider than {_BOX_OFF // 2} pixels are not supported")
        fx, fy = float(cam.K[0, 0]), float(cam.K[1, 1])
        # just beyond the image corners: the bend bound c grows quickly with the radius
        r_lim = 1.02 * r_valid
        if not cam.has_distortion:               # nothing bends: only the packed range limits
            r_lim = max(r_lim, 0.9 * (_BOX_OFF / 2 - 2 * max(self.width, self.height)) / max(fx, fy))
        if np.isfinite(cam.r_max):
            r_lim = min(r_lim, 0.98 * cam.r_max)
        ang = np.linspace(0.0, 2 * np.pi, 721)
        while True:
            if cam.has_distortion:
                M2, s = _distortion_bounds(self._distort, fx, fy, r_lim)
            else:
                M2, s = 0.0, 1.0
            rr = np.linspace(0.0, r_lim, 33)[:, None]
            u, v = self._distort(rr * np.cos(ang), rr * np.sin(ang))
            reach = max(float(np.abs(u).max()), float(np.abs(v).max()))
            # well conditioned, and every reachable pixel coordinate fits the packed boxes
            if (s >= 0.25 and reach < _BOX_OFF / 2) or r_lim < 1e-3:
                break
            r_lim *= 0.93
        if s <= 0:                               # pathological: everything takes the tile path
            r_lim, M2, s = 0.0, 0.0, 1.0
        self.r_lim = float(r_lim)
        #: distortion bend bound: a box of du x dv pixels needs a margin of c (du^2 + dv^2) px
        self._c = M2 / (8.0 * (min(fx, fy) * s) ** 2)
        #: margin valid for every box of at most 2 x 2 pixels (then both extents are < 3 px)
        self._m0 = 18.0 * self._c + _EPS_PX

    def _setup_tiles(self) -> None:
        """Tiles of ``_TILE x _TILE`` pixels: flat pixel indices (padded with the dummy pixel)
        and the exact normalised bounding box of their valid rays."""
        H, W, T = self.height, self.width, _TILE
        nty, ntx = -(-H // T), -(-W // T)
        pad_idx = np.full((nty * T, ntx * T), H * W, dtype=np.intp)
        pad_idx[:H, :W] = np.arange(H * W).reshape(H, W)
        tiles = pad_idx.reshape(nty, T, ntx, T).transpose(0, 2, 1, 3).reshape(nty * ntx, T * T)
        X, Y = self._X[tiles], self._Y[tiles]
        ok = np.isfinite(X).any(axis=1)
        box = np.stack([np.nanmin(X[ok], axis=1), np.nanmax(X[ok], axis=1),
                        np.nanmin(Y[ok], axis=1), np.nanmax(Y[ok], axis=1)], axis=1).astype(np.float64)
        self._tile_pix = np.ascontiguousarray(tiles[ok].T)   # (T*T, n_tiles)
        self._tile_box = box                                 # (n_tiles, 4): xmin, xmax, ymin, ymax

    # ------------------------------------------------------------------ public API
    def render(self, meshes: Sequence[tuple[np.ndarray, np.ndarray]], *, want_faces: bool = False) -> RasterResult:
        """Rasterise meshes given in the camera frame.

        Parameters
        ----------
        meshes : sequence of (vertices_cam, faces)
            ``vertices_cam`` (V, 3) metres in the camera frame, ``faces`` (F, 3) int vertex
            indices. The mesh's position in the sequence is its value in ``obj_index``.
        want_faces : bool
            Also return the per-pixel face index.

        Returns
        -------
        RasterResult

        Raises
        ------
        ValueError
            Bad shapes, face indices out of range, non-finite vertices.
        """
        checked = [self._check_mesh(V, F, k) for k, (V, F) in enumerate(meshes)]
        return self._render(checked, want_faces)

    def render_objects(self, models, T_cam_obj, *, want_faces: bool = False,
                       want_amodal: bool = False) -> RasterResult:
        """Rasterise object models posed by ``T_cam_obj``.

        Parameters
        ----------
        models : sequence of ObjectModel
        T_cam_obj : sequence of (4, 4) float
            Pose of each model: object frame -> camera frame (metres).
        want_faces : bool
            Also return the per-pixel face index.
        want_amodal : bool
            Also return every object's amodal mask (``RasterResult.amodal``, equal to
            :meth:`full_masks`). The compiled pipeline fills them in the same pass as the
            z-buffer (one coverage store per covered pixel), instead of a second render.

        Models whose bounding box lies outside the view frustum are skipped before their
        vertices are transformed.
        """
        posed = self._posed(models, T_cam_obj)
        if want_amodal and self.backend != "numba":
            res = self._render(posed, want_faces)
            res.amodal = self._amodal(posed)
            return res
        return self._render(posed, want_faces, want_amodal)

    def full_mask(self, model, T_cam_obj) -> np.ndarray:
        """Amodal mask of one object (as if alone in the scene): bool ``(H, W)``."""
        return self.full_masks([model], [T_cam_obj])[0]

    def full_masks(self, models, T_cam_obj) -> list[np.ndarray]:
        """Amodal masks (each object alone, no occlusion; no depth computed): list of bool
        ``(H, W)`` in the order of ``models``."""
        return list(self._amodal(self._posed(models, T_cam_obj)))

    def _amodal(self, meshes) -> np.ndarray:
        """Amodal masks of posed meshes (see :meth:`_posed`): bool ``(n, H, W)``."""
        H, W = self.height, self.width
        bases = self._bases(meshes)
        masks = np.zeros((len(meshes), H * W + 1), dtype=bool)
        if self.backend == "numba":
            self._frame_compiled(meshes, bases, None, masks)
        else:
            for pix, gid in self._frame(meshes, bases, want_depth=False):
                k = np.searchsorted(bases, gid, side="right") - 1
                masks.ravel()[k * (H * W + 1) + pix] = True
        return masks[:, :-1].reshape(len(meshes), H, W)

    # ------------------------------------------------------------------ internals
    def _check_mesh(self, vertices, faces, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Validate one ``(vertices, faces)`` pair given to :meth:`render`."""
        V = np.asarray(vertices)
        if V.dtype != np.float32:
            V = V.astype(np.float64, copy=False)
        F = np.asarray(faces)
        if V.ndim != 2 or V.shape[1] != 3:
            raise ValueError(f"mesh {k}: vertices must be (V, 3), got shape {V.shape}")
        if F.size == 0:
            return V, np.zeros((0, 3), dtype=np.int32)
        if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
            raise ValueError(f"mesh {k}: faces must be an integer (F, 3) array, got shape {F.shape} {F.dtype}")
        _, fmin, fmax = self._faces_info(F)
        if fmin < 0 or fmax >= len(V):
            raise ValueError(f"mesh {k}: face index out of range [0, {len(V)})")
        if not np.isfinite(V).all():
            raise ValueError(f"mesh {k}: vertices contain NaN or inf")
        return V, F

    def _cached(self, arr: np.ndarray, kind: str, make):
        """``make(arr)``, cached per ``kind`` while ``arr`` lives if it is read-only (its content
        cannot change; :class:`ObjectModel` arrays are read-only), in :data:`MESH_ARRAYS`. Thread-safe."""
        return self._cache.get(arr, kind, make)

    def _all_front(self, vs: _VertexStage, zv: np.ndarray | None = None) -> bool:
        """Every vertex beyond the near plane (float32, as the vertex stage decides): then the camera is
        outside the mesh's convex hull and nothing is clipped, so back faces of a closed mesh can be culled."""
        if vs.bad is None:
            return True
        zv = np.asarray(vs.V[:, 2], dtype=np.float32) if zv is None else zv
        return bool(zv.min() > np.float32(self.near_m))

    @staticmethod
    def _cull_sign(V: np.ndarray, F: np.ndarray) -> int:
        """Back-face culling sign of a mesh (:func:`~evpose.core.data.mesh_closure.cached_cull_sign`):
        0 (no culling) for writable face arrays."""
        return cached_cull_sign(V, F)

    def _faces_info(self, F: np.ndarray) -> tuple[np.ndarray, int, int]:
        """Faces as a contiguous ``(3, F)`` intp array, with their min and max index."""
        def make(a):
            FT = np.ascontiguousarray(a.T, dtype=np.intp)
            return FT, int(FT.min()), int(FT.max())
        return self._cached(F, "faces", make)

    def _posed(self, models, T_cam_obj) -> list[tuple[np.ndarray | None, np.ndarray]]:
        """Transform visible models to the camera frame; culled ones become ``(None, faces)``."""
        if len(models) != len(T_cam_obj):
            raise ValueError(f"got {len(models)} models but {len(T_cam_obj)} poses")
        out = []
        for model, T in zip(models, T_cam_obj):
            T = np.asarray(T, dtype=np.float64)
            if T.shape != (4, 4):
                raise ValueError(f"T_cam_obj for {getattr(model, 'name', '?')}: expected 4x4, got {T.shape}")
            lo, hi = model.bbox_min_max
            corners = _box_corners(lo, hi) @ T[:3, :3].T + T[:3, 3]
            if not self._corners_visible(corners):
                out.append((None, model.faces))
                continue
            # homogeneous float32 copy of the vertices (cached): one BLAS call per pose, and
            # float32 is all the pipeline needs (3e-8 m at 0.5 m)
            V4 = self._cached(model.vertices_m, "hom32",
                              lambda a: np.hstack([a, np.ones((len(a), 1))]).astype(np.float32))
            out.append((V4 @ T[:3, :].T.astype(np.float32), model.faces))
        return out

    def _corners_visible(self, C: np.ndarray) -> bool:
        """False when the convex hull of the points ``C`` (camera frame, metres) misses the cone
        of valid pixel rays beyond the near plane (all on the outer side of one bounding plane)."""
        if not self._any_valid:
            return False
        xmin, xmax, ymin, ymax = self._frustum
        x, y, z = C[:, 0], C[:, 1], C[:, 2]
        return not ((z <= self.near_m).all() or (x - xmax * z > 0).all() or (xmin * z - x > 0).all()
                    or (y - ymax * z > 0).all() or (ymin * z - y > 0).all())

    def _acc(self, stage: str, dt: float) -> None:
        with self._timings_lock:                 # render threads of one call add to it at once
            self.timings[stage] = self.timings.get(stage, 0.0) + dt

    @staticmethod
    def _bases(meshes) -> np.ndarray:
        """Global id of the first triangle of each mesh, plus the total: int64 ``(n + 1,)``."""
        if len(meshes) > np.iinfo(np.int16).max:
            raise ValueError(f"at most {np.iinfo(np.int16).max} meshes per render call (obj_index is int16)")
        n_faces = np.array([len(F) for _, F in meshes], dtype=np.int64)
        bases = np.concatenate([[0], np.cumsum(n_faces)])
        if bases[-1] >= 2**32 - 1:
            raise ValueError("more than 2^32 - 2 triangles in one render call")
        return bases

    def _frame(self, meshes, bases: np.ndarray, want_depth: bool) -> list:
        """All covered (pixel, triangle) pairs of a frame: list of ``(pix, key)`` with ``key =
        float32(z) bits << 32 | global triangle id`` (``want_depth``), else ``(pix, gid)``.

        Vertex data of all meshes go to frame-wide arrays, so the pixel tests of each
        candidate class run once per frame, not once per mesh.
        """
        live = [(k, V, F) for k, (V, F) in enumerate(meshes) if V is not None and len(F)]
        if not live:
            return []
        n_v = sum(len(V) for _, V, _ in live)
        xy = np.empty(n_v, dtype=np.complex64)              # X/Z + i Y/Z of all vertices
        iz = np.empty(n_v, dtype=np.float32)                # 1/Z (1/metres)
        groups: dict[int, list] = {1: [], 2: [], 4: [], 6: [], 9: []}
        results: list = []

        def evaluate(idx, pix, gid, boxes=None):
            res = (self._eval_tris(xy, iz, idx, pix, want_depth) if boxes is None
                   else self._eval_boxes(xy, iz, idx, *boxes, want_depth))
            if res is not None:
                ti, p, key = res
                g = gid.take(ti)
                if want_depth:
                    key |= g.astype(np.uint64)
                    results.append((p, key))
                else:
                    results.append((p, g))

        voff = 0
        for k, V, F in live:
            vs = self._vertex_stage(V, F, xy[voff:voff + len(V)], iz[voff:voff + len(V)])
            if vs is not None:
                front = self._front_faces(xy[voff:voff + len(V)], vs.FT, V, F) if self._all_front(vs) else None
                self._triangle_stage(vs, voff, int(bases[k]), groups, results, evaluate, want_depth, front)
            voff += len(V)
        t0 = time.perf_counter()
        for items in groups.values():
            if len(items) == 1:
                evaluate(*items[0])
            elif items:
                evaluate(np.concatenate([it[0] for it in items], axis=1),
                         np.concatenate([it[1] for it in items], axis=1),
                         np.concatenate([it[2] for it in items]))
        self._acc("pixel tests", time.perf_counter() - t0)
        return results

    def _render(self, meshes, want_faces: bool, want_amodal: bool = False) -> RasterResult:
        H, W = self.height, self.width
        bases = self._bases(meshes)
        zbuf = np.full(H * W + 1, _EMPTY_KEY, dtype=np.uint64)
        if self.backend == "numba":
            masks = np.zeros((len(meshes), H * W + 1), dtype=bool) if want_amodal else None
            self._frame_compiled(meshes, bases, zbuf, masks)
            t0 = time.perf_counter()
            depth = np.full(H * W, np.inf, dtype=np.float32)
            obj = np.full(H * W, -1, dtype=np.int16)
            face = np.full(H * W, -1, dtype=np.int32) if want_faces else _NO_FACE
            _kern.decode(zbuf, bases, depth, obj, face)
            self._acc("decode", time.perf_counter() - t0)
            return RasterResult(depth.reshape(H, W), obj.reshape(H, W), face.reshape(H, W) if want_faces else None,
                                None if masks is None else masks[:, :-1].reshape(len(meshes), H, W))
        results = self._frame(meshes, bases, want_depth=True)
        t0 = time.perf_counter()
        for pix, key in results:
            np.minimum.at(zbuf, pix, key)
        self._acc("z-buffer", time.perf_counter() - t0)
        t0 = time.perf_counter()
        hit = np.flatnonzero(zbuf[:-1] != _EMPTY_KEY)
        kh = zbuf.take(hit)
        depth = np.full(H * W, np.inf, dtype=np.float32)
        depth[hit] = (kh >> _SHIFT32).astype(np.uint32).view(np.float32)
        gid = (kh & _U64_LOW32).astype(np.int64)
        o = np.searchsorted(bases, gid, side="right") - 1
        obj = np.full(H * W, -1, dtype=np.int16)
        obj[hit] = o
        face = None
        if want_faces:
            face = np.full(H * W, -1, dtype=np.int32)
            face[hit] = gid - bases.take(o)
            face = face.reshape(H, W)
        self._acc("decode", time.perf_counter() - t0)
        return RasterResult(depth.reshape(H, W), obj.reshape(H, W), face)

    # ------------------------------------------------------------------ compiled pipeline
    def _frame_compiled(self, meshes, bases: np.ndarray, zbuf: np.ndarray | None, masks: np.ndarray | None) -> None:
        """The numba pipeline: every live mesh's covered pixels go into ``zbuf`` (keys as in
        :meth:`_frame`) unless it is None, and into its row of ``masks`` (amodal, no depth test)
        unless that is None; both in the same pass when both are given. With :attr:`threads` > 1 the
        meshes are split into groups (:func:`_balanced_groups`) rasterised at once, each group but the
        first into a z-buffer of its own that is then merged into ``zbuf`` by the minimum key."""
        live = [k for k, (V, F) in enumerate(meshes) if V is not None and len(F)]
        n_faces = [len(meshes[k][1]) for k in live]
        if self.threads < 2 or len(live) < 2 or sum(n_faces) < _PARALLEL_MIN_FACES:
            self._meshes_compiled(meshes, live, bases, zbuf, masks)
            return
        groups = _balanced_groups(live, n_faces, self.threads)
        bufs = [None if zbuf is None else np.full_like(zbuf, _EMPTY_KEY) for _ in groups[1:]]
        pool = _raster_pool(self.threads - 1)
        futures = [pool.submit(self._meshes_compiled, meshes, g, bases, b, masks) for g, b in zip(groups[1:], bufs)]
        try:
            self._meshes_compiled(meshes, groups[0], bases, zbuf, masks)
        finally:
            for f in futures:
                f.result()
        t0 = time.perf_counter()
        if zbuf is not None:
            for b in bufs:
                np.minimum(zbuf, b, out=zbuf)
        self._acc("merge", time.perf_counter() - t0)

    def _meshes_compiled(self, meshes, ks, bases: np.ndarray, zbuf: np.ndarray | None,
                         masks: np.ndarray | None) -> None:
        """:meth:`_frame_compiled` for the meshes ``ks`` (indices into ``meshes``) in this thread."""
        W, H = self.width, self.height
        c_bend, eps = np.float32(self._c), np.float32(_EPS_PX)
        for k in ks:
            V, F = meshes[k]
            vs, xy, iz = self._vertex_stage_compiled(V, F)
            if vs is None:
                continue
            t0 = time.perf_counter()
            tile = np.empty(vs.FT.shape[1], dtype=np.intp)
            bad = vs.bad if vs.bad is not None else np.zeros(len(vs.u), dtype=bool)
            zv = np.ascontiguousarray(vs.V[:, 2], dtype=np.float32)
            near = np.float32(self.near_m)
            n_tile = _kern.raster_mesh(vs.FT, vs.rec.view(np.uint16), bad, vs.u, vs.v, xy, iz, self._ray, W, H,
                                       c_bend, eps, _BOX_OFF, np.uint64(bases[k]),
                                       _NO_ZBUF if zbuf is None else zbuf, _NO_MASK if masks is None else masks[k],
                                       tile, np.float32(self._cull_sign(V, F) if self._all_front(vs, zv) else 0),
                                       zv, near, self._fbox32)
            t1 = time.perf_counter()
            self._acc("kernel", t1 - t0)
            if n_tile:
                for want_depth in [w for w, out in ((True, zbuf), (False, masks)) if out is not None]:
                    results: list = []
                    self._tile_path(vs.V, vs.FT, tile[:n_tile], int(bases[k]), want_depth, results)
                    for pix, key in results:
                        if want_depth:
                            _kern.zbuf_min(zbuf, pix, key)
                        else:
                            masks[k, pix] = True
                self._acc("tile path", time.perf_counter() - t1)

    def _vertex_stage_compiled(self, V: np.ndarray, F: np.ndarray):
        """:meth:`_vertex_stage` by the numba kernel (same values): ``(vs, xy, iz)`` with ``xy`` the
        interleaved float32 normalised coordinates and ``iz`` the inverse depths, ``vs`` None when the
        whole mesh is certainly invisible. The tilted-sensor model runs the numpy stage."""
        n = len(V)
        if self._kparams is None:
            xy, iz = np.empty(n, dtype=np.complex64), np.empty(n, dtype=np.float32)
            return self._vertex_stage(V, F, xy, iz), xy.view(np.float32), iz
        t0 = time.perf_counter()
        FT = self._faces_info(F)[0]
        V32 = np.ascontiguousarray(V, dtype=np.float32)
        xy, iz = np.empty(2 * n, dtype=np.float32), np.empty(n, dtype=np.float32)
        u, v = np.empty(n, dtype=np.float32), np.empty(n, dtype=np.float32)
        lanes, bad = np.empty(4 * n, dtype=np.uint16), np.empty(n, dtype=bool)
        n_bad, umin, umax, vmin, vmax = _kern.vertex_stage(
            V32, np.float32(self.near_m), np.float32(self.r_lim**2), *self._kparams, np.float32(self._m0), _BOX_OFF,
            xy, iz, u, v, lanes, bad)
        self._acc("vertices", time.perf_counter() - t0)
        if n_bad == 0:       # whole-mesh cull, as in _vertex_stage
            umin, umax, vmin, vmax = float(umin), float(umax), float(vmin), float(vmax)
            m = self._c * ((umax - umin) ** 2 + (vmax - vmin) ** 2) + 1.0
            if umax < -m or vmax < -m or umin > self.width - 1 + m or vmin > self.height - 1 + m:
                return None, xy, iz
        elif not self._corners_visible(V32):
            return None, xy, iz
        return _VertexStage(V, FT, u, v, lanes.view(np.uint64), bad if n_bad else None), xy, iz

    def warm_up(self) -> float:
        """Compile (or load from numba's disk cache) the kernels this rasteriser calls, by rendering a
        tiny scene (fast path, tile path, faces, amodal masks). Safe to run in a background thread at
        start-up so that the first frame does not pay for it. Returns the seconds it took."""
        t0 = time.perf_counter()
        s = 0.05
        V = np.array([[-s, -s, 1.0], [s, -s, 1.0], [0.0, s, 1.0],               # fast path
                      [-0.3, 0.1, -0.5], [0.3, 0.1, -0.5], [0.0, 0.1, 2.0]])    # crosses the near plane
        F = np.array([[0, 1, 2], [3, 4, 5]])
        self.render([(V, F)], want_faces=True)
        self.render([(V.astype(np.float32), F)])
        model = ObjectModel("warm-up", V, F)
        self.full_masks([model], [np.eye(4)])
        self.render_objects([model], [np.eye(4)], want_amodal=True)
        self.timings.clear()
        return time.perf_counter() - t0

    # ------------------------------------------------------------------ per mesh
    def _vertex_stage(self, V: np.ndarray, F: np.ndarray, xy_out: np.ndarray,
                      iz_out: np.ndarray) -> _VertexStage | None:
        """Per-vertex data of one mesh, or None when the whole mesh is certainly invisible.

        Every vertex gets its normalised coordinates (written to ``xy_out`` as complex64
        ``X/Z + i Y/Z``) and inverse depth (``iz_out``, float32, 1/metres), its distorted
        pixel position ``(u, v)``, and a 64-bit record of four uint16 lanes
        ``(OFF + lo_u, OFF + lo_v, OFF - hi_u, OFF - hi_v)`` with ``lo = ceil(. - m0)``,
        ``hi = floor(. + m0)`` and ``OFF = 16384``. The lane-wise minimum over a triangle's
        vertices is its integer box; adding the two 32-bit halves gives per lane
        ``32768 - (hi - lo)``, whose bit 15 tells empty/one pixel from two or more. Vertices
        outside the fast-path disc (or at / behind the near plane) get the record 0, which sends
        their triangles to the tile path.
        """
        t0 = time.perf_counter()
        W, H = self.width, self.height
        FT = self._faces_info(F)[0]
        V32 = V if V.dtype == np.float32 else V.astype(np.float32)
        z = V32[:, 2]
        iz = iz_out
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            np.divide(np.float32(1.0), z, out=iz)
            x = V32[:, 0] * iz
            y = V32[:, 1] * iz
            xy_out.real = x
            xy_out.imag = y
            r2 = x * x
            r2 += y * y
            good = z > np.float32(self.near_m)
            good &= r2 <= np.float32(self.r_lim**2)
            u, v = self._distort32(x, y, r2)
        all_good = bool(good.all())
        if all_good:
            # whole-mesh cull: every triangle lies in the disc, so its curved image stays within
            # c * (pixel extent of the mesh)^2 of the box of the vertices
            umin, umax, vmin, vmax = float(u.min()), float(u.max()), float(v.min()), float(v.max())
            m = self._c * ((umax - umin) ** 2 + (vmax - vmin) ** 2) + 1.0
            if umax < -m or vmax < -m or umin > W - 1 + m or vmin > H - 1 + m:
                self._acc("vertices", time.perf_counter() - t0)
                return None
        elif not self._corners_visible(V32):             # frustum test on all vertices
            self._acc("vertices", time.perf_counter() - t0)
            return None
        m0 = np.float32(self._m0)
        with np.errstate(invalid="ignore"):
            A = np.empty((len(V), 4), dtype=np.float32)
            np.subtract(m0, u, out=A[:, 0])
            np.subtract(m0, v, out=A[:, 1])
            np.add(u, m0, out=A[:, 2])
            np.add(v, m0, out=A[:, 3])
            np.floor(A, out=A)                   # -lo_u, -lo_v, hi_u, hi_v
            np.subtract(np.float32(_BOX_OFF), A, out=A)
            if not all_good:
                A[~good] = 0.0
            rec = A.astype(np.uint16).view(np.uint64).ravel()
        self._acc("vertices", time.perf_counter() - t0)
        return _VertexStage(V, FT, u, v, rec, None if all_good else ~good, xy_out)

    def _front_faces(self, xy: np.ndarray, FT: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray | None:
        """Faces that are not culled as back faces of a closed mesh (bool per face), or None when the
        mesh is not culled. Same float32 signed area as the compiled kernel (same sign decisions)."""
        sign = self._cull_sign(V, F)
        if not sign:
            return None
        x, y = xy.real, xy.imag
        a, b, c = FT
        x0, y0 = x.take(a), y.take(a)
        area = (x.take(b) - x0) * (y.take(c) - y0)
        area -= (y0 - y.take(b)) * (x0 - x.take(c))
        return ~(area * np.float32(sign) > 0)

    def _triangle_stage(self, vs: _VertexStage, voff: int, base: int, groups: dict, results: list,
                        evaluate, want_depth: bool, front: np.ndarray | None = None) -> None:
        """Candidate pixels of the triangles of one mesh.

        Appends ``(vertex indices (3, n) offset by voff, candidate pixels (k, n), global ids
        (n,))`` to ``groups[k]`` for the frame-wide pixel tests (very large batches go straight
        to ``evaluate(idx, pix, gid)``), and the covered pairs of tile-path triangles directly to
        ``results`` (see :meth:`_frame`). Steps: integer boxes (:meth:`_triangle_boxes`), one-pixel
        boxes (:meth:`_one_pixel_candidates`), the tile path (:meth:`_split_tile_path`), boxes of 2 or
        2 x 2 pixels (:meth:`_small_box_candidates`), larger boxes (:meth:`_large_box_candidates`).
        """
        t0 = time.perf_counter()
        FT = vs.FT

        def add(k, t, pix, idx=None):
            idx = FT.take(t, axis=1) if idx is None else idx
            if voff:
                idx = idx + voff
            groups[k].append((idx, pix, t + base))

        M64, t_one, t_med = self._triangle_boxes(vs)
        if front is not None:                 # back faces of a closed mesh (see mesh_closure)
            t_one, t_med = t_one[front.take(t_one)], t_med[front.take(t_med)]
        t1 = time.perf_counter()
        self._acc("triangle boxes", t1 - t0)
        if len(t_one):
            self._one_pixel_candidates(M64, t_one, add)
        t2 = time.perf_counter()
        self._acc("candidates", t2 - t1)
        if not len(t_med):
            return
        if vs.bad is not None:
            t_med = self._split_tile_path(vs, t_med, base, want_depth, results)
        t3 = time.perf_counter()
        self._acc("tile path", t3 - t2)
        if not len(t_med):
            return
        big = self._small_box_candidates(M64, t_med, add)
        if len(big):
            t3 += self._large_box_candidates(vs, t_med.take(big), voff, base, add, evaluate)
        self._acc("candidates", time.perf_counter() - t3)

    @staticmethod
    def _triangle_boxes(vs: _VertexStage) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Integer candidate boxes of the triangles: the lane-wise minimum ``M64`` (uint64 per triangle) of
        their vertex records, the triangles with exactly one candidate pixel, and those with a side of
        2 or more pixels or on the tile path (record 0)."""
        G = vs.rec.take(vs.FT)                                    # (3, n) uint64
        M = np.minimum(np.minimum(G[0].view(np.uint16), G[1].view(np.uint16)), G[2].view(np.uint16))
        M64 = M.view(np.uint64)
        S = M64 & _U64_LOW32
        S += M64 >> _SHIFT32                                      # lanes: 32768 - (hi - lo)
        t_one = np.flatnonzero(S == _LANE_MASK)                   # one candidate pixel
        S &= _LANE_MASK
        t_med = np.flatnonzero(S != _LANE_MASK)                   # a side of >= 2 px, or tile path
        return M64, t_one, t_med

    def _one_pixel_candidates(self, M64: np.ndarray, t_one: np.ndarray, add) -> None:
        """The one candidate pixel of each triangle ``t_one`` whose box holds exactly one, if in the image."""
        W, H = self.width, self.height
        if _LITTLE_ENDIAN:
            m = M64.take(t_one).view(np.int64)
            lu = m & 0xFFFF                                       # OFF + lo_u (first lane)
            lv = m >> 16
            lv &= 0xFFFF
        else:
            lanes = M64.view(np.uint16).reshape(-1, 4)
            lu = lanes[:, 0].take(t_one).astype(np.int64)
            lv = lanes[:, 1].take(t_one).astype(np.int64)
        lu -= _BOX_OFF
        lv -= _BOX_OFF
        inside = lu.view(np.uint64) < W                           # negative -> huge
        inside &= lv.view(np.uint64) < H
        lv *= W
        lv += lu                                                  # flat pixel index
        if not inside.all():
            t_one, lv = t_one[inside], lv[inside]
        if len(t_one):
            add(1, t_one, lv[None, :])

    def _split_tile_path(self, vs: _VertexStage, t_med: np.ndarray, base: int, want_depth: bool,
                         results: list) -> np.ndarray:
        """Send the triangles of ``t_med`` with a vertex outside the fast-path disc down the tile path
        (their covered pairs go to ``results``); returns the others."""
        tb = vs.bad.take(vs.FT.take(t_med, axis=1)).any(axis=0)
        if tb.any():
            t_tile = t_med[tb]
            self._tile_path(vs.V, vs.FT, t_tile[self._tile_keep(vs, t_tile)], base, want_depth, results)
            t_med = t_med[~tb]
        return t_med

    def _tile_keep(self, vs: _VertexStage, t: np.ndarray) -> np.ndarray:
        """Which tile-path faces ``t`` need the tile path: those with a vertex at or behind the near plane
        (clipping), and those in front of it whose normalised bounding box meets the box of the valid rays
        (float32, the same test as the compiled kernel's ``tile_keep``; back faces are already culled)."""
        idx = vs.FT.take(t, axis=1)
        z = vs.V[:, 2].astype(np.float32).take(idx)
        clip = (z <= np.float32(self.near_m)).any(axis=0)
        x, y = vs.xy.real.take(idx), vs.xy.imag.take(idx)
        xmin, xmax, ymin, ymax = self._fbox32
        miss = (x.max(axis=0) < xmin) | (x.min(axis=0) > xmax) | (y.max(axis=0) < ymin) | (y.min(axis=0) > ymax)
        return clip | ~miss

    def _small_box_candidates(self, M64: np.ndarray, t_med: np.ndarray, add) -> np.ndarray:
        """Boxes of 2 or 2 x 2 pixels inside the image: their integer boxes are exact, so their pixels are
        the candidates. Returns the positions in ``t_med`` of the larger (or image-crossing) non-empty boxes."""
        W, H = self.width, self.height
        L = M64.take(t_med).view(np.uint16).reshape(-1, 4).T.astype(np.int32)   # (4, n)
        lu, lv = L[0] - _BOX_OFF, L[1] - _BOX_OFF
        su, sv = _BOX_OFF - L[2] - lu, _BOX_OFF - L[3] - lv        # box sides - 1
        nonempty = (su >= 0) & (sv >= 0)
        small = nonempty & (su <= 1) & (sv <= 1) & (lu >= 0) & (lv >= 0) & (lu + su < W) & (lv + sv < H)
        corner = (lv * W + lu).astype(np.intp)
        n_side = su + sv
        sel = np.flatnonzero(small & (n_side == 1))              # 1 x 2 or 2 x 1
        if len(sel):
            b = corner.take(sel)
            add(2, t_med.take(sel), np.stack([b, b + su.take(sel) + sv.take(sel) * W]))
        sel = np.flatnonzero(small & (n_side == 2))              # 2 x 2
        if len(sel):
            add(4, t_med.take(sel), corner.take(sel)[None, :] + self._offsets[2])
        return np.flatnonzero(nonempty & ~small)

    def _large_box_candidates(self, vs: _VertexStage, t_big: np.ndarray, voff: int, base: int, add,
                              evaluate) -> float:
        """Triangles ``t_big`` with larger boxes (or crossing the image border): exact float boxes with the
        distortion margin; boxes of at most 3 x 3 pixels become candidate blocks, longer ones have every
        pixel tested at once (:meth:`_long_box_tests`). Returns the seconds spent in those pixel tests."""
        W, H, HW = self.width, self.height, self.width * self.height
        idx = vs.FT.take(t_big, axis=1)
        U, Vv = vs.u.take(idx), vs.v.take(idx)                  # (3, n)
        umin, umax = U.min(axis=0), U.max(axis=0)
        vmin, vmax = Vv.min(axis=0), Vv.max(axis=0)
        du, dv = umax - umin, vmax - vmin
        marg = np.float32(self._c) * (du * du + dv * dv) + np.float32(_EPS_PX)
        u0 = np.maximum(np.ceil(umin - marg), 0).astype(np.intp)
        u1 = np.minimum(np.floor(umax + marg), W - 1).astype(np.intp)
        v0 = np.maximum(np.ceil(vmin - marg), 0).astype(np.intp)
        v1 = np.minimum(np.floor(vmax + marg), H - 1).astype(np.intp)
        nu, nv = u1 - u0 + 1, v1 - v0 + 1
        lng = np.maximum(nu, nv)
        sht = np.minimum(nu, nv)
        corner = v0 * W + u0
        ok = sht > 0
        # blocks from the box corner (extra pixels of a block are tested exactly too;
        # candidates past the last row map to the dummy pixel)
        for k, want in ((4, ok & (lng <= 2)), (6, ok & (lng == 3) & (sht < 3)), (9, ok & (sht == 3) & (lng == 3))):
            sb = np.flatnonzero(want)
            if not len(sb):
                continue
            b = corner.take(sb)[None, :]
            if k == 4:
                pix = b + self._offsets[2]
            elif k == 6:                                    # 3 x 2 along the long side
                pix = b + np.where(nu.take(sb) == 3, self._offsets["3x2"], self._offsets["2x3"])
            else:
                pix = b + self._offsets[3]
            np.minimum(pix, HW, out=pix)
            add(k, t_big.take(sb), pix, idx.take(sb, axis=1))
        sb_all = np.flatnonzero(ok & (lng > 3))
        t_eval = self._long_box_tests(idx, t_big, sb_all, corner, nu, nv, voff, base, evaluate)
        self._acc("pixel tests", t_eval)
        return t_eval

    @staticmethod
    def _long_box_tests(idx, t_big, sb_all, corner, nu, nv, voff: int, base: int, evaluate) -> float:
        """Boxes longer than 3 pixels (positions ``sb_all``): every pixel of the box is tested against the
        triangle's edge coefficients (computed once per triangle, :meth:`_eval_boxes`), in chunks of at
        most _PAIR_CHUNK pairs (a big mesh close to the lens could otherwise need gigabytes). Returns the
        seconds spent."""
        counts_all = nu.take(sb_all) * nv.take(sb_all)
        cum = np.cumsum(counts_all)
        cuts = np.searchsorted(cum, np.arange(_PAIR_CHUNK, int(cum[-1]) if len(cum) else 0, _PAIR_CHUNK))
        t_eval = 0.0
        for sb in np.split(sb_all, cuts):
            if not len(sb):
                continue
            te = time.perf_counter()
            ii = idx.take(sb, axis=1)
            evaluate(ii + voff if voff else ii, None, t_big.take(sb) + base,
                     boxes=(corner.take(sb), nu.take(sb), nv.take(sb)))
            t_eval += time.perf_counter() - te
        return t_eval

    def _eval_tris(self, xy: np.ndarray, iz: np.ndarray, idx: np.ndarray, pix: np.ndarray, want_depth: bool):
        """Exact pixel tests for fast-path triangles.

        Parameters
        ----------
        xy : (N,) complex64
            Normalised coordinates ``X/Z + i Y/Z`` of all vertices (one gather fetches both).
        iz : (N,) float32
            Inverse depth ``1/Z`` of all vertices (1/metres).
        idx : (3, n) intp
            Vertex indices of ``n`` triangles.
        pix : (k, n) intp
            ``k`` candidate pixels for each triangle (the dummy index ``H*W`` has a NaN ray
            and is never covered).

        Returns
        -------
        None if nothing is covered, else ``(ti, pix, key)``: triangle position (column of
        ``idx``), flat pixel index and uint64 depth key ``float32(z) bits << 32`` (None
        without depth) of every covered pair.

        Notes
        -----
        With ``a, b, c`` the vertices in the normalised plane and ``d = p - a`` the pixel ray's
        offset from ``a``, ``E0 = (b - a) x d`` and ``E2 = d x (c - a)`` are the barycentric
        weights of ``c`` and ``b`` times the doubled signed area ``S``; after multiplying by
        ``sign(S)`` the ray is inside the closed triangle iff ``E0 >= 0``, ``E2 >= 0`` and
        ``E0 + E2 <= |S|``. A zero-area triangle gets ``|S| = -1`` and never passes. ``1/z`` is
        interpolated with the same weights (exact for the triangle's plane).
        """
        coef = _edge_coefficients(xy, idx)                       # (7, n), broadcast over the k pixels
        e0, e2, ins = _edge_test(self._XY.take(pix), coef)       # pixel rays (k, n)
        f = np.flatnonzero(ins)
        if not len(f):
            return None
        ti = f if pix.shape[0] == 1 else f % pix.shape[1]
        p = pix.ravel().take(f)
        if not want_depth:
            return ti, p, None
        return _depth_keys(iz, idx, ti, p, e0.ravel().take(f), e2.ravel().take(f), coef[6].take(ti))

    def _eval_boxes(self, xy: np.ndarray, iz: np.ndarray, idx: np.ndarray, corner: np.ndarray,
                    nu: np.ndarray, nv: np.ndarray, want_depth: bool):
        """Exact pixel tests of every pixel of each triangle's candidate box.

        Same test and result as :meth:`_eval_tris` (``ti`` indexes the columns of ``idx``), for
        triangles whose box is ``nu x nv`` pixels from the flat pixel ``corner`` (inside the
        image). The edge coefficients are computed once per triangle and repeated to its
        pixels, instead of gathering three vertices and recomputing them for every pair.
        """
        W = self.width
        m = idx.shape[1]
        coef = _edge_coefficients(xy, idx)                       # per triangle, repeated per pixel
        # pixels: rows of each box, then the pixels of each row (no division per pair)
        row_tri = np.repeat(np.arange(m), nv)
        row_first = np.cumsum(nv) - nv
        row_start = corner.take(row_tri) + (np.arange(len(row_tri)) - row_first.take(row_tri)) * W
        row_len = nu.take(row_tri)
        pair_first = np.cumsum(row_len) - row_len
        pix = np.arange(int(row_len.sum()), dtype=np.intp)
        pix += np.repeat(row_start - pair_first, row_len)
        per_tri = nu * nv
        tp = np.repeat(np.arange(m), per_tri)                    # triangle of each pair
        e0, e2, ins = _edge_test(self._XY.take(pix), np.repeat(coef, per_tri, axis=1))
        f = np.flatnonzero(ins)
        if not len(f):
            return None
        ti = tp.take(f)
        p = pix.take(f)
        if not want_depth:
            return ti, p, None
        return _depth_keys(iz, idx, ti, p, e0.take(f), e2.take(f), coef[6].take(ti))

    def _tile_path(self, V, FT, t, base, want_depth, results):
        """Triangles ``t`` (face indices) crossing the near plane or reaching outside the
        fast-path disc: clip them at the near plane, find the tiles each piece may cover
        (separating-axis test in the normalised plane), fill tiles entirely inside, test the
        pixels of the others. Covered pairs go to ``results`` as in :meth:`_frame`."""
        tris, src = _clip_near(V[FT[:, t].T].astype(np.float64), self.near_m)
        if not len(tris):
            return
        faces = t[src]
        q = tris[:, :, :2] / tris[:, :, 2:3]               # (m, 3, 2) normalised, z >= near
        xmin, xmax, ymin, ymax = self._frustum
        qmin, qmax = q.min(axis=1), q.max(axis=1)
        vis = (qmax[:, 0] >= xmin) & (qmin[:, 0] <= xmax) & (qmax[:, 1] >= ymin) & (qmin[:, 1] <= ymax)
        rows, keep = _tile_rows(tris, q)
        idx = np.flatnonzero(vis & keep)
        if not len(idx):
            return
        rows, faces, qmin, qmax = rows[:, idx], faces[idx], qmin[idx], qmax[idx]
        r64 = rows[:9]
        edges32, plane = rows[:9].astype(np.float32), rows[9:]
        box = self._tile_box                               # (T, 4): xmin, xmax, ymin, ymax
        n_t, n_tiles = len(faces), len(box)
        step = max(1, _TILE_CHUNK // max(n_tiles, 1))
        for s0 in range(0, n_t, step):
            sl = slice(s0, min(n_t, s0 + step))
            over = ((qmax[sl, 0, None] >= box[None, :, 0]) & (qmin[sl, 0, None] <= box[None, :, 1])
                    & (qmax[sl, 1, None] >= box[None, :, 2]) & (qmin[sl, 1, None] <= box[None, :, 3]))
            full = over.copy()
            for r in (0, 3, 6):                            # edge function range over the tile box
                A, B, C = r64[r, sl, None], r64[r + 1, sl, None], r64[r + 2, sl, None]
                ax_lo, ax_hi = A * box[None, :, 0], A * box[None, :, 1]
                by_lo, by_hi = B * box[None, :, 2], B * box[None, :, 3]
                over &= C + np.maximum(ax_lo, ax_hi) + np.maximum(by_lo, by_hi) >= -1e-6
                full &= C + np.minimum(ax_lo, ax_hi) + np.minimum(by_lo, by_hi) > 1e-6
            ti, tj = np.nonzero(over)
            if not len(ti):
                continue
            is_full = full[ti, tj]
            ti += s0
            step_pairs = max(1, _PAIR_CHUNK // (_TILE * _TILE))
            for sub, test in ((~is_full, True), (is_full, False)):
                a_all, b_all = ti[sub], tj[sub]
                for c0 in range(0, len(a_all), step_pairs):        # bounded memory per batch
                    a, b = a_all[c0:c0 + step_pairs], b_all[c0:c0 + step_pairs]
                    res = self._eval_tile(edges32.take(a, axis=1), plane.take(a, axis=1),
                                          self._tile_pix.take(b, axis=1), want_depth, test)
                    if res is not None:
                        k, p, key = res
                        gid = faces.take(a.take(k)) + base
                        results.append((p, key | gid.astype(np.uint64)) if want_depth else (p, gid))

    def _eval_tile(self, edges, plane, pix, want_depth, test):
        """Pixel tests for tile-path triangles: ``edges`` (9, n) float32 and ``plane`` (3, n)
        float64 rows of :func:`_tile_rows`, ``pix`` (k, n) candidate pixels. With ``test``
        False the pixels are known to be inside (tile entirely covered) and only the ray's
        validity is checked. Returns ``(ti, pix, key)`` as :meth:`_eval_tris` does, or None."""
        r = edges[:, None, :]
        X = self._X.take(pix)
        Y = self._Y.take(pix)
        if test:
            ins = None
            for e0 in (0, 3, 6):
                e = r[e0] * X
                e += r[e0 + 1] * Y
                e += r[e0 + 2]
                ins = e >= 0 if ins is None else ins & (e >= 0)
        else:
            ins = np.isfinite(X)
        f = np.flatnonzero(ins)
        if not len(f):
            return None
        ti = f % pix.shape[1]
        p = pix.ravel().take(f)
        if not want_depth:
            return ti, p, None
        invz = plane[1].take(ti) * self._X64.take(p)
        invz += plane[2].take(ti) * self._Y64.take(p)
        invz += plane[0].take(ti)
        pos = invz > 0
        if not pos.all():
            ti, p, invz = ti[pos], p[pos], invz[pos]
        key = (1.0 / invz).astype(np.float32).view(np.uint32).astype(np.uint64) << _SHIFT32
        return ti, p, key


def _balanced_groups(ks: list[int], n_faces: list[int], n_groups: int) -> list[list[int]]:
    """``ks`` split into at most ``n_groups`` non-empty groups of about equal triangle counts (the largest
    mesh first into the lightest group)."""
    groups: list[list[int]] = [[] for _ in range(min(n_groups, len(ks)))]
    load = [0] * len(groups)
    for n, k in sorted(zip(n_faces, ks), reverse=True):
        g = load.index(min(load))
        groups[g].append(k)
        load[g] += n
    return groups


_POOL: dict = {}
_POOL_LOCK = threading.Lock()


def _raster_pool(workers: int):
    """The shared thread pool of the compiled pipeline, grown to at least ``workers`` threads."""
    from concurrent.futures import ThreadPoolExecutor

    with _POOL_LOCK:
        pool = _POOL.get("pool")
        if pool is None or _POOL["workers"] < workers:
            pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="evpose-raster")
            _POOL.update(pool=pool, workers=workers)
        return pool


def warm_up(camera: CameraModel | None = None) -> float:
    """Compile or load the rasteriser's numba kernels off the first frame (see
    :meth:`Rasterizer.warm_up`), with a small distorted camera unless one is given; call it in a
    background thread at start-up. Returns the seconds it took (0 without numba)."""
    if not _kern.HAVE_NUMBA:
        return 0.0
    t0 = time.perf_counter()
    if camera is None:
        camera = CameraModel([[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]], [-0.3, 0.1, 0.001, 0.001, 0.01], 32, 24)
    Rasterizer(camera).warm_up()
    return time.perf_counter() - t0
