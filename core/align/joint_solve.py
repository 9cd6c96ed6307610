"""The inner problem of the joint edge fit: the parameter step that maximises the edge objective with the
event-to-edge association held fixed, and the standard errors at the optimum.

The objective is ``F = sum_e K(s_e + J_e . delta)`` (:func:`evpose.core.align.edges.kernel`) over the associated
events, with the distances linearised in the parameters (:func:`evpose.core.align.joint_model.jacobian`). It is
maximised by iteratively reweighted Newton steps: gradient ``J^T K'(s)`` and curvature ``J^T W J`` with the
ridge's Welsch weights ``W = g(s) / sigma^2`` (positive, so every step is an ascent direction), Levenberg-Marquardt
damping, a trust region on the predicted edge motion, and each step kept only when it raises ``F``.

Standard errors are the cluster-robust sandwich ``A^-1 B A^-1`` over the windows (``A = J^T diag(-K''(s)) J``, the
objective's own curvature, infinite standard errors along directions it does not curve down; ``B`` the spread of
the windows' score sums ``sum_{e in w} K'(s_e) J_e``): events of one window share its pose errors, so
they are not independent, and the spread between windows is what the data say about the estimate's noise. It is
the linearised jackknife over windows; it grows when windows disagree (a model error that differs between
viewpoints), not when all windows are shifted alike. Estimated from few clusters (4 motion segments) it is itself
uncertain: it is widened by the Student-t factor of :func:`small_sample_factor`. Where a weak prior decides what
the events cannot (a hand-eye translation against a common shift of every object), the estimate is as uncertain as
the prior's mean: its score's spread is added to ``B`` (:func:`prior_pull`).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["Layout", "solve_step", "sandwich", "kernel_derivs", "kernel_curvature", "prior_matrix", "prior_pull",
           "cluster_scores", "small_sample_factor"]

_E05 = math.exp(0.5)


class Layout:
    """Column layout of the full parameter vector: clock (2), hand-eye (6), objects (6 each), and which of them
    are free. ``cols(i)`` are the 14 columns of an event of object ``i``."""

    def __init__(self, n_objects: int, clock: bool, skew: bool, hand_eye: bool, objects: list[bool]):
        self.n_objects = n_objects
        self.n = 8 + 6 * n_objects
        free = np.zeros(self.n, bool)
        free[0] = clock
        free[1] = clock and skew
        free[2:8] = hand_eye
        for i, f in enumerate(objects):
            free[8 + 6 * i: 14 + 6 * i] = f
        self.free = free

    def cols(self, i: int) -> np.ndarray:
        return np.r_[0:8, 8 + 6 * i: 14 + 6 * i]


def kernel_derivs(s: np.ndarray, outer: np.ndarray, sigma: float, beta: float, ridge: float = 1.0):
    """``K(s)``, ``K'(s)`` and the Welsch weight ``ridge * g(s) / sigma^2`` of the edge kernel."""
    u = s / sigma
    g = np.exp(-0.5 * u * u)
    bo = beta * outer * _E05
    k = ridge * g - bo * u * g
    dk = (g / sigma) * (-ridge * u + bo * (u * u - 1.0))
    w = ridge * g / (sigma * sigma)
    return k, dk, w


def kernel_curvature(s: np.ndarray, outer: np.ndarray, sigma: float, beta: float, ridge: float = 1.0) -> np.ndarray:
    """``-K''(s)``: the objective's own curvature per event (negative in the kernel's tails)."""
    u = s / sigma
    g = np.exp(-0.5 * u * u)
    return (ridge * (1.0 - u * u) + beta * outer * _E05 * (u ** 3 - 3.0 * u)) * g / (sigma * sigma)


def prior_matrix(prior: np.ndarray | None, n: int) -> np.ndarray:
    """The ``n x n`` prior matrix of ``prior``: None (zeros), a vector (its diagonal) or the matrix itself."""
    if prior is None:
        return np.zeros((n, n))
    prior = np.asarray(prior, dtype=np.float64)
    return np.diag(prior) if prior.ndim == 1 else prior


def _normal_eqs(J: np.ndarray, rows: list, weight: np.ndarray, grad_w: np.ndarray, lay: Layout):
    """``A = sum w J J^T`` and ``g = sum grad_w J`` over all events (``rows[i]``: object i's rows), in
    full-vector indices."""
    A = np.zeros((lay.n, lay.n))
    g = np.zeros(lay.n)
    for i, r in enumerate(rows):
        if r.stop <= r.start:
            continue
        Ji = J[r]
        c = lay.cols(i)
        A[np.ix_(c, c)] += Ji.T @ (Ji * weight[r, None])
        g[c] += grad_w[r] @ Ji
    return A, g


