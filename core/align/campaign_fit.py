"""Campaign calibration: the joint edge fit of many scenes that share parameters, solved from their summed normal
equations (tracker issue 28.2).

A recording campaign shares what a single sequence cannot pin: one hand-eye calibration for every sequence of a
recording day, one placement of the objects (``T_base_obj``) for the sequences of one scene, while each sequence
keeps its own clock. A slow sequence cannot tell a hand-eye error from a common shift of its objects; a fast one of
the same placement can, and fitted together the slow one gets the answer its own events allow.

Model: each scene's objective is the single scene's joint edge objective (:mod:`evpose.core.align.joint_fit`) in its
own parameters; the campaign's objective is their sum, with each scene's hand-eye increment and object poses
replaced by its group's (:class:`CampaignScene`: the hand-eye unit and the placement unit it belongs to; a scene in
no group has units of its own). Parameters: one clock offset per scene (private), one hand-eye increment per
hand-eye unit (camera frame, on top of each scene's correction in effect), one base-frame pose per object of each
placement unit.

Method: coarse to fine over the kernel widths, as the single fit. At every step each scene (on a worker, where its
events are: :class:`~evpose.core.align.campaign_terms.SceneWork`) returns its normal equations at the current state
with a fresh association; the driver eliminates every scene's private parameters (its clock, and poses or hand-eye
no other scene shares) by their Schur complement, solves the summed equations of the shared terms, back-substitutes
the private ones, and sends the new state; the step is kept when the summed objective rises (Levenberg-Marquardt
damping otherwise, and a trust region on every scene's predicted edge motion). No event goes through the driver.

Standard errors: the cluster-robust sandwich over every scene's clusters of windows at once (a shared term's spread
is the disagreement between all the windows of all the scenes that see it), widened by the Student-t factor of
the number of clusters each parameter is seen by, plus the two finest widths' disagreement in quadrature, and the
model-error floors of :mod:`evpose.core.align.uncertainty` -- as the single fit, so a campaign's sigma and a
scene's own are comparable.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from evpose.core.align import uncertainty as U
from evpose.core.align.campaign_result import CampaignResult, scene_result, unit_fits
from evpose.core.align.campaign_terms import SceneRequest
from evpose.core.align.joint_model import he_delta
from evpose.core.align.joint_result import JointParams
from evpose.core.align.joint_solve import _complement, _sandwich_free, n_flat, prior_pull, small_sample_factor
from evpose.core.align.pose_refine import delta_T
from evpose.core.data.events import Cancelled

__all__ = ["CampaignScene", "fit_campaign"]

@dataclass(frozen=True)
class CampaignScene:
    """A scene of a campaign: its ``name`` and the units whose parameters it uses: ``hand_eye`` (e.g.
    ``"group:day1"``; a scene's own: ``"scene:<name>"``) and ``placement`` (the same for its objects' poses)."""

    name: str
    hand_eye: str
    placement: str


#: Outer iterations (fresh associations) per kernel width: this many times the single fit's. Every scene's edge
#: motion is held within the trust region, so the campaign's steps are those of its fastest-moving scene and it
#: needs more of them: with the single fit's 4 its widths ended still moving by the whole trust region, and on
#: bench/campaign.py's seed 33 it settled 1.5 mm / 4.6 mm off where 8 reached 0.45 mm / 0.27 mm (hand-eye / box).
OUTER_FACTOR = 2


class _Problem:
    """The campaign's parameter vector: a clock offset per scene, 6 per hand-eye unit, 6 per object of each
    placement unit; each scene's own layout (:class:`~evpose.core.align.joint_solve.Layout`: offset, skew,
    hand-eye 6, objects 6 each) mapped into it (``maps[name][j]``: the global index of local parameter ``j``,
    -1 where it is not fitted)."""

    def __init__(self, scenes: list, infos: dict, params: JointParams):
        self.scenes, self.infos, self.params = scenes, infos, params
        self.keys: list = []
        index: dict = {}

        def col(key):
            if key not in index:
                index[key] = len(self.keys)
                self.keys.append(key)
            return index[key]

        self.maps = {}
        #: ``(placement unit, object)`` -> (edge centre in the object frame, radius): the pose steps' pivot and scale
        self.geometry = {}
        for cs in scenes:
            info = infos[cs.name]
            for nm in info.names:
                self.geometry.setdefault((cs.placement, nm), (info.centre_obj[nm], info.radius_m[nm]))
            m = np.full(8 + 6 * len(info.names), -1, np.int64)
            if params.clock:
                m[0] = col(("clock", cs.name))
            if params.hand_eye:
                m[2:8] = [col(("hand-eye", cs.hand_eye, j)) for j in range(6)]
            for i, nm in enumerate(info.names):
                if nm not in info.held and (params.objects is None or nm in params.objects):
                    m[8 + 6 * i: 14 + 6 * i] = [col(("object", cs.placement, nm, j)) for j in range(6)]
            self.maps[cs.name] = m
        self.n = len(self.keys)
        users = np.zeros(self.n, np.int64)
        for m in self.maps.values():
            users[m[m >= 0]] += 1
        self.shared = users >= 2                          # seen by two scenes or more: solved on the driver
        self.shared_index = np.cumsum(self.shared) - 1
        self.base = 0                                     # the number of the last fresh association asked for

    def local(self, name: str, x: np.ndarray) -> np.ndarray:
        """A global vector in scene ``name``'s layout (zeros where not mapped)."""
        m = self.maps[name]
        out = np.zeros(len(m))
        out[m >= 0] = x[m[m >= 0]]
        return out


