"""Refinement from events: an object's pose correction ``dT_base`` or the clock offset.

Model edges
-----------
For each window the object's **contour generators** are taken from the mesh itself: edges
shared by a front- and a back-facing triangle (and boundary edges of open meshes), for the
camera position at the window's label time. They are sampled every ``spacing_px`` pixels, and
a sample is kept when the rasterised depth (all objects, one z-buffer) shows it is not hidden.
Each sample has a 2D normal; samples with the object's mask on one side and something else on
the other are *outer* silhouette samples (their normal points outwards); the others are depth
discontinuities inside the object (self-occlusion). Working from the mesh keeps the edges
sub-pixel exact (a rasterised boundary is biased half a pixel inwards, which at half DAVIS
resolution would be a ~2.5 % scale, i.e. ~10 mm depth, error).

Objective
---------
Every event is related to its nearest edge sample (at the event's own time: the camera pose is
interpolated per event, so a window's motion does not smear the fit) by its signed distance
``s = n . (x_event - x_edge)`` in undistorted pixels. The fit maximises the mean of

    K(s) = g(s) + beta * outer * (-s / sigma) * g(s) * e^0.5,   g(s) = exp(-s^2 / (2 sigma^2))

over the events within a band around the edges: the first term rewards events **on** the
edges, the second the **contrast** of event density across the silhouette (textured objects
fire more events inside than the background outside, or fewer: ``beta`` in [-1, 1] is
estimated from the events). The pose enters through the edge samples (fixed points on the
mesh, re-projected per event), the association is refreshed by re-rendering at each outer
iteration, and ``sigma`` goes coarse to fine (``sigmas_px``), so a start error of several
pixels is pulled in. The inner problem is smooth in the 6 pose parameters (translation in mm
and rotation scaled to mm at the object radius, about the object's centre in the base frame)
and is solved by BFGS; the clock offset is a 1-D bounded search of the same objective.

Acceptance
----------
The result is compared with the start on the same events with a fresh association for each
(``objective_before`` / ``objective_after``, at the finest sigma): when the fit does not
improve it, the start is kept (``accepted=False``). ``score_before`` / ``score_after`` are the
:mod:`core.score` alignment scores of the same windows (mean over windows), for reporting.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from evpose.core.data.events import Cancelled
from evpose.core.data.geometry import inv_T, make_T
from evpose.core.label.raster import Rasterizer

__all__ = ["RefineResult", "RefineParams", "refine_object", "refine_offset", "refine_offset_from_sync",
           "sync_edge_half_range_us", "apply_offset_result", "choose_windows", "delta_T"]


# ---------------------------------------------------------------------------- parameters / results
#: Coarse-to-fine kernel widths (px at half DAVIS346 resolution, fx = 146; scaled by fx / 146).
DEFAULT_SIGMAS_PX = (1.5, 0.8, 0.5, 0.3, 0.2, 0.12, 0.08)
#: Windows are taken where the image moves at least this fast (px/s at half DAVIS346 resolution,
#: scaled by fx / 146): a camera speed of ~0.07 m/s past a scene 0.5 m away; on slower sequences
#: at least MIN_WINDOW_SHARE of the sequence's fast image speed (95th percentile), at least 1 px/s.
MIN_WINDOW_PX_S = 20.0
MIN_WINDOW_SHARE = 0.25


@dataclass(frozen=True)
class RefineParams:
    """Knobs of the refinement (pixels are pixels of the scene camera).

    ``sigmas_px=None`` picks :data:`DEFAULT_SIGMAS_PX` = ``(1.5, 0.8, 0.5, 0.3, 0.2, 0.12, 0.08)``
    px scaled by ``fx / 146`` (half DAVIS346 focal length), i.e. ~3 px down to ~0.16 px at full
    DAVIS resolution. The fine levels matter: on textured objects the event density is much
    higher inside the silhouette than outside, and the edge kernel's optimum is then displaced
    from the true edge by an amount proportional to ``sigma`` (on the benchmark scenes, stopping
    at 0.5 px left ~1.5 mm of depth and ~1 degree of out-of-plane rotation; ``bench/accuracy.py``).
    Windows are motion-compensated per event, so they may be long (10 ms); more windows spread
    over the sequence give more viewpoints, which is what constrains the depth and the rotation.
    """

    n_windows: int = 24
    window_us: int = 10_000
    max_events: int = 20_000
    sigmas_px: tuple | None = None
    outer_per_level: int = 8
    step_sigmas: float = 1.0      # trust region of one outer step: edges move at most this many sigma
    band_sigmas: float = 3.0
    spacing_px: float = 0.5
    max_iter: int = 60
    n_sub: int = 3
    polish_evals: int = 0         # compass-search evaluations per level (0: none)
    polish_min_sigmas: float = 0.05
    ridge_sigma_px: float = 10.0  # the ridge term is used at levels with sigma <= this (x fx/146)


@dataclass
class RefineResult:
    """Outcome of a refinement.

    Attributes
    ----------
    kind : "pose" or "offset"
    object : str or None
    dT_base : (4, 4) or None
        The object's **total** correction to store (``T_base_obj' = dT_base @ T_base_obj``
        of the manifest); the start value when not accepted.
    offset_us : int or None
        Total effective clock offset (offset refinement).
    offset_std_us : float or None
        Its standard error (jackknife over the windows) when accepted; ``inf`` when the windows
        do not pin it, NaN with fewer than 3 windows.
    skew_ppm : float or None
        Total skew of the accepted clock (the start's unless ``skew_estimated``).
    skew_std_ppm : float or None
        Standard error of the skew fitted from the windows (also when it was not taken).
    skew_estimated : bool
        The fitted skew was taken (see :func:`refine_offset`).
    dR_deg, dt_mm : float
        Size of the change found (rotation angle, translation of the object's centre).
    score_before, score_after : float or None
        Mean :mod:`core.score` alignment score over the refinement windows.
    objective_before, objective_after : float
        The fitted objective (mean kernel value per event, higher is better).
    n_windows, iterations : int
    runtime_s : float
    accepted : bool
    reason : str
    trace : list of dict
        Per outer iteration: ``iteration``, ``sigma_px``, ``objective``, ``T_base_obj`` or
        ``offset_us``, ``elapsed_s`` (for error-against-iterations benchmarks).
    """

    kind: str
    object: str | None
    dT_base: np.ndarray | None = None
    offset_us: int | None = None
    offset_std_us: float | None = None
    skew_ppm: float | None = None
    skew_std_ppm: float | None = None
    skew_estimated: bool = False
    dR_deg: float = 0.0
    dt_mm: float = 0.0
    score_before: float | None = None
    score_after: float | None = None
    objective_before: float = float("nan")
    objective_after: float = float("nan")
    n_windows: int = 0
    iterations: int = 0
    runtime_s: float = 0.0
    accepted: bool = False
    reason: str = ""
    trace: list = field(default_factory=list)

    def to_json(self) -> dict:
        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)

        d = {"kind": self.kind, "object": self.object, "dR_deg": float(self.dR_deg), "dt_mm": float(self.dt_mm),
             "score_before": num(self.score_before), "score_after": num(self.score_after),
             "objective_before": num(self.objective_before), "objective_after": num(self.objective_after),
             "n_windows": int(self.n_windows), "iterations": int(self.iterations),
             "runtime_s": float(self.runtime_s), "accepted": bool(self.accepted), "reason": self.reason}
        if self.dT_base is not None:
            d["dT_base"] = np.asarray(self.dT_base).tolist()
        if self.offset_us is not None:
            d["offset_us"] = int(self.offset_us)
        if self.offset_std_us is not None:
            d["offset_std_us"] = num(self.offset_std_us)
        if self.kind == "offset":
            d["skew_ppm"] = num(self.skew_ppm)
            d["skew_std_ppm"] = num(self.skew_std_ppm)
            d["skew_estimated"] = bool(self.skew_estimated)
        return d


def delta_T(x: np.ndarray, centre_m: np.ndarray, radius_m: float) -> np.ndarray:
    """``dT_base`` from parameters ``x = (t_mm (3), r (3))``: rotation vector ``r * 1 mm / radius``
    about ``centre_m`` (base frame), then a translation of ``t_mm`` millimetres."""
    x = np.asarray(x, dtype=np.float64)
    R = Rotation.from_rotvec(x[3:6] * 1e-3 / radius_m).as_matrix()
    return make_T(R, centre_m + x[:3] * 1e-3 - R @ centre_m)


def _pose_change(dT: np.ndarray, centre_m: np.ndarray) -> tuple[float, float]:
    """(rotation deg, displacement of the centre mm) of a base-frame delta."""
    ang = float(np.degrees(Rotation.from_matrix(dT[:3, :3]).magnitude()))
    moved = dT[:3, :3] @ centre_m + dT[:3, 3] - centre_m
    return ang, float(np.linalg.norm(moved) * 1e3)


# ---------------------------------------------------------------------------- mesh contours
class _MeshEdges:
    """Edge topology of a mesh: unique edges, their (up to two) faces, face normals."""

    def __init__(self, model):
        V = np.asarray(model.vertices_m, dtype=np.float64)
        F = np.asarray(model.faces, dtype=np.int64)
        e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        fid = np.tile(np.arange(len(F)), 3)
        es = np.sort(e, axis=1)
        key = es[:, 0] * len(V) + es[:, 1]
        order = np.argsort(key, kind="stable")
        ks = key[order]
        _, start, counts = np.unique(ks, return_index=True, return_counts=True)
        self.edges = es[order[start]]
        self.f1 = fid[order[start]]
        nxt = np.minimum(start + 1, len(order) - 1)
        self.f2 = np.where(counts >= 2, fid[order[nxt]], -1)
        self.V = V
        self.normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        self.v0 = V[F[:, 0]]
        lo, hi = V.min(0), V.max(0)
        self.centre = 0.5 * (lo + hi)
        self.radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)

    def contour_edges(self, cam_pos_obj: np.ndarray) -> np.ndarray:
        """Indices of contour-generator and open boundary edges seen from ``cam_pos_obj``."""
        facing = np.einsum("ij,ij->i", self.normals, cam_pos_obj - self.v0) > 0
        f1 = facing[self.f1]
        f2 = np.where(self.f2 >= 0, facing[np.maximum(self.f2, 0)], ~f1)
        boundary = self.f2 < 0
        return np.flatnonzero((f1 != f2) & (~boundary | f1))


class _Window:
    """Events of one window prepared for fitting: undistorted pixels, per-event camera pose."""

    def __init__(self, scene, t0_us: int, t1_us: int, clock, max_events: int):
        self.t0, self.t1 = int(t0_us), int(t1_us)
        self.t_label = self.t0 + (self.t1 - self.t0) // 2
        ev = scene.events.window(self.t0, self.t1)
        if len(ev) > max_events:
            ev = ev[::int(math.ceil(len(ev) / max_events))]
        self.ev_t = ev.t
        cam = scene.camera
        uv = np.stack([ev.x, ev.y], axis=1).astype(np.float64)
        self.xy = cam.undistort_points(uv, K_new=cam.K) if len(ev) else np.zeros((0, 2))
        self.set_clock(scene, clock)

    def set_clock(self, scene, clock):
        T_bc, ok = scene.T_base_cam(self.ev_t, clock=clock)
        self.ok = ok & np.all(np.isfinite(self.xy), axis=1)
        self.T_cb = inv_T(T_bc)        # (M, 4, 4) camera <- base, per event
        self.clock = clock


def _project(P_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    z = np.maximum(P_cam[..., 2], 1e-6)
    return np.stack([K[0, 0] * P_cam[..., 0] / z + K[0, 2], K[1, 1] * P_cam[..., 1] / z + K[1, 2]], axis=-1)


class _Contours:
    """Visible contour samples of all objects for one window at a set of poses."""

    def __init__(self, scene, models, mesh_edges, T_bo_list, win: _Window, raster: Rasterizer, p: RefineParams,
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
            import cv2

            res = raster.render_objects(models, T_co)
            depth = res.depth_m.astype(np.float32)
            dmax = cv2.dilate(np.where(np.isfinite(depth), depth, np.float32(1e9)), np.ones((3, 3), np.uint8))
            render = (res, dmax)
        self.render = render
        res, dmax = render
        H, W = dmax.shape
        P_obj, obj_id, nrm, outer = [], [], [], []
        for k, (me, T) in enumerate(zip(mesh_edges, T_co)):
            if only is not None and k != only and reuse is not None and reuse.valid:
                m = reuse.obj == k  # unchanged object: keep its samples
                P_obj.append(reuse.P[m])
                obj_id.append(reuse.obj[m])
                nrm.append(reuse.normal[m])
                outer.append(reuse.outer[m])
                continue
            cam_obj = inv_T(T)[:3, 3]
            idx = me.contour_edges(cam_obj)
            if len(idx) == 0:
                continue
            A = me.V[me.edges[idx, 0]]
            B = me.V[me.edges[idx, 1]]
            Ac = A @ T[:3, :3].T + T[:3, 3]
            Bc = B @ T[:3, :3].T + T[:3, 3]
            front = (Ac[:, 2] > cam.near_m) & (Bc[:, 2] > cam.near_m)
            A, B, Ac, Bc = A[front], B[front], Ac[front], Bc[front]
            if len(A) == 0:
                continue
            pa, pb = _project(Ac, K), _project(Bc, K)
            L = np.linalg.norm(pb - pa, axis=1)
            n = np.maximum(1, np.ceil(L / p.spacing_px)).astype(np.int64)
            n = np.minimum(n, 4096)
            rep = np.repeat(np.arange(len(A)), n)
            frac = (np.arange(len(rep)) - np.repeat(np.cumsum(n) - n, n) + 0.5) / n[rep]
            P = A[rep] + frac[:, None] * (B[rep] - A[rep])
            Pc = P @ T[:3, :3].T + T[:3, 3]
            d2 = pb[rep] - pa[rep]
            d2 = d2 / np.maximum(np.linalg.norm(d2, axis=1, keepdims=True), 1e-12)
            normal = np.stack([d2[:, 1], -d2[:, 0]], axis=1)
            # visibility against the z-buffer (3x3 max depth must reach the sample's depth)
            uv, okp = cam.project(Pc)
            inside = okp & cam.in_image(uv)
            ui = np.clip(np.rint(np.nan_to_num(uv[:, 0])).astype(np.intp), 0, W - 1)
            vi = np.clip(np.rint(np.nan_to_num(uv[:, 1])).astype(np.intp), 0, H - 1)
            tol = np.maximum(0.003, 0.01 * Pc[:, 2])
            vis = inside & (dmax[vi, ui] >= Pc[:, 2] - tol)
            if not vis.any():
                continue
            P, Pc, normal = P[vis], Pc[vis], normal[vis]
            # which side is the object? look 1.5 px to either side in the label image
            xy0 = _project(Pc, K)
            sides = []
            for sgn in (1.0, -1.0):
                q = xy0 + sgn * 1.5 * normal
                qn = np.stack([(q[:, 0] - K[0, 2]) / K[0, 0], (q[:, 1] - K[1, 2]) / K[1, 1]], axis=1)
                quv = cam.distort_normalized(qn)
                qi = np.rint(quv).astype(np.intp)
                inimg = (qi[:, 0] >= 0) & (qi[:, 0] < W) & (qi[:, 1] >= 0) & (qi[:, 1] < H)
                lab = np.full(len(q), -1, np.int64)
                lab[inimg] = res.obj_index[qi[inimg, 1], qi[inimg, 0]]
                sides.append(lab == k)
            plus_in, minus_in = sides
            flip = plus_in & ~minus_in       # normal points into the object: turn it outwards
            normal[flip] *= -1
            out_flag = plus_in ^ minus_in    # object on exactly one side: outer silhouette
            P_obj.append(P)
            obj_id.append(np.full(len(P), k))
            nrm.append(normal)
            outer.append(out_flag)
        if not P_obj:
            self.P = np.zeros((0, 3))
            self.obj = np.zeros(0, np.int64)
            self.normal = np.zeros((0, 2))
            self.outer = np.zeros(0, bool)
        else:
            self.P = np.concatenate(P_obj)
            self.obj = np.concatenate(obj_id)
            self.normal = np.concatenate(nrm)
            self.outer = np.concatenate(outer)
        self.res = res

    def associate(self, win: _Window, T_bo_list, band_px: float, n_sub: int):
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
            xy = _project(Pb @ T_cb[:3, :3].T + T_cb[:3, 3], self.K)
            tree = cKDTree(xy)
            d, i = tree.query(win.xy[e], distance_upper_bound=band_px)
            ok = np.isfinite(d)
            e, i = e[ok], i[ok]
            # signed distance with the exact per-event pose
            Pc = np.einsum("nij,nj->ni", win.T_cb[e, :3, :3], Pb[i]) + win.T_cb[e, :3, 3]
            s = np.einsum("ij,ij->i", self.normal[i], win.xy[e] - _project(Pc, self.K))
            ev_i.append(e)
            smp_i.append(i)
            sd.append(s)
        if not ev_i:
            return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0)
        return np.concatenate(ev_i), np.concatenate(smp_i), np.concatenate(sd)


# ---------------------------------------------------------------------------- window choice
def _window_speeds_px_s(scene, centres_us: np.ndarray, window_us: int, clock, proxy=None):
    """Mean image speed (px/s, :func:`evpose.core.align.scene_proxy.scene_motion_proxy`) over windows of
    ``window_us`` centred on ``centres_us``; returns ``(speed, valid)``."""
    from evpose.core.align.scene_proxy import scene_motion_proxy

    proxy = proxy or scene_motion_proxy(scene)
    c = np.asarray(centres_us, np.int64)
    a = clock.pose_time_rel(c - window_us // 2, proxy.t0_us)
    b = clock.pose_time_rel(c + window_us // 2, proxy.t0_us)
    return proxy.mean_over(a, b)


def choose_windows(scene, n_windows: int, window_us: int, objects=None, clock=None, min_px_s: float | None = None,
                   proxy=None):
    """``n_windows`` windows of ``window_us`` spread evenly over the moving part of the sequence
    (image speed above ``min_px_s``, default :data:`MIN_WINDOW_PX_S` at half DAVIS346 resolution
    scaled by ``fx / 146``, lowered to a quarter of the sequence's fast speed on slow sequences,
    and, when ``objects`` are given, at least one of them in front of the camera). ``proxy``:
    the scene's :func:`evpose.core.align.scene_proxy.scene_motion_proxy` when the caller has it.
    Returns a list of ``(t0_us, t1_us)``."""
    ev = scene.events
    if ev.t_first_us is None or ev.t_last_us - ev.t_first_us < window_us:
        return []
    clock = clock or scene.clock
    grid = np.arange(ev.t_first_us + window_us, ev.t_last_us - window_us, max(window_us // 2, 500), dtype=np.int64)
    if len(grid) == 0:
        return []
    sp, ok = _window_speeds_px_s(scene, grid, window_us, clock, proxy)
    if min_px_s is None:
        # a slow sequence (low resolution, far scene) still has its faster half
        fast = float(np.percentile(sp[ok], 95)) if ok.any() else 0.0
        min_px_s = max(min(MIN_WINDOW_PX_S * float(scene.camera.K[0, 0]) / 146.0, MIN_WINDOW_SHARE * fast), 1.0)
    good = ok & (sp >= min_px_s)
    if objects:
        T, v = scene.T_cam_obj(grid, objects, clock=clock)
        z = T[:, :, 2, 3]
        good &= v & (z > 0.05).any(axis=1)
    cand = grid[good]
    if len(cand) == 0:
        return []
    pick = cand[np.unique(np.linspace(0, len(cand) - 1, min(n_windows, len(cand))).round().astype(int))]
    return [(int(t - window_us // 2), int(t - window_us // 2 + window_us)) for t in pick]


# ---------------------------------------------------------------------------- refinement
class _Setup:
    def __init__(self, scene, names, windows, clock, p: RefineParams):
        self.scene = scene
        self.names = names
        self.models = [scene.raster_model(n) for n in names]
        self.edges = [_MeshEdges(m) for m in self.models]
        self.raster = Rasterizer(scene.camera)
        self.clock = clock
        self.wins = [_Window(scene, a, b, clock, p.max_events) for a, b in windows]
        fx = float(scene.camera.K[0, 0])
        self.sigmas = tuple(p.sigmas_px) if p.sigmas_px else tuple(s * fx / 146.0 for s in DEFAULT_SIGMAS_PX)
        self.p = p

    def contours(self, T_bo_list, clock=None, previous=None, only=None):
        """Contour samples per window; ``previous`` contours lend their z-buffers (no re-render)
        and, with ``only=k``, the samples of every object but k."""
        prev = previous or [None] * len(self.wins)
        return [_Contours(self.scene, self.models, self.edges, T_bo_list, w, self.raster, self.p, clock or self.clock,
                          None if c is None or not c.valid else c.render, c, only)
                for w, c in zip(self.wins, prev)]


def _kernel(s, outer, sigma, beta, ridge=1.0):
    u = s / sigma
    g = np.exp(-0.5 * u * u)
    # ridge (events on the edge) + odd, decaying step detector (density contrast across it);
    # both vanish away from the edge, so a fixed event set cannot drift the fit outwards
    return ridge * g + beta * outer * (-u) * g * _E05


_E05 = math.exp(0.5)


def _beta(s, outer, sigma):
    o = outer & (np.abs(s) <= 3 * sigma)
    n_in, n_out = int((s[o] < 0).sum()), int((s[o] > 0).sum())
    return 0.0 if n_in + n_out < 10 else float((n_in - n_out) / (n_in + n_out))


def _band_distances(setup: _Setup, T_bo_list, k: int | None, sigma: float, clock, contours):
    """Per window: signed distances and outer flags of the events within the band of the
    contours (object k's only when k is given)."""
    band = setup.p.band_sigmas * sigma
    S, O = [], []
    for w, c in zip(setup.wins, contours):
        if clock is not None and w.clock is not clock:
            w.set_clock(setup.scene, clock)
        ei, si, sd = c.associate(w, T_bo_list, band, setup.p.n_sub)
        if k is not None:
            keep = c.obj[si] == k
            si, sd = si[keep], sd[keep]
        S.append(sd)
        O.append(c.outer[si])
    return S, O


def _evaluate(setup: _Setup, T_bo_list, k: int | None, sigma: float, beta: float | None, clock=None,
              contours=None, per_window: bool = False):
    """Objective at a pose set: mean kernel over events associated with object k (all objects
    when k is None) within the band; also returns beta and the event count (and, with
    ``per_window``, each window's share of the objective, which sum to it)."""
    contours = contours or setup.contours(T_bo_list, clock)
    S, O = _band_distances(setup, T_bo_list, k, sigma, clock, contours)
    s = np.concatenate(S) if S else np.zeros(0)
    o = np.concatenate(O) if O else np.zeros(0, bool)
    if beta is None:
        beta = _beta(s, o, sigma)
    # a sum over the events within the band of the current edges (normalised by the fixed number
    # of events in the windows), not a mean: a pose that keeps fewer events near its edges must
    # not win by discarding the badly fitting ones
    n_all = max(sum(int(w.ok.sum()) for w in setup.wins), 1)
    val = float(_kernel(s, o, sigma, beta).sum()) / n_all if len(s) else float("nan")
    if per_window:
        parts = np.array([float(_kernel(a, b, sigma, beta).sum()) / n_all for a, b in zip(S, O)])
        return val, beta, len(s), parts
    return val, beta, len(s)


def _mean_score(scene, windows, name, poses=None, clock=None):
    from evpose.core.align.score_table import score_windows

    try:
        tab = score_windows(scene, windows, [name], poses=poses, clock=clock)
    except Exception:  # scoring is for reporting only
        return None
    return tab.mean_score(name)


def refine_object(scene, name: str, *, windows=None, params: RefineParams = RefineParams(), clock=None,
                  with_scores: bool = True, progress=None, cancel=None) -> RefineResult:
    """Refine the pose correction of object ``name`` (6-DoF, base frame) from events.

    Parameters
    ----------
    scene : evpose.core.data.scene.Scene
        Its current corrections are the start.
    windows : list of (t0_us, t1_us), optional
        Default :func:`choose_windows` (``params.n_windows`` windows of ``params.window_us``).
    clock : ClockModel, optional
        Default: the scene's clock in effect (synchronise first).
    progress : callable, optional
        ``progress(fraction, message)``.
    cancel : callable, optional
        ``cancel() -> bool``; True raises :class:`evpose.core.data.events.Cancelled`.
    """
    t_start = time.perf_counter()
    names = scene.object_names
    if name not in names:
        raise KeyError(f"{scene.manifest.path}: objects: no object named {name!r}")
    k = names.index(name)
    clock = clock or scene.clock
    start_delta = scene.corrections.object_delta(name)
    T_manifest = scene.manifest.object(name).T_base_obj
    result = RefineResult("pose", name, dT_base=start_delta)
    if windows is None:
        windows = choose_windows(scene, params.n_windows, params.window_us, [name], clock)
    result.n_windows = len(windows)
    if not windows:
        result.reason = "no window with camera motion and the object in view"
        result.runtime_s = time.perf_counter() - t_start
        return result
    setup = _Setup(scene, names, windows, clock, params)
    T_bo = [scene.T_base_obj(n) for n in names]
    T_start = T_bo[k].copy()
    me = setup.edges[k]
    radius = me.radius
    it = 0
    n_total = len(setup.sigmas) * params.outer_per_level
    K = scene.camera.K
    # pixels per millimetre at the object (for the per-step trust region)
    T_co_w, v_w = scene.T_cam_obj(np.array([w.t_label for w in setup.wins]), [name], clock=clock)
    z_med = float(np.median(T_co_w[v_w, 0, 2, 3])) if v_w.any() else 0.5
    px_per_mm = float(K[0, 0]) * 1e-3 / max(z_med, 0.05)
    stop = False
    n_eval = 0
    for level, sigma in enumerate(setup.sigmas):
        if cancel is not None and cancel():
            raise Cancelled("refinement cancelled")
        renders = setup.contours(T_bo)          # one z-buffer per window and level
        # the level's objective (fresh association, fixed beta): every accepted step must raise it
        j_cur, beta, _ = _evaluate(setup, T_bo, k, sigma, None, contours=renders)
        ridge = 1.0 if sigma <= params.ridge_sigma_px * float(K[0, 0]) / 146.0 + 1e-9 else 0.0
        contours = renders
        for outer in range(params.outer_per_level):
            if cancel is not None and cancel():
                raise Cancelled("refinement cancelled")
            band = params.band_sigmas * sigma
            data = []
            for w, c in zip(setup.wins, contours):
                ei, si, sd = c.associate(w, T_bo, band, params.n_sub)
                keep = c.obj[si] == k
                ei, si = ei[keep], si[keep]
                if len(ei) == 0:
                    continue
                Pb = c.P[si] @ T_bo[k][:3, :3].T + T_bo[k][:3, 3]
                data.append((w.xy[ei], w.T_cb[ei, :3, :], Pb, c.normal[si], c.outer[si]))
            if not data:
                result.reason = "no events near the object's edges"
                stop = True
                break
            xy = np.concatenate([d[0] for d in data])
            A = np.concatenate([d[1] for d in data])
            Pb = np.concatenate([d[2] for d in data])
            nrm = np.concatenate([d[3] for d in data])
            out = np.concatenate([d[4] for d in data]).astype(np.float64)
            centre = T_bo[k][:3, :3] @ me.centre + T_bo[k][:3, 3]
            Rm, tm = A[:, :, :3], A[:, :, 3]

            def s_of(x):
                dT = delta_T(x, centre, radius)
                Q = Pb @ dT[:3, :3].T + dT[:3, 3]
                Pc = np.einsum("nij,nj->ni", Rm, Q) + tm
                return np.einsum("ij,ij->i", nrm, xy - _project(Pc, K))

            def f(x):
                return -float(_kernel(s_of(x), out, sigma, beta, ridge).mean())

            # proposal: the fit with the association held fixed, within a trust region (edges move
            # at most step_sigmas * sigma)
            step = params.step_sigmas * sigma / px_per_mm
            res = optimize.minimize(f, np.zeros(6), method="L-BFGS-B", bounds=[(-step, step)] * 6,
                                    options={"maxiter": params.max_iter, "eps": 1e-3})
            # acceptance: backtracking on the level's objective with a fresh association
            accepted_step = None
            for alpha in (1.0, 0.5, 0.25):
                x = alpha * res.x
                T_try = list(T_bo)
                T_try[k] = delta_T(x, centre, radius) @ T_bo[k]
                c_try = setup.contours(T_try, previous=contours, only=k)
                j_try, _, _ = _evaluate(setup, T_try, k, sigma, beta, contours=c_try)
                n_eval += 1
                if np.isfinite(j_try) and j_try > j_cur:
                    accepted_step = (x, T_try, c_try, j_try)
                    break
            if accepted_step is None:
                break  # no improving step: converged at this level
            x, T_bo, contours, j_cur = accepted_step
            it += 1
            result.trace.append({"iteration": it, "sigma_px": float(sigma), "objective": float(j_cur),
                                 "n_events": int(len(xy)), "beta": beta, "T_base_obj": T_bo[k].copy(),
                                 "step_mm": float(np.abs(x).max()), "elapsed_s": time.perf_counter() - t_start})
            if progress is not None:
                progress(min(it / n_total, 1.0), f"{name}: sigma {sigma:.2f} px, objective {j_cur:.4f}")
            if np.abs(x).max() < 0.02:  # converged at this level (< 0.02 mm)
                break
        if stop:
            break
        # polish: compass search on the level's objective itself (fresh association), which
        # also escapes where the fixed-association proposal stalls
        if params.polish_evals > 0:
            h = 0.5 * sigma / px_per_mm
            h_min = params.polish_min_sigmas * sigma / px_per_mm
            evals = 0
            while h >= h_min and evals < params.polish_evals:
                improved = False
                centre = T_bo[k][:3, :3] @ me.centre + T_bo[k][:3, 3]
                for i in range(6):
                    for sgn in (1.0, -1.0):
                        x = np.zeros(6)
                        x[i] = sgn * h
                        T_try = list(T_bo)
                        T_try[k] = delta_T(x, centre, radius) @ T_bo[k]
                        c_try = setup.contours(T_try, previous=contours, only=k)
                        j_try, _, _ = _evaluate(setup, T_try, k, sigma, beta, contours=c_try)
                        evals += 1
                        if np.isfinite(j_try) and j_try > j_cur:
                            T_bo, contours, j_cur, improved = T_try, c_try, j_try, True
                            break
                    if improved:
                        break
                if not improved:
                    h *= 0.5
            it += 1
            result.trace.append({"iteration": it, "sigma_px": float(sigma), "objective": float(j_cur),
                                 "n_events": -1, "beta": beta, "T_base_obj": T_bo[k].copy(), "step_mm": h,
                                 "polish_evals": evals, "elapsed_s": time.perf_counter() - t_start})
    result.iterations = it
    # acceptance on the same windows, fresh association, finest sigma, same beta
    sig = setup.sigmas[-1]
    T_before = [scene.T_base_obj(n) for n in names]
    j0, beta0, n0 = _evaluate(setup, T_before, k, sig, None)
    j1, _, n1 = _evaluate(setup, T_bo, k, sig, beta0)
    result.objective_before, result.objective_after = j0, j1
    improved = np.isfinite(j1) and (not np.isfinite(j0) or j1 > j0)
    if improved and it > 0:
        new_delta = T_bo[k] @ inv_T(T_manifest)
        result.dT_base = new_delta
        result.accepted = True
        dT_change = T_bo[k] @ inv_T(T_start)
        c0 = T_start[:3, :3] @ me.centre + T_start[:3, 3]
        result.dR_deg, result.dt_mm = _pose_change(dT_change, c0)
    elif not result.reason:
        result.reason = "the fit did not improve the objective; start kept"
    if with_scores:
        result.score_before = _mean_score(scene, windows, name, clock=clock)
        result.score_after = _mean_score(scene, windows, name, clock=clock,
                                         poses={name: result.dT_base @ T_manifest})
    result.runtime_s = time.perf_counter() - t_start
    return result


#: Final grid of :func:`refine_offset`: offsets ``± STD_GRID_STEPS`` steps of a quarter of the
#: finest kernel's width (in time, at the windows' median image speed) around the optimum, widened
#: by the drift the skew range allows over the windows.
STD_GRID_STEPS = 6
#: Skew change searched by :func:`refine_offset` around the start skew (ppm). The fitted skew
#: replaces the start's when its standard error is at most SKEW_EDGE_MAX_STD_PPM (the windows pin
#: it: the event rate's own skew on a short sequence can be off by 100+ ppm) or when the change
#: stands out by SKEW_EDGE_SIGMAS standard errors.
SKEW_EDGE_RANGE_PPM = 300.0
SKEW_EDGE_MAX_STD_PPM = 15.0
SKEW_EDGE_SIGMAS = 3.0


def _peak_fit(grid: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Centre and height of a least-squares parabola through the upper half of a sampled peak
    (the points within half the sampled range of the maximum), so the fine-scale roughness of
    the objective (events changing their nearest edge sample) does not decide the offset.
    ``(nan, nan)`` when the peak is not inside the evenly spaced ``grid``."""
    nan = (float("nan"), float("nan"))
    ok = np.isfinite(y)
    if ok.sum() < 3:
        return nan
    j = int(np.argmax(np.where(ok, y, -np.inf)))
    if j == 0 or j == len(y) - 1:
        return nan
    ymax, ymin = float(y[j]), float(np.min(y[ok]))
    use = ok & (y >= ymax - 0.5 * (ymax - ymin))
    if use.sum() < 3:
        use = np.zeros(len(y), bool)
        use[j - 1:j + 2] = True
    step = float(grid[1] - grid[0])
    x = (grid[use] - grid[j]) / step
    c2, c1, c0 = np.polyfit(x, y[use], 2)
    if not c2 < 0:
        return nan
    xc = -c1 / (2.0 * c2)
    centre = float(grid[j] + xc * step)
    if not grid[0] <= centre <= grid[-1]:
        return nan
    return centre, float(c0 + c1 * xc + c2 * xc * xc)


def _clock_fit(grid_us: np.ndarray, parts: np.ndarray, tau_us: np.ndarray, dk_ppm: np.ndarray) -> tuple:
    """Offset and skew change that maximise the windows' summed objective.

    ``parts[:, w]`` is window w's share of the objective at the offsets ``grid_us`` (all at the
    start skew); a window only sees the clock through its effective offset, so under a skew
    change ``dk`` window w at ``tau_us[w]`` (µs after the clock's reference) is read at
    ``c + dk * (tau_w - mean tau)``, where ``c`` is the offset at the windows' mean time. For
    each ``dk`` of the evenly spaced ``dk_ppm`` the summed curve's peak (:func:`_peak_fit` on
    the grid's central part, which every window covers) gives ``c`` and a height; the heights'
    peak over ``dk`` gives the skew change. Returns ``(offset_us at the clock reference,
    dk_ppm)``; NaNs when the peak is not inside the grids. With ``dk_ppm = [0]`` it is the 1-D
    offset fit at the start skew.
    """
    nan = (float("nan"), float("nan"))
    rel = (tau_us - tau_us.mean()) * 1e-6
    margin = float(np.max(np.abs(dk_ppm))) * float(np.max(np.abs(rel), initial=0.0))
    cgrid = grid_us[(grid_us >= grid_us[0] + margin - 1e-6) & (grid_us <= grid_us[-1] - margin + 1e-6)]
    if len(cgrid) < 3:
        return nan

    def peak_at(dk):
        tot = np.zeros(len(cgrid))
        for w in range(parts.shape[1]):
            tot += np.interp(cgrid + dk * rel[w], grid_us, parts[:, w])
        return _peak_fit(cgrid, tot)

    if len(dk_ppm) == 1:
        c, _ = peak_at(float(dk_ppm[0]))
        dk = float(dk_ppm[0])
    else:
        heights = np.array([peak_at(float(d))[1] for d in dk_ppm])
        dk, _ = _peak_fit(dk_ppm, heights)
        if not np.isfinite(dk):
            return nan
        c, _ = peak_at(dk)
    if not np.isfinite(c):
        return nan
    return c - dk * 1e-6 * float(tau_us.mean()), dk


def _jackknife_clock(grid_us: np.ndarray, parts: np.ndarray, tau_us: np.ndarray, dk_ppm: np.ndarray) -> tuple:
    """Jackknife standard errors of :func:`_clock_fit` over windows: ``(offset std µs, skew std
    ppm)`` from the leave-one-window-out fits (their spread scaled by ``(n - 1) / n``); ``inf``
    when a leave-one-out peak is not inside the grids (the windows do not pin it), NaN for fewer
    than 3 windows."""
    n = parts.shape[1]
    if n < 3:
        return float("nan"), float("nan")
    fits = np.array([_clock_fit(grid_us, np.delete(parts, i, axis=1), np.delete(tau_us, i), dk_ppm)
                     for i in range(n)])
    if not np.isfinite(fits).all():
        return float("inf"), float("inf")
    sd = np.sqrt((n - 1) / n * ((fits - fits.mean(axis=0)) ** 2).sum(axis=0))
    return float(sd[0]), float(sd[1])


#: Windows of the offset refinement hold at least this much image motion at the sequence's fast
#: speed (px), up to MAX_OFFSET_WINDOW_US: on a slow sequence a 10 ms window holds few events.
OFFSET_WINDOW_PX = 1.0
MAX_OFFSET_WINDOW_US = 50_000


def offset_window_us(proxy, window_us: int) -> int:
    """Window length for :func:`refine_offset`: ``window_us``, lengthened on slow sequences so the
    image moves :data:`OFFSET_WINDOW_PX` at the fast (95th percentile) speed of the scene's
    motion ``proxy`` (:func:`evpose.core.align.scene_proxy.scene_motion_proxy`)."""
    v = proxy.value[proxy.value > 0]
    if len(v) == 0:
        return int(window_us)
    fast = float(np.percentile(v, 95))
    return int(np.clip(OFFSET_WINDOW_PX / max(fast, 1e-3) * 1e6, window_us, max(window_us, MAX_OFFSET_WINDOW_US)))


def refine_offset(scene, *, windows=None, params: RefineParams = RefineParams(), half_range_us: float = 3000.0,
                  clock=None, skew_range_ppm: float = SKEW_EDGE_RANGE_PPM, progress=None,
                  cancel=None) -> RefineResult:
    """Refine the clock offset from event/edge alignment over all objects (and the skew, when
    the windows show it): a bounded 1-D search within ``± half_range_us`` of the start clock,
    coarse to fine, then a fit of offset and skew on the finest level.

    The start is ``clock`` (default: the scene's clock in effect). A range wider than the
    coarsest kernel's width in time (its sigma over the windows' median image speed) is scanned
    on a grid first, so a start several milliseconds off on a fast sequence is pulled in. The
    object poses are taken as right: an error in them shifts the edges as an offset would.

    The estimate is not the optimiser's last point (the objective is rough on a fine scale):
    each window's share of the finest level's objective is sampled on a grid of offsets, and
    :func:`_clock_fit` takes the centre of a parabola through the top of their sum; with a skew
    change within ``± skew_range_ppm``, windows at different times are read at different
    offsets. The fitted skew is taken when the windows pin it (:data:`SKEW_EDGE_MAX_STD_PPM`)
    or when it stands out by :data:`SKEW_EDGE_SIGMAS` standard errors (``skew_range_ppm=0``
    keeps the start's). Standard errors are jackknifed over the windows
    (:func:`_jackknife_clock`; they grow when windows disagree, but a pose error that shifts all
    windows alike does not show in them).

    Returns the total offset in ``offset_us`` (at the clock's reference time), its standard
    error in ``offset_std_us`` and the skew in ``skew_ppm``.
    """
    from evpose.core.align.scene_proxy import scene_motion_proxy
    from evpose.core.data.trajectory import ClockModel

    t_start = time.perf_counter()
    clock0 = clock or scene.clock
    proxy = scene_motion_proxy(scene)

    def at(o):
        return ClockModel(int(round(o)), clock0.skew_ppm, clock0.t_ref_us)

    result = RefineResult("offset", None, offset_us=int(clock0.offset_us))
    window_us = params.window_us
    if windows is None:
        window_us = offset_window_us(proxy, params.window_us)
        windows = choose_windows(scene, params.n_windows, window_us, scene.object_names, clock0, proxy=proxy)
    result.n_windows = len(windows)
    if not windows:
        result.reason = "no window with camera motion"
        result.runtime_s = time.perf_counter() - t_start
        return result
    setup = _Setup(scene, scene.object_names, windows, clock0, params)
    T_bo = [scene.T_base_obj(n) for n in scene.object_names]
    sp, ok = _window_speeds_px_s(scene, np.array([w.t_label for w in setup.wins]), window_us, clock0, proxy)
    v_px_s = float(np.median(sp[ok])) if ok.any() else 0.0
    v_px_us = max(v_px_s, 1.0) * 1e-6
    off = float(clock0.offset_us)
    width = float(half_range_us)
    it = 0
    for level, sigma in enumerate(setup.sigmas):
        if cancel is not None and cancel():
            raise Cancelled("refinement cancelled")
        contours = setup.contours(T_bo, at(off))
        _, beta, _ = _evaluate(setup, T_bo, None, sigma, None, clock=at(off), contours=contours)

        def f(o):
            v, _, _ = _evaluate(setup, T_bo, None, sigma, beta, clock=at(o), contours=contours)
            return -v if np.isfinite(v) else 0.0

        lo, hi = off - width, off + width
        kernel_us = sigma / v_px_us            # the objective's bump is about this wide in time
        if level == 0 and width > 2.0 * kernel_us:
            grid = np.linspace(lo, hi, int(min(np.ceil(2.0 * width / (0.5 * kernel_us)), 200)) + 1)
            vals = np.array([f(o) for o in grid])
            j = int(np.argmin(vals))
            lo, hi = grid[max(j - 1, 0)], grid[min(j + 1, len(grid) - 1)]
        res = optimize.minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 5.0})
        off = float(res.x)
        width = max(min(width, (hi - lo) / 2.0) / 3.0, 300.0)
        it += 1
        result.trace.append({"iteration": it, "sigma_px": float(sigma), "objective": float(-res.fun),
                             "offset_us": int(round(off)), "elapsed_s": time.perf_counter() - t_start})
        if progress is not None:
            progress(it / (len(setup.sigmas) + 1), f"offset: sigma {sigma:.2f} px -> {off:.0f} us")
    result.iterations = it
    # final: each window's share of the finest level's objective on a grid of offsets around the
    # optimum (wide enough for the skew range); the fits read it (no re-association)
    sig = setup.sigmas[-1]
    k0 = float(clock0.skew_ppm)
    tau = np.array([w.t_label - clock0.t_ref_us for w in setup.wins], np.float64)
    rel_max = float(np.max(np.abs(tau - tau.mean()))) * 1e-6
    step = max(0.25 * sig / v_px_us, 2.0)
    n_drift = int(np.ceil(skew_range_ppm * rel_max / step)) if len(setup.wins) >= 3 else 0
    grid = off + step * np.arange(-STD_GRID_STEPS - n_drift, STD_GRID_STEPS + n_drift + 1)
    contours = setup.contours(T_bo, at(off))
    _, beta_f, _ = _evaluate(setup, T_bo, None, sig, None, clock=at(off), contours=contours)
    parts = np.stack([_evaluate(setup, T_bo, None, sig, beta_f, clock=at(o), contours=contours,
                                per_window=True)[3] for o in grid])
    skew = k0
    if n_drift > 0:
        # the skew too, taken when the windows pin it (SKEW_EDGE_MAX_STD_PPM) or show it beyond
        # SKEW_EDGE_SIGMAS standard errors
        dk_grid = np.linspace(-skew_range_ppm, skew_range_ppm, int(np.clip(2 * n_drift + 1, 5, 61)))
        fit_off, dk = _clock_fit(grid, parts, tau, dk_grid)
        off_std, dk_std = _jackknife_clock(grid, parts, tau, dk_grid)
        result.skew_std_ppm = dk_std
        result.skew_estimated = bool(np.isfinite(dk) and np.isfinite(dk_std)
                                     and (abs(dk) > SKEW_EDGE_SIGMAS * dk_std or dk_std <= SKEW_EDGE_MAX_STD_PPM))
        if result.skew_estimated:
            skew = k0 + dk
    if not result.skew_estimated:
        fit_off, _ = _clock_fit(grid, parts, tau, np.zeros(1))
        off_std, _ = _jackknife_clock(grid, parts, tau, np.zeros(1))
    if progress is not None:
        progress(1.0, f"offset: peak fit -> {fit_off:.0f} us")
    start_inside = bool(grid[0] <= clock0.offset_us <= grid[-1])
    if np.isfinite(fit_off):
        off = fit_off
    c1 = ClockModel(int(round(off)), skew, clock0.t_ref_us)
    j0, beta0, _ = _evaluate(setup, T_bo, None, sig, None, clock=clock0)
    j1, _, _ = _evaluate(setup, T_bo, None, sig, beta0, clock=c1)
    result.objective_before, result.objective_after = j0, j1
    # within the grid the fit maximises the smoothed objective, which includes the start; a start
    # outside it is compared on the raw objective
    if np.isfinite(fit_off) and np.isfinite(j1) and (start_inside or not np.isfinite(j0) or j1 > j0):
        result.offset_us = int(round(off))
        result.offset_std_us = off_std
        result.skew_ppm = skew
        result.accepted = True
    else:
        result.skew_estimated = False
        result.reason = ("the windows' objective has no peak near the optimum; start kept" if not np.isfinite(fit_off)
                         else "the fit did not improve the objective; start kept")
    result.runtime_s = time.perf_counter() - t_start
    return result


#: Search range of :func:`refine_offset_from_sync`: this many of the rate estimate's standard
#: errors, clamped to [``SYNC_EDGE_MIN_RANGE_US``, ``SYNC_EDGE_MAX_RANGE_US``].
SYNC_EDGE_STDS = 3.0
SYNC_EDGE_MIN_RANGE_US = 1000.0
SYNC_EDGE_MAX_RANGE_US = 50_000.0


def sync_edge_half_range_us(sync_result) -> float:
    """Search half range of :func:`refine_offset_from_sync` around a rate estimate:
    :data:`SYNC_EDGE_STDS` of its standard errors, clamped to [:data:`SYNC_EDGE_MIN_RANGE_US`,
    :data:`SYNC_EDGE_MAX_RANGE_US`] (the maximum when it has none)."""
    std = getattr(sync_result, "offset_std_us", None)
    span = SYNC_EDGE_STDS * std if std is not None and math.isfinite(std) else SYNC_EDGE_MAX_RANGE_US
    return float(np.clip(span, SYNC_EDGE_MIN_RANGE_US, SYNC_EDGE_MAX_RANGE_US))


def refine_offset_from_sync(scene, sync_result, *, params: RefineParams = RefineParams(), progress=None,
                            cancel=None) -> RefineResult:
    """Second stage of the clock sync: the offset (and skew) from event/edge alignment
    (:func:`refine_offset`), started at a reliable event-rate estimate
    (:func:`evpose.core.align.estimate.sync_scene`; its clock, with the prior skew when it estimated none) and
    searched within :func:`sync_edge_half_range_us`.

    The rate pins the offset only loosely on slow sequences (a slow move starts and stops
    gradually); the edges pin it to where the events are, ~0.05-0.3 ms on the benchmark scenes
    at 0.1-1.0 m/s, provided the object poses are right. Not accepted (start kept) when the rate
    estimate is not reliable.
    """
    if sync_result.offset_us is None or not sync_result.reliable:
        return RefineResult("offset", None, offset_us=int(scene.clock.offset_us),
                            reason="no reliable event-rate estimate to start from")
    return refine_offset(scene, params=params, half_range_us=sync_edge_half_range_us(sync_result),
                         clock=sync_result.clock(), progress=progress, cancel=cancel)


def apply_offset_result(history, scene, result: RefineResult, text: str = "clock from edges") -> bool:
    """Store an accepted offset refinement (offset and skew) as clock corrections through
    ``history``, as one undo step; returns whether applied."""
    if result.kind != "offset" or not result.accepted or result.offset_us is None:
        return False
    skew = scene.clock.skew_ppm if result.skew_ppm is None else float(result.skew_ppm)
    with history.group(text):
        history.set(("offset_us",), int(result.offset_us) - int(scene.manifest.clock_offset_us))
        history.set(("skew_ppm",), skew - float(scene.manifest.clock_skew_ppm))
    return True
