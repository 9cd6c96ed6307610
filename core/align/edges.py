"""The edge objective shared by the pose and the clock refinement: how well events lie on the
objects' edges at a given set of poses and a given clock.

Every event within a band around the edges is related to its nearest contour sample
(:class:`~evpose.core.align.contours.Contours`) by the signed distance ``s`` (px, along the
sample's normal), and scores the kernel

    K(s) = g(s) + beta * outer * (-s / sigma) * g(s) * e^0.5,   g(s) = exp(-s^2 / (2 sigma^2)):

a ridge for events **on** the edges, plus an odd step detector for the **contrast** of event
density across the silhouette (textured objects fire more events inside than the plain
background outside, or fewer; ``beta`` in [-1, 1] is estimated from the events). Both terms
vanish away from the edge, so a fixed event set cannot drift the fit outwards. The objective is
the kernel's sum over the events in the band divided by the fixed number of events in the
windows, not a mean: a pose that keeps fewer events near its edges must not win by discarding
the badly fitting ones. ``sigma`` goes coarse to fine (:data:`DEFAULT_SIGMAS_PX`), so a start
error of several pixels is pulled in. Derivation and measurements: ``docs/refine.md``.
"""
from __future__ import annotations

import math

import numpy as np

from evpose.core.align.contours import Contours
from evpose.core.align.event_windows import EventWindow
from evpose.core.align.mesh_edges import MeshEdges
from evpose.core.align.refine_result import DEFAULT_SIGMAS_PX, RefineParams
from evpose.core.label.raster import Rasterizer

__all__ = ["EdgeSetup", "evaluate", "kernel"]


class EdgeSetup:
    """What a refinement fits on, prepared once: the objects' raster models and mesh edges, the
    event windows (:class:`~evpose.core.align.event_windows.EventWindow`) at ``clock`` (their per-event camera
    poses left to the caller with ``event_poses=False``), and the
    coarse-to-fine kernel widths ``sigmas`` (px of the scene camera)."""

    def __init__(self, scene, names, windows, clock, p: RefineParams, event_poses: bool = True):
        self.scene = scene
        self.models = [scene.raster_model(n) for n in names]
        self.edges = [MeshEdges(m) for m in self.models]
        self.raster = Rasterizer(scene.camera)
        self.clock = clock
        self.wins = [EventWindow(scene, a, b, clock, p.max_events, poses=event_poses) for a, b in windows]
        fx = float(scene.camera.K[0, 0])
        self.sigmas = tuple(p.sigmas_px) if p.sigmas_px else tuple(s * fx / 146.0 for s in DEFAULT_SIGMAS_PX)
        self.p = p

    def contours(self, T_bo_list, clock=None, previous=None, only=None):
        """Contour samples per window; ``previous`` contours lend their z-buffers (no re-render)
        and, with ``only=k``, the samples of every object but k."""
        prev = previous or [None] * len(self.wins)
        return [Contours(self.scene, self.models, self.edges, T_bo_list, w, self.raster, self.p, clock or self.clock,
                         None if c is None or not c.valid else c.render, c, only)
                for w, c in zip(self.wins, prev)]


_E05 = math.exp(0.5)


def kernel(s, outer, sigma, beta, ridge=1.0):
    """The edge kernel of signed distances ``s`` (px) at width ``sigma``: ``ridge`` times the
    Gaussian ridge plus ``beta`` times the step detector on ``outer`` samples."""
    u = s / sigma
    g = np.exp(-0.5 * u * u)
    # ridge (events on the edge) + odd, decaying step detector (density contrast across it);
    # both vanish away from the edge, so a fixed event set cannot drift the fit outwards
    return ridge * g + beta * outer * (-u) * g * _E05


def _beta(s, outer, sigma):
    """Density contrast across the silhouette in [-1, 1]: the share of the outer samples' events
    within 3 sigma that are inside minus outside (0 below 10 such events)."""
    o = outer & (np.abs(s) <= 3 * sigma)
    n_in, n_out = int((s[o] < 0).sum()), int((s[o] > 0).sum())
    return 0.0 if n_in + n_out < 10 else float((n_in - n_out) / (n_in + n_out))


def _band_distances(setup: EdgeSetup, T_bo_list, k: int | None, sigma: float, clock, contours):
    """Per window: signed distances and outer flags of the events within the band of the
    contours (object k's only when k is given)."""
    band = setup.p.band_sigmas * sigma
    S, O = [], []
    for w, c in zip(setup.wins, contours):
        if clock is not None and w.clock is not clock:
            w.set_clock(setup.scene, clock)
        _, si, sd = c.associate(w, T_bo_list, band, setup.p.n_sub)
        if k is not None:
            keep = c.obj[si] == k
            si, sd = si[keep], sd[keep]
        S.append(sd)
        O.append(c.outer[si])
    return S, O


def evaluate(setup: EdgeSetup, T_bo_list, k: int | None, sigma: float, beta: float | None, clock=None,
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
    val = float(kernel(s, o, sigma, beta).sum()) / n_all if len(s) else float("nan")
    if per_window:
        parts = np.array([float(kernel(a, b, sigma, beta).sum()) / n_all for a, b in zip(S, O)])
        return val, beta, len(s), parts
    return val, beta, len(s)

