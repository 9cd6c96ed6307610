"""Whole-sequence curves for the timeline: event rate and robot speed on the event clock."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evpose.core.data.scene import Scene

#: the timeline's bin (event rate and speed), µs
TIMELINE_BIN_US = 1000


@dataclass
class TimelineData:
    """Whole-sequence curves on the event clock (seconds since the first event)."""

    t_ref_us: int
    t_s: np.ndarray          # bin centres, s
    rate_hz: np.ndarray      # events per second
    speed_mps: np.ndarray    # camera linear speed at the pose time of each bin (current clock)
    angular_dps: np.ndarray  # camera angular speed, degrees per second
    speed_valid: np.ndarray  # False where the pose time is outside the trajectory or in a hole
    #: (H, 2) trajectory holes on the event clock, s since ``t_ref_us`` (current clock): no labels there
    holes_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def timeline_data(scene: Scene, bin_us: int = TIMELINE_BIN_US) -> TimelineData:
    """Event rate and robot speed, the latter mapped through the clock in effect so a wrong
    offset shows as a shift between the two curves."""
    t_bins, counts = scene.events.rate(bin_us)
    t_ref = scene.t_ref_us
    centres = t_bins + bin_us // 2
    if not scene.has_poses:                  # an event-only scene: the rate alone
        none = np.zeros(len(centres))
        return TimelineData(t_ref, (centres - t_ref) * 1e-6, counts * (1e6 / bin_us), none, none.copy(),
                            np.zeros(len(centres), bool))
    t_pose = scene.clock.pose_time(centres) if len(centres) else centres
    v, w, valid = scene.trajectory.speed(t_pose) if len(centres) else (np.zeros(0),) * 3
    holes = [((h["t0_us"] - t_ref) * 1e-6, (h["t1_us"] - t_ref) * 1e-6)
             for h in scene.trajectory_holes(window_us=bin_us)] if scene.trajectory.holes else []
    return TimelineData(t_ref, (centres - t_ref) * 1e-6, counts * (1e6 / bin_us), np.asarray(v),
                        np.degrees(np.asarray(w)), np.asarray(valid, bool), np.array(holes, np.float64).reshape(-1, 2))
