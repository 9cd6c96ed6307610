"""Joint refinement from edges: the clock (offset, and skew when the windows pin it), the object poses and,
optionally, a hand-eye correction, fitted together on the edge objective (:mod:`evpose.core.align.edges`).

Why joint: a clock offset shifts each window's edges by the image velocity times the offset, a pose error by an
amount fixed in the base frame, and a hand-eye error by an amount fixed in the camera. Each separate estimate
takes the others as right, so a 5 mm / 3 degree pose error shifted the edge clock by 1.6-4.3 ms, and the clock
error in turn biased the poses. Fitted together, each parameter is pulled only by what it alone explains: the
clock by how the misfit changes with the image velocity (moving vs slow windows, direction changes), the
objects by what stays put in the base frame, the hand-eye by what stays put in the camera across viewpoints.

Method: coarse to fine over the kernel widths (as the pose refinement). At each width the events are associated
with their nearest visible edge sample at the current estimate; the parameter step is the maximiser of the
objective with that association fixed and the distances linearised (:func:`evpose.core.align.joint_solve.solve_step`:
analytic derivatives, :mod:`evpose.core.align.joint_model`), then the events are associated again at the new
estimate; a width's result is kept only when it raises that width's objective with a fresh association (else the
width's start is restored). Then, in the clock-and-poses fit, a second look
(:func:`evpose.core.align.joint_second_look.second_look`): the objects fitted again from their start poses over the
fine widths with the clock as fitted, each kept where its share of the objective at the finest width is clearly
higher -- the first pass fits the objects while the clock is still wrong and its coarse widths blur an edge with
a shadow or a neighbour's edge beside it, and can settle in a wrong optimum. Joint optimisation rather than
alternation: alternating the clock and the poses converges slowly along the directions where they trade off (an
offset on a straight move looks like a shift along the motion) and its per-stage standard errors ignore that
trade-off; the joint curvature carries it.

Standard errors are the cluster-robust sandwich (:func:`evpose.core.align.joint_solve.sandwich`) over the camera's
moves (:func:`evpose.core.align.event_windows.window_clusters`: windows of one move share its errors), leaving out
the rotations the silhouettes cannot show (:func:`_symmetry_axes`: the spin of a solid of revolution, held at the
start).
The skew is kept when its standard error is at most :data:`SKEW_MAX_STD_PPM` or its change stands out by
:data:`SKEW_SIGMAS` standard errors; otherwise the start's skew is kept and the finest level is re-solved without it.
"""
from __future__ import annotations

import math
import time

import numpy as np

from evpose.core.align.edges import EdgeSetup, _beta
from evpose.core.align.event_windows import choose_windows, window_clusters
from evpose.core.align.joint_check import check_held_out
from evpose.core.align.joint_model import (HAND_EYE_RADIUS_M, HandEyeScene, JointState, gather, he_delta,
                                           jacobian, set_window_clock)
from evpose.core.align.joint_result import JointParams, JointResult, ObjectFit
from evpose.core.align.joint_solve import Layout, kernel_derivs, sandwich, solve_step
from evpose.core.align.pose_refine import _pose_change, delta_T
from evpose.core.align.scene_proxy import scene_motion_proxy
from evpose.core.align import uncertainty as U
from evpose.core.align.uncertainty import with_floor
from evpose.core.align.clock_refine import offset_window_us
from evpose.core.data.events import Cancelled
from evpose.core.data.geometry import inv_T

__all__ = ["MIN_OBJECT_EVENTS", "MIN_OBJECT_WINDOWS", "SKEW_LEVELS", "SKEW_MAX_STD_PPM", "SKEW_SIGMAS", "refine_joint"]

