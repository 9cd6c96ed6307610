"""The camera's motion in a synthetic scene: minimum-jerk moves between random waypoints, with dwells.

Trajectory **A** translates the camera at a fixed orientation; **B** also rotates it to look at the
objects. The rendered motion is sampled finely (``motion_rate_hz``); the recorded trajectory holds its
samples at the robot's ``pose_rate_hz``, so interpolating it is an approximation, as for a real arm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from evpose.core.data.trajectory import Trajectory
from evpose.core.sim.synth_config import SynthConfig
from evpose.core.sim.synth_objects import TABLE_CENTRE_BASE

#: Pose clock origin of synthetic scenes: an epoch timestamp, so precision issues would show.
POSE_CLOCK_ORIGIN_US = 1_700_000_000_000_000


def _look_at(position: np.ndarray, target: np.ndarray, roll_rad: float = 0.0) -> np.ndarray:
    """Rotation ``R_base_cam`` of an OpenCV camera at ``position`` looking at ``target``."""
    z = target - position
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)
    return R @ Rotation.from_rotvec([0, 0, roll_rad]).as_matrix()


def _min_jerk(tau: np.ndarray) -> np.ndarray:
    return tau**3 * (10 - 15 * tau + 6 * tau**2)


@dataclass
class Motion:
    """The camera's motion in a synthetic scene.

    Attributes
    ----------
    recorded : Trajectory
        What the robot reports: samples of ``true`` on a regular pose clock at ``pose_rate_hz``
        (written to ``trajectory.csv``; readers interpolate it with lerp + slerp).
    true : Trajectory
        The motion that is rendered: the minimum-jerk moves sampled at ``motion_rate_hz``, so the
        image moves smoothly, as under a real arm. (Rendering the recorded samples instead makes the
        camera's speed a staircase with a step at every pose sample, and the event rate shows it: an
        artificial 4 ms ripple in the likelihood of the clock offset at 250 Hz that no real
        recording has.)
    segments : list of (int, int)
        Pose-clock start and end of each move.
    """

    recorded: Trajectory
    true: Trajectory
    segments: list


def make_motion(cfg: SynthConfig, rng: np.random.Generator, margin_s: float) -> Motion:
    """Camera motion ``T_base_cam`` on the pose clock covering ``duration + 2 margin``: moves
    between random waypoints with minimum-jerk profiles (peak speed ``speed_mps``) and dwells."""
    c = TABLE_CENTRE_BASE

    def sample_position(d_range=(0.33, 0.5)):
        d = rng.uniform(*d_range)
        el = math.radians(rng.uniform(45, 72))
        az = math.radians(90 + rng.uniform(-35, 35))
        return c + d * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])

    if cfg.trajectory == "A":
        p_mean = sample_position((0.38, 0.42))
        R_fixed = _look_at(p_mean, c)

        def waypoint():
            offs = R_fixed @ np.array([rng.uniform(-0.09, 0.09), rng.uniform(-0.06, 0.06), rng.uniform(-0.05, 0.05)])
            return p_mean + offs, R_fixed
    else:
        def waypoint():
            p = sample_position()
            return p, _look_at(p, c + rng.normal(scale=0.02, size=3), math.radians(rng.uniform(-12, 12)))

    total_s = cfg.duration_s + 2 * margin_s
    p, R = waypoint()
    t = round(margin_s * 0.7 * 1e6) * 1e-6
    knots_t, knots_p, knots_R, segments = [np.array([0.0, t])], [np.array([p, p])], [Rotation.from_matrix([R, R])], []
    while t < total_s:
        p_next, R_next = waypoint()
        length = float(np.linalg.norm(p_next - p))
        if length < 0.06:
            continue
        T_seg = 1.875 * length / cfg.speed_mps  # min-jerk peak speed = 1.875 L / T
        segments.append((t, t + T_seg))
        taus = np.linspace(0, 1, max(int(T_seg * cfg.motion_rate_hz), 2) + 1)[1:]
        # whole-µs knot times, and the profile evaluated at exactly those times (rounding after
        # evaluating would add a 0.2 % jitter to the speed between 250 µs knots)
        t_knot = np.rint((t + taus * T_seg) * 1e6) * 1e-6
        s = np.clip(_min_jerk(np.clip((t_knot - t) / T_seg, 0.0, 1.0)), 0.0, 1.0)
        knots_t.append(t_knot)
        knots_p.append(p + s[:, None] * (p_next - p))
        knots_R.append(Slerp([0.0, 1.0], Rotation.from_matrix([R, R_next]))(s))
        t = float(t_knot[-1])
        t = round((t + rng.uniform(0.15, 0.45)) * 1e6) * 1e-6     # dwell
        knots_t.append(np.array([t]))
        knots_p.append(p_next[None])
        knots_R.append(Rotation.from_matrix([R_next]))
        p, R = p_next, R_next
    kt_us = np.concatenate(knots_t) * 1e6
    kp = np.concatenate(knots_p)
    kR = Rotation.concatenate(knots_R)
    keep = np.r_[True, np.diff(np.rint(kt_us)) > 0]      # strictly increasing whole µs
    kt_us, kp, kR = np.rint(kt_us[keep]).astype(np.int64), kp[keep], kR[keep]
    true = Trajectory(kt_us + POSE_CLOCK_ORIGIN_US, kp, kR.as_quat(), source="synthetic (true motion)")
    # resample on a regular pose clock grid (a robot controller publishing at pose_rate_hz)
    dt_us = int(round(1e6 / cfg.pose_rate_hz))
    t_us = np.arange(0, int(kt_us[-1]) + 1, dt_us, dtype=np.int64)
    rots = Slerp(kt_us.astype(float), kR)(t_us.astype(float))
    pos = np.stack([np.interp(t_us, kt_us, kp[:, i]) for i in range(3)], axis=1)
    recorded = Trajectory(t_us + POSE_CLOCK_ORIGIN_US, pos, rots.as_quat(), source="synthetic")
    segs = [(POSE_CLOCK_ORIGIN_US + int(a * 1e6), POSE_CLOCK_ORIGIN_US + int(b * 1e6)) for a, b in segments]
    return Motion(recorded, true, segs)


def make_trajectory(cfg: SynthConfig, rng: np.random.Generator, margin_s: float) -> tuple[Trajectory, list]:
    """The recorded trajectory and the moves of :func:`make_motion`."""
    m = make_motion(cfg, rng, margin_s)
    return m.recorded, m.segments
