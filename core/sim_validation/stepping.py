"""Adaptive frame times: render often enough that no pixel moves more than ``max_px`` between two frames.

The displacement is measured, not bounded from speeds: a sparse grid of the last frame's hit points (base frame)
is projected through the lens (:func:`evpose.core.sim_validation.rays.distort`) with the last rendered pose and a
candidate one, and the candidate step shrinks until the largest image motion fits. Steps stop at every move's
start and end; while nothing moves by ``static_px``, the sensor steps (noise, leak) without a new frame.
"""
from __future__ import annotations

import numpy as np

from evpose.core.sim_validation.rays import distort, undistort

#: Longest step while the image stands still (µs): the sensor still gets noise and leak events.
MAX_STATIC_US = 10_000
#: Image motion below which no new frame is rendered, px.
STATIC_PX = 0.05


class FrameSteps:
    """Chooses the next step for a camera ``K``, ``dist`` of ``width x height`` pixels."""

    def __init__(self, K: np.ndarray, dist, width: int, height: int, max_px: float):
        self.K, self.dist, self.max_px = np.asarray(K, dtype=np.float64), dist, float(max_px)
        corners = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], np.float64)
        xy, _ = undistort(corners, self.K, dist)
        self.r_lim = 1.3 * float(np.max(np.hypot(xy[:, 0], xy[:, 1])))   # ignore points far outside the view

    def displacement(self, points: np.ndarray, T_a: np.ndarray, T_b: np.ndarray) -> float:
        """Largest image motion (px) of base-frame ``points`` between camera poses ``T_a`` and ``T_b``."""
        if len(points) == 0:
            return 0.0
        uv = []
        for T in (T_a, T_b):
            p = (points - T[:3, 3]) @ T[:3, :3]
            uv.append((p, p[:, :2] / np.maximum(p[:, 2:3], 1e-9)))
        (pa, xa), (pb, xb) = uv
        ok = (pa[:, 2] > 0.02) & (pb[:, 2] > 0.02) & (np.hypot(xa[:, 0], xa[:, 1]) < self.r_lim) \
            & (np.hypot(xb[:, 0], xb[:, 1]) < self.r_lim)
        if not ok.any():
            return 0.0
        d = distort(xb[ok], self.K, self.dist) - distort(xa[ok], self.K, self.dist)
        return float(np.max(np.hypot(d[:, 0], d[:, 1])))

    def next_step(self, t_us: int, dt_us: int, boundary_us: int, points: np.ndarray, T_last: np.ndarray,
                  pose_at) -> tuple[int, np.ndarray, float]:
        """``(t_next, T_next, displacement px)``: the longest step (at most 1.5 x the last one,
        :data:`MAX_STATIC_US`, and up to ``boundary_us``) whose image motion since the last rendered pose
        ``T_last`` stays within ``max_px``. ``pose_at(t_us)`` gives ``T_base_cam`` at an event time."""
        dt = int(max(1, min(int(1.5 * dt_us) + 1, MAX_STATIC_US, boundary_us - t_us)))
        for _ in range(30):
            T = pose_at(t_us + dt)
            d = self.displacement(points, T_last, T)
            if d <= self.max_px or dt == 1:
                return t_us + dt, T, d
            dt = max(1, int(dt * min(0.8 * self.max_px / d, 0.9)))
        return t_us + dt, T, d
