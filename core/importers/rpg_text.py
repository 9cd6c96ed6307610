"""Exact, vectorised parsing of large text tables of decimal numbers (the RPG ``events.txt``).

Parsing is streamed in 4 MB blocks and vectorised over the bytes (no Python loop per line, no pandas):
tokens are found from separator positions and every number is assembled from its decimal digits in int64
(up to 19 digits below 9e18), so seconds -> µs is **exact**: ``µs = floor(m * 10**6 / 10**d + 1/2)`` for the
decimal mantissa ``m`` with ``d`` fraction digits (round half up; e.g. ``0.0000005`` -> 1 µs). A block holding
anything but digits, ``.``, ``-``, spaces, tabs, commas and newlines (exponents, ``nan``, ``+``) raises
:class:`NotPlainDecimal` and is parsed with ``np.loadtxt`` instead (:func:`fallback_block`, float64). Tokens with
more than 19 digits go the same way.
"""
from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np

from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.report import ImportContext
from evpose.core.importers.time_units import TIME_UNITS

BLOCK_BYTES = 4 << 20
_POW10 = np.array([10**k for k in range(19)], dtype=np.int64)


class NotPlainDecimal(Exception):
    """The vectorised parser cannot take this block (non-plain characters or > 18 digits)."""


def parse_columns(buf: bytes, ncols: int, *, file, line0: int, int_cols=()) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised exact parser of a block of complete lines of decimal numbers.

    Returns
    -------
    mant : (n, ncols) int64
        Decimal mantissa with sign (``"-1.25"`` -> -125).
    ndec : (n, ncols) int64
        Digits after the decimal point (``"-1.25"`` -> 2).

    Raises :class:`ImportFailure` for a line with the wrong number of columns or a malformed number (naming
    ``line0 + k``, 1-based), and ``NotPlainDecimal`` for characters it does not handle.
    """
    a = np.frombuffer(buf, np.uint8)
    if len(a) == 0:
        return np.empty((0, ncols), np.int64), np.empty((0, ncols), np.int64)
    is_nl = a == 10
    is_sep = is_nl | (a == 32) | (a == 9) | (a == 13) | (a == 44)
    is_digit = (a >= 48) & (a <= 57)
    is_dot = a == 46
    is_minus = a == 45
    if not np.all(is_sep | is_digit | is_dot | is_minus):
        raise NotPlainDecimal()
    tok = ~is_sep
    starts = np.flatnonzero(tok & np.concatenate(([True], is_sep[:-1])))
    ends = np.flatnonzero(tok & np.concatenate((is_sep[1:], [True]))) + 1
    nl_pos = np.flatnonzero(is_nl)
    n_lines = len(nl_pos) + (0 if a[-1] == 10 else 1)
    line_of = np.searchsorted(nl_pos, starts)
    per_line = np.bincount(line_of, minlength=n_lines)
    bad = (per_line != 0) & (per_line != ncols)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise ImportFailure(file, f"line {line0 + k}", "-", f"expected {ncols} columns, got {int(per_line[k])}")
    cdig = np.cumsum(is_digit, dtype=np.int64)
    before = np.where(starts > 0, cdig[np.maximum(starts - 1, 0)], 0)
    nd = cdig[ends - 1] - before
    if np.any(nd == 0):
        k = int(np.flatnonzero(nd == 0)[0])
        raise ImportFailure(file, f"line {line0 + int(line_of[k])}", f"column {k % ncols + 1}",
                            f"not a number ({bytes(a[starts[k]:ends[k]]).decode(errors='replace')!r})")
    if nd.max() > 18:          # 19 digits fit int64 when the leading digit is at most 8 (< 9.0e18)
        big = np.flatnonzero(nd > 18)
        if nd.max() > 19 or np.any(a[ends[big] - nd[big] - (ends[big] - starts[big] - nd[big])] > 56):
            raise NotPlainDecimal()
    # minus only as the first character of a token
    if is_minus.any():
        mpos = np.flatnonzero(is_minus)
        ok = np.isin(mpos, starts)
        if not ok.all():
            k = int(np.searchsorted(starts, mpos[~ok][0], side="right") - 1)
            raise ImportFailure(file, f"line {line0 + int(line_of[k])}", f"column {k % ncols + 1}",
                                f"malformed number ({bytes(a[starts[k]:ends[k]]).decode(errors='replace')!r})")
    ndec = np.zeros(len(starts), np.int64)
    if is_dot.any():
        dpos = np.flatnonzero(is_dot)
        dtok = np.searchsorted(starts, dpos, side="right") - 1
        cnt = np.bincount(dtok, minlength=len(starts))
        if cnt.max() > 1:
            k = int(np.flatnonzero(cnt > 1)[0])
            raise ImportFailure(file, f"line {line0 + int(line_of[k])}", f"column {k % ncols + 1}",
                                f"malformed number ({bytes(a[starts[k]:ends[k]]).decode(errors='replace')!r})")
        ndec[dtok] = cdig[ends[dtok] - 1] - cdig[dpos]
    dpos_all = np.flatnonzero(is_digit)
    dtok_all = np.repeat(np.arange(len(starts)), nd)
    place = cdig[ends[dtok_all] - 1] - cdig[dpos_all]
    contrib = (a[dpos_all].astype(np.int64) - 48) * _POW10[place]
    offs = np.concatenate(([0], np.cumsum(nd)[:-1]))
    mant = np.add.reduceat(contrib, offs)
    neg = a[starts] == 45
    mant[neg] = -mant[neg]
    mant, ndec = mant.reshape(-1, ncols), ndec.reshape(-1, ncols)
    for c in int_cols:
        if np.any(ndec[:, c]):
            r = int(np.flatnonzero(ndec[:, c])[0])
            k = r * ncols + c
            raise ImportFailure(file, f"line {line0 + int(line_of[k])}", f"column {c + 1}", "expected an integer")
    return mant, ndec


def mantissa_to_us(mant: np.ndarray, ndec: np.ndarray, unit: str) -> np.ndarray:
    """Exact ``mant / 10**ndec`` in ``unit`` -> int64 µs, round half up."""
    s = TIME_UNITS[unit]
    k = {1: 0, 1000: 3, 10**6: 6}.get(s.numerator, 0) if s.denominator == 1 else -3
    e = k - ndec
    out = np.empty(len(mant), np.int64)
    for ev in np.unique(e):
        m = e == ev
        if ev >= 0:
            if np.any(np.abs(mant[m]) > (2**63 - 1) // 10**int(ev)):
                raise ValueError("time outside the int64 µs range")
            out[m] = mant[m] * np.int64(10**int(ev))
        else:
            q = np.int64(10**int(-ev))
            out[m] = (mant[m] + q // 2) // q          # floor(m / q + 1/2), no overflow for |m| < 9.2e18 - q
    return out


def strip_comments(block: bytes) -> bytes:
    """The block with ``#`` comment lines blanked (line numbers kept)."""
    if b"#" not in block:
        return block
    lines = block.split(b"\n")
    return b"\n".join(b"" if ln.lstrip().startswith(b"#") else ln for ln in lines)