#: The fitted skew is kept when its standard error is at most this (ppm) or its change exceeds SKEW_SIGMAS of it.
SKEW_MAX_STD_PPM = 15.0
SKEW_SIGMAS = 3.0
#: A fitted skew beyond this (ppm) is dropped: the rate stage searches no further, and real clocks drift by tens of ppm.
MAX_SKEW_PPM = 1500.0
#: An object is fitted only when at least MIN_OBJECT_WINDOWS windows hold MIN_OBJECT_EVENTS events near its
#: edges at the coarsest width: with fewer, its pose is pinned by a handful of viewpoints (an object mostly out of
#: view) and the windows' spread says nothing of its uncertainty; it is held at its start and reported.
MIN_OBJECT_WINDOWS = 4
MIN_OBJECT_EVENTS = 30
#: The skew is free at this many of the finest kernel widths only: a skew of 10 ppm moves the clock by 25 µs
#: over 2.5 s, which the coarse widths cannot see, while a free skew there trades off against the pose errors.
SKEW_LEVELS = 2
#: Two objects coincide (:func:`_twins`) when their sizes agree within TWIN_SIZE_REL of the larger extent, their
#: centres lie within TWIN_CENTRE_REL of it and they are turned less than TWIN_DEG from each other.
TWIN_SIZE_REL = 0.1
TWIN_CENTRE_REL = 0.1
TWIN_DEG = 10.0
#: Weight of the prior that holds a rotation the silhouettes cannot show (per associated event and rotation unit
#: squared): ~10^4 times the events' own curvature at the finest width, so the held spin stays within ~10^-4 of a
#: rotation unit of its start.
HOLD_WEIGHT = 1e6


class _Fit:
    """The state of one joint fit: the scene seen through the current hand-eye, the event windows, the current
    estimate and the last fresh association."""

    def __init__(self, scene, names, windows, state: JointState, p: JointParams):
        self.scene, self.names, self.p = scene, names, p
        self.view = HandEyeScene(scene, state.H)
        # the windows' per-event camera poses come from poses() (knot-interpolated), not EdgeSetup's exact ones
        self.setup = EdgeSetup(self.view, names, windows, state.clock(), p.refine_params(), event_poses=False)
        self.K = scene.camera.K
        self.symmetry = [scene.model(n).symmetry for n in names]
        self.state = state
        self.radii = np.array([me.radius for me in self.setup.edges])
        self._clock_key = None
        self.poses(state)
        self.contours = None             # the last contours (their z-buffers serve the next look)
        self.clusters = None             # a group id per window for the standard errors (None: each window)
        self._looked = None              # (state, contours) of the last look
        self.cov_pull = None             # the object prior's share of the last covariance (:func:`_covariance`)

    def centres(self, state: JointState) -> np.ndarray:
        return np.array([T[:3, :3] @ me.centre + T[:3, 3] for T, me in zip(state.T_bo, self.setup.edges)])

    def poses(self, state: JointState) -> None:
        """The windows' per-event camera poses at ``state`` (:func:`set_window_clock`), when its clock or
        hand-eye differs from the last call's."""
        self.view.H = state.H
        clock = state.clock()
        key = (clock.offset_us, clock.skew_ppm, state.H.tobytes())
        if key != self._clock_key:
            for w in self.setup.wins:
                set_window_clock(self.view, w, clock)
            self._clock_key = key

    def look(self, state: JointState, previous=None):
        """The visible contour samples of every window at ``state`` (``previous`` contours lend their
        z-buffers); the last state's are kept (they do not depend on the kernel width)."""
        if self._looked is not None and self._looked[0] is state:
            return self._looked[1]
        self.poses(state)
        contours = self.setup.contours(state.T_bo, state.clock(), previous=previous)
        self._looked = (state, contours)
        return contours

    def data(self, state: JointState, contours, sigma: float):
        """The events associated with ``contours``' samples at ``state`` (samples are points on the meshes:
        contours of a nearby state serve a trial step)."""
        self.poses(state)
        return gather(self.setup, contours, state, self.p.band_sigmas * sigma, self.p.n_sub)

    def value(self, d, sigma: float, beta: float) -> float:
        """The objective: kernel sum over the associated events per valid event of the windows."""
        if d is None:
            return float("nan")
        k, _, _ = kernel_derivs(d.s, d.outer, sigma, beta)
        return float(k.sum()) / d.n_events

    def apply(self, state: JointState, delta: np.ndarray) -> JointState:
        """The state moved by a full parameter vector ``delta`` (layout of :class:`Layout`)."""
        out = state.copy()
        out.offset_us += float(delta[0])
        out.skew_ppm += float(delta[1])
        if np.any(delta[2:8]):
            out.H = state.H @ he_delta(delta[2:8])
        centres = self.centres(state)
        for i in range(len(state.T_bo)):
            x = delta[8 + 6 * i: 14 + 6 * i]
            if np.any(x):
                out.T_bo[i] = delta_T(x, centres[i], self.radii[i]) @ state.T_bo[i]
        return out


