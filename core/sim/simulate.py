"""The simulation loop of a synthetic scene: render frames along the true motion and turn the log-intensity
changes into events (:mod:`evpose.core.sim.evsim`), written as they come."""
from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from evpose.core.data.clock import ClockModel
from evpose.core.data.event_writer import EventWriter
from evpose.core.data.events import Cancelled, EventArray
from evpose.core.data.trajectory import Trajectory
from evpose.core.sim.evsim import EventSimulator
from evpose.core.sim.motion import Motion
from evpose.core.sim.renderer import SceneRenderer

#: The simulator steps at least this often (µs), so static stretches still get sensor noise.
NOISE_STEP_US = 10_000


def render_times(traj: Trajectory, clock: ClockModel, e0: int, e1: int, f_px: float, z_min_m: float,
                  max_px: float, max_interval_us: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Simulator steps (event-clock µs, ascending, in ``(e0, e1]``) and which of them render a frame.

    While the camera moves, frames are rendered so that the image moves at most ``max_px``
    between them (and, when ``max_interval_us`` > 0, at most that long apart); each run of motion
    gets a frame where it starts, and every noise step that falls inside a motion is rendered
    too. Otherwise the simulator would interpolate the brightness change of the next frame from
    an earlier "unchanged" step and emit the events of that interval late (by ~0.5 ms on average
    at 2 px per frame, before this was fixed) or, at a motion start, up to a noise step early.
    While the camera stands still only the noise steps (every :data:`NOISE_STEP_US`) are taken.
    """
    v, w, _ = traj.speed()
    px_per_s = f_px * (v / z_min_m + w)
    moving = px_per_s > 1e-6
    seg_ev = clock.event_time(traj.t_us)
    times = []
    for k in np.flatnonzero(moving):
        a, b = max(seg_ev[k], e0), min(seg_ev[k + 1], e1)
        if b <= a:
            continue
        n = max(1, int(math.ceil(px_per_s[k] * (b - a) * 1e-6 / max_px)))
        if max_interval_us > 0:
            n = max(n, int(math.ceil((b - a) / max_interval_us)))
        times.append(np.linspace(a, b, n + 1)[1:])
    grid = np.append(np.arange(e0 + NOISE_STEP_US, e1 + 1, NOISE_STEP_US, dtype=np.int64), np.int64(e1))
    k = np.searchsorted(seg_ev, grid, side="left") - 1       # pose interval holding each noise step
    in_motion = (k >= 0) & (k < len(moving)) & moving[np.clip(k, 0, len(moving) - 1)]
    starts = seg_ev[:-1][moving & ~np.r_[False, moving[:-1]]]  # where each run of motion begins
    render = np.unique(np.rint(np.concatenate(times + [grid[in_motion], starts])).astype(np.int64))
    render = render[(render > e0) & (render <= e1)]
    steps = np.union1d(render, grid)
    return steps, np.isin(steps, render)


def simulate_events(path: Path, motion: Motion, clock: ClockModel, e0: int, e1: int, renderer: SceneRenderer,
                    sim: EventSimulator, *, max_px_per_frame: float, max_frame_interval_us: int,
                    progress: Callable[[float, str], None] | None = None,
                    cancel: Callable[[], bool] | None = None) -> tuple[int, int]:
    """Simulate the events of ``(e0, e1]`` (event clock, µs; ``clock`` maps it to the pose clock) into the
    event file ``path``, the first event (a hot pixel at ``e0``) defining ``t_ref``.

    Returns
    -------
    n_events, frames_rendered : int
    """
    camera = renderer.camera
    T0, _ = motion.true.at_event_time(np.array([e0]), clock)
    log0, depth0 = renderer.render(T0[0])
    z_min = float(np.percentile(depth0[np.isfinite(depth0)], 1)) if np.isfinite(depth0).any() else 0.3
    steps, is_render = render_times(motion.recorded, clock, e0, e1, float(camera.K[0, 0]), max(0.1, 0.8 * z_min),
                                    max_px_per_frame, max_frame_interval_us)
    sim.reset(log0, e0)
    n_events = 0
    with EventWriter(path, time_dtype="int64", cancel=cancel) as writer:
        writer.append(EventArray(np.array([sim.hot[0] % camera.width], np.uint16),
                                 np.array([sim.hot[0] // camera.width], np.uint16),
                                 np.array([e0], np.int64), np.array([1], np.uint8)))  # first event defines t_ref
        n_events += 1
        Ts, valid = motion.true.at_event_time(steps[is_render], clock)
        if not valid.all():
            raise RuntimeError("internal: render time outside the trajectory")
        k_render = 0
        for i, t in enumerate(steps):
            if is_render[i]:
                log_frame, _ = renderer.render(Ts[k_render])
                k_render += 1
            else:
                log_frame = None
            ev = sim.step(log_frame, int(t))
            if len(ev):
                writer.append(ev)
                n_events += len(ev)
            if progress is not None and (i % 50 == 0 or i == len(steps) - 1):
                progress((i + 1) / len(steps), f"simulated {(t - e0) / 1e6:.2f} s, {n_events} events")
            if cancel is not None and cancel():
                raise Cancelled("synthesis cancelled")
    return n_events, int(is_render.sum())