@dataclass
class _State:
    """The campaign's estimate: per scene its offset (µs), per hand-eye unit its increment ``H``, per
    ``(placement unit, object)`` its base-frame pose."""

    offset_us: dict
    H: dict
    T: dict

    def copy(self) -> "_State":
        return _State(dict(self.offset_us), {k: v.copy() for k, v in self.H.items()},
                      {k: v.copy() for k, v in self.T.items()})


def _start(scenes, infos) -> tuple[_State, list]:
    """The start: each scene's clock, no hand-eye increment, each placement's object poses from the first of its
    scenes that has the object (a note for every other scene whose pose in effect differs by > 0.05 mm/deg; also
    for a scene whose hand-eye correction in effect differs from its group's first scene's)."""
    from evpose.core.data.geometry import pose_error

    state, notes, he_first = _State({}, {}, {}), [], {}
    for cs in scenes:
        info = infos[cs.name]
        state.offset_us[cs.name] = float(info.offset_us)
        state.H.setdefault(cs.hand_eye, np.eye(4))
        first = he_first.setdefault(cs.hand_eye, (cs.name, np.asarray(info.hand_eye, np.float64)))
        et, er = pose_error(np.asarray(info.hand_eye, np.float64), first[1])
        if first[0] != cs.name and (np.linalg.norm(et) * 1e3 > 0.05 or math.degrees(np.linalg.norm(er)) > 0.05):
            notes.append(f"{cs.name}: its hand-eye correction in effect differs from {first[0]}'s by "
                         f"{np.linalg.norm(et) * 1e3:.2f} mm / {math.degrees(np.linalg.norm(er)):.2f} deg; "
                         f"{cs.hand_eye}'s increment is fitted on top of each, so the difference stays")
        for nm in info.names:
            key = (cs.placement, nm)
            if key not in state.T:
                state.T[key] = np.asarray(info.T_start[nm], np.float64).copy()
                continue
            et, er = pose_error(info.T_start[nm], state.T[key])
            if np.linalg.norm(et) * 1e3 > 0.05 or math.degrees(np.linalg.norm(er)) > 0.05:
                notes.append(f"{cs.name}: {nm}'s pose in effect differs from {cs.placement}'s start by "
                             f"{np.linalg.norm(et) * 1e3:.2f} mm / {math.degrees(np.linalg.norm(er)):.2f} deg; "
                             "the placement's is used")
    return state, notes