def _layout(n: int, p: JointParams, names, skew_free: bool, held=()) -> Layout:
    objs = [(p.objects is None or nm in p.objects) and nm not in held for nm in names]
    return Layout(n, p.clock, skew_free, p.hand_eye, objs)


def _twins(fit: _Fit, names, counts) -> dict:
    """Objects that coincide with another at the start (same size within :data:`TWIN_SIZE_REL`, centres closer than
    :data:`TWIN_CENTRE_REL` of their size, turned less than :data:`TWIN_DEG`): their silhouettes are one, so the
    events cannot tell which of the two they belong to. Of each pair the one with fewer associated events
    (``counts``; the later one on a tie) is held, with the reason."""
    from evpose.core.data.geometry import rotation_angle

    held = {}
    models = fit.setup.models
    size = [np.asarray(m.bbox_min_max[1]) - np.asarray(m.bbox_min_max[0]) for m in models]
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if names[i] in held or names[j] in held:
                continue
            ext = float(max(size[i].max(), size[j].max()))
            if np.any(np.abs(np.sort(size[i]) - np.sort(size[j])) > TWIN_SIZE_REL * ext):
                continue
            Ti, Tj = fit.state.T_bo[i], fit.state.T_bo[j]
            ci = Ti[:3, :3] @ models[i].bbox_center_m + Ti[:3, 3]
            cj = Tj[:3, :3] @ models[j].bbox_center_m + Tj[:3, 3]
            dist = float(np.linalg.norm(ci - cj))
            ang = float(np.degrees(rotation_angle(Ti[:3, :3].T @ Tj[:3, :3])))
            if dist > TWIN_CENTRE_REL * ext or ang > TWIN_DEG:
                continue
            k, other = (j, i) if counts[j] <= counts[i] else (i, j)
            held[names[k]] = (f"it coincides with {names[other]} (same size, centres {dist * 1e3:.1f} mm apart, "
                              f"turned {ang:.1f} deg): the events cannot tell the two apart; pose kept")
    return held


def _held_objects(fit: _Fit, sigma: float, p: JointParams, names) -> dict:
    """Objects to hold at their start, with the reason: without evidence (:data:`MIN_OBJECT_WINDOWS`), or
    coinciding with another object (:func:`_twins`)."""
    d = fit.data(fit.state, fit.look(fit.state), sigma)
    counts = np.zeros(len(names), np.int64) if d is None else np.bincount(d.obj, minlength=len(names))
    held = {n: why for n, why in _twins(fit, names, counts).items() if p.objects is None or n in p.objects}
    for i, name in enumerate(names):
        if (p.objects is not None and name not in p.objects) or name in held:
            continue
        n_win = 0 if d is None else int(np.sum(np.bincount(d.win[d.obj == i], minlength=len(fit.setup.wins))
                                               >= MIN_OBJECT_EVENTS))
        if n_win < MIN_OBJECT_WINDOWS:
            held[name] = (f"too little evidence: {n_win} of {len(fit.setup.wins)} windows hold {MIN_OBJECT_EVENTS}+ "
                          f"events near its edges (at least {MIN_OBJECT_WINDOWS} needed); pose kept")
    return held


