"""Review marks on the timeline: merged runs of marks as translucent bands, stale marks hatched.

Marks over all objects fill the full height; object-specific marks are thin lanes at the top (one lane
per object, in the object list's order). A mark is *stale* when it was made before a later change of the
clock or of the object's pose: drawn hatched and dashed, with the reason in the tooltip."""
from __future__ import annotations

from dataclasses import dataclass

import pyqtgraph as pg
from PySide6 import QtCore

from evpose.widgets.timeline.style import STATUS_COLORS

__all__ = ["MarkRegion", "merge_runs", "mark_regions", "stale_key"]

GLOBAL_MARK_ALPHA = 55           # marks over all objects: full-height translucent bands
OBJECT_MARK_ALPHA = 150          # object-specific marks: thin opaque-ish lanes at the top
OBJECT_LANE = 0.07               # lane height (fraction of the plot height) per object


@dataclass
class MarkRegion:
    """One drawn review region: a run of merged, overlapping or adjacent marks of one status and scope.

    ``stale``: the marks were made before a later change of the clock or of the object's pose (drawn
    hatched, with the reason in the tooltip)."""

    t0_us: int
    t1_us: int
    status: str
    object: str | None
    item: pg.LinearRegionItem
    stale: bool = False


def merge_runs(spans) -> list[list[int]]:
    """Overlapping or touching ``(t0, t1)`` spans merged into sorted runs."""
    spans = sorted(spans)
    runs = [list(spans[0])]
    for t0, t1 in spans[1:]:
        if t0 <= runs[-1][1]:
            runs[-1][1] = max(runs[-1][1], t1)
        else:
            runs.append([t0, t1])
    return runs


def stale_key(session) -> tuple:
    """Which of the document's marks are stale now (redraw when this changes)."""
    now = session.mark_state()
    return tuple(bool(session.stale_reasons(m, now=now)) for m in session.scene.corrections.reviews)


def _group_marks(session) -> tuple[dict, dict, tuple]:
    """Marks grouped by (status, object, stale) -> spans; the stale reason of each stale group; the stale key."""
    groups: dict[tuple, list] = {}
    why: dict[tuple, str] = {}
    now = session.mark_state()
    stale_flags = []
    for mark in session.scene.corrections.reviews:
        reasons = session.stale_reasons(mark, now=now)
        stale_flags.append(bool(reasons))
        key = (mark.status, mark.object, bool(reasons))
        groups.setdefault(key, []).append((mark.t0_us, mark.t1_us))
        if reasons:
            why.setdefault(key, "; ".join(reasons))
    return groups, why, tuple(stale_flags)


def _look(status: str, obj: str | None, stale: bool, names: list[str]):
    """Vertical span (fractions of the plot height), brush, pen and z of a group's bands."""
    color = STATUS_COLORS.get(status, (128, 128, 128))
    if obj is None:
        span, alpha, z = (0.0, 1.0), GLOBAL_MARK_ALPHA, -20
    else:
        k = names.index(obj) if obj in names else len(names)
        span = (max(1.0 - (k + 1) * OBJECT_LANE, 0.0), 1.0 - k * OBJECT_LANE)
        alpha, z = OBJECT_MARK_ALPHA, -10
    if stale:
        brush = pg.mkBrush(*color, min(alpha * 3, 255))
        brush.setStyle(QtCore.Qt.BDiagPattern)      # hatched: verified on other labels
        pen = pg.mkPen(*color, min(alpha + 60, 255), style=QtCore.Qt.DashLine)
    else:
        brush, pen = pg.mkBrush(*color, alpha), pg.mkPen(*color, min(alpha + 60, 255))
    return span, brush, pen, z


def mark_regions(session, x_of) -> tuple[list[MarkRegion], tuple]:
    """The bands of the document's review marks (not yet added to a plot) and the stale key they show.

    ``x_of(t_us)`` maps event time (µs) to plot x (s)."""
    groups, why, key = _group_marks(session)
    names = session.object_names
    regions = []
    for (status, obj, stale), spans in groups.items():
        span, brush, pen, z = _look(status, obj, stale, names)
        for t0, t1 in merge_runs(spans):
            item = pg.LinearRegionItem((x_of(t0), x_of(t1)), movable=False, span=span, brush=brush, pen=pen)
            item.setZValue(z)
            item.setAcceptedMouseButtons(QtCore.Qt.NoButton)
            for line in item.lines:
                line.setAcceptedMouseButtons(QtCore.Qt.NoButton)
            item.setToolTip(f"{status}{'' if obj is None else ' (' + obj + ')'}: "
                            f"{x_of(t0):.3f}–{x_of(t1):.3f} s"
                            + (f"\nSTALE: {why[(status, obj, stale)]}" if stale else ""))
            regions.append(MarkRegion(int(t0), int(t1), status, obj, item, stale))
    return regions, key
