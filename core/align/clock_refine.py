"""Refinement of the clock offset (and skew) from event/edge alignment over all objects.

The event rate (:mod:`evpose.core.align.estimate`) pins the clock only as well as the motion's
starts and stops allow; the edges pin it to where the events are, provided the object poses are
right (an error in them shifts the edges as an offset would). The offset is searched within a
range of the start clock on the edge objective (:mod:`evpose.core.align.edges`), coarse to fine;
the estimate is then fitted on the windows' shares of the finest level's objective
(:mod:`evpose.core.align.clock_fit`), with the skew when the windows pin it. Measurements:
``docs/refine.md``.
"""
from __future__ import annotations

import time

import numpy as np
from scipy import optimize

from evpose.core.align.clock_fit import fit_clock, jackknife_clock
from evpose.core.align.edges import EdgeSetup, evaluate
from evpose.core.align.event_windows import choose_windows, window_speeds_px_s
from evpose.core.align.refine_result import RefineParams, RefineResult
from evpose.core.align.scene_proxy import scene_motion_proxy
from evpose.core.data.clock import ClockModel
from evpose.core.data.events import Cancelled

__all__ = ["MAX_OFFSET_WINDOW_US", "OFFSET_WINDOW_PX", "SKEW_EDGE_MAX_STD_PPM", "SKEW_EDGE_RANGE_PPM",
           "SKEW_EDGE_SIGMAS", "STD_GRID_STEPS", "offset_window_us", "refine_offset"]

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


class _OffsetFit:
    """The fit's fixed parts: the edge setup, the object poses (taken as right) and the start
    clock, whose skew and reference time every candidate offset keeps."""

    def __init__(self, scene, windows, clock0: ClockModel, params: RefineParams):
        self.setup = EdgeSetup(scene, scene.object_names, windows, clock0, params)
        self.T_bo = [scene.T_base_obj(n) for n in scene.object_names]
        self.clock0 = clock0

    def at(self, o: float) -> ClockModel:
        """The start clock with offset ``o`` (µs, rounded)."""
        return ClockModel(int(round(o)), self.clock0.skew_ppm, self.clock0.t_ref_us)

    def evaluate(self, sigma: float, beta, clock, contours=None, per_window: bool = False):
        """The edge objective of all objects at ``clock`` (see :func:`evpose.core.align.edges.evaluate`)."""
        return evaluate(self.setup, self.T_bo, None, sigma, beta, clock=clock, contours=contours,
                        per_window=per_window)


def _coarse_to_fine(fit: _OffsetFit, half_range_us: float, v_px_us: float, result: RefineResult, t_start: float,
                    progress, cancel) -> float:
    """A bounded 1-D search of the offset per kernel width, each within a third of the previous
    range (at least 300 µs); at the coarsest, a range wider than twice the kernel's width in time
    (its sigma over the image speed ``v_px_us``) is scanned on a grid first. Returns the offset."""
    setup = fit.setup
    off = float(fit.clock0.offset_us)
    width = float(half_range_us)
    for level, sigma in enumerate(setup.sigmas):
        if cancel is not None and cancel():
            raise Cancelled("refinement cancelled")
        contours = setup.contours(fit.T_bo, fit.at(off))
        _, beta, _ = fit.evaluate(sigma, None, fit.at(off), contours)

        def f(o, sigma=sigma, beta=beta, contours=contours):
            v, _, _ = fit.evaluate(sigma, beta, fit.at(o), contours)
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
        result.iterations += 1
        result.trace.append({"iteration": result.iterations, "sigma_px": float(sigma), "objective": float(-res.fun),
                             "offset_us": int(round(off)), "elapsed_s": time.perf_counter() - t_start})
        if progress is not None:
            progress(result.iterations / (len(setup.sigmas) + 1), f"offset: sigma {sigma:.2f} px -> {off:.0f} us")
    return off