def level_beta(d, sigma: float, p: JointParams, fx: float) -> float:
    """The density contrast ``beta`` of a width's first association ``d`` (:func:`~evpose.core.align.edges._beta`),
    or 0 where ``p`` leaves the kernel's step term out (:meth:`JointParams.step_at`)."""
    return _beta(d.s, d.outer, sigma) if p.step_at(sigma, fx) else 0.0


def _prior_variance(lay: Layout, p: JointParams, radii: np.ndarray) -> np.ndarray:
    """Per parameter, the variance the object prior of :func:`_prior` believes of a start pose (0: no prior):
    ``p.prior_obj_mm ** 2`` per translation axis, ``p.prior_obj_deg ** 2`` per rotation axis (in the layout's
    rotation units). The prior decides only what the events cannot tell apart; there its own uncertainty is the
    estimate's (:func:`~evpose.core.align.joint_solve.sandwich`'s ``prior_var``)."""
    var = np.zeros(lay.n)
    if p.hand_eye and lay.free[8:].any():
        for i, r in enumerate(radii):
            unit_deg = math.degrees(1e-3 / r)                    # degrees per rotation unit
            var[8 + 6 * i: 14 + 6 * i] = np.r_[np.full(3, p.prior_obj_mm ** 2),
                                               np.full(3, (p.prior_obj_deg / unit_deg) ** 2)]
    return var * lay.free


def _prior(lay: Layout, p: JointParams, radii: np.ndarray, n_assoc: int, held_axes=()) -> np.ndarray:
    """The prior matrix of the parameters (zeros = none).

    With the hand-eye and objects both free, the object corrections get a zero-mean prior of ``p.prior_obj_mm`` /
    ``p.prior_obj_deg`` (:func:`_prior_variance`) worth ``p.prior_weight`` of the associated events: it decides
    only along directions the events cannot tell apart (a common shift of every object against a hand-eye
    translation on a trajectory that does not rotate). ``held_axes[i]``: unit rotation axes (base frame) along
    which object ``i``'s rotation is held at its start (:func:`_symmetry_axes`: the spin of a solid of revolution)
    by a prior :data:`HOLD_WEIGHT` times the associated events: the events cannot see it, so a step must not move
    it (the standard errors leave those directions out: :func:`_held_directions`)."""
    var = _prior_variance(lay, p, radii)
    w = p.prior_weight * n_assoc
    prior = np.diag(np.divide(w, var, out=np.zeros(lay.n), where=var > 0))
    H = _held_directions(lay.n, held_axes)
    prior += HOLD_WEIGHT * max(n_assoc, 1) * (H @ H.T)
    free = lay.free.astype(float)
    return prior * np.outer(free, free)


def _held_directions(n: int, held_axes) -> np.ndarray:
    """``(n, h)``: the held rotation axes of :func:`_symmetry_axes` as unit directions of the parameter vector."""
    cols = []
    for i, axes in enumerate(held_axes):
        for a in axes:
            v = np.zeros(n)
            v[11 + 6 * i: 14 + 6 * i] = a
            cols.append(v)
    return np.stack(cols, axis=1) if cols else np.zeros((n, 0))


def _symmetry_axes(fit: "_Fit", state: JointState) -> list[list[np.ndarray]]:
    """Per object, the rotation axes (base frame, unit) its silhouettes cannot show at ``state``: the symmetry
    axis of a solid of revolution, all three for a sphere (:attr:`evpose.core.data.objects.ObjectModel.symmetry`)."""
    out = []
    for (kind, axis), T in zip(fit.symmetry, state.T_bo):
        if kind == "radial":
            out.append([T[:3, :3] @ axis])
        elif kind == "spherical":
            out.append(list(np.eye(3)))
        else:
            out.append([])
    return out


def _bounds(fit: _Fit, d, sigma: float, p: JointParams, n: int) -> np.ndarray:
    """Largest change of each pose parameter in one step (objects and hand-eye): what moves the edges by
    ``p.step_sigmas * sigma`` px at the associated samples' median depth, so a direction the events barely see
    (rotation about a symmetry axis) cannot run away within a step. The clock is bounded by the trust region on
    the edge motion alone."""
    move = p.step_sigmas * sigma
    z = np.median(d.P_c[:, 2]) if len(d.s) else 0.5
    px_per_mm = float(fit.K[0, 0]) * 1e-3 / max(float(z), 0.05)
    b = np.full(n, move / px_per_mm)
    b[:2] = np.inf
    return b


