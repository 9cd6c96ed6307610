"""The event windows of the edge refinement: which windows to use, and their events prepared.

Windows are taken where the image moves (static moments fire few events and pin nothing),
spread evenly over the moving part of the sequence (more viewpoints constrain depth and
rotation), with at least one object in front of the camera. Each window's events are
undistorted once, and the camera pose is interpolated per event so that a long window's
motion does not smear the fit.
"""
from __future__ import annotations

import math

import numpy as np

from evpose.core.align.scene_proxy import scene_motion_proxy
from evpose.core.data.geometry import inv_T

__all__ = ["MIN_WINDOW_PX_S", "MIN_WINDOW_SHARE", "MIN_CLUSTERS", "EventWindow", "choose_windows", "window_clusters",
           "window_speeds_px_s"]

#: Windows are taken where the image moves at least this fast (px/s at half DAVIS346 resolution,
#: scaled by fx / 146): a camera speed of ~0.07 m/s past a scene 0.5 m away; on slower sequences
#: at least MIN_WINDOW_SHARE of the sequence's fast image speed (95th percentile), at least 1 px/s.
MIN_WINDOW_PX_S = 20.0
MIN_WINDOW_SHARE = 0.25
#: Fewest groups of windows the standard errors are computed over (:func:`window_clusters`).
MIN_CLUSTERS = 4


class EventWindow:
    """Events of one window prepared for fitting: undistorted pixels, per-event camera pose."""

    def __init__(self, scene, t0_us: int, t1_us: int, clock, max_events: int, poses: bool = True):
        self.t0, self.t1 = int(t0_us), int(t1_us)
        self.t_label = self.t0 + (self.t1 - self.t0) // 2
        ev = scene.events.window(self.t0, self.t1)
        if len(ev) > max_events:
            ev = ev[::int(math.ceil(len(ev) / max_events))]
        self.ev_t = ev.t
        cam = scene.camera
        uv = np.stack([ev.x, ev.y], axis=1).astype(np.float64)
        self.xy = cam.undistort_points(uv, K_new=cam.K) if len(ev) else np.zeros((0, 2))
        if poses:            # otherwise the caller sets them (the joint fit: interpolated between knots)
            self.set_clock(scene, clock)

    def set_clock(self, scene, clock):
        """Per-event camera poses (``T_cb``: camera <- base) and validity under ``clock``."""
        T_bc, ok = scene.T_base_cam(self.ev_t, clock=clock)
        self.ok = ok & np.all(np.isfinite(self.xy), axis=1)
        self.T_cb = inv_T(T_bc)        # (M, 4, 4) camera <- base, per event
        self.clock = clock


def window_speeds_px_s(scene, centres_us: np.ndarray, window_us: int, clock, proxy=None):
    """Mean image speed (px/s, :func:`evpose.core.align.scene_proxy.scene_motion_proxy`) over windows of
    ``window_us`` centred on ``centres_us``; returns ``(speed, valid)``."""
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
    sp, ok = window_speeds_px_s(scene, grid, window_us, clock, proxy)
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


def window_clusters(scene, windows, clock=None, proxy=None, min_clusters: int = MIN_CLUSTERS) -> np.ndarray:
    """A group id per window of ``windows`` (list of ``(t0_us, t1_us)``) for the standard errors: the camera's
    move (a run of image motion between two stops, on a 5 ms grid) each window lies in. Windows of one move share
    its direction, speed and viewpoint, so their errors are alike: they are one piece of evidence, not several.
    With fewer than ``min_clusters`` moves the windows are grouped into ``min_clusters`` runs of consecutive
    windows instead (as evenly as possible), so a recording of one long move still gets a spread."""
    n = len(windows)
    if n == 0:
        return np.zeros(0, np.int64)
    centres = np.array([(a + b) // 2 for a, b in windows], np.int64)
    ids = np.full(n, -1, np.int64)
    ev = scene.events
    clock = clock or scene.clock
    if ev.t_first_us is not None and ev.t_last_us > ev.t_first_us:
        step = 5000
        grid = np.arange(ev.t_first_us, ev.t_last_us, step, dtype=np.int64)
        sp, ok = window_speeds_px_s(scene, grid, step, clock, proxy)
        fast = float(np.percentile(sp[ok], 95)) if ok.any() else 0.0
        thr = max(min(MIN_WINDOW_PX_S * float(scene.camera.K[0, 0]) / 146.0, MIN_WINDOW_SHARE * fast), 1.0)
        moving = ok & (sp >= 0.5 * thr)
        run = np.cumsum(np.r_[moving[:1], moving[1:] & ~moving[:-1]])        # id of the move each grid point is in
        k = np.clip(np.searchsorted(grid, centres, side="right") - 1, 0, len(grid) - 1)
        ids = np.where(moving[k], run[k], -1)
    order = np.argsort(centres, kind="stable")
    if len(np.unique(ids[ids >= 0])) + int(np.count_nonzero(ids < 0)) < min(min_clusters, n):
        return (np.arange(n)[np.argsort(order)] * min(min_clusters, n)) // n     # consecutive runs of windows
    lone = ids < 0                                       # a window between moves: a group of its own
    ids[lone] = ids.max(initial=0) + 1 + np.arange(int(lone.sum()))
    return np.unique(ids, return_inverse=True)[1]