def _final_fit(fit: _OffsetFit, off: float, v_px_us: float, skew_range_ppm: float, result: RefineResult):
    """Each window's share of the finest level's objective on a grid of offsets around ``off``
    (wide enough for the skew range), read by :func:`~evpose.core.align.clock_fit.fit_clock`
    without re-association. The skew is taken when the windows pin it
    (:data:`SKEW_EDGE_MAX_STD_PPM`) or show it beyond :data:`SKEW_EDGE_SIGMAS` standard errors.
    Returns ``(grid, fitted offset, its standard error, skew)``."""
    setup, clock0 = fit.setup, fit.clock0
    sig = setup.sigmas[-1]
    k0 = float(clock0.skew_ppm)
    tau = np.array([w.t_label - clock0.t_ref_us for w in setup.wins], np.float64)
    rel_max = float(np.max(np.abs(tau - tau.mean()))) * 1e-6
    step = max(0.25 * sig / v_px_us, 2.0)
    n_drift = int(np.ceil(skew_range_ppm * rel_max / step)) if len(setup.wins) >= 3 else 0
    grid = off + step * np.arange(-STD_GRID_STEPS - n_drift, STD_GRID_STEPS + n_drift + 1)
    contours = setup.contours(fit.T_bo, fit.at(off))
    _, beta_f, _ = fit.evaluate(sig, None, fit.at(off), contours)
    parts = np.stack([fit.evaluate(sig, beta_f, fit.at(o), contours, per_window=True)[3] for o in grid])
    skew = k0
    if n_drift > 0:
        dk_grid = np.linspace(-skew_range_ppm, skew_range_ppm, int(np.clip(2 * n_drift + 1, 5, 61)))
        fit_off, dk = fit_clock(grid, parts, tau, dk_grid)
        off_std, dk_std = jackknife_clock(grid, parts, tau, dk_grid)
        result.skew_std_ppm = dk_std
        result.skew_estimated = bool(np.isfinite(dk) and np.isfinite(dk_std)
                                     and (abs(dk) > SKEW_EDGE_SIGMAS * dk_std or dk_std <= SKEW_EDGE_MAX_STD_PPM))
        if result.skew_estimated:
            skew = k0 + dk
    if not result.skew_estimated:
        fit_off, _ = fit_clock(grid, parts, tau, np.zeros(1))
        off_std, _ = jackknife_clock(grid, parts, tau, np.zeros(1))
    return grid, fit_off, off_std, skew


def _accept(fit: _OffsetFit, grid: np.ndarray, off: float, fit_off: float, off_std: float, skew: float,
            result: RefineResult) -> None:
    """Take the fitted clock when the objective has a peak near the optimum and the fit does not
    do worse than the start: within the grid the fit maximises the smoothed objective, which
    includes the start; a start outside it is compared on the raw objective."""
    clock0, sig = fit.clock0, fit.setup.sigmas[-1]
    start_inside = bool(grid[0] <= clock0.offset_us <= grid[-1])
    if np.isfinite(fit_off):
        off = fit_off
    c1 = ClockModel(int(round(off)), skew, clock0.t_ref_us)
    j0, beta0, _ = fit.evaluate(sig, None, clock0)
    j1, _, _ = fit.evaluate(sig, beta0, c1)
    result.objective_before, result.objective_after = j0, j1
    if np.isfinite(fit_off) and np.isfinite(j1) and (start_inside or not np.isfinite(j0) or j1 > j0):
        result.offset_us = int(round(off))
        result.offset_std_us = off_std
        result.skew_ppm = skew
        result.accepted = True
    else:
        result.skew_estimated = False
        result.reason = ("the windows' objective has no peak near the optimum; start kept" if not np.isfinite(fit_off)
                         else "the fit did not improve the objective; start kept")


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
    :func:`~evpose.core.align.clock_fit.fit_clock` takes the centre of a parabola through the top
    of their sum; with a skew change within ``± skew_range_ppm``, windows at different times are
    read at different offsets. The fitted skew is taken when the windows pin it (:data:`SKEW_EDGE_MAX_STD_PPM`)
    or when it stands out by :data:`SKEW_EDGE_SIGMAS` standard errors (``skew_range_ppm=0``
    keeps the start's). Standard errors are jackknifed over the windows
    (:func:`~evpose.core.align.clock_fit.jackknife_clock`; they grow when windows disagree, but a
    pose error that shifts all windows alike does not show in them).

    Returns the total offset in ``offset_us`` (at the clock's reference time), its standard
    error in ``offset_std_us`` and the skew in ``skew_ppm``.
    """
    t_start = time.perf_counter()
    clock0 = clock or scene.clock
    proxy = scene_motion_proxy(scene)
    t_start = time.perf_counter()
    clock0 = clock or scene.clock
    proxy = scene_motion_proxy(scene)
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
    fit = _OffsetFit(scene, windows, clock0, params)
    sp, ok = window_speeds_px_s(scene, np.array([w.t_label for w in fit.setup.wins]), window_us, clock0, proxy)
    v_px_s = float(np.median(sp[ok])) if ok.any() else 0.0
    v_px_us = max(v_px_s, 1.0) * 1e-6
    off = _coarse_to_fine(fit, half_range_us, v_px_us, result, t_start, progress, cancel)
    grid, fit_off, off_std, skew = _final_fit(fit, off, v_px_us, skew_range_ppm, result)
    if progress is not None:
        progress(1.0, f"offset: peak fit -> {fit_off:.0f} us")
    _accept(fit, grid, off, fit_off, off_std, skew, result)
    result.runtime_s = time.perf_counter() - t_start
    return result