def _level(fit: _Fit, sigma: float, lay: Layout, p: JointParams, result: JointResult, total: np.ndarray,
           t_start: float, progress, cancel):
    """Fit at one kernel width: per outer iteration the contours and the association at the current state, and
    the step that maximises the objective with them held fixed (bounded per parameter by :func:`_bounds`). The
    level ends at its best state by the level's objective with a fresh association (a step whose fresh association
    falls -- a contour appearing or hiding -- is undone, not the whole width: bench/campaign.py lost a width's
    progress that way), which is its start when no step raised it. Returns the level's beta, or None without events."""
    state0, total0 = fit.state, total.copy()
    beta, j0, converged, best = None, None, False, None
    for k in range(p.outer_per_level + 1):
        if cancel is not None and cancel():
            raise Cancelled("joint refinement cancelled")
        contours = fit.contours = fit.look(fit.state, previous=fit.contours)
        d = fit.data(fit.state, contours, sigma)
        if d is None:
            return beta
        if beta is None:
            beta = level_beta(d, sigma, p, float(fit.K[0, 0]))
        j = fit.value(d, sigma, beta)                   # the objective of the current state
        if j0 is None:
            j0 = j
        if best is None or j > best[0]:
            best = (j, fit.state, total.copy(), contours)
        if k == p.outer_per_level or converged:
            break
        rows = d.slices(len(fit.state.T_bo))
        J = jacobian(d, fit.K, fit.centres(fit.state), fit.radii)
        prior = _prior(lay, p, fit.radii, len(d.s), _symmetry_axes(fit, fit.state))
        delta, f0, f1, move = solve_step(d.s, J, rows, d.outer, sigma, beta, lay, p.step_sigmas * sigma, prior, total,
                                         bounds=_bounds(fit, d, sigma, p, lay.n) if p.step_bounds else None)
        if not f1 > f0:
            break
        fit.state = fit.apply(fit.state, delta)
        total += delta
        result.iterations += 1
        result.trace.append({"iteration": result.iterations, "sigma_px": float(sigma), "objective": j,
                             "offset_us": fit.state.offset_us, "skew_ppm": fit.state.skew_ppm,
                             "n_events": int(len(d.s)), "elapsed_s": time.perf_counter() - t_start})
        if progress is not None:
            progress(None, f"sigma {sigma:.2f} px: objective {j:.4f}, offset {fit.state.offset_us:.0f} us")
        converged = move < p.converged_move * sigma     # evaluated once more above, then the level ends
    if best is not None and best[0] > j:                # a later step lost (a fresh association fell): the
        _, fit.state, total[:], fit.contours = best     # best state of the width, not all of it thrown away
    elif not j >= j0:                                   # the level made things worse: back to its start
        fit.state = state0
        total[:] = total0
        fit.contours = None
    return beta


def _covariance(fit: _Fit, sigma: float, beta: float, lay: Layout, p: JointParams, total: np.ndarray):
    """The parameter covariance at the final state (finest width), None without data."""
    contours = fit.look(fit.state, previous=fit.contours)
    d = fit.data(fit.state, contours, sigma)
    if d is None:
        return None
    J = jacobian(d, fit.K, fit.centres(fit.state), fit.radii)
    rows = d.slices(len(fit.state.T_bo))
    axes = _symmetry_axes(fit, fit.state)
    prior, held = _prior(lay, p, fit.radii, len(d.s)), _held_directions(lay.n, axes)
    var = _prior_variance(lay, p, fit.radii)
    cov, fit.cov_pull = sandwich(d.s, J, rows, d.win, d.outer, sigma, beta, lay, prior, held=held,
                                 clusters=fit.clusters, prior_var=var, parts=True)
    return cov


