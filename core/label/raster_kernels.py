"""Compiled (numba) kernels of the rasteriser's hot stages (:mod:`evpose.core.label.raster`).

One loop per mesh replaces the numpy candidate generation, pixel tests and z-buffer of
:class:`~evpose.core.label.raster.Rasterizer`: for every triangle it forms the same integer
candidate box (from the packed per-vertex boxes of the vertex stage) or, for larger boxes,
the same float box with the distortion bend margin, tests the same pixels with the same
float32 edge functions (same operations in the same order, no fused multiply-add: numba
compiles without fast-math) and keeps the minimum ``(float32 z bits << 32) | triangle id``
key per pixel. The z-buffer minimum does not depend on the order of the pairs, so the
output equals the numpy path's bit for bit.

Kernels are compiled with ``cache=True`` (machine code stored next to this file, or in
numba's user cache directory when that is read-only), so only the very first start on a
machine compiles (~2-4 s); later starts load them from the cache (~0.1 s).
:func:`warm_up` does that off the first frame (call it in a background thread at start-up).

``HAVE_NUMBA`` is False when numba cannot be imported; the rasteriser then uses its numpy
path (same results, ~3x slower).

Units: as in :mod:`evpose.core.label.raster`: normalised ray coordinates ``x/z, y/z``,
inverse depths in 1/metres, pixels ``(u, v)`` flat-indexed ``v * W + u``.
"""
from __future__ import annotations

import math

import numpy as np

try:
    from numba import njit
    HAVE_NUMBA = True
except ImportError:                                  # pragma: no cover - numba is a dependency
    HAVE_NUMBA = False

__all__ = ["HAVE_NUMBA", "vertex_stage", "raster_mesh", "zbuf_min", "decode", "tile_keep"]