def solve_step(s0: np.ndarray, J: np.ndarray, rows: list, outer: np.ndarray, sigma: float, beta: float,
               lay: Layout, max_move_px: float, prior: np.ndarray | None = None, theta0: np.ndarray | None = None,
               bounds: np.ndarray | None = None, iters: int = 8) -> tuple[np.ndarray, float, float, float]:
    """The step ``delta`` (full vector, zeros at fixed parameters) maximising ``sum K(s0 + J delta)`` minus the
    prior ``0.5 theta^T P theta`` with ``theta = theta0 + delta`` (``prior``: the ``n x n`` matrix ``P``, or its
    diagonal as a vector; None for none), with the RMS of the
    predicted edge motion ``J delta`` at most ``max_move_px`` and each ``|delta_j|`` at most ``bounds[j]``;
    ``rows[i]`` are object i's rows (the data sorted by object). Returns ``(delta, F(0), F(delta), move)`` with
    ``move`` the RMS of ``J delta`` (px)."""
    free = np.flatnonzero(lay.free)
    n = lay.n
    P = prior_matrix(prior, n)
    theta0 = np.zeros(n) if theta0 is None else theta0

    def lin(delta):
        out = s0.copy()
        for i, r in enumerate(rows):
            if r.stop > r.start:
                out[r] += J[r] @ delta[lay.cols(i)]
        return out

    def objective(delta, s):
        k, _, _ = kernel_derivs(s, outer, sigma, beta)
        th = theta0 + delta
        return float(k.sum()) - 0.5 * float(th @ P @ th)

    delta = np.zeros(n)
    s = s0
    f0 = f = objective(delta, s)
    lam = 1e-3
    for _ in range(iters):
        _, dk, w = kernel_derivs(s, outer, sigma, beta)
        A, g = _normal_eqs(J, rows, w, dk, lay)
        A += P
        g -= P @ (theta0 + delta)
        Af, gf = A[np.ix_(free, free)], g[free]
        scale = np.sqrt(np.maximum(np.diag(Af), 1e-12))
        improved = False
        for _ in range(8):
            M = Af / np.outer(scale, scale) + lam * np.eye(len(free))
            try:
                step_f = np.linalg.solve(M, gf / scale) / scale
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            step = np.zeros(n)
            step[free] = step_f
            cand = delta + step
            if bounds is not None:                          # every parameter within its bound (projected step)
                cand = np.clip(cand, -bounds, bounds)
            cand, s_c = _within_trust_region(delta, cand, lin, s0, max_move_px)
            f_c = objective(cand, s_c)
            if f_c > f:
                gain = f_c - f
                delta, s, f = cand, s_c, f_c
                lam = max(lam / 3.0, 1e-6)
                improved = True
                break
            lam *= 4.0
        if not improved or gain < 1e-7 * abs(f):
            break
    return delta, f0, f, float(np.sqrt(np.mean((s - s0) ** 2))) if len(s0) else 0.0


def _within_trust_region(delta: np.ndarray, cand: np.ndarray, lin, s0: np.ndarray, max_move_px: float):
    """``delta + t (cand - delta)`` with the largest ``t`` in [0, 1] whose RMS edge motion ``|lin(.) - s0|`` is at
    most ``max_move_px`` (``delta`` itself is within it), and its distances. The motion is a convex function of ``t``
    (``lin`` is affine), so bisection finds ``t``; both ends lie within the parameter bounds, so does the result."""
    s_c = lin(cand)
    if not len(s0) or float(np.sqrt(np.mean((s_c - s0) ** 2))) <= max_move_px:
        return cand, s_c
    s_d = lin(delta)
    lo, hi = 0.0, 1.0
    for _ in range(30):
        t = 0.5 * (lo + hi)
        if float(np.sqrt(np.mean((s_d + t * (s_c - s_d) - s0) ** 2))) <= max_move_px:
            lo = t
        else:
            hi = t
    return delta + lo * (cand - delta), s_d + lo * (s_c - s_d)