def _choose(scene, p: JointParams, clock, names, windows):
    if windows is not None:
        return list(windows)
    proxy = scene_motion_proxy(scene)
    window_us = offset_window_us(proxy, p.window_us) if p.clock else p.window_us
    return choose_windows(scene, p.n_windows, window_us, names, clock, proxy=proxy)


def refine_joint(scene, *, params: JointParams = JointParams(), clock=None, windows=None, progress=None,
                 cancel=None) -> JointResult:
    """Refine the clock, the object poses and (with ``params.hand_eye``) a hand-eye correction together from
    event/edge alignment.

    Parameters
    ----------
    scene : evpose.core.data.scene.Scene
        Its corrections in effect are the start (poses, hand-eye); ``clock`` overrides its clock (e.g. the
        event-rate estimate).
    params : JointParams
        What is free (``clock``, ``skew``, ``objects``, ``hand_eye``) and the knobs.
    windows : list of (t0_us, t1_us), optional
        Default :func:`~evpose.core.align.event_windows.choose_windows` (lengthened on slow sequences).
    progress : callable, optional
        ``progress(fraction, message)``; ``cancel() -> bool`` True raises
        :class:`~evpose.core.data.events.Cancelled`.

    Returns
    -------
    JointResult
        Totals to store (clock, each object's ``dT_base``, the hand-eye ``dT_cam``), their standard errors,
        objective before / after, and whether the fit improved the start (``accepted``).
    """
    t_start = time.perf_counter()
    clock0 = clock or scene.clock
    names = scene.object_names
    T_start = [scene.T_base_obj(n) for n in names]
    state = JointState(float(clock0.offset_us), float(clock0.skew_ppm), int(clock0.t_ref_us), np.eye(4),
                       [T.copy() for T in T_start])
    result = JointResult(params=params, offset_us=int(clock0.offset_us), skew_ppm=float(clock0.skew_ppm),
                         hand_eye_dT_cam=scene.corrections.hand_eye_delta.copy())
    windows = _choose(scene, params, clock0, names, windows)
    result.n_windows = len(windows)
    if not windows:
        result.reason = "no window with camera motion and an object in view"
        result.runtime_s = time.perf_counter() - t_start
        return result
    fit = _Fit(scene, names, windows, state, params)
    fit.clusters = window_clusters(scene, windows, clock0)
    sigmas = params.sigmas(float(scene.camera.K[0, 0]))
    skew_free = params.clock and params.skew in ("fit", "auto")
    total = np.zeros(8 + 6 * len(names))
    beta = None
    held = _held_objects(fit, sigmas[0], params, names)
    for name in held:
        result.held[name] = held[name]
    lay = _layout(len(names), params, names, skew_free, held)
    coarse = _layout(len(names), params, names, False, held)    # the skew waits for the fine levels
    totals = []                                                  # the estimate after each width
    for level, sigma in enumerate(sigmas):
        if progress is not None:
            progress(level / (len(sigmas) + 1), f"sigma {sigma:.2f} px")
        fine = level >= len(sigmas) - SKEW_LEVELS
        b = _level(fit, sigma, lay if fine else coarse, params, result, total, t_start, progress, cancel)
        if b is None:                                            # no events near the edges at this width: stop
            break
        beta = b
        totals.append(total.copy())
    if beta is None:
        result.reason = "no events near the objects' edges"
    elif not params.hand_eye:       # with the hand-eye free the objects' poses share directions with it: see there
        from evpose.core.align.joint_second_look import second_look

        second_look(fit, sigmas, lay, params, result, total, totals, T_start, t_start, progress, cancel)
    sigma_end = sigmas[max(len(totals) - 1, 0)]                  # the finest width that had events
    cov = _final_covariance(fit, result, params, names, sigma_end, beta, lay, total, totals, clock0, t_start,
                            progress, cancel)
    _finish(scene, fit, result, T_start, clock0, sigma_end, beta, cov, cov_layout(result, params, names), total)
    check_held_out(scene, result, windows, clock0, dict(zip(names, T_start)), windows[0][1] - windows[0][0])
    result.runtime_s = time.perf_counter() - t_start
    if progress is not None:
        progress(1.0, "done" if result.accepted else result.reason)
    return result


