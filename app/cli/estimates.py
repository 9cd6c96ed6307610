"""What ``evpose sync`` and ``evpose refine`` share: the ``--windows`` bound, the line describing a
clock estimate from edges. ``--apply`` saves through :func:`evpose.core.align.apply.save_applied` (revision
check: another program's edits saved meanwhile are merged; a real conflict is refused with exit status 2
and one line naming the field and both values).
"""
from __future__ import annotations

import math

from evpose.app.cli.options import check_int

__all__ = ["MAX_WINDOWS_OPT", "check_windows", "edges_line"]

#: ``--windows`` of ``sync --edges`` and ``refine``: each window costs a render per iteration.
MAX_WINDOWS_OPT = 10_000


def check_windows(args) -> None:
    check_int("--windows", args.windows, 1, MAX_WINDOWS_OPT)


def edges_line(r, label: str = "edges") -> str:
    """One line for an offset refinement from edges (``r``: the refinement's result)."""
    if not r.accepted:
        return f"{label}: start kept ({r.reason})"
    std = r.offset_std_us
    pm = "" if std is None or not math.isfinite(std) else f" ± {std:.0f} us (1 sigma)"
    sk = f"{r.skew_ppm:.2f} ppm " + (f"(fitted, ± {r.skew_std_ppm:.1f} ppm)" if r.skew_estimated else "(kept)")
    return (f"{label}: offset {r.offset_us} us{pm}, skew {sk}; {r.n_windows} windows, {r.runtime_s:.1f} s "
            "(assumes the object poses are right)")
