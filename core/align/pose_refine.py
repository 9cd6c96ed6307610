"""Refinement of an object's pose correction ``dT_base`` (6-DoF, base frame) from events.

The pose is fitted to the edge objective (:mod:`evpose.core.align.edges`) coarse to fine: at
each kernel width, a proposal is fitted with the event-to-edge association held fixed (L-BFGS
within a trust region, smooth in the 6 parameters: translation in mm and rotation scaled to mm
at the object's radius, about its centre), then accepted only when it raises the objective with
a fresh association (backtracking). The result is compared with the start on the same events
(``objective_before`` / ``objective_after`` at the finest width) and the start is kept when the
fit does not improve it, so a refinement can never make a pose worse by its own measure.
Measurements: ``docs/refine.md``.
"""
from __future__ import annotations

import time

import numpy as np
from scipy import optimize
from scipy.spatial.transform import Rotation

from evpose.core.align.contours import project
from evpose.core.align.edges import EdgeSetup, evaluate, kernel
from evpose.core.align.event_windows import choose_windows
from evpose.core.align.refine_result import RefineParams, RefineResult
from evpose.core.align.score_table import score_windows
from evpose.core.data.events import Cancelled
from evpose.core.data.geometry import inv_T, make_T

__all__ = ["delta_T", "refine_object"]

#: An accepted step smaller than this (mm, largest parameter) ends its level: converged.
CONVERGED_STEP_MM = 0.02


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


def _mean_score(scene, windows, name, poses=None, clock=None):
    try:
        tab = score_windows(scene, windows, [name], poses=poses, clock=clock)
    except Exception:  # scoring is for reporting only
        return None
    return tab.mean_score(name)


def _check_cancel(cancel) -> None:
    if cancel is not None and cancel():
        raise Cancelled("refinement cancelled")


class _PoseFit:
    """One object's coarse-to-fine fit: the poses of all objects (only object ``k`` moves), the
    accepted iterations and their trace (into ``result``)."""

    def __init__(self, scene, k: int, windows, clock, params: RefineParams, result: RefineResult, t_start: float,
                 progress):
        names = scene.object_names
        self.setup = EdgeSetup(scene, names, windows, clock, params)
        self.T_bo = [scene.T_base_obj(n) for n in names]
        self.k, self.name, self.p = k, names[k], params
        self.me = self.setup.edges[k]
        self.K = scene.camera.K
        self.result, self.t_start, self.progress = result, t_start, progress
        self.it = 0
        self.n_total = len(self.setup.sigmas) * params.outer_per_level
        # pixels per millimetre at the object (for the per-step trust region)
        T_co_w, v_w = scene.T_cam_obj(np.array([w.t_label for w in self.setup.wins]), [self.name], clock=clock)
        z_med = float(np.median(T_co_w[v_w, 0, 2, 3])) if v_w.any() else 0.5
        self.px_per_mm = float(self.K[0, 0]) * 1e-3 / max(z_med, 0.05)

    def centre(self) -> np.ndarray:
        """The object's centre in the base frame at its current pose (m)."""
        T = self.T_bo[self.k]
        return T[:3, :3] @ self.me.centre + T[:3, 3]

    def level(self, sigma: float, cancel) -> bool:
        """Fit at one kernel width: proposals and fresh-association acceptance until no step
        improves the level's objective, the step converges or ``outer_per_level`` steps are taken.
        False when no event lies near the object's edges (the fit stops)."""
        setup, k, p = self.setup, self.k, self.p
        renders = setup.contours(self.T_bo)          # one z-buffer per window and level
        # the level's objective (fresh association, fixed beta): every accepted step must raise it
        j_cur, beta, _ = evaluate(setup, self.T_bo, k, sigma, None, contours=renders)
        ridge = 1.0 if sigma <= p.ridge_sigma_px * float(self.K[0, 0]) / 146.0 + 1e-9 else 0.0
        contours = renders
        for _ in range(p.outer_per_level):
            _check_cancel(cancel)
            data = self._associated(contours, sigma)
            if data is None:
                self.result.reason = "no events near the object's edges"
                return False
            centre = self.centre()
            x = self._proposal(data, centre, sigma, beta, ridge)
            step = self._backtrack(x, centre, contours, sigma, beta, j_cur)
            if step is None:
                break  # no improving step: converged at this level
            x, self.T_bo, contours, j_cur = step
            self._record(sigma, j_cur, len(data[0]), beta, x)
            if np.abs(x).max() < CONVERGED_STEP_MM:  # converged at this level
                break
        return True

    def _associated(self, contours, sigma: float):
        """The events within the band of object k's edges with their per-event camera pose and
        edge sample: ``(xy, T_cb (M, 3, 4), sample in base frame, normal, outer)``; None if none."""
        k, T = self.k, self.T_bo[self.k]
        band = self.p.band_sigmas * sigma
        data = []
        for w, c in zip(self.setup.wins, contours):
            ei, si, _ = c.associate(w, self.T_bo, band, self.p.n_sub)
            keep = c.obj[si] == k
            ei, si = ei[keep], si[keep]
            if len(ei) == 0:
                continue
            Pb = c.P[si] @ T[:3, :3].T + T[:3, 3]
            data.append((w.xy[ei], w.T_cb[ei, :3, :], Pb, c.normal[si], c.outer[si]))
        if not data:
            return None
        return (np.concatenate([d[0] for d in data]), np.concatenate([d[1] for d in data]),
                np.concatenate([d[2] for d in data]), np.concatenate([d[3] for d in data]),
                np.concatenate([d[4] for d in data]).astype(np.float64))

    def _proposal(self, data, centre: np.ndarray, sigma: float, beta: float, ridge: float) -> np.ndarray:
        """The step ``x`` maximising the kernel with the association held fixed, within a trust
        region (edges move at most ``step_sigmas * sigma``)."""
        xy, A, Pb, nrm, out = data
        Rm, tm = A[:, :, :3], A[:, :, 3]
        K, radius = self.K, self.me.radius

        def s_of(x):
            dT = delta_T(x, centre, radius)
            Q = Pb @ dT[:3, :3].T + dT[:3, 3]
            Pc = np.einsum("nij,nj->ni", Rm, Q) + tm
            return np.einsum("ij,ij->i", nrm, xy - project(Pc, K))

        def f(x):
            return -float(kernel(s_of(x), out, sigma, beta, ridge).mean())

        step = self.p.step_sigmas * sigma / self.px_per_mm
        res = optimize.minimize(f, np.zeros(6), method="L-BFGS-B", bounds=[(-step, step)] * 6,
                                options={"maxiter": self.p.max_iter, "eps": 1e-3})
        return res.x

    def _backtrack(self, x_full, centre, contours, sigma: float, beta: float, j_cur: float):
        """The first of the full, half and quarter step that raises the level's objective with a
        fresh association: ``(x, poses, contours, objective)``, or None."""
        k = self.k
        for alpha in (1.0, 0.5, 0.25):
            x = alpha * x_full
            T_try = list(self.T_bo)
            T_try[k] = delta_T(x, centre, self.me.radius) @ self.T_bo[k]
            c_try = self.setup.contours(T_try, previous=contours, only=k)
            j_try, _, _ = evaluate(self.setup, T_try, k, sigma, beta, contours=c_try)
            if np.isfinite(j_try) and j_try > j_cur:
                return x, T_try, c_try, j_try
        return None

    def _record(self, sigma: float, j_cur: float, n_events: int, beta: float, x: np.ndarray) -> None:
        self.it += 1
        self.result.trace.append({"iteration": self.it, "sigma_px": float(sigma), "objective": float(j_cur),
                                  "n_events": int(n_events), "beta": beta, "T_base_obj": self.T_bo[self.k].copy(),
                                  "step_mm": float(np.abs(x).max()), "elapsed_s": time.perf_counter() - self.t_start})
        if self.progress is not None:
            self.progress(min(self.it / self.n_total, 1.0), f"{self.name}: sigma {sigma:.2f} px, objective {j_cur:.4f}")


