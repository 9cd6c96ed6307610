"""The trajectory CSV file: ``t_us,x,y,z,qx,qy,qz,qw`` (header required, any column order, UTF-8).

``t_us`` is integer µs on the pose clock (a float with an integer value is accepted), ``x, y, z`` the
position in metres and ``qx, qy, qz, qw`` the scalar-last quaternion of the trajectory's frame in the base
frame. Every error is a :class:`~evpose.core.data.trajectory.TrajectoryError` naming the file, the line
and the column; only a regular file of bounded size is read.
"""
from __future__ import annotations

import codecs
import csv
import math
from pathlib import Path

import numpy as np

from evpose.core.data.atomic import atomic_write_text
from evpose.core.data.clock import MAX_ABS_TIME_US
from evpose.core.data.input_files import MAX_TRAJECTORY_BYTES, InputFileError, open_regular
from evpose.core.data.trajectory import TrajectoryError

CSV_HEADER = ("t_us", "x", "y", "z", "qx", "qy", "qz", "qw")


def pose_csv_text(t_us, positions_m, quats_xyzw) -> str:
    """The CSV text of the samples (header line first); floats with repr precision (exact round trip)."""
    lines = [",".join(CSV_HEADER)]
    lines += [f"{int(ti)}," + ",".join(repr(float(v)) for v in (*p, *q))
              for ti, p, q in zip(t_us, positions_m, quats_xyzw)]
    return "\n".join(lines) + "\n"


def write_pose_csv(path, t_us, positions_m, quats_xyzw) -> Path:
    """Write the samples atomically (:func:`pose_csv_text`)."""
    return atomic_write_text(path, pose_csv_text(t_us, positions_m, quats_xyzw))


def read_pose_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The samples of a trajectory CSV: ``t_us`` (N,) int64 and ``[x, y, z, qx, qy, qz, qw]`` (N, 7)
    float64, in file order (not validated beyond parsing: :class:`~evpose.core.data.trajectory.Trajectory`
    does that).

    Only a regular file of at most :data:`evpose.core.data.input_files.MAX_TRAJECTORY_BYTES` is read
    (a FIFO or a device is refused before it is read).
    """
    try:
        f = open_regular(path, "r", max_bytes=MAX_TRAJECTORY_BYTES, encoding="utf-8", newline="")
    except InputFileError as exc:
        raise TrajectoryError(f"{path}: cannot open the trajectory file: {exc.reason}") from None
    rows = _Rows(path)
    try:
        with f:
            reader = csv.reader(f)
            rows.read(reader, _header_columns(path, reader))
    except UnicodeDecodeError as exc:
        raise TrajectoryError(f"{path}: {_decode_error_where(path, exc)}: not UTF-8 text "
                              f"(byte 0x{exc.object[exc.start]:02x}); the trajectory must be a UTF-8 CSV") from None
    except csv.Error as exc:
        raise TrajectoryError(f"{path}: line {rows.row_no + 1}: not a CSV row ({exc})") from None
    except OSError as exc:
        raise TrajectoryError(f"{path}: cannot read the trajectory file ({exc.strerror or exc})") from None
    if not rows.t:
        raise TrajectoryError(f"{path}: t_us: the trajectory has no samples")
    return np.asarray(rows.t, dtype=np.int64), np.asarray(rows.values, dtype=np.float64)


def _header_columns(path: Path, reader) -> tuple[list[int], int]:
    """Column positions of :data:`CSV_HEADER` in the header line, and the header's width."""
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise TrajectoryError(f"{path}: the file is empty (expected header {','.join(CSV_HEADER)})") from None
    missing = [c for c in CSV_HEADER if c not in header]
    if missing:
        raise TrajectoryError(f"{path}: header: missing column(s) {', '.join(missing)} "
                              f"(expected {','.join(CSV_HEADER)})")
    return [header.index(c) for c in CSV_HEADER], len(header)


class _Rows:
    """The samples read so far, and the number of the last line read (for a CSV error of the next one)."""

    def __init__(self, path: Path):
        self.path, self.row_no = path, 1
        self.t: list[int] = []
        self.values: list[list[float]] = []

    def read(self, reader, columns: tuple[list[int], int]) -> None:
        cols, width = columns
        for row_no, row in enumerate(reader, start=2):
            self.row_no = row_no
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) < width:
                raise TrajectoryError(f"{self.path}: line {self.row_no}: expected {width} columns, got {len(row)}")
            self.t.append(self._time(row[cols[0]]))
            self.values.append([self._number(name, row[c]) for name, c in zip(CSV_HEADER[1:], cols[1:])])

    def _time(self, text: str) -> int:
        try:
            t = _parse_int_us(text)
        except ValueError:
            raise TrajectoryError(f"{self.path}: line {self.row_no}: t_us: not an integer ({text[:40]!r})") from None
        if abs(t) > MAX_ABS_TIME_US:
            raise TrajectoryError(f"{self.path}: line {self.row_no}: t_us: {text.strip()[:40]} is out of range "
                                  f"(|t_us| must be at most 2**53 = {MAX_ABS_TIME_US} us, about 285 years)")
        return t

    def _number(self, name: str, text: str) -> float:
        try:
            return float(text)
        except ValueError:
            raise TrajectoryError(f"{self.path}: line {self.row_no}: {name}: not a number ({text[:40]!r})") from None


def _decode_error_where(path: Path, exc: UnicodeDecodeError) -> str:
    """``line N`` of the first byte that is not UTF-8 (found by a second, binary pass: the text
    reader decodes in blocks, so its error position is relative to an unknown block)."""
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