def _requests(prob: _Problem, state: _State, theta: np.ndarray, sigma: float, betas: dict | None,
              covariance: bool = False, delta: np.ndarray | None = None) -> dict:
    """Every scene's request at ``state`` (fresh: a new ``base`` number), or at ``delta`` from the state of the
    last fresh one."""
    if delta is None:
        prob.base += 1
    out = {}
    for cs in prob.scenes:
        info = prob.infos[cs.name]
        out[cs.name] = SceneRequest(state.offset_us[cs.name], state.H[cs.hand_eye],
                                    {nm: state.T[(cs.placement, nm)] for nm in info.names},
                                    prob.local(cs.name, theta), float(sigma),
                                    None if betas is None else betas[cs.name], prob.base,
                                    None if delta is None else prob.local(cs.name, delta), covariance)
    return out


def _apply(prob: _Problem, state: _State, delta: np.ndarray) -> _State:
    """``state`` moved by the global step ``delta`` (objects about their edge centres, as the single fit)."""
    out = state.copy()
    done = set()
    for k, key in enumerate(prob.keys):
        if key[0] == "clock":
            out.offset_us[key[1]] += float(delta[k])
        elif key[:2] not in done and key[0] == "hand-eye":
            done.add(key[:2])
            out.H[key[1]] = state.H[key[1]] @ he_delta(delta[k: k + 6])
        elif key[:3] not in done and key[0] == "object":
            done.add(key[:3])
            centre_obj, radius = prob.geometry[key[1:3]]
            T = state.T[key[1:3]]
            out.T[key[1:3]] = delta_T(delta[k: k + 6], T[:3, :3] @ centre_obj + T[:3, 3], radius) @ T
    return out


def _step(prob: _Problem, terms: dict, lam: float) -> np.ndarray:
    """The damped Gauss-Newton step of the summed normal equations, every scene's private parameters eliminated by
    their Schur complement (the shared block is as large as the shared terms, whatever the number of scenes)."""
    n, sh = prob.n, prob.shared
    diag = np.zeros(n)
    for name, t in terms.items():
        m = prob.maps[name]
        loc = np.flatnonzero(m >= 0)
        np.add.at(diag, m[loc], np.diag(t.A)[loc])
    # Marquardt's damping, relative to each parameter's own curvature (the parameters' units differ by orders of
    # magnitude: an absolute ridge froze the clock, whose curvature per µs is ~1e-6 of a pose's per mm); a
    # parameter without curvature (no data this step) gets a unit one
    damp = np.where(diag > 0, lam * diag, 1.0)
    nq = int(sh.sum())
    S, r = np.diag(damp[sh]), np.zeros(nq)
    back = {}
    for name, t in terms.items():
        m = prob.maps[name]
        loc = np.flatnonzero(m >= 0)
        p = loc[~sh[m[loc]]]
        q = loc[sh[m[loc]]]
        qi = prob.shared_index[m[q]]
        App = t.A[np.ix_(p, p)] + np.diag(damp[m[p]])
        Apq = t.A[np.ix_(p, q)]
        sol = np.linalg.solve(App, np.column_stack([Apq, t.g[p]])) if len(p) else np.zeros((0, len(q) + 1))
        K, y = sol[:, :-1], sol[:, -1]
        S[np.ix_(qi, qi)] += t.A[np.ix_(q, q)] - Apq.T @ K
        r[qi] += t.g[q] - Apq.T @ y
        back[name] = (p, qi, K, y)
    dq = np.linalg.solve(S, r) if nq else np.zeros(0)
    delta = np.zeros(n)
    delta[sh] = dq
    for name, (p, qi, K, y) in back.items():
        delta[prob.maps[name][p]] = y - K @ dq[qi]
    return delta


