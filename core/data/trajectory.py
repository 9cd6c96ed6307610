"""Timed poses with interpolation and the clock model relating event time to pose time.

A :class:`Trajectory` holds samples ``T_base_frame(t_us)`` (``frame`` is ``cam`` or ``tcp``) on
the **pose clock** (int64 microseconds). Translation is interpolated linearly, rotation with
scipy's :class:`~scipy.spatial.transform.Slerp` (shortest path, so antipodal quaternions are the
same rotation). Nothing is extrapolated: times outside ``[t_first_us, t_last_us]`` come back with
``valid = False`` and an identity pose in their row, never NaN.

Nothing is invented inside a **hole** either: two consecutive samples further apart than
``max_gap_us`` bound a hole, and times strictly between them are not valid (the samples themselves
are). Pose topics drop messages; interpolating across a 200 ms gap of a 0.5 m/s move puts labels
14 mm off. :func:`default_max_gap_us` derives the bound from the sampling interval
(:data:`MAX_GAP_STEPS` median steps) for trajectories read from files; scenes may set it
(``[trajectory] max_gap_us`` in ``scene.toml``).

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

from evpose.core.data.atomic import atomic_write_text
from evpose.core.data.geometry import make_T
from evpose.core.errors import InputError

CSV_HEADER = ("t_us", "x", "y", "z", "qx", "qy", "qz", "qw")
#: Largest accepted |time| and |clock offset|, µs (2**53, about 285 years): the clock model and the
#: interpolation compute in float64, exact for integers up to 2**53, so larger values would be rounded
#: (and 10**30 does not even fit int64). Unix-epoch µs (1.7e15 in 2023) are far inside.
MAX_ABS_TIME_US = 2**53
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


class TrajectoryError(InputError):
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
        self._hole_seg = (np.diff(t) > self.max_gap_us) if mg is not None else np.zeros(max(len(t) - 1, 0), bool)

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
        out: list[str | None] = []
        for c, k in zip(code.tolist(), seg.tolist()):
            if c == 0:
                out.append(None)
            elif c == 1:
                out.append(REASON_BEFORE)
            elif c == 2:
                out.append(REASON_AFTER)
            elif c == 3:
                out.append(hole_reason(self.t_us[k], self.t_us[k + 1], self.max_gap_us))
            else:
                out.append("label time not a number on the pose clock")
        return out

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
        lines = [",".join(CSV_HEADER)]
        lines += [f"{int(ti)}," + ",".join(repr(float(v)) for v in (*p, *q))
                  for ti, p, q in zip(self.t_us, self.positions_m, self.quats_xyzw)]
        return atomic_write_text(path, "\n".join(lines) + "\n")

    @classmethod
    def load_csv(cls, path, *, repair: bool = False, max_gap_us="auto") -> "Trajectory":
        """Read a ``t_us,x,y,z,qx,qy,qz,qw`` CSV (header required, any column order, UTF-8).

        Only a regular file of at most :data:`evpose.core.data.input_files.MAX_TRAJECTORY_BYTES` is read (a FIFO
        or a device is refused before it is read). ``max_gap_us``: "auto" (default) for
        :func:`default_max_gap_us` of the file's times, None for no limit, or µs.
        """
        from evpose.core.data.input_files import (
            MAX_TRAJECTORY_BYTES,
            InputFileError,
            open_regular,
        )

        path = Path(path)
        try:
            f = open_regular(path, "r", max_bytes=MAX_TRAJECTORY_BYTES, encoding="utf-8", newline="")
        except InputFileError as exc:
            raise TrajectoryError(f"{path}: cannot open the trajectory file: {exc.reason}") from None
        row_no = 1
        try:
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
                        raise TrajectoryError(f"{path}: line {row_no}: t_us: not an integer ({row[cols[0]][:40]!r})") from None
                    if abs(t_list[-1]) > MAX_ABS_TIME_US:
                        raise TrajectoryError(f"{path}: line {row_no}: t_us: {row[cols[0]].strip()[:40]} is out of range "
                                              f"(|t_us| must be at most 2**53 = {MAX_ABS_TIME_US} us, about 285 years)")
                    rec = []
                    for name, c in zip(CSV_HEADER[1:], cols[1:]):
                        try:
                            rec.append(float(row[c]))
                        except ValueError:
                            raise TrajectoryError(f"{path}: line {row_no}: {name}: not a number ({row[c][:40]!r})") from None
                    vals.append(rec)
        except UnicodeDecodeError as exc:
            raise TrajectoryError(f"{path}: {_decode_error_where(path, exc)}: not UTF-8 text "
                                  f"(byte 0x{exc.object[exc.start]:02x}); the trajectory must be a UTF-8 CSV") from None
        except csv.Error as exc:
            raise TrajectoryError(f"{path}: line {row_no + 1}: not a CSV row ({exc})") from None
        except OSError as exc:
            raise TrajectoryError(f"{path}: cannot read the trajectory file ({exc.strerror or exc})") from None
        if not t_list:
            raise TrajectoryError(f"{path}: t_us: the trajectory has no samples")
        arr = np.asarray(vals, dtype=np.float64)
        t = np.asarray(t_list, dtype=np.int64)
        if isinstance(max_gap_us, str):
            if max_gap_us != "auto":
                raise ValueError(f"load_csv: max_gap_us must be 'auto', None or a positive integer, got {max_gap_us!r}")
            max_gap_us = default_max_gap_us(np.unique(t))
        return cls(t, arr[:, :3], arr[:, 3:], source=str(path), repair=repair, max_gap_us=max_gap_us)


def _decode_error_where(path: Path, exc: UnicodeDecodeError) -> str:
    """``line N`` of the first byte that is not UTF-8 (found by a second, binary pass: the text
    reader decodes in blocks, so its error position is relative to an unknown block)."""
    import codecs

    dec = codecs.getincrementaldecoder("utf-8")()
    line, newline = 1, b"\n"
    try:
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 16), b""):
                try:
                    dec.decode(block)
                except UnicodeDecodeError as e:
                    return f"line {line + block[:max(e.start, 0)].count(newline)}"
                line += block.count(newline)
    except OSError:
        pass
    return "text"


def _parse_int_us(text: str) -> int:
    text = text.strip()
    try:
        return int(text)
    except ValueError:
        v = float(text)
        if not math.isfinite(v) or v != round(v):
            raise
        return int(v)