def sandwich(s: np.ndarray, J: np.ndarray, rows: list, win: np.ndarray, outer: np.ndarray, sigma: float,
             beta: float, lay: Layout, prior: np.ndarray | None = None, held: np.ndarray | None = None,
             clusters: np.ndarray | None = None, prior_var: np.ndarray | None = None, parts: bool = False):
    """Cluster-robust covariance of the free parameters at the optimum (full ``n x n`` matrix, NaN rows/columns
    for fixed parameters): ``A^-1 B A^-1`` with ``A`` the objective's curvature and ``B`` the covariance of the
    clusters' score sums scaled to their number (``n_c / (n_c - 1)``). Clusters are the windows, or ``clusters``
    (one id per window index ``win``: e.g. the motion segment each window lies in, since windows of one move share
    its errors). An object whose parameters touch a direction the objective does not curve down along (a pose the
    events do not pin: mostly out of view, a symmetry nobody declared) gets infinite standard errors and is left
    out of the others' covariance; everything is infinite with fewer than 3 clusters.

    ``held``: ``(n, h)`` unit directions of the parameter space held at the start (the spin of a solid of
    revolution): the covariance is that of the other directions (zero along the held ones), which are judged flat
    or not on their own.

    ``prior_var``: per parameter, the variance of the prior's mean (0: none; :func:`prior_pull`): where the prior
    decides what the events cannot (a common shift of the objects against a hand-eye translation), the estimate is
    as uncertain as the prior's mean, and the events' spread alone would call it exact. ``parts``: return
    ``(cov, cov_pull)``, the prior's share apart (zero where the covariance is not finite)."""
    n = lay.n
    _, dk, _ = kernel_derivs(s, outer, sigma, beta)
    A, _ = _normal_eqs(J, rows, kernel_curvature(s, outer, sigma, beta), dk, lay)   # observed curvature
    A += prior_matrix(prior, n)
    groups = win if clusters is None else np.asarray(clusters)[win]
    ids = np.unique(groups)
    cov = np.full((n, n), np.nan)
    free = lay.free.copy()
    cov_pull = np.zeros((n, n))
    if len(ids) < 3:
        cov[np.ix_(free, free)] = np.inf
        return (cov, cov_pull) if parts else cov
    inflate = small_sample_factor(len(ids))
    G = cluster_scores(J, rows, groups, dk, lay)
    held = np.zeros((n, 0)) if held is None else np.asarray(held, dtype=np.float64).reshape(n, -1)
    pull = prior_pull(prior_matrix(prior, n), prior_var)
    for _ in range(lay.n_objects + 2):
        f = np.flatnonzero(free)
        if len(f) == 0:
            break
        C, flat, C_pull, _ = _sandwich_free(A[np.ix_(f, f)], G[:, f], len(ids), _complement(held, f, free),
                                            pull[np.ix_(f, f)])
        cov_pull[np.ix_(f, f)] = C_pull
        C = C * inflate + C_pull
        if not flat.any():
            cov[np.ix_(f, f)] = C
            break
        touched = f[flat]
        blocks = {(j - 8) // 6 for j in touched if j >= 8}
        if not blocks:                                    # the clock or hand-eye itself is not pinned
            cov[np.ix_(f, f)] = C
            cov[touched, :] = np.inf
            cov[:, touched] = np.inf
            break
        for b in blocks:                                  # leave those objects out, then the others again
            cols = np.arange(8 + 6 * b, 14 + 6 * b)
            cov[cols, :] = np.inf
            cov[:, cols] = np.inf
            free[cols] = False
    return (cov, np.where(np.isfinite(cov), cov_pull, 0.0)) if parts else cov


def cluster_scores(J: np.ndarray, rows: list, groups: np.ndarray, dk: np.ndarray, lay: Layout) -> np.ndarray:
    """``(n_groups, n)``: the score sum ``sum_e K'(s_e) J_e`` of each group of events (``groups``: a group id per
    event; one row per distinct id, in sorted order), in full-vector indices."""
    ids = np.unique(groups)
    G = np.zeros((len(ids), lay.n))
    psi = J * dk[:, None]                                  # per-event score contributions
    for i, r in enumerate(rows):
        if r.stop <= r.start:
            continue
        c = lay.cols(i)
        gr = np.searchsorted(ids, groups[r])
        for j in range(14):
            G[:, c[j]] += np.bincount(gr, weights=psi[r, j], minlength=len(ids))
    return G


def small_sample_factor(n_clusters: int) -> float:
    """Variance factor for a covariance estimated from ``n_clusters`` cluster sums: ``(t_{0.975, n-1} /
    z_{0.975})^2``, so that +-2 sigma keeps ~95 % coverage when the spread comes from few groups (4 motion segments:
    x2.6 in variance, sigma x1.6; 40 windows: x1.05). Without it, a sigma estimated from 4 moves is 2 sigma off in
    ~14 % of scenes instead of 5 %. The quantiles from :mod:`scipy.special` (what ``scipy.stats.t.ppf`` and
    ``norm.ppf`` call: the same bits, without importing :mod:`scipy.stats`, ~19 MB resident in the app)."""
    from scipy.special import ndtri, stdtrit

    if n_clusters < 2:
        return math.inf
    return float((stdtrit(n_clusters - 1, 0.975) / ndtri(0.975)) ** 2)


def _complement(held: np.ndarray, f: np.ndarray, free: np.ndarray) -> np.ndarray | None:
    """An orthonormal basis (columns, in the coordinates ``f``) of the directions orthogonal to the held ones
    that lie within the free parameters; None when nothing is held there."""
    from scipy.linalg import null_space

    keep = [k for k in range(held.shape[1]) if np.all(free[np.abs(held[:, k]) > 0])]
    if not keep:
        return None
    return null_space(held[np.ix_(f, keep)].T)


def prior_pull(P: np.ndarray, prior_var: np.ndarray | None) -> np.ndarray:
    """``P V P``: the covariance of the prior's score ``P (theta - mu)`` when its mean ``mu`` is off by an error
    of variance ``V = diag(prior_var)`` (the start poses' own uncertainty). Added to the events' score covariance
    in the sandwich, it gives ``A^-1 P V P A^-1``: ~V along directions only the prior decides, ~0 where the
    events' curvature outweighs ``P``."""
    n = P.shape[0]
    if prior_var is None:
        return np.zeros((n, n))
    v = np.asarray(prior_var, dtype=np.float64)
    return P @ (v[:, None] * P)


def _scaled_eigh(A: np.ndarray):
    """``(evals, evecs, scale, ok)`` of ``A`` scaled to a unit diagonal; ``ok``: the eigenvalues the curvature is
    positive along (above 1e-6 of the largest)."""
    scale = np.sqrt(np.maximum(np.abs(np.diag(A)), 1e-300))
    evals, evecs = np.linalg.eigh(A / np.outer(scale, scale))
    return evals, evecs, scale, evals > 1e-6 * max(float(evals.max()), 1e-300)


def n_flat(A: np.ndarray, Q: np.ndarray | None = None) -> int:
    """How many directions ``A`` (within the orthonormal columns of ``Q``) does not curve down along."""
    if Q is not None:
        A = Q.T @ A @ Q
    return int(np.sum(~_scaled_eigh(A)[3])) if A.size else 0


class Sandwich(NamedTuple):
    """:func:`_sandwich_free`'s answer over the free parameters ``f``: ``cov`` (``A^-1 B A^-1``), ``flat`` (per
    parameter: a non-negligible share in a direction where ``A`` is not positive, inverted as zero there),
    ``cov_pull`` (``A^-1 pull A^-1``) and ``flat_dirs`` (``(len(f), k)``: those directions, unit length in the
    curvature-scaled coordinates, so that each parameter's share of a direction can be compared)."""

    cov: np.ndarray
    flat: np.ndarray
    cov_pull: np.ndarray
    flat_dirs: np.ndarray


def _sandwich_free(A: np.ndarray, G: np.ndarray, n_groups: int, Q: np.ndarray | None = None,
                   pull: np.ndarray | None = None) -> Sandwich:
    """The sandwich of the free parameters (:class:`Sandwich`), within the subspace spanned by the orthonormal
    columns of ``Q`` (all of it when None; zero covariance outside); ``pull``: a further score covariance kept
    apart (:func:`prior_pull`: not scaled by the clusters' small-sample factor)."""
    if Q is None:
        Q = np.eye(A.shape[0])
    A, G = Q.T @ A @ Q, G @ Q
    G = G - G.mean(axis=0)
    B = G.T @ G * (n_groups / (n_groups - 1.0))
    evals, evecs, scale, ok = _scaled_eigh(A)
    Ainv = (evecs[:, ok] / evals[ok]) @ evecs[:, ok].T / np.outer(scale, scale)
    dirs = Q @ evecs[:, ~ok]
    C_pull = np.zeros_like(A) if pull is None else Ainv @ (Q.T @ pull @ Q) @ Ainv
    return Sandwich(Q @ (Ainv @ B @ Ainv) @ Q.T, (dirs ** 2).sum(axis=1) > 0.05, Q @ C_pull @ Q.T, dirs)