if HAVE_NUMBA:
    @njit(cache=True, nogil=True, error_model="numpy")
    def vertex_stage(V, near, r_lim2, prm, flags, m0, off, xy, iz, u, v, lanes, bad):
        """Per-vertex data of one mesh (``Rasterizer._vertex_stage`` of the numpy path, same float32
        operations in the same order).

        Parameters
        ----------
        V : (N, 3) float32
            Vertices, camera frame (metres).
        near, r_lim2 : float32
            Near plane (metres) and squared radius of the fast-path disc (normalised units).
        prm : (16,) float32
            ``k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, fx, fy, cx, cy`` of the OpenCV model.
        flags : (4,) bool
            Radial, rational, tangential and thin-prism terms present.
        m0 : float32
            Margin (pixels) of the integer boxes; ``off`` their offset.
        xy, iz, u, v, lanes, bad
            Outputs: interleaved ``x/z, y/z`` (2N,), ``1/z`` (N,), distorted pixel (N,) each,
            packed boxes ``OFF + lo_u, OFF + lo_v, OFF - hi_u, OFF - hi_v`` (4N,) uint16 (0 for
            bad vertices), and ``bad`` (N,): at or behind the near plane or outside the disc.

        Returns
        -------
        (n_bad, umin, umax, vmin, vmax)
            Number of bad vertices and the pixel range of all vertices (meaningful when none is bad).
        """
        one, two = np.float32(1.0), np.float32(2.0)
        k1, k2, p1, p2, k3, k4, k5, k6 = prm[0], prm[1], prm[2], prm[3], prm[4], prm[5], prm[6], prm[7]
        s1, s2, s3, s4, fx, fy, cx, cy = prm[8], prm[9], prm[10], prm[11], prm[12], prm[13], prm[14], prm[15]
        radial, rational, tangential, prism = flags[0], flags[1], flags[2], flags[3]
        n_bad = 0
        off32 = np.float32(off)
        umin, umax = np.float32(np.inf), np.float32(-np.inf)
        vmin, vmax = np.float32(np.inf), np.float32(-np.inf)
        for i in range(V.shape[0]):
            z = V[i, 2]
            izi = one / z
            x = V[i, 0] * izi
            y = V[i, 1] * izi
            iz[i] = izi
            xy[2 * i] = x
            xy[2 * i + 1] = y
            r2 = x * x
            r2 = r2 + y * y
            uu, vv = x, y
            if radial or rational:
                rad = k3 * r2
                rad = (((rad + k2) * r2) + k1) * r2 + one
                if rational:
                    den = (((k6 * r2 + k5) * r2) + k4) * r2 + one
                    rad = rad / den
                uu = x * rad
                vv = y * rad
            if tangential:
                xy2 = (x * y) * two
                uu = (uu + ((x * x) * two + r2) * p2) + p1 * xy2
                vv = (vv + ((y * y) * two + r2) * p1) + p2 * xy2
            if prism:
                r4 = r2 * r2
                uu = uu + (s1 * r2 + s2 * r4)
                vv = vv + (s3 * r2 + s4 * r4)
            uu = uu * fx + cx
            vv = vv * fy + cy
            u[i] = uu
            v[i] = vv
            umin, umax = min(umin, uu), max(umax, uu)
            vmin, vmax = min(vmin, vv), max(vmax, vv)
            if z > near and r2 <= r_lim2:
                bad[i] = False
                lanes[4 * i] = np.uint16(np.int64(off32 - np.floor(m0 - uu)))
                lanes[4 * i + 1] = np.uint16(np.int64(off32 - np.floor(m0 - vv)))
                lanes[4 * i + 2] = np.uint16(np.int64(off32 - np.floor(uu + m0)))
                lanes[4 * i + 3] = np.uint16(np.int64(off32 - np.floor(vv + m0)))
            else:
                bad[i] = True
                n_bad += 1
                lanes[4 * i] = lanes[4 * i + 1] = lanes[4 * i + 2] = lanes[4 * i + 3] = 0
        return n_bad, umin, umax, vmin, vmax

    @njit(cache=True, nogil=True, error_model="numpy")
    def _float_box(a, b, c, W, H, u, v, c_bend, eps):
        """Candidate box ``(u0, u1, v0, v1)`` (inclusive, clipped to the image) of a triangle whose
        integer box is larger than 2 x 2 pixels or crosses the image border: the float box of its
        distorted vertices with the bend margin (``_large_box_candidates`` of the numpy path)."""
        umin, umax = min(u[a], u[b], u[c]), max(u[a], u[b], u[c])
        vmin, vmax = min(v[a], v[b], v[c]), max(v[a], v[b], v[c])
        du = umax - umin
        dv = vmax - vmin
        marg = c_bend * (du * du + dv * dv) + eps       # float32, as the numpy path
        u0 = max(np.int64(math.ceil(umin - marg)), 0)
        u1 = min(np.int64(math.floor(umax + marg)), W - 1)
        v0 = max(np.int64(math.ceil(vmin - marg)), 0)
        v1 = min(np.int64(math.floor(vmax + marg)), H - 1)
        return u0, u1, v0, v1

    @njit(cache=True, nogil=True, error_model="numpy")
    def _tile_faces(FT, bad, tile_out, zv, near, xy, fbox, cull):
        """Faces with a vertex off the fast path, written to ``tile_out``; returns their number. Of those
        with every vertex beyond the near plane (nothing to clip), the ones whose normalised bounding box
        misses ``fbox`` (the box of all valid pixel rays plus a margin: they cover no pixel) and, with
        ``cull``, the back faces are left out (:func:`tile_keep`, the numpy path's same test)."""
        n = 0
        if not bad.any():
            return 0
        for t in range(FT.shape[1]):
            a, b, c = FT[0, t], FT[1, t], FT[2, t]
            if bad[a] or bad[b] or bad[c]:
                if (zv[a] > near) & (zv[b] > near) & (zv[c] > near) and not tile_keep(
                        xy[2 * a], xy[2 * a + 1], xy[2 * b], xy[2 * b + 1], xy[2 * c], xy[2 * c + 1], fbox, cull):
                    continue
                tile_out[n] = t
                n += 1
        return n

    @njit(cache=True, nogil=True, error_model="numpy")
    def tile_keep(xa, ya, xb, yb, xc, yc, fbox, cull):
        """Does a triangle in front of the near plane (normalised vertices) need the tile path? Not when its
        bounding box misses ``fbox`` ``(xmin, xmax, ymin, ymax)`` or it is a back face (``cull``)."""
        if max(xa, xb, xc) < fbox[0] or min(xa, xb, xc) > fbox[1]:
            return False
        if max(ya, yb, yc) < fbox[2] or min(ya, yb, yc) > fbox[3]:
            return False
        area = (xb - xa) * (yc - ya)
        area = area - (ya - yb) * (xa - xc)
        return not area * cull > 0

    @njit(cache=True, nogil=True, error_model="numpy")
    def _nonempty_faces(FT, lanes, bad, any_bad, off, out, xy, cull):
        """Fast-path faces whose integer box holds a pixel centre and that are not back faces of a
        closed mesh (``cull``, see :func:`raster_mesh`), written to ``out`` without a branch per face
        (most faces of dense meshes have no pixel centre, half of a closed mesh faces away); returns
        their number."""
        n = 0
        for t in range(FT.shape[1]):
            a, b, c = FT[0, t], FT[1, t], FT[2, t]
            x0, y0 = xy[2 * a], xy[2 * a + 1]
            area = (xy[2 * b] - x0) * (xy[2 * c + 1] - y0)
            area = area - (y0 - xy[2 * b + 1]) * (x0 - xy[2 * c])
            lo_u = np.int64(min(lanes[4 * a], lanes[4 * b], lanes[4 * c]))
            lo_v = np.int64(min(lanes[4 * a + 1], lanes[4 * b + 1], lanes[4 * c + 1]))
            hi_u = 2 * off - np.int64(min(lanes[4 * a + 2], lanes[4 * b + 2], lanes[4 * c + 2]))
            hi_v = 2 * off - np.int64(min(lanes[4 * a + 3], lanes[4 * b + 3], lanes[4 * c + 3]))
            keep = (hi_u >= lo_u) & (hi_v >= lo_v) & (not area * cull > 0)
            if any_bad:
                keep &= not (bad[a] | bad[b] | bad[c])
            out[n] = t
            n += keep
        return n

    @njit(cache=True, nogil=True, error_model="numpy")
    def raster_mesh(FT, lanes, bad, u, v, xy, iz, ray, W, H, c_bend, eps, off, gid0, zbuf, mask, tile_out, cull,
                    zv, near, fbox):
        """Rasterise the fast-path triangles of one mesh.

        Parameters
        ----------
        FT : (3, F) intp
            Faces (vertex indices).
        lanes : (4 N,) uint16
            Packed integer boxes of the vertices ``OFF + lo_u, OFF + lo_v, OFF - hi_u, OFF - hi_v``.
        bad : (N,) bool
            Vertices off the fast path (their triangles go to ``tile_out``); may be all False.
        u, v : (N,) float32
            Distorted pixel positions of the vertices.
        xy : (2 N,) float32
            Interleaved normalised coordinates ``x/z, y/z`` of the vertices.
        iz : (N,) float32
            Inverse depths ``1/z`` (1/metres).
        ray : (2 (H W + 1),) float32
            Interleaved pixel-centre rays (NaN where invalid).
        W, H : int
            Image size.
        c_bend, eps : float32
            Distortion bend constant and extra margin (pixels) of the large boxes.
        off : int
            Offset of the packed boxes.
        gid0 : uint64
            Global id of the mesh's first triangle.
        zbuf : (H W + 1,) uint64
            z-buffer of keys ``(float32 z bits << 32) | gid``, updated in place when its length
            is not zero (depth).
        mask : (H W + 1,) bool
            Coverage (amodal mask) written in place when its length is not zero: no depth test;
            pairs with ``1/z <= 0`` count, as in the numpy path. Both may be given (one pass).
        tile_out : (F,) intp
            Receives the faces that must take the tile path.
        cull : float32
            Back-face culling sign (:func:`evpose.core.data.mesh_closure.cull_sign`): faces whose
            signed normalised-plane area ``A`` has ``cull * A > 0`` are skipped; 0 culls nothing.
            The caller passes 0 unless every vertex lies beyond the near plane.
        zv : (N,) float32
            Vertex depths ``z`` (metres); ``near`` the near plane (float32).
        fbox : (4,) float32
            ``xmin, xmax, ymin, ymax`` of all valid pixel rays, widened by a margin: tile-path faces in
            front of the near plane whose bounding box misses it are dropped.

        Returns
        -------
        int
            Number of faces written to ``tile_out``.
        """
        n_tile = _tile_faces(FT, bad, tile_out, zv, near, xy, fbox, cull)
        depth_mode = len(zbuf) > 0
        mask_mode = len(mask) > 0
        one = np.float32(1.0)
        fbuf = np.empty(1, np.float32)
        ubuf = fbuf.view(np.uint32)
        cand = np.empty(FT.shape[1], np.int64)
        n_cand = _nonempty_faces(FT, lanes, bad, n_tile > 0, off, cand, xy, cull)
        for i in range(n_cand):
            t = cand[i]
            a, b, c = FT[0, t], FT[1, t], FT[2, t]
            # integer box (exact for boxes of at most 2 x 2 pixels, see _small_box_candidates)
            u0 = np.int64(min(lanes[4 * a], lanes[4 * b], lanes[4 * c])) - off
            v0 = np.int64(min(lanes[4 * a + 1], lanes[4 * b + 1], lanes[4 * c + 1])) - off
            u1 = off - np.int64(min(lanes[4 * a + 2], lanes[4 * b + 2], lanes[4 * c + 2]))
            v1 = off - np.int64(min(lanes[4 * a + 3], lanes[4 * b + 3], lanes[4 * c + 3]))
            if (u1 - u0 > 1) | (v1 - v0 > 1) | (u0 < 0) | (v0 < 0) | (u1 >= W) | (v1 >= H):
                if (u1 == u0) & (v1 == v0):               # one pixel, off the image
                    continue
                u0, u1, v0, v1 = _float_box(a, b, c, W, H, u, v, c_bend, eps)
                if u1 < u0 or v1 < v0:
                    continue
            x0, y0 = xy[2 * a], xy[2 * a + 1]
            c2 = y0 - xy[2 * b + 1]
            c3 = xy[2 * b] - x0
            c4 = xy[2 * c + 1] - y0
            c5 = x0 - xy[2 * c]
            area = c3 * c4
            area = area - c2 * c5
            if area * cull > 0:                         # back face of a closed mesh: never the first hit
                continue
            if area < 0:
                c2, c3, c4, c5, area = -c2, -c3, -c4, -c5, -area
            elif not area > 0:                         # zero area (or NaN): covers nothing
                continue
            i0 = iz[a]
            d1 = iz[b] - i0
            d2 = iz[c] - i0
            gid = gid0 + np.uint64(t)
            for pv in range(v0, v1 + 1):
                for pu in range(u0, u1 + 1):
                    p = pv * W + pu
                    dx = ray[2 * p] - x0
                    dy = ray[2 * p + 1] - y0
                    e0 = c2 * dx
                    e0 = e0 + c3 * dy
                    e2 = c4 * dx
                    e2 = e2 + c5 * dy
                    if not (e0 >= 0 and e2 >= 0 and e0 + e2 <= area):
                        continue
                    if mask_mode:
                        mask[p] = True
                    if not depth_mode:
                        continue
                    wb = e2 * d1
                    wb = wb + e0 * d2
                    wb = wb / area
                    wb = wb + i0
                    if wb > 0:
                        fbuf[0] = one / wb
                        key = (np.uint64(ubuf[0]) << np.uint64(32)) | gid
                        if key < zbuf[p]:
                            zbuf[p] = key
        return n_tile

    @njit(cache=True, nogil=True, error_model="numpy")
    def zbuf_min(zbuf, pix, key):
        """``zbuf[pix] = min(zbuf[pix], key)`` pair by pair (``np.minimum.at``)."""
        for i in range(len(pix)):
            p = pix[i]
            if key[i] < zbuf[p]:
                zbuf[p] = key[i]

    @njit(cache=True, nogil=True, error_model="numpy")
    def decode(zbuf, bases, depth, obj, face):
        """Split the z-buffer keys (first ``len(depth)`` entries) into float32 depth (inf where
        empty), mesh index (-1) and face index within the mesh (-1; skipped when ``face`` is
        empty). ``bases`` holds the global id of each mesh's first triangle plus the total."""
        zf = np.empty(1, np.uint32)
        zv = zf.view(np.float32)
        empty = np.uint64(0xFFFFFFFFFFFFFFFF)
        low = np.uint64(0xFFFFFFFF)
        want_face = len(face) > 0
        for p in range(len(depth)):
            k = zbuf[p]
            if k == empty:
                continue
            zf[0] = np.uint32(k >> np.uint64(32))
            depth[p] = zv[0]
            gid = np.int64(k & low)
            o = np.searchsorted(bases, gid, side="right") - 1
            obj[p] = o
            if want_face:
                face[p] = gid - bases[o]
else:                                                  # pragma: no cover
    raster_mesh = zbuf_min = decode = tile_keep = None