def _bounds(prob: _Problem, terms: dict) -> np.ndarray:
    """Each parameter's largest change in one solve: the tightest of its scenes' bounds."""
    bound = np.full(prob.n, np.inf)
    for name, t in terms.items():
        m = prob.maps[name]
        loc = np.flatnonzero(m >= 0)
        np.minimum.at(bound, m[loc], t.bounds[loc])
    return bound


def _moves(prob: _Problem, terms: dict, x: np.ndarray, y: np.ndarray | None = None) -> list:
    """Per scene with associated events ``x^T M y / N``: the predicted edge motion's mean square for ``x = y``."""
    out = []
    for name, t in terms.items():
        if t.n_assoc:
            xl = prob.local(name, x)
            yl = xl if y is None else prob.local(name, y)
            out.append(float(xl @ t.M @ yl) / t.n_assoc)
    return out


def _within_motion(prob: _Problem, terms: dict, delta: np.ndarray, cand: np.ndarray, max_move_px: float):
    """``delta + t (cand - delta)`` with the largest ``t`` in [0, 1] that keeps every scene's predicted RMS edge
    motion within ``max_move_px`` (``delta`` is within it; the motion's square is quadratic in ``t``)."""
    step = cand - delta
    t = 1.0
    m2 = max_move_px ** 2
    for a, b, c in zip(_moves(prob, terms, step), _moves(prob, terms, delta, step), _moves(prob, terms, delta)):
        if a <= 0 or a + 2 * b + c <= m2:
            continue
        t = min(t, max(0.0, (-b + math.sqrt(max(b * b - a * (c - m2), 0.0))) / a))
    return delta + t * step


def _solve(evaluator, prob: _Problem, state: _State, theta: np.ndarray, sigma: float, betas: dict, terms0: dict,
           cancel, iters: int = 8):
    """:func:`~evpose.core.align.joint_solve.solve_step` over the campaign: the step maximising the summed
    objective with every scene's association held (iteratively reweighted, Levenberg-Marquardt damped, each
    trial answered by the scenes from their kept association), within the per-parameter bounds and the trust
    region on every scene's edge motion. Returns ``(delta, F(0), F(delta), largest RMS motion px)``."""
    p = prob.params
    bound = _bounds(prob, terms0)
    delta, terms = np.zeros(prob.n), terms0
    f0 = f = sum(t.F for t in terms0.values())
    lam = 1e-3
    for _ in range(iters):
        improved, gain = False, 0.0
        for _ in range(8):
            if cancel is not None and cancel():
                raise Cancelled("campaign fit cancelled")
            cand = np.clip(delta + _step(prob, terms, lam), -bound, bound)
            cand = _within_motion(prob, terms0, delta, cand, p.step_sigmas * sigma)
            trial = evaluator.evaluate(_requests(prob, state, theta, sigma, betas, delta=cand))
            fc = sum(t.F for t in trial.values())
            if fc > f:
                gain, delta, terms, f = fc - f, cand, trial, fc
                lam = max(lam / 3.0, 1e-6)
                improved = True
                break
            lam *= 4.0
        if not improved or gain < 1e-7 * abs(f):
            break
    return delta, f0, f, math.sqrt(max(_moves(prob, terms0, delta), default=0.0))


def _evaluate(evaluator, prob, state, theta, sigma, betas, covariance=False) -> dict:
    return evaluator.evaluate(_requests(prob, state, theta, sigma, betas, covariance))


def _level(evaluator, prob: _Problem, state: _State, theta: np.ndarray, sigma: float, trace: list, cancel):
    """One kernel width, as the single fit's: per outer iteration every scene's contours and association at the
    current state, and the step that maximises the summed objective with them held (:func:`_solve`); the width
    ends at its best state by the summed objective with a fresh association (its start when no step raised it).
    Returns ``(state, theta, betas)``."""
    p = prob.params
    betas, converged, best = None, False, None
    outer = OUTER_FACTOR * p.outer_per_level
    for k in range(outer + 1):
        terms = _evaluate(evaluator, prob, state, theta, sigma, betas)
        if betas is None:
            betas = {nm: t.beta for nm, t in terms.items()}
        j = sum(t.F for t in terms.values())
        if best is None or j > best[0]:
            best = (j, state, theta)
        if k == outer or converged:
            break
        delta, f0, f1, move = _solve(evaluator, prob, state, theta, sigma, betas, terms, cancel)
        if not f1 > f0:
            break
        state, theta = _apply(prob, state, delta), theta + delta
        trace.append({"sigma_px": float(sigma), "objective": float(j), "predicted": float(f1), "move_px": float(move)})
        converged = move < p.converged_move * sigma
    return best[1], best[2], betas


