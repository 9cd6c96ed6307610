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

__all__ = ["MIN_WINDOW_PX_S", "MIN_WINDOW_SHARE", "EventWindow", "choose_windows", "window_speeds_px_s"]

#: Windows are taken where the image moves at least this fast (px/s at half DAVIS346 resolution,
#: scaled by fx / 146): a camera speed of ~0.07 m/s past a scene 0.5 m away; on slower sequences
#: at least MIN_WINDOW_SHARE of the sequence's fast image speed (95th percentile), at least 1 px/s.
MIN_WINDOW_PX_S = 20.0
MIN_WINDOW_SHARE = 0.25


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

