"""The Poisson likelihood of the binned event counts given the motion proxy at a clock.

The NCC weights every bin alike and is biased by what the proxy cannot know (the scene's
contrast, which edges are in view, the direction of motion: 0.2-2 ms on rendered scenes, see
``docs/sync.md``). :class:`PoissonFit` models the raw counts as a noise floor plus the proxy
times a slowly varying gain, profiles the gain out, and so lets the timing come from the shape
of the rate, where the motion starts and stops most of all.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from evpose.core.align.rate_series import RateSeries

__all__ = ["PoissonFit"]


class PoissonFit:
    """Poisson likelihood of the binned counts under ``lambda = n0 + exp(g_b(t)) * proxy``: a
    noise floor ``n0`` (background activity and hot pixels, per bin) plus the image motion
    times a gain that varies slowly inside each block ``b`` (a polynomial of degree ``deg`` in
    time). The gain absorbs what the proxy does not know (the scene's contrast, which edges are
    in view, the direction of motion), so the timing comes from the *shape* of the rate - most
    of all where the motion starts and stops - and not from its level.

    The blocks are fixed bin ranges (runs of motion at the start clock, widened by ``margin``
    bins and cut into pieces of at most ``max_len`` bins), so the likelihood of different clocks
    is computed on the same bins. :meth:`loglik` profiles the gains out (Fisher scoring, all
    blocks at once).
    """

    def __init__(self, prob: RateSeries, offset_us: float, skew_ppm: float, sel: np.ndarray, margin: int,
                 max_len: int, deg: int = 2):
        self.prob = prob
        c = prob.counts
        p_lo, ok_lo = prob.proxy_bins(offset_us - margin * prob.bin_us, skew_ppm)
        p_hi, ok_hi = prob.proxy_bins(offset_us + margin * prob.bin_us, skew_ppm)
        p, ok = prob.proxy_bins(offset_us, skew_ppm)
        use = sel & ok & ok_lo & ok_hi
        top = float(p[use].max()) if use.any() else 0.0
        moving = use & (p > 1e-3 * top)
        still = use & (p <= 0.0) & (p_lo <= 0.0) & (p_hi <= 0.0)
        if still.sum() >= 50:
            n0 = float(np.mean(c[still]))
        elif use.any():
            n0 = 0.5 * float(np.percentile(c[use], 5))
        else:
            n0 = 0.0
        self.n0 = max(n0, 0.05)
        wide = ndimage.binary_dilation(moving, iterations=max(int(margin), 1)) & use
        blocks = []
        lab, _ = ndimage.label(wide)
        for sl in ndimage.find_objects(lab):
            a, b = sl[0].start, sl[0].stop
            k = max(1, int(math.ceil((b - a) / max_len)))
            edges = np.linspace(a, b, k + 1).astype(int)
            blocks += [(int(x), int(y)) for x, y in zip(edges[:-1], edges[1:]) if y - x >= 10]
        self.blocks = blocks
        self.ok = bool(blocks) and moving.sum() >= 10
        if not self.ok:
            return
        self.idx = np.concatenate([np.arange(a, b) for a, b in blocks])
        self.bid = np.concatenate([np.full(b - a, j) for j, (a, b) in enumerate(blocks)])
        self.starts = np.cumsum([0] + [b - a for a, b in blocks[:-1]])
        u = np.concatenate([np.linspace(-1.0, 1.0, b - a) for a, b in blocks])
        self.X = np.polynomial.legendre.legvander(u, deg)                    # (N, D)
        self.XX = self.X[:, :, None] * self.X[:, None, :]                    # (N, D, D)
        self.c = c[self.idx]
        self.beta = None

    def loglik(self, offset_us: float, skew_ppm: float) -> float:
        """Profile log-likelihood (up to a constant) at a clock; higher is better."""
        p, _ = self.prob.proxy_bins(offset_us, skew_ppm)
        p = np.maximum(p[self.idx], 0.0)
        B, D = len(self.blocks), self.X.shape[1]
        c, n0, X = self.c, self.n0, self.X
        if self.beta is None:
            sc = np.add.reduceat(c, self.starts)
            sp = np.add.reduceat(p, self.starts)
            beta = np.zeros((B, D))
            beta[:, 0] = np.log(np.maximum(sc - n0 * np.diff(np.append(self.starts, len(c))), 1.0)
                                / np.maximum(sp, 1e-9))
        else:
            beta = self.beta.copy()
        ridge = 1e-8 * np.eye(D)
        for _ in range(30):
            mu = np.exp(np.clip(np.einsum("nd,nd->n", X, beta[self.bid]), -50, 50)) * p
            lam = n0 + mu
            grad = np.add.reduceat(X * ((c / lam - 1.0) * mu)[:, None], self.starts)
            H = np.add.reduceat(self.XX * (mu * mu / lam)[:, None, None], self.starts)
            H += ridge * (1.0 + np.trace(H, axis1=1, axis2=2))[:, None, None]
            step = np.clip(np.linalg.solve(H, grad[..., None])[..., 0], -2.0, 2.0)
            beta += step
            if np.abs(step).max() < 1e-7:
                break
        self.beta = beta
        mu = np.exp(np.clip(np.einsum("nd,nd->n", X, beta[self.bid]), -50, 50)) * p
        lam = n0 + mu
        return float(np.sum(c * np.log(lam) - lam))