def _covariance(evaluator, prob: _Problem, state: _State, theta: np.ndarray, sigma: float, betas: dict,
                shift: np.ndarray) -> np.ndarray:
    """Standard errors' covariance (global layout; inf rows/columns where the events leave a direction flat)."""
    terms = _evaluate(evaluator, prob, state, theta, sigma, betas, covariance=True)
    A, P = np.zeros((prob.n, prob.n)), np.zeros((prob.n, prob.n))
    var = np.zeros(prob.n)
    rows, seen, held = [], np.zeros(prob.n, np.int64), []
    for name, t in terms.items():
        m = prob.maps[name]
        loc = np.flatnonzero(m >= 0)
        A[np.ix_(m[loc], m[loc])] += t.A_obs[np.ix_(loc, loc)]
        if t.prior is not None:                # a shared object's start pose: one error, priored by every scene
            P[np.ix_(m[loc], m[loc])] += t.prior[np.ix_(loc, loc)]
            var[m[loc]] = np.maximum(var[m[loc]], t.prior_var[loc])
        for h in (t.held.T if t.held is not None else ()):
            if np.any(h[loc]):
                v = np.zeros(prob.n)
                v[m[loc]] = h[loc]
                held.append(v)
        if t.G is not None and len(t.G):
            G = np.zeros((len(t.G), prob.n))
            G[:, m[loc]] = t.G[:, loc]
            rows.append(G)
            seen[m[loc]] += len(t.G)
    cov = np.full((prob.n, prob.n), np.inf)
    G = np.concatenate(rows) if rows else np.zeros((0, prob.n))
    if len(G) < 3:
        return cov
    C, C_pull = _sandwich_blocks(prob, A, G, np.stack(held, axis=1) if held else np.zeros((prob.n, 0)),
                                 prior_pull(P, var))
    f = np.sqrt([small_sample_factor(int(k)) if k >= 2 else math.inf for k in seen])
    with np.errstate(invalid="ignore"):
        cov = C * np.outer(f, f) + C_pull + np.diag(shift ** 2)
    return np.where(np.isnan(cov), np.inf, cov)


#: Kernel widths, finest first, at which the standard errors are tried (:func:`_pinned_covariance`).
COVARIANCE_WIDTHS = 3


def _pinned_covariance(evaluator, prob: _Problem, state: _State, theta: np.ndarray, sigmas: tuple, betas: dict,
                       shift: np.ndarray) -> tuple[np.ndarray, float]:
    """The covariance at the finest kernel width whose observed curvature pins every fitted term (no infinite
    standard error), trying up to :data:`COVARIANCE_WIDTHS` widths, finest first; else the one that pins most.

    At the finest width (0.08 px at half DAVIS346 resolution, 0.16 px at full) most events lie in the kernel's
    tails, whose curvature is negative: summed over several scenes the observed curvature turned indefinite along
    directions every scene pins on its own at the next width (bench/campaign.py: all three objects of a campaign
    'not pinned', its hand-eye 6 sigma off). The spread between the windows at a coarser width is a conservative
    standard error for the finer estimate (its kernel is wider than the noise), and the two finest widths'
    disagreement is added in quadrature as before. Returns ``(covariance, the width used px)``."""
    best = None
    for back in range(min(COVARIANCE_WIDTHS, len(sigmas))):
        sigma = sigmas[-1 - back]
        cov = _covariance(evaluator, prob, state, theta, sigma, betas if back == 0 else None, shift)
        flat = int(np.sum(~np.isfinite(np.diag(cov))))
        if best is None or flat < best[0]:
            best = (flat, cov, sigma)
        if flat == 0:
            break
    return best[1], float(best[2])


