"""Exact conversions of time stamps in seconds / ms / µs / ns to int64 µs (round half up).

Times in evpose are int64 µs. Published data stores seconds as float64 or decimal text, nanoseconds as
integers, and ROS time as (sec, nsec); each conversion here is exact where the input is (integer parts are
never scaled in floating point) and rounds half up, ``floor(x * 10**6 + 1/2)`` for seconds.
"""
from __future__ import annotations

import math
import re
from fractions import Fraction

import numpy as np

#: Scale of each time unit to µs.
TIME_UNITS = {"s": Fraction(10**6), "ms": Fraction(10**3), "us": Fraction(1), "ns": Fraction(1, 1000)}


def float_to_us(t, unit: str) -> np.ndarray:
    """Float times in ``unit`` -> int64 µs, round half up. The integer part is converted exactly and only the
    fraction is scaled in floating point, so float64 seconds that represent whole µs (even epoch seconds) come
    back exactly. Caller checks finiteness first."""
    t = np.asarray(t)
    if t.dtype.kind in "iu":
        return int_to_us(t, unit)
    t = t.astype(np.float64)
    scale = float(TIME_UNITS[unit])
    if t.size and float(np.abs(t).max()) * scale >= 9.2e18:
        raise ValueError(f"time {float(np.abs(t).max())!r} {unit} is outside the int64 µs range")
    whole = np.floor(t)
    frac = t - whole
    whole_i = whole.astype(np.int64)
    if scale >= 1:
        return whole_i * np.int64(int(scale)) + np.floor(frac * scale + 0.5).astype(np.int64)
    return np.floor(t * scale + 0.5).astype(np.int64)


def int_to_us(t, unit: str) -> np.ndarray:
    """Integer times in ``unit`` -> int64 µs (ns: round half up)."""
    t = np.asarray(t)
    if t.dtype == np.uint64 and t.size and int(t.max()) > 2**63 - 1:
        raise ValueError(f"time {int(t.max())} {unit} is outside the int64 range")
    t = t.astype(np.int64)
    s = TIME_UNITS[unit]
    if s.denominator == 1:
        if t.size and s.numerator > 1 and int(np.abs(t).max()) > (2**63 - 1) // s.numerator:
            raise ValueError(f"time {int(np.abs(t).max())} {unit} is outside the int64 µs range")
        return t * np.int64(s.numerator)
    q = np.int64(s.denominator)
    return (t + q // 2) // q


_DECIMAL = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE]([+-]?\d{1,3}))?$")


def decimal_to_us(token: str, unit: str) -> int:
    """One decimal string (``"1468940293.951234"``, ``"1e-3"``) in ``unit`` -> µs, exactly, round half up.

    Raises ``ValueError`` for anything else (and for exponents beyond +-40, which no time stamp needs and which
    would make exact arithmetic slow)."""
    tok = token.strip()
    m = _DECIMAL.match(tok)
    if m is None or len(tok) > 64 or (m.group(3) is not None and abs(int(m.group(3))) > 40):
        raise ValueError(f"not a decimal number: {token!r}")
    v = Fraction(tok) * TIME_UNITS[unit]
    return math.floor(v + Fraction(1, 2))


def ros_time_to_us(sec, nsec) -> np.ndarray:
    """ROS ``time`` (uint32 sec, uint32 nsec) -> int64 µs, nanoseconds rounded half up."""
    return np.asarray(sec, np.int64) * 1_000_000 + (np.asarray(nsec, np.int64) + 500) // 1000
