"""Holes in a trajectory: where it gives no pose, and why.

Nothing is extrapolated: times outside the samples get no pose. Nothing is invented inside a **hole**
either: two consecutive samples further apart than ``max_gap_us`` bound a hole, and times strictly
between them get no pose (the samples themselves do). Pose topics drop messages; interpolating across a
200 ms gap of a 0.5 m/s move puts labels 14 mm off. :func:`default_max_gap_us` derives the bound from the
sampling interval (:data:`MAX_GAP_STEPS` median steps) for trajectories read from files; scenes may set it
(``[trajectory] max_gap_us`` in ``scene.toml``).

:meth:`evpose.core.data.trajectory.Trajectory.locate_rel` codes each time: 0 has a pose, 1 before the
first sample, 2 after the last, 3 inside a hole, 4 not a number; :func:`no_pose_reasons` words them.
"""
from __future__ import annotations

import math

import numpy as np

#: Default maximum interpolation gap in median sampling steps (:func:`default_max_gap_us`). Measured with
#: ``bench/trajectory_gaps.py`` (min-jerk moves recorded at 250 Hz), worst camera pose error of linear/slerp
#: interpolation across a gap of k steps at 1.0 m/s: k=1 (no gap) 0.04 mm / 0.01 deg, k=2 0.16 mm, k=3 0.36 mm,
#: k=4 0.63 mm / 0.13 deg, k=5 0.98 mm / 0.20 deg, k=10 3.8 mm / 0.77 deg, k=50 38 mm / 12.9 deg (a quarter of
#: that at 0.5 m/s: the error grows with the square of the gap and of the speed). 4 steps bridge up to three
#: dropped messages in a row, the routine losses of a pose topic, and refuse gaps whose interpolation costs
#: more than about half a millimetre at the fastest E-POSE speed.
MAX_GAP_STEPS = 4
#: Reasons for a missing pose (also the export's unlabeled reasons).
REASON_BEFORE = "label time outside the trajectory: pose time before its first pose (no extrapolation)"
REASON_AFTER = "label time outside the trajectory: pose time after its last pose (no extrapolation)"


def hole_reason(t_a_us: int, t_b_us: int, max_gap_us: int) -> str:
    """The reason given for a time inside the hole ``(t_a_us, t_b_us)`` (pose clock, µs)."""
    return (f"label time in a trajectory hole [{int(t_a_us)}, {int(t_b_us)}] us (pose clock): "
            f"{(t_b_us - t_a_us) / 1000:g} ms without a pose, more than max_gap_us = {int(max_gap_us)}")


def default_max_gap_us(t_us) -> int | None:
    """:data:`MAX_GAP_STEPS` times the median sampling step (µs, rounded up); None for fewer than 2 samples.

    The median ignores the gaps themselves and the jitter of individual steps, so it is the rate
    the recorder meant to publish at.
    """
    t = np.asarray(t_us, dtype=np.int64)
    if len(t) < 2:
        return None
    d = np.diff(t)
    d = d[d > 0]
    if len(d) == 0:
        return None
    return int(math.ceil(MAX_GAP_STEPS * float(np.median(d))))


def hole_segments(t_us: np.ndarray, max_gap_us: int | None) -> np.ndarray:
    """Per segment ``(t_us[i], t_us[i + 1])`` of sorted sample times: True where it is a hole (the samples
    are more than ``max_gap_us`` apart; None: no limit, no hole)."""
    if max_gap_us is None:
        return np.zeros(max(len(t_us) - 1, 0), bool)
    return np.diff(t_us) > max_gap_us


def no_pose_reasons(code: np.ndarray, seg: np.ndarray, t_us: np.ndarray, max_gap_us: int | None) -> list[str | None]:
    """Why there is no pose, per status ``code`` and segment ``seg`` of
    :meth:`evpose.core.data.trajectory.Trajectory.locate_rel` (``t_us``: the sample times): None where
    there is one."""
    out: list[str | None] = []
    for c, k in zip(code.tolist(), seg.tolist()):
        if c == 0:
            out.append(None)
        elif c == 1:
            out.append(REASON_BEFORE)
        elif c == 2:
            out.append(REASON_AFTER)
        elif c == 3:
            out.append(hole_reason(t_us[k], t_us[k + 1], max_gap_us))
        else:
            out.append("label time not a number on the pose clock")
    return out