def _sandwich_blocks(prob: _Problem, A: np.ndarray, G: np.ndarray, held: np.ndarray,
                     pull: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(A^-1 B A^-1, A^-1 pull A^-1)`` over the parameters the events pin: as
    :func:`~evpose.core.align.joint_solve.sandwich`, a scene's clock or an object whose parameters touch a flat
    direction gets infinite standard errors and is left out of the others' covariance (one at a time, then the
    rest again: :func:`_flat_blocks`); a hand-eye that does is infinite itself.
    ``pull``: the prior's score covariance (:func:`~evpose.core.align.joint_solve.prior_pull`)."""
    n = prob.n
    cov = np.full((n, n), np.inf)
    cov_pull = np.zeros((n, n))
    free = np.ones(n, bool)
    blocks: dict = {}
    for k, key in enumerate(prob.keys):
        blocks.setdefault(key[:3] if key[0] == "object" else key[:2], []).append(k)
    for _ in range(len(blocks) + 1):
        f = np.flatnonzero(free)
        if len(f) == 0:
            break
        C, flat, C_pull, dirs = _sandwich_free(A[np.ix_(f, f)], G[:, f], len(G), _complement(held, f, free),
                                               pull[np.ix_(f, f)])
        cov[np.ix_(f, f)] = C
        cov_pull[np.ix_(f, f)] = C_pull
        if not flat.any():
            break
        drop = _flat_blocks(prob, A, held, blocks, free, f, dirs)
        if not drop:                                      # a hand-eye unit itself is not pinned
            touched = f[flat]
            cov[touched, :] = np.inf
            cov[:, touched] = np.inf
            break
        for key in drop:
            free[blocks[key]] = False
            cov[blocks[key], :] = np.inf
            cov[:, blocks[key]] = np.inf
    return cov, np.where(np.isfinite(cov), cov_pull, 0.0)


def _flat_blocks(prob: _Problem, A: np.ndarray, held: np.ndarray, blocks: dict, free: np.ndarray, f: np.ndarray,
                 dirs: np.ndarray) -> set:
    """The block to leave out for the flat directions ``dirs`` (columns over the free parameters ``f``): of the
    clocks and objects (never a hand-eye unit) with a share above 5 % of them, the one whose removal leaves the
    fewest flat directions; on a tie a scene's own term before a shared one, then the smaller, then the larger
    share. A slow scene's clock that trades with what the others pin goes, not the shared objects; an object seen
    from one side goes, not the clock of a scene whose events pin it once that object is out (a rule by share
    alone dropped that clock: two flat directions mix in their eigenvectors). Empty when no clock or object has
    such a share: the hand-eye itself is flat."""
    pos = {int(j): k for k, j in enumerate(f)}
    best, best_key = None, None
    for key, cols in blocks.items():
        if key[0] == "hand-eye" or not free[cols].any():
            continue
        share = float(sum(np.sum(dirs[pos[c]] ** 2) for c in cols if c in pos))
        if share <= 0.05:
            continue
        rest = free.copy()
        rest[cols] = False
        g = np.flatnonzero(rest)
        left = n_flat(A[np.ix_(g, g)], _complement(held, g, rest))
        rank = (left, int(prob.shared[cols].any()), len(cols), -share)
        if best is None or rank < best:
            best, best_key = rank, key
    return set() if best_key is None else {best_key}