def cov_layout(result: JointResult, params: JointParams, names) -> Layout:
    """The layout the final covariance is in: the skew free only when it was kept."""
    return _layout(len(names), params, names, params.clock and result.skew_estimated, result.held)


def _final_covariance(fit: _Fit, result: JointResult, params: JointParams, names, sigma, beta, lay: Layout, total,
                      totals, clock0, t_start, progress, cancel):
    """Standard errors at the end (:func:`_covariance` plus the two finest widths' disagreement in quadrature: a
    bias that shrinks with the kernel width, events on one side of textured edges, is an error the spread between
    windows cannot show), and the skew decision: kept when pinned (:data:`SKEW_MAX_STD_PPM`) or significant
    (:data:`SKEW_SIGMAS`), else the start's skew and the finest width solved again without it."""
    if beta is None:
        return None
    shift = totals[-1] - totals[-2] if len(totals) >= 2 else np.zeros_like(total)

    def cov_at(layout):
        cov = _covariance(fit, sigma, beta, layout, params, total)
        return None if cov is None else cov + np.diag(shift ** 2)

    cov = cov_at(lay)
    if not (params.clock and params.skew in ("auto", "fit")):
        return cov
    if params.skew == "fit" or cov is None:
        result.skew_estimated = params.skew == "fit"
        return cov
    sk = math.sqrt(cov[1, 1]) if np.isfinite(cov[1, 1]) else math.inf
    plausible = abs(fit.state.skew_ppm) <= MAX_SKEW_PPM
    if plausible and (sk <= SKEW_MAX_STD_PPM or abs(total[1]) > SKEW_SIGMAS * sk):
        result.skew_estimated = True
        return cov
    if not plausible:
        result.skew_implausible = True
        result.notes.append(f"a fitted skew of {fit.state.skew_ppm:.0f} ppm is beyond the +-{MAX_SKEW_PPM:g} ppm of "
                            "real clocks (another error, e.g. the camera mounting, pulling the clock): the start's kept")
    fit.state = fit.state.copy()                                 # not pinned: the start's skew, finest width again
    fit.state.skew_ppm = float(clock0.skew_ppm)
    fit.contours = None
    total[1] = 0.0
    lay = _layout(len(names), params, names, False, result.held)
    _level(fit, sigma, lay, params, result, total, t_start, progress, cancel)
    result.skew_std_ppm = sk
    return cov_at(lay)


