"""The robot's motion in a validation scene: moves between waypoints with their own speed profiles and stops.

Each move follows a straight line or an arc about the objects, with one of three profiles: **trapezoid**
(constant acceleration to the top speed, cruise, constant deceleration), **sine** (raised-cosine speed) or
**sweep** (back and forth 2-4 times along the same path without stopping, sinusoidal). Every move's peak
Cartesian speed is the requested speed (a trapezoid on a short move may not reach it). Moves are separated by
stops, after which the arm rings briefly (a decaying oscillation of ``ringing_mm``): rendered, but not in the
recorded poses, as joint encoders do not see the links flex. The recorded trajectory samples the motion at
the robot's ``pose_rate_hz``, each sample taken ``pose_jitter_us`` (1 sigma) off its timestamp.

Trajectory ``A`` keeps the camera's orientation fixed (translation only); ``B`` turns it to look at the
objects from every waypoint. Poses are evaluated in closed form at any time (no pre-sampled spline).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from evpose.core.sim_validation.config import ValidationConfig


#: The camera keeps this far from every object's bounding box (a robot programmed not to touch the scene), m.
CLEARANCE_M = 0.07


def _look_at(p: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    z = (target - p) / np.linalg.norm(target - p)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1) @ Rotation.from_euler("z", roll).as_matrix()


def _profile(kind: str, tau: np.ndarray, f_acc: float, n_pass: int) -> np.ndarray:
    """Path parameter s(tau) in [0, 1] for tau in [0, 1]."""
    tau = np.clip(tau, 0.0, 1.0)
    if kind == "sine":
        return tau - np.sin(2 * np.pi * tau) / (2 * np.pi)
    if kind == "sweep":
        return 0.5 * (1.0 - np.cos(np.pi * n_pass * tau))
    f = f_acc                                          # trapezoid: accelerate over [0, f], cruise, decelerate
    vmax = 1.0 / (1.0 - f)
    up = 0.5 * vmax / f * tau**2
    cruise = 0.5 * vmax * f + vmax * (tau - f)
    down = 1.0 - 0.5 * vmax / f * (1.0 - tau) ** 2
    return np.where(tau < f, up, np.where(tau <= 1.0 - f, cruise, down))


@dataclass
class Move:
    t0: float                 # start, seconds of pose time from the motion's origin
    T: float                  # duration, s
    kind: str
    f_acc: float
    n_pass: int
    path: tuple               # ("line", p0, p1) or ("arc", centre, d0, d1, r0, r1)
    R0: np.ndarray
    R1: np.ndarray
    ring: tuple               # (amplitude m, frequency Hz, decay s, direction (3,))

    def __post_init__(self):
        self.slerp = Slerp([0.0, 1.0], Rotation.from_matrix([self.R0, self.R1]))

    def position(self, s: np.ndarray) -> np.ndarray:
        if self.path[0] == "line":
            _, p0, p1 = self.path
            return p0 + s[:, None] * (p1 - p0)
        _, c, d0, d1, r0, r1 = self.path
        ang = math.acos(min(1.0, float(d0 @ d1)))
        w0 = np.sin((1 - s) * ang) / math.sin(ang) if ang > 1e-9 else 1 - s
        w1 = np.sin(s * ang) / math.sin(ang) if ang > 1e-9 else s
        return c + (w0[:, None] * d0 + w1[:, None] * d1) * (r0 + s * (r1 - r0))[:, None]

    def end_state(self) -> tuple[np.ndarray, np.ndarray]:
        s_end = float(_profile(self.kind, np.array([1.0]), self.f_acc, self.n_pass)[0])
        return self.position(np.array([s_end]))[0], (self.R1 if s_end > 0.5 else self.R0)


class CameraMotion:
    """``T_base_cam`` as a function of pose time (seconds from ``origin_us``) for a config and generator."""

    def __init__(self, cfg: ValidationConfig, target: np.ndarray, rng: np.random.Generator, span_s: float,
                 origin_us: int, obstacles=()):
        self.origin_us, self.span_s, self.cfg, self.target = int(origin_us), float(span_s), cfg, target
        self.obstacles = [(np.asarray(lo), np.asarray(hi)) for lo, hi in obstacles]
        self.moves: list[Move] = []
        self._plan(rng)

    def clear(self, points: np.ndarray) -> bool:
        """Whether every point keeps :data:`CLEARANCE_M` from every obstacle's bounding box (base frame)."""
        for lo, hi in self.obstacles:
            gap = np.maximum(np.maximum(lo - points, points - hi), 0.0)
            if np.min(np.linalg.norm(gap, axis=1)) < CLEARANCE_M:
                return False
        return True

    # ------------------------------------------------------------------ planning
    def _waypoint(self, rng, fixed=None) -> tuple[np.ndarray, np.ndarray]:
        if fixed is not None:
            p_mean, R = fixed
            return p_mean + R @ np.array([rng.uniform(-0.12, 0.12), rng.uniform(-0.08, 0.08),
                                          rng.uniform(-0.06, 0.06)]), R
        d, el, az = rng.uniform(0.3, 0.5), math.radians(rng.uniform(40, 75)), math.radians(90 + rng.uniform(-50, 50))
        p = self.target + d * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        return p, _look_at(p, self.target + rng.normal(0, 0.015, 3), math.radians(rng.uniform(-15, 15)))

    def _plan(self, rng) -> None:
        cfg = self.cfg
        fixed = None
        if cfg.trajectory == "A":
            for _ in range(1000):
                p, R = self._waypoint(rng)
                if self.clear(p[None]):
                    break
            fixed = (p, R)
        for _ in range(1000):
            p, R = self._waypoint(rng, fixed)
            if self.clear(p[None]):
                break
        t = rng.uniform(0.2, 0.5)
        kinds = ("trapezoid", "sine", "sweep") if cfg.profile == "mixed" else (cfg.profile,)
        tries = 0
        while t < self.span_s:
            tries += 1
            if tries > 20_000:
                raise RuntimeError("motion: no waypoint keeps clear of the objects; the scene is too crowded")
            q, Rq = self._waypoint(rng, fixed)
            if not (0.06 <= np.linalg.norm(q - p) <= min(0.45, 0.12 + 0.33 * cfg.speed_mps)):
                continue                                  # slow moves are short: stops every few seconds
            if not self.clear(q[None]):
                continue
            kind = str(rng.choice(kinds, p=[0.45, 0.35, 0.2] if len(kinds) == 3 else None))
            if cfg.trajectory == "B" and rng.uniform() < 0.5:
                d0, d1 = p - self.target, q - self.target
                path = ("arc", self.target, d0 / np.linalg.norm(d0), d1 / np.linalg.norm(d1),
                        float(np.linalg.norm(d0)), float(np.linalg.norm(d1)))
            else:
                path = ("line", p, q)
            ring = (cfg.ringing_mm * 1e-3, rng.uniform(8, 15), rng.uniform(0.05, 0.12), rng.normal(size=3))
            move = Move(t, 1.0, kind, 0.25, int(rng.integers(2, 5)), path, R, Rq, ring)
            if not self.clear(move.position(np.linspace(0.0, 1.0, 60))):
                continue
            move.T, move.f_acc = self._timing(move, rng)
            self.moves.append(move)
            t += move.T
            p, R = move.end_state()
            t += rng.uniform(0.1, 0.7)                    # stop

    def _timing(self, move: Move, rng) -> tuple[float, float]:
        """Duration and acceleration fraction for a peak speed of ``speed_mps``. A trapezoid accelerates at 3-6 x
        the speed per second; a move too short to reach the speed that way is triangular (and slower)."""
        v = self.cfg.speed_mps
        length = float(np.sum(np.linalg.norm(np.diff(move.position(np.linspace(0.0, 1.0, 2001)), axis=0), axis=1)))
        f = 0.25
        if move.kind == "trapezoid":
            accel = v * rng.uniform(3.0, 6.0)
            if length < v * v / accel:
                return 2.0 * math.sqrt(length / accel), 0.5
            f = (v / accel) / (length / v + v / accel)
        tau = np.linspace(0.0, 1.0, 4001)
        pos = move.position(_profile(move.kind, tau, f, move.n_pass))
        peak = float(np.max(np.linalg.norm(np.diff(pos, axis=0), axis=1))) * (len(tau) - 1)   # m per unit tau
        return peak / v, f

    # ------------------------------------------------------------------ evaluation
    @property
    def segments_us(self) -> list[tuple[int, int]]:
        """Pose-clock start and end (µs) of every move."""
        return [(self.origin_us + int(round(m.t0 * 1e6)), self.origin_us + int(round((m.t0 + m.T) * 1e6)))
                for m in self.moves]

    def poses(self, t_s: np.ndarray, ringing: bool = True) -> np.ndarray:
        """``T_base_cam (N, 4, 4)`` at pose times ``t_s`` (seconds from the origin)."""
        t_s = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        starts = np.array([m.t0 for m in self.moves])
        k = np.searchsorted(starts, t_s, side="right") - 1
        out = np.tile(np.eye(4), (len(t_s), 1, 1))
        first = self.moves[0]
        p0 = first.position(np.array([0.0]))[0]
        out[k < 0, :3, :3], out[k < 0, :3, 3] = first.R0, p0
        for j in np.unique(k[k >= 0]):
            m, sel = self.moves[j], np.flatnonzero(k == j)
            tau = (t_s[sel] - m.t0) / m.T
            s = _profile(m.kind, tau, m.f_acc, m.n_pass)
            out[sel, :3, 3] = m.position(s)
            out[sel, :3, :3] = m.slerp(s).as_matrix()
            after = tau > 1.0
            if ringing and after.any() and m.ring[0] > 0:
                amp, freq, decay, axis = m.ring
                dt = t_s[sel[after]] - (m.t0 + m.T)
                wobble = amp * np.exp(-dt / decay) * np.sin(2 * np.pi * freq * dt)
                out[sel[after], :3, 3] += wobble[:, None] * (axis / np.linalg.norm(axis))
                out[sel[after], :3, :3] = Rotation.from_rotvec(
                    (wobble / 0.3)[:, None] * (axis / np.linalg.norm(axis))).as_matrix() @ out[sel[after], :3, :3]
        return out
