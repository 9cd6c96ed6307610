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

from .events import Cancelled
from .geometry import inv_T, make_T
from .raster import Rasterizer

__all__ = ["RefineResult", "RefineParams", "refine_object", "refine_offset", "choose_windows", "delta_T"]


# ---------------------------------------------------------------------------- parameters / results
#: Coarse-to-fine kernel widths (px at half DAVIS346 resolution, fx = 146; scaled by fx / 146).
DEFAULT_SIGMAS_PX = (1.5, 0.8, 0.5, 0.3, 0.2, 0.12, 0.08)


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
def choose_windows(scene, n_windows: int, window_us: int, objects=None, clock=None, min_px_s: float = 20.0):
    """``n_windows`` windows of ``window_us`` spread evenly over the moving part of the sequence
    (image speed above ``min_px_s`` and, when ``objects`` are given, at least one of them in
    front of the camera). Returns a list of ``(t0_us, t1_us)``."""
    from .sync import scene_motion_proxy

    ev = scene.events
    if ev.t_first_us is None or ev.t_last_us - ev.t_first_us < window_us:
        return []
    clock = clock or scene.clock
    proxy = scene_motion_proxy(scene)
    grid = np.arange(ev.t_first_us + window_us, ev.t_last_us - window_us, max(window_us // 2, 500), dtype=np.int64)
    if len(grid) == 0:
        return []
    a = clock.pose_time_rel(grid - window_us // 2, proxy.t0_us)
    b = clock.pose_time_rel(grid + window_us // 2, proxy.t0_us)
    sp, ok = proxy.mean_over(a, b)
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


def _evaluate(setup: _Setup, T_bo_list, k: int | None, sigma: float, beta: float | None, clock=None,
              contours=None):
    """Objective at a pose set: mean kernel over events associated with object k (all objects
    when k is None) within the band; also returns beta and the event count."""
    contours = contours or setup.contours(T_bo_list, clock)
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
    s = np.concatenate(S) if S else np.zeros(0)
    o = np.concatenate(O) if O else np.zeros(0, bool)
    if beta is None:
        beta = _beta(s, o, sigma)
    # a sum over the events within the band of the current edges (normalised by the fixed number
    # of events in the windows), not a mean: a pose that keeps fewer events near its edges must
    # not win by discarding the badly fitting ones
    n_all = sum(int(w.ok.sum()) for w in setup.wins)
    val = float(_kernel(s, o, sigma, beta).sum()) / max(n_all, 1) if len(s) else float("nan")
    return val, beta, len(s)


def _mean_score(scene, windows, name, poses=None, clock=None):
    from .score import score_windows

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
    scene : core.scene.Scene
        Its current corrections are the start.
    windows : list of (t0_us, t1_us), optional
        Default :func:`choose_windows` (``params.n_windows`` windows of ``params.window_us``).
    clock : ClockModel, optional
        Default: the scene's clock in effect (synchronise first).
    progress : callable, optional
        ``progress(fraction, message)``.
    cancel : callable, optional
        ``cancel() -> bool``; True raises :class:`core.events.Cancelled`.
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


def refine_offset(scene, *, windows=None, params: RefineParams = RefineParams(), half_range_us: float = 3000.0,
                  progress=None, cancel=None) -> RefineResult:
    """Refine the clock offset (skew kept) by the same edge objective over all objects:
    a bounded 1-D search within ``± half_range_us`` of the clock in effect, coarse to fine.
    Returns the total offset in ``offset_us``."""
    from .trajectory import ClockModel

    t_start = time.perf_counter()
    clock0 = scene.clock
    result = RefineResult("offset", None, offset_us=int(clock0.offset_us))
    if windows is None:
        windows = choose_windows(scene, params.n_windows, params.window_us, scene.object_names, clock0)
    result.n_windows = len(windows)
    if not windows:
        result.reason = "no window with camera motion"
        result.runtime_s = time.perf_counter() - t_start
        return result
    setup = _Setup(scene, scene.object_names, windows, clock0, params)
    T_bo = [scene.T_base_obj(n) for n in scene.object_names]
    off = float(clock0.offset_us)
    width = float(half_range_us)
    it = 0
    beta = None
    for level, sigma in enumerate(setup.sigmas):
        if cancel is not None and cancel():
            raise Cancelled("refinement cancelled")
        contours = setup.contours(T_bo, ClockModel(int(round(off)), clock0.skew_ppm, clock0.t_ref_us))
        _, beta, _ = _evaluate(setup, T_bo, None, sigma, None,
                               clock=ClockModel(int(round(off)), clock0.skew_ppm, clock0.t_ref_us), contours=contours)

        def f(o):
            c = ClockModel(int(round(o)), clock0.skew_ppm, clock0.t_ref_us)
            v, _, _ = _evaluate(setup, T_bo, None, sigma, beta, clock=c, contours=contours)
            return -v if np.isfinite(v) else 0.0

        res = optimize.minimize_scalar(f, bounds=(off - width, off + width), method="bounded",
                                       options={"xatol": 5.0})
        off = float(res.x)
        width = max(width / 3.0, 300.0)
        it += 1
        result.trace.append({"iteration": it, "sigma_px": float(sigma), "objective": float(-res.fun),
                             "offset_us": int(round(off)), "elapsed_s": time.perf_counter() - t_start})
        if progress is not None:
            progress(it / len(setup.sigmas), f"offset: sigma {sigma:.2f} px -> {off:.0f} us")
    result.iterations = it
    sig = setup.sigmas[-1]
    c0 = clock0
    c1 = ClockModel(int(round(off)), clock0.skew_ppm, clock0.t_ref_us)
    j0, beta0, _ = _evaluate(setup, T_bo, None, sig, None, clock=c0)
    j1, _, _ = _evaluate(setup, T_bo, None, sig, beta0, clock=c1)
    result.objective_before, result.objective_after = j0, j1
    if np.isfinite(j1) and (not np.isfinite(j0) or j1 > j0):
        result.offset_us = int(round(off))
        result.accepted = True
    else:
        result.reason = "the fit did not improve the objective; start kept"
    result.runtime_s = time.perf_counter() - t_start
    return result
