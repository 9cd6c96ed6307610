"""Range checks of numeric options, done before anything is read: a nonsensical value ends in one line
naming the option (:class:`evpose.app.cli.errors.CliError`, exit 2)."""
from __future__ import annotations

import math

from evpose.app.cli.errors import CliError

__all__ = ["check_int", "check_float"]


def check_int(option: str, value: int | None, lo: int, hi: int) -> None:
    """Refuse an integer option outside ``[lo, hi]`` (None: not given, accepted)."""
    if value is not None and not lo <= value <= hi:
        raise CliError(f"{option}: must be an integer in [{lo}, {hi}], got {value}")


def check_float(option: str, value: float | None, lo: float, hi: float, *, lo_open: bool = False) -> None:
    """Refuse a float option that is not finite or outside ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``)."""
    if value is None:
        return
    if not (math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi):
        raise CliError(f"{option}: must be a finite number in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {value}")