def _finish(scene, fit: _Fit, result: JointResult, T_start, clock0, sigma, beta, cov, lay: Layout, total):
    """Compare the fit with the start on the same windows at the finest width (fresh association each, the
    start's beta) and fill the result's totals and standard errors."""
    end = fit.state
    d1 = fit.data(end, fit.look(end), sigma)            # the end's contours: still cached from the covariance
    start = JointState(float(clock0.offset_us), float(clock0.skew_ppm), int(clock0.t_ref_us), np.eye(4),
                       [T.copy() for T in T_start])
    d0 = fit.data(start, fit.look(start), sigma)
    if d0 is None or beta is None:
        result.reason = result.reason or "no events near the objects' edges"
        return
    beta0 = level_beta(d0, sigma, fit.p, float(fit.K[0, 0]))
    j0 = fit.value(d0, sigma, beta0)
    j1 = fit.value(d1, sigma, beta0)
    result.objective_before, result.objective_after = j0, j1
    if not (np.isfinite(j1) and (not np.isfinite(j0) or j1 > j0)):
        if not np.isfinite(j0):
            result.reason = "the fit did not improve the objective; start kept"
            return
        # Nothing beats the start: it is the answer, with the standard errors of the fit at it (a right start --
        # the rate's clock, the poses in effect -- is confirmed with the edges' precision, not left with the rate's)
        fit.state, fit.contours = start, None
        cov = _covariance(fit, sigma, beta0, lay, fit.p, np.zeros_like(total))
        end = start
        result.notes.append(f"the start is where the edges agree best (objective {j0:.4f}, the fit reached "
                            f"{j1:.4f}): kept, with the fit's standard errors at it")
    result.accepted = True
    result.reason = ""
    sd = np.sqrt(np.where(np.isfinite(np.diag(cov)), np.diag(cov), np.inf)) if cov is not None else np.full(lay.n, np.inf)
    if lay.free[0] and np.isfinite(sd[0]):
        result.offset_us = int(round(end.offset_us))
        result.offset_std_data_us = float(sd[0])
        result.offset_std_us = with_floor(sd[0], U.JOINT_OFFSET_FLOOR_US)
        result.skew_ppm = float(end.skew_ppm)
        if lay.free[1]:
            result.skew_std_ppm = with_floor(sd[1], U.JOINT_SKEW_FLOOR_PPM)
    elif lay.free[0]:                                   # the edges do not pin the clock: the start's is kept
        result.offset_std_us = math.inf
        result.skew_estimated = False
    if lay.free[2:8].any():
        result.hand_eye_dT_cam = scene.corrections.hand_eye_delta @ end.H
        result.hand_eye_dR_deg, result.hand_eye_dt_mm = _pose_change(end.H, np.zeros(3))     # deg, mm of the origin
        result.hand_eye_std_mm = with_floor(np.sqrt(np.sum(sd[2:5] ** 2)), U.HAND_EYE_FLOOR_MM)
        result.hand_eye_std_deg = with_floor(np.sqrt(np.sum(sd[5:8] ** 2)) * math.degrees(1e-3 / HAND_EYE_RADIUS_M),
                                             U.HAND_EYE_FLOOR_DEG)
        if cov is not None and fit.cov_pull is not None:
            ev = np.sqrt(np.maximum(np.diag(cov)[2:8] - np.diag(fit.cov_pull)[2:8], 0.0))
            result.hand_eye_std_events_mm = with_floor(np.sqrt(np.sum(ev[:3] ** 2)), U.HAND_EYE_FLOOR_MM)
            result.hand_eye_std_events_deg = with_floor(
                np.sqrt(np.sum(ev[3:] ** 2)) * math.degrees(1e-3 / HAND_EYE_RADIUS_M), U.HAND_EYE_FLOOR_DEG)
    for i, name in enumerate(fit.names):
        if not lay.free[8 + 6 * i]:
            continue
        if not np.all(np.isfinite(sd[8 + 6 * i: 14 + 6 * i])):
            result.held[name] = "the events do not pin its pose (a direction of it leaves the objective flat); pose kept"
            continue
        T_man = scene.manifest.object(name).T_base_obj
        c0 = T_start[i][:3, :3] @ fit.setup.edges[i].centre + T_start[i][:3, 3]
        ang, moved = _pose_change(end.T_bo[i] @ inv_T(T_start[i]), c0)      # deg, displacement of the centre mm
        s = sd[8 + 6 * i: 14 + 6 * i]
        result.objects[name] = ObjectFit(
            dT_base=end.T_bo[i] @ inv_T(T_man), dt_mm=moved, dR_deg=ang,
            std_mm=with_floor(np.sqrt(np.sum(s[:3] ** 2)), U.POSE_FLOOR_MM),
            std_deg=with_floor(np.sqrt(np.sum(s[3:] ** 2)) * math.degrees(1e-3 / fit.radii[i]), U.POSE_FLOOR_DEG),
            held_rotation=_held_rotation_text(fit.symmetry[i]))


def _held_rotation_text(symmetry) -> str:
    kind, axis = symmetry
    if kind == "radial":
        return f"spin about its symmetry axis (object frame {np.round(axis, 3).tolist()}): the silhouettes cannot show it"
    if kind == "spherical":
        return "every rotation (a sphere): the silhouettes cannot show it"
    return ""
