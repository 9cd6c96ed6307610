"""Validation of poses read from files: 4x4 transforms and pose samples -> a :class:`Trajectory`.

Published poses come with NaNs, non-unit quaternions, rounded rotation matrices and repeated time stamps.
Each check here either refuses the value (naming file, record and field) or, with ``--repair`` where a
repair is safe, fixes it and reports what it changed.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from evpose.core.data.geometry import ROTATION_TOLERANCE, make_T, orthonormalize
from evpose.core.data.trajectory import Trajectory, TrajectoryError
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.report import ImportContext


def check_T(T, ctx: ImportContext, file, record: str, fld: str, *, tolerance: float = ROTATION_TOLERANCE,
            quiet: bool = False) -> tuple[np.ndarray, float]:
    """Validate one 4x4 transform from a file: shape, finiteness, last row, rotation residual.

    Returns the transform with its rotation projected onto SO(3) and the residual ``max|R R^T - I|``.
    Above ``tolerance`` it raises unless ``--repair`` (then the projection is reported).
    """
    try:
        T = np.asarray(T, dtype=np.float64)
    except (TypeError, ValueError):
        raise ImportFailure(file, record, fld, "not a numeric 4x4 matrix") from None
    if T.shape == (3, 4):
        T = np.vstack([T, [0.0, 0.0, 0.0, 1.0]])
    if T.shape != (4, 4):
        raise ImportFailure(file, record, fld, f"expected a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ImportFailure(file, record, fld, "contains NaN or inf")
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise ImportFailure(file, record, fld, f"last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    R, residual = orthonormalize(T[:3, :3])
    if residual > tolerance:
        if not ctx.repair:
            raise ImportFailure(file, record, fld, f"rotation is not orthonormal (max|R R^T - I| = {residual:.4g} > "
                                f"tolerance {tolerance:g}); fix the value or pass --repair to project it onto SO(3)")
        if not quiet:
            ctx.report.repair(f"{file}: {record}: {fld}: rotation projected onto SO(3) (residual {residual:.4g} > "
                              f"tolerance {tolerance:g}, --repair)")
    return make_T(R, T[:3, 3]), residual


def check_finite_rows(arr: np.ndarray, names, file, record_of: Callable[[int], str]) -> None:
    """Raise naming the first row/field that is NaN or inf."""
    arr = np.asarray(arr, dtype=np.float64)
    bad = ~np.isfinite(arr)
    if bad.any():
        r, c = np.argwhere(bad.reshape(len(arr), -1))[0]
        raise ImportFailure(file, record_of(int(r)), names[int(c)], f"not finite ({arr.reshape(len(arr), -1)[r, c]})")


def make_trajectory(ctx: ImportContext, file, t_us, positions_m, quats_xyzw, *, record_of=None,
                    fields=("t", "x", "y", "z", "qx", "qy", "qz", "qw")) -> Trajectory:
    """Validate pose samples and build a :class:`Trajectory` (frame in the base frame, metres, µs).

    NaN/inf and zero quaternions are refused naming the record; non-unit quaternions are normalised and
    reported; decreasing or conflicting duplicate times are refused unless ``--repair`` (then sorted, last
    sample per time kept, reported). Exact duplicates are always dropped and reported.
    """
    record_of = record_of or (lambda i: f"row {i}")
    t_us = np.asarray(t_us, dtype=np.int64)
    pos = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(quats_xyzw, dtype=np.float64).reshape(-1, 4)
    if len(t_us) == 0:
        raise ImportFailure(file, "(all records)", fields[0], "no pose samples")
    if not (len(t_us) == len(pos) == len(q)):
        raise ImportFailure(file, "(all records)", fields[0], f"{len(t_us)} times for {len(pos)} positions and "
                            f"{len(q)} orientations")
    check_finite_rows(np.hstack([pos, q]), fields[1:], file, record_of)
    norms = np.linalg.norm(q, axis=1)
    if np.any(norms < 1e-9):
        r = int(np.flatnonzero(norms < 1e-9)[0])
        raise ImportFailure(file, record_of(r), "/".join(fields[4:]), "zero quaternion")
    dev = np.abs(norms - 1.0)
    if dev.max() > 1e-6:
        r = int(np.argmax(dev))
        ctx.report.repair(f"{file}: normalised {int(np.count_nonzero(dev > 1e-6))} non-unit quaternion(s) "
                          f"(max |norm - 1| = {dev.max():.3g} at {record_of(r)})")
    d = np.diff(t_us)
    if np.any(d <= 0):
        eq = np.flatnonzero(d == 0)
        same = np.zeros(len(d), bool)
        if len(eq):
            qa, qb = q[eq] / norms[eq, None], q[eq + 1] / norms[eq + 1, None]
            same[eq] = (np.abs(pos[eq] - pos[eq + 1]).max(1) <= 1e-12) & (
                np.minimum(np.abs(qa - qb), np.abs(qa + qb)).max(1) <= 1e-12)
        conflict = (d < 0) | ((d == 0) & ~same)
        if conflict.any() and not ctx.repair:
            r = int(np.flatnonzero(conflict)[0]) + 1
            kind = "decreases" if d[r - 1] < 0 else "repeats with a different pose"
            raise ImportFailure(file, record_of(r), fields[0], f"time {kind} ({t_us[r - 1]} -> {t_us[r]} µs); "
                                "pass --repair to sort the samples and keep the last one per time")
    try:
        traj = Trajectory(t_us, pos, q, source=str(file), repair=ctx.repair)
    except TrajectoryError as exc:
        raise ImportFailure(file, "(trajectory)", fields[0], str(exc).replace(f"{file}: ", "", 1)) from None
    for note in traj.notes:
        if not note.startswith("normalised"):
            ctx.report.repair(f"{file}: trajectory: {note}")
    return traj


def poses_from_matrices(ctx: ImportContext, file, T, record_of) -> tuple[np.ndarray, np.ndarray, float]:
    """(N, 4, 4) transforms -> positions (N, 3), quaternions xyzw (N, 4), max rotation residual.

    Each rotation is validated with :func:`check_T` (refused above tolerance unless ``--repair``).
    """
    from scipy.spatial.transform import Rotation

    T = np.asarray(T, dtype=np.float64)
    out = np.empty((len(T), 4, 4))          # (N, 3, 4) input gets its last row
    res = np.zeros(len(T))
    n_proj = 0
    for i in range(len(T)):
        out[i], res[i] = check_T(T[i], ctx, file, record_of(i), "T", quiet=True)
        n_proj += res[i] > ROTATION_TOLERANCE
    if len(T) and res.max() > 1e-9:
        msg = (f"{file}: {len(T)} rotation(s) projected onto SO(3) (max residual {res.max():.3g} at "
               f"{record_of(int(np.argmax(res)))})")
        (ctx.report.repair if n_proj else ctx.report.assume)(msg)
    return out[:, :3, 3].copy(), Rotation.from_matrix(out[:, :3, :3]).as_quat(), float(res.max() if len(T) else 0.0)
