"""Timed poses with interpolation and the clock model relating event time to pose time.

A :class:`Trajectory` holds samples ``T_base_frame(t_us)`` (``frame`` is ``cam`` or ``tcp``) on
the **pose clock** (int64 microseconds). Translation is interpolated linearly, rotation with
scipy's :class:`~scipy.spatial.transform.Slerp` (shortest path, so antipodal quaternions are the
same rotation). Nothing is extrapolated: times outside ``[t_first_us, t_last_us]`` come back with
``valid = False`` and an identity pose in their row, never NaN.

The :class:`ClockModel` maps event time to pose time (DESIGN section 3)::

    t_pose_us = t_event_us + offset_us + skew_ppm * 1e-6 * (t_event_us - t_ref_us)
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .fileio import atomic_write_text
from .geometry import make_T

CSV_HEADER = ("t_us", "x", "y", "z", "qx", "qy", "qz", "qw")


class TrajectoryError(ValueError):
    """Invalid trajectory data; the message names the source file, row and field."""


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
    """

    t_us: np.ndarray
    positions_m: np.ndarray
    quats_xyzw: np.ndarray
    source: str = "<memory>"
    repair: bool = False
    notes: list[str] = field(default_factory=list)

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
        if not np.issubdtype(t.dtype, np.integer):
            if not np.all(np.isfinite(t)):
                bad = int(np.flatnonzero(~np.isfinite(t))[0])
                raise TrajectoryError(f"{src}: t_us: row {bad} is not finite")
            if np.any(t != np.round(t)):
                raise TrajectoryError(f"{src}: t_us: times must be integer microseconds")
        t = t.astype(np.int64)
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

    # ------------------------------------------------------------------ interpolation
    def _interp_rel(self, t_rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t_rel = np.atleast_1d(np.asarray(t_rel, dtype=np.float64))
        n = len(t_rel)
        T_out = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        valid = (t_rel >= 0.0) & (t_rel <= self._t_rel[-1])
        if not valid.any():
            return T_out, valid
        tv = t_rel[valid]
        if self._slerp is None:
            T_out[valid] = make_T(self._rot.as_matrix()[0], self.positions_m[0])
            return T_out, valid
        i = np.clip(np.searchsorted(self._t_rel, tv, side="right") - 1, 0, len(self._t_rel) - 2)
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
            False outside ``[t_first_us, t_last_us]`` (no extrapolation).
        """
        return self._interp_rel(ClockModel().pose_time_rel(t_pose_us, self.t_first_us))

    def at_event_time(self, t_event_us, clock: ClockModel) -> tuple[np.ndarray, np.ndarray]:
        """Poses at event-clock times, mapped to the pose clock with ``clock``."""
        return self._interp_rel(clock.pose_time_rel(t_event_us, self.t_first_us))

    def speed(self, t_pose_us=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Linear speed (m/s) and angular speed (rad/s) of the interpolated motion.

        The interpolation is piecewise linear/slerp, so both speeds are constant between
        samples. Without ``t_pose_us`` the per-segment speeds are returned (length N-1, valid).
        """
        seg_dt_s = np.diff(self.t_us).astype(np.float64) * 1e-6
        v_seg = np.linalg.norm(np.diff(self.positions_m, axis=0), axis=1) / seg_dt_s
        w_seg = (self._rot[:-1].inv() * self._rot[1:]).magnitude() / seg_dt_s
        if t_pose_us is None:
            return v_seg, w_seg, np.ones(len(v_seg), dtype=bool)
        t_rel = ClockModel().pose_time_rel(t_pose_us, self.t_first_us)
        t_rel = np.atleast_1d(t_rel)
        valid = (t_rel >= 0) & (t_rel <= self._t_rel[-1]) & (len(self) >= 2)
        i = np.clip(np.searchsorted(self._t_rel, t_rel, side="right") - 1, 0, max(len(self) - 2, 0))
        if len(self) < 2:
            z = np.zeros(len(t_rel))
            return z, z.copy(), valid
        return np.where(valid, v_seg[i], 0.0), np.where(valid, w_seg[i], 0.0), valid

    # ------------------------------------------------------------------ files
    def save_csv(self, path) -> Path:
        """Write ``t_us,x,y,z,qx,qy,qz,qw`` atomically; floats with repr precision (exact round trip)."""
        lines = [",".join(CSV_HEADER)]
        lines += [f"{int(ti)}," + ",".join(repr(float(v)) for v in (*p, *q))
                  for ti, p, q in zip(self.t_us, self.positions_m, self.quats_xyzw)]
        return atomic_write_text(path, "\n".join(lines) + "\n")

    @classmethod
    def load_csv(cls, path, *, repair: bool = False) -> "Trajectory":
        """Read a ``t_us,x,y,z,qx,qy,qz,qw`` CSV (header required, any column order)."""
        path = Path(path)
        try:
            f = open(path, newline="")
        except OSError as exc:
            raise TrajectoryError(f"{path}: cannot open the trajectory file ({exc.strerror})") from None
        with f:
            reader = csv.reader(f)
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise TrajectoryError(f"{path}: the file is empty (expected header {','.join(CSV_HEADER)})") from None
            missing = [c for c in CSV_HEADER if c not in header]
            if missing:
                raise TrajectoryError(f"{path}: header: missing column(s) {', '.join(missing)} "
                                      f"(expected {','.join(CSV_HEADER)})")
            cols = [header.index(c) for c in CSV_HEADER]
            t_list: list[int] = []
            vals: list[list[float]] = []
            for row_no, row in enumerate(reader, start=2):
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) < len(header):
                    raise TrajectoryError(f"{path}: line {row_no}: expected {len(header)} columns, got {len(row)}")
                try:
                    t_list.append(_parse_int_us(row[cols[0]]))
                except ValueError:
                    raise TrajectoryError(f"{path}: line {row_no}: t_us: not an integer ({row[cols[0]]!r})") from None
                rec = []
                for name, c in zip(CSV_HEADER[1:], cols[1:]):
                    try:
                        rec.append(float(row[c]))
                    except ValueError:
                        raise TrajectoryError(f"{path}: line {row_no}: {name}: not a number ({row[c]!r})") from None
                vals.append(rec)
        if not t_list:
            raise TrajectoryError(f"{path}: t_us: the trajectory has no samples")
        arr = np.asarray(vals, dtype=np.float64)
        return cls(np.asarray(t_list, dtype=np.int64), arr[:, :3], arr[:, 3:], source=str(path), repair=repair)


def _parse_int_us(text: str) -> int:
    text = text.strip()
    try:
        return int(text)
    except ValueError:
        v = float(text)
        if not math.isfinite(v) or v != round(v):
            raise
        return int(v)
