"""Timed poses with interpolation: the :class:`Trajectory`.

A :class:`Trajectory` holds samples ``T_base_frame(t_us)`` (``frame`` is ``cam`` or ``tcp``) on
the **pose clock** (int64 microseconds). Translation is interpolated linearly, rotation with
scipy's :class:`~scipy.spatial.transform.Slerp` (shortest path, so antipodal quaternions are the
same rotation). Nothing is extrapolated: times outside ``[t_first_us, t_last_us]`` come back with
``valid = False`` and an identity pose in their row, never NaN. Nothing is invented inside a hole
either (:mod:`evpose.core.data.trajectory_holes`).

Event times map to pose times through the :class:`~evpose.core.data.clock.ClockModel`; the file format
is in :mod:`evpose.core.data.trajectory_csv`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from evpose.core.data.clock import MAX_ABS_TIME_US, ClockModel
from evpose.core.data.geometry import make_T
from evpose.core.data.trajectory_holes import default_max_gap_us, hole_segments, no_pose_reasons
from evpose.core.errors import InputError


class TrajectoryError(InputError):
    """Invalid trajectory data; the message names the source file, row and field."""




@dataclass
class Trajectory:
    """Timed poses ``T_base_frame`` on the pose clock.

    Parameters
    ----------
    t_us : array of int64, shape (N,)
        Sample times in microseconds, strictly increasing after validation.
    positions_m : array, shape (N, 3)
        Origin of ``frame`` in the base frame, metres.
    quats_xyzw : array, shape (N, 4)
        Orientation of ``frame`` in the base frame, scalar-last; normalised here.
    source : str
        Name used in error messages (file path).
    repair : bool
        If False (default), conflicting duplicate or decreasing timestamps raise
        :class:`TrajectoryError`. If True, samples are stably sorted by time and, of samples
        sharing a timestamp, the last one is kept; what was done is listed in ``notes``.
        Exact duplicates (same time and pose) are always dropped and noted.
    max_gap_us : int, optional
        Consecutive samples further apart than this (µs) bound a hole: times strictly between them
        get no pose. None (default for trajectories built in memory): no limit; files are read with
        :func:`default_max_gap_us` by :meth:`load_csv`.
    """

    t_us: np.ndarray
    positions_m: np.ndarray
    quats_xyzw: np.ndarray
    source: str = "<memory>"
    repair: bool = False
    notes: list[str] = field(default_factory=list)
    max_gap_us: int | None = None

    def __post_init__(self):
        src = self.source
        t = np.asarray(self.t_us)
        pos = np.asarray(self.positions_m, dtype=np.float64)
        q = np.asarray(self.quats_xyzw, dtype=np.float64)
        if t.ndim != 1 or pos.shape != (len(t), 3) or q.shape != (len(t), 4):
            raise TrajectoryError(
                f"{src}: expected t_us (N,), positions (N, 3), quaternions (N, 4); got "
                f"{t.shape}, {pos.shape}, {q.shape}")
        if len(t) == 0:
            raise TrajectoryError(f"{src}: t_us: the trajectory has no samples")
        if t.dtype.kind not in "iuf":   # e.g. Python ints beyond int64 (object array)
            try:
                t = t.astype(np.float64)
            except (TypeError, ValueError, OverflowError):
                raise TrajectoryError(f"{src}: t_us: expected integer microseconds, got dtype {t.dtype}") from None
        if not np.issubdtype(t.dtype, np.integer):
            if not np.all(np.isfinite(t)):
                bad = int(np.flatnonzero(~np.isfinite(t))[0])
                raise TrajectoryError(f"{src}: t_us: row {bad} is not finite")
            if np.any(t != np.round(t)):
                raise TrajectoryError(f"{src}: t_us: times must be integer microseconds")
        if t.dtype.kind == "f" or t.dtype == np.uint64:
            big = np.flatnonzero(np.abs(t.astype(np.float64)) > MAX_ABS_TIME_US)
        else:
            big = np.flatnonzero(np.abs(t.astype(np.int64)) > MAX_ABS_TIME_US)
        if len(big):
            raise TrajectoryError(f"{src}: t_us: row {int(big[0])}: {t[big[0]]} is out of range "
                                  f"(|t_us| must be at most 2**53 = {MAX_ABS_TIME_US} us, about 285 years)")
        t = t.astype(np.int64)
        mg = self.max_gap_us
        if mg is not None and (isinstance(mg, bool) or not isinstance(mg, (int, np.integer)) or mg <= 0):
            raise TrajectoryError(f"{src}: max_gap_us: must be a positive integer number of microseconds, got {mg!r}")
        for name, arr, cols in (("x/y/z", pos, "xyz"), ("qx/qy/qz/qw", q, ("qx", "qy", "qz", "qw"))):
            bad = ~np.isfinite(arr)
            if bad.any():
                r, c = np.argwhere(bad)[0]
                raise TrajectoryError(f"{src}: {cols[c]}: row {r} is not finite ({arr[r, c]})")
        norms = np.linalg.norm(q, axis=1)
        if np.any(norms < 1e-9):
            r = int(np.flatnonzero(norms < 1e-9)[0])
            raise TrajectoryError(f"{src}: qx/qy/qz/qw: row {r} is a zero quaternion")
        dev = float(np.max(np.abs(norms - 1.0)))
        if dev > 1e-6:
            self.notes.append(f"normalised non-unit quaternions (max |norm - 1| = {dev:.3g})")
        q = q / norms[:, None]
        t, pos, q = self._order(t, pos, q)
        self.t_us, self.positions_m, self.quats_xyzw = t, pos, q
        self._rot = Rotation.from_quat(q)
        self._t_rel = (t - t[0]).astype(np.float64)
        self._slerp = Slerp(self._t_rel, self._rot) if len(t) >= 2 else None
        self.max_gap_us = None if mg is None else int(mg)
        self._hole_seg = hole_segments(t, self.max_gap_us)

    def _order(self, t, pos, q):
        src = self.source
        dt = np.diff(t)
        if np.all(dt > 0):
            return t, pos, q
        same_pose = np.zeros(len(dt), dtype=bool)
        eq = dt == 0
        if eq.any():
            i = np.flatnonzero(eq)
            same_pose[i] = (np.abs(pos[i] - pos[i + 1]).max(1) <= 1e-12) & (
                np.minimum(np.abs(q[i] - q[i + 1]), np.abs(q[i] + q[i + 1])).max(1) <= 1e-12)
        conflicts = (dt < 0) | (eq & ~same_pose)
        if conflicts.any() and not self.repair:
            r = int(np.flatnonzero(conflicts)[0]) + 1
            kind = "decreases" if dt[r - 1] < 0 else "repeats with a different pose"
            raise TrajectoryError(
                f"{src}: t_us: time {kind} at row {r} ({t[r - 1]} -> {t[r]}); "
                f"sort the file or load it with repair=True (keeps the last sample per timestamp)")
        order = np.argsort(t, kind="stable")
        t, pos, q = t[order], pos[order], q[order]
        keep = np.append(t[1:] != t[:-1], True)  # last sample of each timestamp
        n_sorted = int(np.count_nonzero(dt < 0))
        n_dropped = len(t) - int(keep.sum())
        if n_sorted:
            self.notes.append(f"sorted {n_sorted} out-of-order pose timestamps")
        if n_dropped:
            self.notes.append(f"dropped {n_dropped} samples with a repeated timestamp (kept the last)")
        return t[keep], pos[keep], q[keep]

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def from_T(cls, t_us, T, **kwargs) -> "Trajectory":
        """Build from times and transforms ``T_base_frame (N, 4, 4)``."""
        T = np.asarray(T, dtype=np.float64)
        return cls(np.asarray(t_us), T[:, :3, 3], Rotation.from_matrix(T[:, :3, :3]).as_quat(), **kwargs)

    def __len__(self) -> int:
        return len(self.t_us)

    @property
    def t_first_us(self) -> int:
        return int(self.t_us[0])

    @property
    def t_last_us(self) -> int:
        return int(self.t_us[-1])

    def T(self) -> np.ndarray:
        """All samples as ``(N, 4, 4)`` transforms."""
        return make_T(self._rot.as_matrix(), self.positions_m)

    @property
    def hole_index(self) -> np.ndarray:
        """Index ``i`` of the sample that starts each hole (the hole is ``(t_us[i], t_us[i + 1])``)."""
        return np.flatnonzero(self._hole_seg)

    @property
    def holes(self) -> list[tuple[int, int]]:
        """``(t_a_us, t_b_us)`` per hole (pose clock): consecutive samples more than ``max_gap_us``
        apart; times strictly between them have no pose."""
        return [(int(self.t_us[k]), int(self.t_us[k + 1])) for k in self.hole_index]

    # ------------------------------------------------------------------ interpolation
    def locate_rel(self, t_rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per time (µs relative to the first sample): a status code (0 valid, 1 before the first
        sample, 2 after the last, 3 inside a hole, 4 not a number) and the segment index."""
        t_rel = np.atleast_1d(np.asarray(t_rel, dtype=np.float64))
        code = np.zeros(len(t_rel), np.int8)
        code[t_rel < 0.0] = 1
        code[t_rel > self._t_rel[-1]] = 2
        code[np.isnan(t_rel)] = 4
        seg = np.clip(np.searchsorted(self._t_rel, np.nan_to_num(t_rel), side="right") - 1, 0,
                      max(len(self._t_rel) - 2, 0))
        if self._hole_seg.any():
            inner = (code == 0) & self._hole_seg[seg] & (t_rel > self._t_rel[seg]) & (t_rel < self._t_rel[seg + 1])
            code[inner] = 3
        return code, seg

    def reasons_rel(self, t_rel) -> list[str | None]:
        """Why there is no pose at each time (µs relative to the first sample): None where there is one."""
        code, seg = self.locate_rel(t_rel)
        return no_pose_reasons(code, seg, self.t_us, self.max_gap_us)

    def reasons(self, t_pose_us) -> list[str | None]:
        """:meth:`reasons_rel` for pose-clock times (µs)."""
        return self.reasons_rel(ClockModel().pose_time_rel(t_pose_us, self.t_first_us))

    def reasons_at_event_time(self, t_event_us, clock: "ClockModel") -> list[str | None]:
        """:meth:`reasons_rel` for event-clock times mapped through ``clock``."""
        return self.reasons_rel(clock.pose_time_rel(t_event_us, self.t_first_us))

    def _interp_rel(self, t_rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t_rel = np.atleast_1d(np.asarray(t_rel, dtype=np.float64))
        n = len(t_rel)
        T_out = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        code, seg = self.locate_rel(t_rel)
        valid = code == 0
        if not valid.any():
            return T_out, valid
        tv = t_rel[valid]
        if self._slerp is None:
            T_out[valid] = make_T(self._rot.as_matrix()[0], self.positions_m[0])
            return T_out, valid
        i = seg[valid]
        alpha = (tv - self._t_rel[i]) / (self._t_rel[i + 1] - self._t_rel[i])
        pos = self.positions_m[i] + alpha[:, None] * (self.positions_m[i + 1] - self.positions_m[i])
        T_out[valid] = make_T(self._slerp(tv).as_matrix(), pos)
        return T_out, valid

    def interpolate(self, t_pose_us) -> tuple[np.ndarray, np.ndarray]:
        """Poses at pose-clock times.

        Parameters
        ----------
        t_pose_us : int or array
            Pose-clock times in microseconds (int64 exact; float accepted for fitting).

        Returns
        -------
        T : (N, 4, 4) float64
            ``T_base_frame`` per time; identity where not valid.
        valid : (N,) bool
            False outside ``[t_first_us, t_last_us]`` (no extrapolation) and inside holes.
        """
        return self._interp_rel(ClockModel().pose_time_rel(t_pose_us, self.t_first_us))

    def at_event_time(self, t_event_us, clock: ClockModel) -> tuple[np.ndarray, np.ndarray]:
        """Poses at event-clock times, mapped to the pose clock with ``clock``."""
        return self._interp_rel(clock.pose_time_rel(t_event_us, self.t_first_us))

    def speed(self, t_pose_us=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Linear speed (m/s) and angular speed (rad/s) of the interpolated motion.

        The interpolation is piecewise linear/slerp, so both speeds are constant between
        samples. Without ``t_pose_us`` the per-segment speeds are returned (length N-1; valid is
        False for the segments that span a hole). Times outside the trajectory or inside a hole
        are not valid and have speed 0.
        """
        seg_dt_s = np.diff(self.t_us).astype(np.float64) * 1e-6
        v_seg = np.linalg.norm(np.diff(self.positions_m, axis=0), axis=1) / seg_dt_s
        w_seg = (self._rot[:-1].inv() * self._rot[1:]).magnitude() / seg_dt_s
        if t_pose_us is None:
            return v_seg, w_seg, ~self._hole_seg
        t_rel = ClockModel().pose_time_rel(t_pose_us, self.t_first_us)
        code, i = self.locate_rel(t_rel)
        valid = (code == 0) & (len(self) >= 2)
        if len(self) < 2:
            z = np.zeros(len(code))
            return z, z.copy(), valid
        return np.where(valid, v_seg[i], 0.0), np.where(valid, w_seg[i], 0.0), valid

    # ------------------------------------------------------------------ files
    def save_csv(self, path) -> Path:
        """Write ``t_us,x,y,z,qx,qy,qz,qw`` atomically; floats with repr precision (exact round trip)."""
        from evpose.core.data.trajectory_csv import write_pose_csv  # (it imports TrajectoryError from here)

        return write_pose_csv(path, self.t_us, self.positions_m, self.quats_xyzw)

    @classmethod
    def load_csv(cls, path, *, repair: bool = False, max_gap_us="auto") -> "Trajectory":
        """Read a ``t_us,x,y,z,qx,qy,qz,qw`` CSV (header required, any column order, UTF-8;
        :func:`evpose.core.data.trajectory_csv.read_pose_csv`).

        Only a regular file of at most :data:`evpose.core.data.input_files.MAX_TRAJECTORY_BYTES` is read (a FIFO
        or a device is refused before it is read). ``max_gap_us``: "auto" (default) for
        :func:`~evpose.core.data.trajectory_holes.default_max_gap_us` of the file's times, None for no limit, or µs.
        """
        from evpose.core.data.trajectory_csv import read_pose_csv

        path = Path(path)
        t, arr = read_pose_csv(path)
        if isinstance(max_gap_us, str):
            if max_gap_us != "auto":
                raise ValueError(f"load_csv: max_gap_us must be 'auto', None or a positive integer, got {max_gap_us!r}")
            max_gap_us = default_max_gap_us(np.unique(t))
        return cls(t, arr[:, :3], arr[:, 3:], source=str(path), repair=repair, max_gap_us=max_gap_us)
