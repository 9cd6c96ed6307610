"""The clock model relating event time to pose time (DESIGN section 3)::

    t_pose_us = t_event_us + offset_us + skew_ppm * 1e-6 * (t_event_us - t_ref_us)

``t_ref_us`` is the recording's first event time, so ``offset_us`` is the offset at the start and the skew
term stays well conditioned with absolute (epoch) timestamps of 10**15 µs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Largest accepted |time| and |clock offset|, µs (2**53, about 285 years): the clock model and the
#: interpolation compute in float64, exact for integers up to 2**53, so larger values would be rounded
#: (and 10**30 does not even fit int64). Unix-epoch µs (1.7e15 in 2023) are far inside.
MAX_ABS_TIME_US = 2**53


@dataclass(frozen=True)
class ClockModel:
    """Affine map from the event clock to the pose clock.

    Parameters
    ----------
    offset_us : int
        Pose time minus event time at ``t_ref_us`` (microseconds).
    skew_ppm : float
        Relative rate difference of the two clocks in parts per million.
    t_ref_us : int
        Reference event time, the recording's first event, so the skew term stays well
        conditioned with absolute (epoch) timestamps.
    """

    offset_us: int = 0
    skew_ppm: float = 0.0
    t_ref_us: int = 0

    def pose_time_rel(self, t_event_us, origin_us: int) -> np.ndarray:
        """Pose time relative to ``origin_us`` as float64 microseconds.

        All large quantities are subtracted in int64 before converting to float, so precision
        does not degrade with epoch timestamps (10^15 us).
        """
        t = np.asarray(t_event_us)
        if np.issubdtype(t.dtype, np.integer):
            d_origin = (t.astype(np.int64) - np.int64(origin_us)).astype(np.float64)
            d_ref = (t.astype(np.int64) - np.int64(self.t_ref_us)).astype(np.float64)
        else:
            t = t.astype(np.float64)
            d_origin = t - float(origin_us)
            d_ref = t - float(self.t_ref_us)
        return d_origin + float(self.offset_us) + self.skew_ppm * 1e-6 * d_ref

    def pose_time(self, t_event_us) -> np.ndarray:
        """Pose time in int64 microseconds (rounded to the nearest microsecond)."""
        t = np.asarray(t_event_us, dtype=np.int64)
        d_ref = (t - np.int64(self.t_ref_us)).astype(np.float64)
        return t + np.rint(float(self.offset_us) + self.skew_ppm * 1e-6 * d_ref).astype(np.int64)

    def event_time(self, t_pose_us) -> np.ndarray:
        """Inverse map: event time (int64 us, rounded) for pose times."""
        t_pose = np.asarray(t_pose_us, dtype=np.int64)
        k = 1.0 + self.skew_ppm * 1e-6
        # t_pose - t_ref = (t_ev - t_ref) * k + offset
        d = (t_pose - np.int64(self.t_ref_us)).astype(np.float64) - float(self.offset_us)
        return np.int64(self.t_ref_us) + np.rint(d / k).astype(np.int64)
