"""The visible contour samples of every object in one event window, and which event goes with
which sample.

For the camera pose at the window's label time, each object's contour generators
(:class:`~evpose.core.align.mesh_edges.MeshEdges`) are sampled every ``spacing_px`` pixels and a
sample is kept when the z-buffer of all objects (one render, so objects occlude each other
exactly) shows it is not hidden. Each sample gets a 2D normal; samples with the object on
exactly one side are *outer* silhouette samples (normal pointing outwards), the others depth
discontinuities inside the object. Samples are fixed points on the mesh, so a pose change only
re-projects them; :meth:`Contours.associate` relates every event to its nearest sample at the
event's own time.
"""
from __future__ import annotations

import numpy as np

from evpose.core.align import edge_samples_kernel as _kernel
from evpose.core.align.event_windows import EventWindow
from evpose.core.align.mesh_edges import MeshEdges
from evpose.core.align.nearest import nearest_within
from evpose.core.align.refine_result import RefineParams
from evpose.core.data.geometry import inv_T
from evpose.core.label.raster import Rasterizer

__all__ = ["Contours", "project"]


def project(P_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    z = np.maximum(P_cam[..., 2], 1e-6)
    return np.stack([K[0, 0] * P_cam[..., 0] / z + K[0, 2], K[1, 1] * P_cam[..., 1] / z + K[1, 2]], axis=-1)


def _render(raster: Rasterizer, models, T_co: list) -> tuple:
    """The z-buffer for visibility and sides: ``(RasterResult, 3x3 max-filtered depth)``."""
    import cv2

    res = raster.render_objects(models, T_co)
    depth = res.depth_m.astype(np.float32)
    dmax = cv2.dilate(np.where(np.isfinite(depth), depth, np.float32(1e9)), np.ones((3, 3), np.uint8))
    return res, dmax


def _edge_samples(cam, me: MeshEdges, T: np.ndarray, spacing_px: float, compiled: bool = _kernel.HAVE_NUMBA):
    """Samples every ``spacing_px`` along the contour generators of one object in front of the
    camera (``T``: camera <- object): ``(P object frame, P camera frame, unit 2D normal)`` or None.
    ``compiled``: :func:`evpose.core.align.edge_samples_kernel.edge_samples` (same arrays, ~10x faster)."""
    K = cam.K
    cam_obj = inv_T(T)[:3, 3]
    if compiled:
        return _kernel.edge_samples(me, T, cam_obj, K, cam.near_m, spacing_px)
    idx = me.contour_edges(cam_obj)
    if len(idx) == 0:
        return None
    A = me.V[me.edges[idx, 0]]
    B = me.V[me.edges[idx, 1]]
    Ac = A @ T[:3, :3].T + T[:3, 3]
    Bc = B @ T[:3, :3].T + T[:3, 3]
    front = (Ac[:, 2] > cam.near_m) & (Bc[:, 2] > cam.near_m)
    A, B, Ac, Bc = A[front], B[front], Ac[front], Bc[front]
    if len(A) == 0:
        return None
    pa, pb = project(Ac, K), project(Bc, K)
    L = np.linalg.norm(pb - pa, axis=1)
    n = np.maximum(1, np.ceil(L / spacing_px)).astype(np.int64)
    n = np.minimum(n, 4096)
    rep = np.repeat(np.arange(len(A)), n)
    frac = (np.arange(len(rep)) - np.repeat(np.cumsum(n) - n, n) + 0.5) / n[rep]
    P = A[rep] + frac[:, None] * (B[rep] - A[rep])
    Pc = P @ T[:3, :3].T + T[:3, 3]
    d2 = pb[rep] - pa[rep]
    d2 = d2 / np.maximum(np.linalg.norm(d2, axis=1, keepdims=True), 1e-12)
    normal = np.stack([d2[:, 1], -d2[:, 0]], axis=1)
    return P, Pc, normal


def _visible(cam, Pc: np.ndarray, dmax: np.ndarray) -> np.ndarray:
    """Samples not hidden: the 3x3 max depth of the z-buffer reaches the sample's depth."""
    H, W = dmax.shape
    uv, okp = cam.project(Pc)
    inside = okp & cam.in_image(uv)
    ui = np.rint(np.clip(np.nan_to_num(uv[:, 0]), 0, W - 1)).astype(np.intp)     # clipped before the cast: a
    vi = np.rint(np.clip(np.nan_to_num(uv[:, 1]), 0, H - 1)).astype(np.intp)     # point behind has huge uv
    tol = np.maximum(0.003, 0.01 * Pc[:, 2])
    return inside & (dmax[vi, ui] >= Pc[:, 2] - tol)


def _orient(cam, Pc: np.ndarray, normal: np.ndarray, obj_index: np.ndarray, k: int) -> np.ndarray:
    """Turn the normals of object ``k``'s samples outwards (in place) by looking 1.5 px to either
    side in the label image; returns the outer flags (the object on exactly one side)."""
    K = cam.K
    H, W = obj_index.shape
    xy0 = project(Pc, K)
    sides = []
    for sgn in (1.0, -1.0):
        q = xy0 + sgn * 1.5 * normal
        qn = np.stack([(q[:, 0] - K[0, 2]) / K[0, 0], (q[:, 1] - K[1, 2]) / K[1, 1]], axis=1)
        quv = cam.distort_normalized(qn)
        qi = np.rint(quv).astype(np.intp)
        inimg = (qi[:, 0] >= 0) & (qi[:, 0] < W) & (qi[:, 1] >= 0) & (qi[:, 1] < H)
        lab = np.full(len(q), -1, np.int64)
        lab[inimg] = obj_index[qi[inimg, 1], qi[inimg, 0]]
        sides.append(lab == k)
    plus_in, minus_in = sides
    flip = plus_in & ~minus_in       # normal points into the object: turn it outwards
    normal[flip] *= -1
    return plus_in ^ minus_in        # object on exactly one side: outer silhouette


class Contours:
    """Visible contour samples of all objects for one window at a set of poses.

    ``P`` (object frame), ``obj`` (object index), ``normal`` (2D, outwards on the silhouette) and
    ``outer`` per sample; ``render`` the z-buffer, which may be lent to the contours of a small
    pose change (``render``), and ``reuse`` the contours whose samples are kept for every object
    but ``only``.
    """

    def __init__(self, scene, models, mesh_edges, T_bo_list, win: EventWindow, raster: Rasterizer, p: RefineParams,
                 clock, render=None, reuse=None, only=None):
        cam = scene.camera
        K = cam.K
        self.K = K
        T_bc_lab, ok = scene.T_base_cam(np.array([win.t_label]), clock=clock)
        self.valid = bool(ok[0])
        self.P = np.zeros((0, 3))
        self.obj = np.zeros(0, np.int64)
        self.normal = np.zeros((0, 2))
        self.outer = np.zeros(0, bool)
        self.render = None
        if not self.valid:
            return
        T_cb = inv_T(T_bc_lab[0])
        T_co = [T_cb @ T for T in T_bo_list]
        if render is None:  # the z-buffer for visibility and sides; may be reused for small pose changes
            render = _render(raster, models, T_co)
        self.render = render
        res, dmax = render
        P_obj, obj_id, nrm, outer = [], [], [], []
        for k, (me, T) in enumerate(zip(mesh_edges, T_co)):
            if only is not None and k != only and reuse is not None and reuse.valid:
                m = reuse.obj == k  # unchanged object: keep its samples
                P_obj.append(reuse.P[m])
                obj_id.append(reuse.obj[m])
                nrm.append(reuse.normal[m])
                outer.append(reuse.outer[m])
                continue
            samples = _edge_samples(cam, me, T, p.spacing_px)
            if samples is None:
                continue
            P, Pc, normal = samples
            vis = _visible(cam, Pc, dmax)
            if not vis.any():
                continue
            P, Pc, normal = P[vis], Pc[vis], normal[vis]
            out_flag = _orient(cam, Pc, normal, res.obj_index, k)
            P_obj.append(P)
            obj_id.append(np.full(len(P), k))
            nrm.append(normal)
            outer.append(out_flag)
        if P_obj:
            self.P = np.concatenate(P_obj)
            self.obj = np.concatenate(obj_id)
            self.normal = np.concatenate(nrm)
            self.outer = np.concatenate(outer)

    def associate(self, win: EventWindow, T_bo_list, band_px: float, n_sub: int):
        """Nearest edge sample per event (at the event's time, via ``n_sub`` sub-windows).

        Returns ``(event_index, sample_index, signed_distance_px)`` for events within ``band_px``.
        """
        if not self.valid or len(self.P) == 0 or not win.ok.any():
            return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0)
        Pb = np.empty_like(self.P)
        for k, T in enumerate(T_bo_list):
            m = self.obj == k
            Pb[m] = self.P[m] @ T[:3, :3].T + T[:3, 3]
        t = win.ev_t
        edges = np.linspace(win.t0, win.t1, n_sub + 1)
        sub = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n_sub - 1)
        ev_i, smp_i, sd = [], [], []
        for j in range(n_sub):
            e = np.flatnonzero((sub == j) & win.ok)
            if len(e) == 0:
                continue
            mid = e[len(e) // 2]
            T_cb = win.T_cb[mid]
            xy = project(Pb @ T_cb[:3, :3].T + T_cb[:3, 3], self.K)
            d, i = nearest_within(xy, win.xy[e], band_px)
            ok = np.isfinite(d)
            e, i = e[ok], i[ok]
            # signed distance with the exact per-event pose
            Pc = np.einsum("nij,nj->ni", win.T_cb[e, :3, :3], Pb[i]) + win.T_cb[e, :3, 3]
            s = np.einsum("ij,ij->i", self.normal[i], win.xy[e] - project(Pc, self.K))
            ev_i.append(e)
            smp_i.append(i)
            sd.append(s)
        if not ev_i:
            return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0)
        return np.concatenate(ev_i), np.concatenate(smp_i), np.concatenate(sd)

