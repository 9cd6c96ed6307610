"""Pose text files (TUM, RPG ``groundtruth.txt``, our ``trajectory.csv``) -> a validated :class:`Trajectory`.

One line per sample, ``t x y z qx qy qz qw`` (whitespace or comma separated), optionally with a header naming
the columns in any order. Times are converted exactly from their decimal text, so that seconds written with
six decimals come back as the very µs they were written from.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.pose_checks import make_trajectory
from evpose.core.importers.report import ImportContext
from evpose.core.importers.time_guess import resolve_time_unit
from evpose.core.importers.time_units import decimal_to_us

_POSE_COLS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")
_HEADER_ALIASES = {
    "t": ("t_us", "t", "time", "timestamp", "ts", "t_s", "t_ns", "#timestamp", "# timestamp", "#time"),
    "x": ("x", "px", "tx", "p_x", "pos_x"), "y": ("y", "py", "ty", "p_y", "pos_y"),
    "z": ("z", "pz", "tz", "p_z", "pos_z"),
    "qx": ("qx", "q_x", "rx"), "qy": ("qy", "q_y", "ry"), "qz": ("qz", "q_z", "rz"), "qw": ("qw", "q_w", "rw"),
}
_UNIT_FROM_TIME_HEADER = {"t_us": "us", "t_s": "s", "t_ns": "ns", "t_ms": "ms"}


def read_pose_text(path, ctx: ImportContext, *, declared_unit: str | None = None, what: str = "trajectory"):
    """Read a pose file: ``t x y z qx qy qz qw`` per line (whitespace or comma separated; TUM / RPG
    ``groundtruth.txt``), optionally with a header line naming the columns (any order; our
    ``t_us,x,y,z,qx,qy,qz,qw`` CSV). Lines starting with ``#`` or ``//`` are comments (a comment line that names
    the columns counts as the header).

    Times are converted exactly from their decimal text (round half up); the unit comes from the header
    (``t_us``/``t_s``/``t_ns``), ``--time-unit``, the format's ``declared_unit`` when plausible, or a guess from
    the sampling period (all reported).

    Returns a :class:`Trajectory` (validated by :func:`make_trajectory`).
    """
    path = Path(path)
    with wrap_errors(path, "(file)", "-", "cannot read"):
        text = path.read_bytes().decode("utf-8")
    cols, unit_hdr, rows, line_nos = _split_rows(text, path)
    if not rows:
        raise ImportFailure(path, "(file)", "t", f"no pose samples in the {what} file")
    cols = cols or list(range(8))
    t_tok, vals, t_float = _numbers(rows, cols, line_nos, path)
    if unit_hdr is not None and ctx.options.time_unit is None:
        unit = unit_hdr
        ctx.report.details.setdefault("time_units", {})[f"{path.name}"] = {"unit": unit, "why": "column header"}
    else:
        unit = resolve_time_unit(ctx, t_float, what=f"{path.name} (poses)", kind="poses", declared=declared_unit)
    t_us = np.empty(len(t_tok), np.int64)
    for i, tok in enumerate(t_tok):
        try:
            t_us[i] = decimal_to_us(tok, unit)
        except (ValueError, ZeroDivisionError, OverflowError):
            raise ImportFailure(path, f"line {line_nos[i]}", "t", f"not a decimal number ({tok!r})") from None
    return make_trajectory(ctx, path, t_us, vals[:, :3], vals[:, 3:], record_of=lambda i: f"line {line_nos[i]}")


def _split_rows(text: str, path: Path):
    """Tokens of the data lines, their line numbers, and the column order and time unit of a header line.

    Returns ``(cols or None, unit from the header or None, rows, line numbers)``.
    """
    cols = None
    rows: list[list[str]] = []
    line_nos: list[int] = []
    unit_hdr = None
    for ln, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s:
            continue
        is_comment = s.startswith(("#", "//"))
        toks = [t for t in re.split(r"[,\s]+", s.lstrip("#/").strip()) if t]
        if cols is None and not rows and _looks_like_header(toks):
            names = [t.strip().lower() for t in toks]
            mapping = _header_columns(names)
            if len(mapping) == 8:
                cols = [mapping[k] for k in _POSE_COLS]
                unit_hdr = _UNIT_FROM_TIME_HEADER.get(names[mapping["t"]])
                continue
            if not is_comment:
                raise ImportFailure(path, f"line {ln}", "header", f"cannot map columns {toks} to "
                                    f"{','.join(_POSE_COLS)}")
            continue
        if is_comment:
            continue
        rows.append(toks)
        line_nos.append(ln)
    return cols, unit_hdr, rows, line_nos


def _looks_like_header(toks: list[str]) -> bool:
    return bool(toks) and any(re.search(r"[a-df-zA-DF-Z_]", t) for t in toks) and not all(_is_number(t) for t in toks)


def _header_columns(names: list[str]) -> dict[str, int]:
    """Pose column -> index of the first header name that is one of its aliases."""
    mapping = {}
    for key, aliases in _HEADER_ALIASES.items():
        for j, nm in enumerate(names):
            if nm in aliases:
                mapping[key] = j
                break
    return mapping


def _numbers(rows, cols, line_nos, path: Path):
    """``(time tokens, positions + quaternions (N, 7), times as float (N,))``; refuses a short line, a
    non-number and a non-finite time naming the line and the column."""
    need = max(cols) + 1
    vals = np.empty((len(rows), 7))
    t_tok = []
    for i, toks in enumerate(rows):
        if len(toks) < need:
            raise ImportFailure(path, f"line {line_nos[i]}", "-", f"expected {need} columns, got {len(toks)}")
        t_tok.append(toks[cols[0]])
        for j, c in enumerate(cols[1:]):
            try:
                vals[i, j] = float(toks[c])
            except ValueError:
                raise ImportFailure(path, f"line {line_nos[i]}", _POSE_COLS[j + 1],
                                    f"not a number ({toks[c]!r})") from None
    t_float = np.empty(len(t_tok))
    for i, tok in enumerate(t_tok):
        try:
            t_float[i] = float(tok)
        except ValueError:
            raise ImportFailure(path, f"line {line_nos[i]}", "t", f"not a number ({tok!r})") from None
        if not math.isfinite(t_float[i]):
            raise ImportFailure(path, f"line {line_nos[i]}", "t", f"not finite ({tok!r})")
    return t_tok, vals, t_float


def _is_number(tok: str) -> bool:
    try:
        float(tok)
        return True
    except ValueError:
        return False