def iter_text_blocks(path: Path, ctx: ImportContext, block_bytes: int = BLOCK_BYTES):
    """Yield (first line number, bytes of complete lines) of a text file, streamed."""
    with wrap_errors(path, "(file)", "-", "cannot open"):
        f = open(path, "rb")
    with f:
        line0, rest = 1, b""
        while True:
            ctx.check_cancel()
            with wrap_errors(path, f"line {line0}", "-", "cannot read"):
                data = f.read(block_bytes)
            if not data:
                if rest.strip():
                    yield line0, rest
                return
            data = rest + data
            cut = data.rfind(b"\n")
            if cut < 0:
                rest = data
                if len(rest) > 64 * block_bytes:
                    raise ImportFailure(path, f"line {line0}", "-", "line longer than 256 MB (binary file?)")
                continue
            block, rest = data[:cut + 1], data[cut + 1:]
            yield line0, block
            line0 += block.count(b"\n")


def fallback_block(block: bytes, path: Path, line0: int, ncols: int) -> np.ndarray:
    """A block the exact parser cannot take, read with ``np.loadtxt`` as float64 (errors name the line)."""
    try:
        arr = np.loadtxt(io.BytesIO(block), dtype=np.float64, ndmin=2, comments="#",
                         delimiter=None if b"," not in block else ",")
    except ValueError as exc:
        m = re.search(r"row (\d+)", str(exc))       # numpy counts data rows from 0, skipping blank/comment lines
        data_lines = [i for i, ln in enumerate(block.split(b"\n")) if ln.strip() and not ln.lstrip().startswith(b"#")]
        r = int(m.group(1)) if m else -1
        rec = f"line {line0 + data_lines[r]}" if 0 <= r < len(data_lines) else f"lines {line0}+"
        raise ImportFailure(path, rec, "-", f"not a table of {ncols} numbers ({exc})") from None
    if arr.size == 0:
        return np.empty((0, ncols))
    if arr.shape[1] != ncols:
        raise ImportFailure(path, f"lines {line0}+", "-", f"expected {ncols} columns, got {arr.shape[1]}")
    return arr

