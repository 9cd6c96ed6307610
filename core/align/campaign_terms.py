"""One scene's part of a campaign fit (:mod:`evpose.core.align.campaign_fit`), computed where the scene's events are
(a Dask worker, or the driver's own process): the normal equations of the joint edge fit at a state the driver
sends, never the events themselves.

A campaign fits scenes that share parameters (a hand-eye calibration, an object placement) together. Each scene's
events pin its own clock and say something about the shared terms; the driver sums what they say
(:func:`evpose.core.align.campaign_fit.fit_campaign`). What a scene sends back per request is small: its objective,
``A = J^T W J`` and ``g = J^T K'(s)`` in its own 14+6k parameters (:class:`~evpose.core.align.joint_solve.Layout`),
``J^T J`` and the number of associated events (for the trust region on the predicted edge motion), each
parameter's step bound, and at the end the observed curvature and the score sums of its clusters of windows (the
cluster-robust standard errors of :func:`~evpose.core.align.joint_solve.sandwich`, over every scene at once).

The model is the single scene's (:mod:`evpose.core.align.joint_model`): same windows (chosen once, with the scene's
own clock), same association, kernel, priors (the object prior against the hand-eye, the held spin of a solid of
revolution) and held objects (:func:`evpose.core.align.joint_fit._held_objects`: too little evidence in this
scene, or a twin of another object); the skew is held at the scene's own (a campaign fits offsets).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evpose.core.align.event_windows import window_clusters
from evpose.core.align.joint_fit import (_bounds, _choose, _Fit, _held_directions, _held_objects, _layout, _prior,
                                        _prior_variance, _symmetry_axes, level_beta)
from evpose.core.align.joint_model import JointState, jacobian
from evpose.core.align.joint_result import JointParams
from evpose.core.align.joint_solve import _normal_eqs, cluster_scores, kernel_curvature, kernel_derivs

__all__ = ["LocalEvaluator", "SceneInfo", "SceneRequest", "SceneTerms", "SceneWork"]


@dataclass
class SceneInfo:
    """What the driver needs of a scene before the first step: its objects (``names``), clock (``offset_us``,
    ``skew_ppm``, ``t_ref_us``), each object's pose in effect (``T_start``, base frame) and in its manifest
    (``T_manifest``), the hand-eye correction in effect (``hand_eye``, camera frame), each object's edge centre
    (object frame, m) and radius (m), the objects held in this scene with the reason, the kernel widths and the
    number of windows."""

    names: list
    offset_us: int
    skew_ppm: float
    t_ref_us: int
    T_start: dict
    T_manifest: dict
    hand_eye: np.ndarray
    centre_obj: dict
    radius_m: dict
    held: dict
    sigmas_px: tuple
    n_windows: int
    #: the corrections' digest when the scene was opened: what the campaign's share of it is planned against
    digest: str = ""


@dataclass
class SceneRequest:
    """A state to evaluate: the clock offset (µs, float), the hand-eye increment ``H`` (camera frame, on top of the
    scene's correction), each object's base-frame pose (``T_bo``, by name), ``theta`` the change since the start in
    the scene's own layout (the priors'), the kernel width and its ``beta`` (None: computed here, at this state).

    ``base``: the driver's number for this state. Without ``delta`` the contours and the association are made
    afresh at the state (and kept under ``base``); with ``delta`` (the scene's own layout) the terms are those of
    the linearised distances ``s + J delta`` of the association kept for ``base`` (made again first when this
    process does not hold it: a worker that replaced a lost one) -- the inner iterations of
    :func:`~evpose.core.align.joint_solve.solve_step`, without rendering anything. ``covariance``: also the observed
    curvature and the clusters' score sums."""

    offset_us: float
    H: np.ndarray
    T_bo: dict
    theta: np.ndarray
    sigma_px: float
    beta: float | None = None
    base: int = 0
    delta: np.ndarray | None = None
    covariance: bool = False


@dataclass
class SceneTerms:
    """A scene's answer (parameters in its own layout, only the free ones non-zero): ``F`` the kernel sum minus the
    prior's penalty, ``beta``, ``n_assoc`` (associated events), ``A`` (Welsch-weighted curvature plus prior), ``g``
    (gradient of ``F``), ``M = J^T J`` (the predicted edge motion ``delta^T M delta / n_assoc``), ``bounds`` (largest
    change per parameter in one step) and, for a covariance request, ``A_obs`` (observed curvature plus prior),
    ``G`` (one row of score sums per cluster of windows) and ``held`` (``(n, h)``: the directions held at the start,
    the spins of solids of revolution, which the standard errors leave out), ``prior`` (the object prior in
    ``A_obs``) and ``prior_var`` (its mean's variance per parameter:
    :func:`~evpose.core.align.joint_solve.prior_pull`)."""

    F: float
    beta: float | None
    n_assoc: int
    A: np.ndarray
    g: np.ndarray
    M: np.ndarray
    bounds: np.ndarray
    A_obs: np.ndarray | None = None
    G: np.ndarray | None = field(default=None, repr=False)
    held: np.ndarray | None = None
    prior: np.ndarray | None = None
    prior_var: np.ndarray | None = None


class SceneWork:
    """A scene opened for a campaign: its windows and edge setup, kept across the driver's requests."""

    def __init__(self, scene, params: JointParams):
        p = self.params = JointParams(**{**params.__dict__, "skew": "fixed"})
        self.scene = scene
        clock = scene.clock
        self.names = list(scene.object_names)
        self.T_manifest = {n: scene.manifest.object(n).T_base_obj for n in self.names}
        self.T_start = {n: scene.T_base_obj(n) for n in self.names}
        self._digest = scene.corrections.digest()
        windows = _choose(scene, p, clock, self.names, None)
        self.fit = None
        self.held = {}
        self.sigmas = p.sigmas(float(scene.camera.K[0, 0]))     # as the single fit's
        if windows:
            state = JointState(float(clock.offset_us), float(clock.skew_ppm), int(clock.t_ref_us), np.eye(4),
                               [self.T_start[n].copy() for n in self.names])
            self.fit = _Fit(scene, self.names, windows, state, p)
            self.fit.clusters = window_clusters(scene, windows, clock)
            self.held = _held_objects(self.fit, self.sigmas[0], p, self.names)
        self.lay = _layout(len(self.names), p, self.names, False, self.held)
        self.n_windows = len(windows)
        self._kept = None              # (base, data, J, rows, prior, beta, theta) of the last fresh association
        self._M = self._bounds = None

    def info(self) -> SceneInfo:
        c = self.scene.clock
        edges = self.fit.setup.edges if self.fit is not None else None
        centre = {n: (np.asarray(edges[i].centre, np.float64) if edges is not None else np.zeros(3))
                  for i, n in enumerate(self.names)}
        radius = {n: (float(edges[i].radius) if edges is not None else 0.05) for i, n in enumerate(self.names)}
        return SceneInfo(self.names, int(c.offset_us), float(c.skew_ppm), int(c.t_ref_us), self.T_start,
                         self.T_manifest, np.asarray(self.scene.corrections.hand_eye_delta, np.float64), centre,
                         radius, dict(self.held), self.sigmas, self.n_windows, self._digest)

    def evaluate(self, req: SceneRequest) -> SceneTerms:
        """The scene's terms at ``req``'s state (fresh contours and association), or at ``req.delta`` from it."""
        if self.fit is None:
            return self._nothing(req.beta)
        if req.delta is None or self._kept is None or self._kept[0] != req.base:
            self._associate(req)
        base, d, J, rows, P, beta, theta0 = self._kept
        n, sigma, lay, free = self.lay.n, req.sigma_px, self.lay, self.lay.free.astype(np.float64)
        if d is None:
            return self._nothing(beta)
        delta = np.zeros(n) if req.delta is None else np.asarray(req.delta, np.float64) * free
        s = d.s.copy()
        for i, r in enumerate(rows):
            if r.stop > r.start:
                s[r] += J[r] @ delta[lay.cols(i)]
        theta = theta0 + delta
        k, dk, w = kernel_derivs(s, d.outer, sigma, beta)
        A, g = _normal_eqs(J, rows, w, dk, lay)
        mask = np.outer(free, free)
        out = SceneTerms(float(k.sum()) - 0.5 * float(theta @ P @ theta), beta, int(len(s)), (A + P) * mask,
                         (g - P @ theta) * free, self._M, self._bounds)
        if req.covariance:        # as the single fit's: the held spins left out of the covariance, not priored
            A_obs, _ = _normal_eqs(J, rows, kernel_curvature(s, d.outer, sigma, beta), dk, lay)
            out.prior = _prior(lay, self.params, self.fit.radii, len(s)) * mask
            out.prior_var = _prior_variance(lay, self.params, self.fit.radii) * free
            out.A_obs = A_obs * mask + out.prior
            out.held = _held_directions(n, _symmetry_axes(self.fit, self.fit.state)) * free[:, None]
            groups = d.win if self.fit.clusters is None else np.asarray(self.fit.clusters)[d.win]
            out.G = cluster_scores(J, rows, groups, dk, lay) * free
        return out

    def _nothing(self, beta) -> SceneTerms:
        """The terms of a scene without windows or without events near the edges: it says nothing (also no
        curvature and no clusters for the standard errors)."""
        n = self.lay.n
        return SceneTerms(0.0, beta, 0, np.zeros((n, n)), np.zeros(n), np.zeros((n, n)), np.full(n, np.inf),
                          np.zeros((n, n)), np.zeros((0, n)), None)

    def _associate(self, req: SceneRequest) -> None:
        """Contours and association at ``req``'s state, kept under ``req.base`` with their Jacobian, prior, beta,
        ``J^T J`` and step bounds."""
        fit, c, lay = self.fit, self.scene.clock, self.lay
        state = JointState(float(req.offset_us), float(c.skew_ppm), int(c.t_ref_us), np.asarray(req.H, np.float64),
                           [np.asarray(req.T_bo[nm], np.float64) for nm in self.names])
        fit.state = state
        # rendered afresh (no z-buffer lent by the last contours): the answer must not depend on which states this
        # process saw before -- a Dask task run on another worker than the scene's usual one (work stealing, a lost
        # worker) gave another hand-eye than the dry run (0.4 mrad) when it did
        fit._looked = None
        fit.contours = fit.look(state, previous=None)
        d = fit.data(state, fit.contours, req.sigma_px)
        beta = req.beta
        if d is None:
            self._kept = (req.base, None, None, None, None, beta, None)
            return
        if beta is None:
            beta = level_beta(d, req.sigma_px, self.params, float(fit.K[0, 0]))
        J = jacobian(d, fit.K, fit.centres(state), fit.radii)
        rows = d.slices(len(self.names))
        P = _prior(lay, self.params, fit.radii, len(d.s), _symmetry_axes(fit, state))
        free = lay.free.astype(np.float64)
        M, _ = _normal_eqs(J, rows, np.ones(len(d.s)), np.zeros(len(d.s)), lay)
        self._M = M * np.outer(free, free)
        self._bounds = np.where(lay.free, _bounds(fit, d, req.sigma_px, self.params, lay.n), np.inf)
        self._kept = (req.base, d, J, rows, P, float(beta), np.asarray(req.theta, np.float64))


class LocalEvaluator:
    """The scenes of a campaign answered in this process (:func:`evpose.core.align.campaign_fit.fit_campaign`'s
    ``evaluator``): ``scenes`` maps each name to an open :class:`~evpose.core.data.scene.Scene`."""

    def __init__(self, scenes: dict, params: JointParams):
        self.work = {name: SceneWork(scene, params) for name, scene in scenes.items()}

    def infos(self) -> dict:
        return {name: w.info() for name, w in self.work.items()}

    def evaluate(self, requests: dict) -> dict:
        return {name: self.work[name].evaluate(req) for name, req in requests.items()}