def fit_campaign(evaluator, scenes: list, params: JointParams = JointParams(hand_eye=True), *, progress=None,
                 cancel=None) -> CampaignResult:
    """Fit ``scenes`` (:class:`CampaignScene`) together.

    ``evaluator`` answers for the scenes: ``evaluator.infos()`` -> ``{name: SceneInfo}`` and
    ``evaluator.evaluate({name: SceneRequest})`` -> ``{name: SceneTerms}``
    (:class:`~evpose.core.align.campaign_terms.SceneWork` of each scene, in this process or on Dask workers).
    ``params``: what is fitted (``clock``: each scene's offset; ``hand_eye``: the hand-eye units; ``objects``: the
    objects' poses, None for all) and the single fit's knobs; the skew is each scene's own (held).
    """
    t0 = time.perf_counter()
    infos = evaluator.infos()
    prob = _Problem(scenes, infos, params)
    state0, notes = _start(scenes, infos)
    result = CampaignResult(params=params, scenes=[cs.name for cs in scenes], notes=notes,
                            planned_on={cs.name: infos[cs.name].digest for cs in scenes})
    sigmas = next(iter(infos.values())).sigmas_px if infos else ()
    other = [n for n, i in infos.items() if not np.allclose(i.sigmas_px, sigmas, rtol=1e-6, atol=0)]
    if other:                 # one width in px for every scene: the kernel is in px of each scene's own camera
        result.reason = (f"the scenes' cameras differ (kernel widths in px: {', '.join(sorted(other))} against "
                         f"{next(iter(infos))}): a campaign of one camera resolution only; fit the others apart")
        return _finish(result, prob, state0, state0, None, t0)
    if prob.n == 0 or not any(i.n_windows for i in infos.values()):
        result.reason = "nothing to fit: no scene has windows with camera motion and an object in view"
        return _finish(result, prob, state0, state0, None, t0)
    state, theta, totals, betas = state0, np.zeros(prob.n), [], None
    for level, sigma in enumerate(sigmas):
        if progress is not None:
            progress(level / (len(sigmas) + 2), f"sigma {sigma:.2f} px: {len(scenes)} scenes")
        state, theta, betas = _level(evaluator, prob, state, theta, sigma, result.trace, cancel)
        totals.append(theta.copy())
    shift = totals[-1] - totals[-2] if len(totals) >= 2 else np.zeros(prob.n)
    if progress is not None:
        progress(len(sigmas) / (len(sigmas) + 2), "standard errors")
    cov, result.covariance_sigma_px = _pinned_covariance(evaluator, prob, state, theta, sigmas, betas, shift)
    start = _evaluate(evaluator, prob, state0, np.zeros(prob.n), sigmas[-1], None)    # the start's own beta
    end = _evaluate(evaluator, prob, state, theta, sigmas[-1], {n: t.beta for n, t in start.items()})
    result.objective_before = {n: float(t.F) for n, t in start.items()}
    result.objective_after = {n: float(end[n].F) for n in start}
    result.accepted = sum(result.objective_after.values()) > sum(result.objective_before.values())
    if not result.accepted:
        result.reason = "the campaign fit did not raise the summed edge objective; the start is kept"
    return _finish(result, prob, state0, state, cov, t0)


def _finish(result: CampaignResult, prob: _Problem, state0: _State, state: _State, cov, t0: float) -> CampaignResult:
    sd = (np.sqrt(np.where(np.isfinite(np.diag(cov)), np.diag(cov), np.inf)) if cov is not None
          else np.full(prob.n, np.inf))
    end = state if result.accepted else state0
    index = {key: k for k, key in enumerate(prob.keys)}
    result.hand_eye, result.placements = unit_fits(prob.scenes, prob.infos, index, state0, end, sd,
                                                   result.accepted, prob.params)
    for cs in prob.scenes:
        k = index.get(("clock", cs.name))
        offset_std = with_floor_or_inf(sd[k] if k is not None else math.inf, U.JOINT_OFFSET_FLOOR_US)
        result.per_scene[cs.name] = scene_result(cs, prob.infos[cs.name], end.offset_us[cs.name], offset_std,
                                                 result, prob.params)
    result.runtime_s = time.perf_counter() - t0
    return result


def with_floor_or_inf(std: float, floor: float) -> float:
    return U.with_floor(std, floor) if math.isfinite(std) else math.inf
