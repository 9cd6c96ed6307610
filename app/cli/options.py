"""Range checks of numeric options, done before anything is read: a nonsensical value ends in one line
naming the option (:class:`evpose.app.cli.errors.CliError`, exit 2); :func:`scheduler_option` checks a
``--scheduler`` address while the command line is parsed."""
from __future__ import annotations

import argparse
import math

from evpose.app.cli.errors import CliError

__all__ = ["check_int", "check_float", "scheduler_option"]


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


def scheduler_option(text: str) -> str:
    """``type=`` of ``--scheduler``: the address as given, refused by the parser (one line naming the option)
    unless it is ``tcp://host:port`` or ``host:port`` (:func:`evpose.core.dataset.cluster.scheduler_address`;
    a light module: no Dask is imported to parse)."""
    from evpose.core.dataset.cluster import ClusterError, scheduler_address

    try:
        scheduler_address(text)
    except ClusterError as exc:
        raise argparse.ArgumentTypeError(f"{text}: {exc}") from None
    return text