def _accept(scene, fit: _PoseFit, T_manifest: np.ndarray, T_start: np.ndarray) -> None:
    """Compare the fit with the start on the same windows (fresh association, finest sigma, the
    start's beta) and take it only when it improves the objective."""
    result, k = fit.result, fit.k
    sig = fit.setup.sigmas[-1]
    T_before = [scene.T_base_obj(n) for n in scene.object_names]
    j0, beta0, _ = evaluate(fit.setup, T_before, k, sig, None)
    j1, _, _ = evaluate(fit.setup, fit.T_bo, k, sig, beta0)
    result.objective_before, result.objective_after = j0, j1
    improved = np.isfinite(j1) and (not np.isfinite(j0) or j1 > j0)
    if improved and fit.it > 0:
        result.dT_base = fit.T_bo[k] @ inv_T(T_manifest)
        result.accepted = True
        dT_change = fit.T_bo[k] @ inv_T(T_start)
        c0 = T_start[:3, :3] @ fit.me.centre + T_start[:3, 3]
        result.dR_deg, result.dt_mm = _pose_change(dT_change, c0)
    elif not result.reason:
        result.reason = "the fit did not improve the objective; start kept"


def refine_object(scene, name: str, *, windows=None, params: RefineParams = RefineParams(), clock=None,
                  with_scores: bool = True, progress=None, cancel=None) -> RefineResult:
    """Refine the pose correction of object ``name`` (6-DoF, base frame) from events.

    Parameters
    ----------
    scene : evpose.core.data.scene.Scene
        Its current corrections are the start.
    windows : list of (t0_us, t1_us), optional
        Default :func:`~evpose.core.align.event_windows.choose_windows` (``params.n_windows``
        windows of ``params.window_us``).
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
    T_manifest = scene.manifest.object(name).T_base_obj
    result = RefineResult("pose", name, dT_base=scene.corrections.object_delta(name))
    if windows is None:
        windows = choose_windows(scene, params.n_windows, params.window_us, [name], clock)
    result.n_windows = len(windows)
    if not windows:
        result.reason = "no window with camera motion and the object in view"
        result.runtime_s = time.perf_counter() - t_start
        return result
    fit = _PoseFit(scene, k, windows, clock, params, result, t_start, progress)
    T_start = fit.T_bo[k].copy()
    for sigma in fit.setup.sigmas:
        _check_cancel(cancel)
        if not fit.level(sigma, cancel):
            break
    result.iterations = fit.it
    _accept(scene, fit, T_manifest, T_start)
    if with_scores:
        result.score_before = _mean_score(scene, windows, name, clock=clock)
        result.score_after = _mean_score(scene, windows, name, clock=clock,
                                         poses={name: result.dT_base @ T_manifest})
    result.runtime_s = time.perf_counter() - t_start
    return result
