"""What ``evpose sync`` and ``evpose refine`` share: the ``--windows`` bound, the line describing a
clock estimate from edges. ``--apply`` saves through :func:`evpose.core.align.apply.save_applied` (revision
check: another program's edits saved meanwhile are merged; a real conflict is refused with exit status 2
and one line naming the field and both values).
"""
from __future__ import annotations

import math

from evpose.app.cli.options import check_int

__all__ = ["MAX_WINDOWS_OPT", "change_lines", "check_windows", "edges_line", "joint_lines"]

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


def joint_lines(r, label: str = "edges") -> list[str]:
    """Lines for a joint refinement (:class:`~evpose.core.align.joint_result.JointResult`): the clock, then each
    object's change and the hand-eye correction, with standard errors."""
    notes = [f"  note: {n}" for n in getattr(r, "notes", [])]
    if not r.accepted:
        return [f"{label}: start kept ({r.reason})"] + notes

    def pm(x, unit, nd):
        return " (not pinned)" if x is None or not math.isfinite(x) else f" ± {x:.{nd}f} {unit}"

    lines = []
    p = r.params
    if p.clock:
        if r.skew_estimated:
            sk = f"{r.skew_ppm:.2f} ppm (fitted{pm(r.skew_std_ppm, 'ppm', 1)})"
        elif r.skew_std_ppm is not None and p.skew != "fixed":         # fitted, but the windows did not pin it
            sk = f"{r.skew_ppm:.2f} ppm (kept: not pinned, the windows allow{pm(r.skew_std_ppm, 'ppm', 1)})"
        else:
            sk = f"{r.skew_ppm:.2f} ppm (kept)"
        lines.append(f"{label}: offset {r.offset_us} us{pm(r.offset_std_us, 'us', 0)}, skew {sk}; "
                     f"{r.n_windows} windows, {r.runtime_s:.1f} s (clock and poses fitted together)")
    for name, o in r.objects.items():
        lines.append(f"  {name}: dt {o.dt_mm:.2f} mm{pm(o.std_mm, 'mm', 2)}, dR {o.dR_deg:.2f} deg"
                     f"{pm(o.std_deg, 'deg', 3)}")
    for name, why in r.held.items():
        lines.append(f"  {name}: {why}")
    if p.hand_eye:
        lines.append(f"  hand-eye: dt {r.hand_eye_dt_mm:.2f} mm{pm(r.hand_eye_std_mm, 'mm', 2)}, dR "
                     f"{r.hand_eye_dR_deg:.3f} deg{pm(r.hand_eye_std_deg, 'deg', 3)}")
    return lines + notes


def change_lines(data: dict, applied: bool) -> list[str]:
    """What ``--apply`` stores (``applied``) or would store (a dry run) of a document with ``changes`` and ``kept``
    (:func:`evpose.core.align.apply.plan_joint_result`), one line each."""
    changes = data.get("changes") or []
    head = "applied" if applied else "--apply would store"
    if not changes:
        return [f"{'nothing applied' if applied else '--apply would store nothing'}"
                + (f" ({'; '.join(data.get('kept') or [])})" if data.get("kept") else "")]
    return [f"{head}: {c['text']}" for c in changes] + [f"kept: {k}" for k in data.get("kept") or []]

