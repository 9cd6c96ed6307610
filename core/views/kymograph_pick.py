"""The kymograph's default line: of the lines across the shown objects along their motion
(:func:`~evpose.core.views.kymograph_line.candidate_lines`), one with enough evidence about the lag.

Every candidate is read as a drawn line would be (:func:`~evpose.core.views.kymograph_read.read_line`) but not
judged yet, and ranked by its evidence (:func:`~evpose.core.views.kymograph_confidence.evidence`: how fast its
edges move along it where their own events are), the selected object's best line first. The first
``JUDGED_LINES`` of them are judged (σ and verdict), and the first that reads is the default line: the order does
not depend on σ, so its σ is not the smallest of many noisy ones. One clock moves every track, so the other
lines that read must agree with it within ``AGREE_SIGMAS`` of their combined σ; when one does not, the reading is
too weak (a texture line parallel to an edge, or a pose error, can make one line read a wrong lag that its own
σ cannot show). When none of them reads, the first is shown and its reading says why it is too weak.
"""
from __future__ import annotations

import numpy as np

from evpose.core.views.kymograph_confidence import DISAGREE
from evpose.core.views.kymograph_line import candidate_lines
from evpose.core.views.kymograph_read import LineReading, SpanData, judge_reading, read_line

#: The silhouettes this far before and after the current time (µs) give an object's motion now.
MOTION_PROBE_US = 10_000
#: This many candidates, by evidence, are judged (σ and verdict): the first that reads is shown, the others check it.
JUDGED_LINES = 3
#: Two readings disagree when they are farther apart than this many times their combined σ.
AGREE_SIGMAS = 2.0


def pick_default_line(span: SpanData, view) -> tuple[LineReading | None, int]:
    """``(reading, lines read)`` of the default line for the session's ``view`` (its selected and hidden
    objects), judged; ``(None, 0)`` when no shown object is visible."""
    now = span.nearest_map(span.tc_us)
    if now is None:
        return None, 0
    names = span.names
    shown = [k for k, n in enumerate(names) if n not in span.hidden]
    preferred = names.index(view.selected) if view.selected in names and view.selected not in span.hidden else None
    ok = [i for i, m in enumerate(span.maps) if m is not None]
    candidates = candidate_lines(now, span.nearest_map(span.tc_us - MOTION_PROBE_US),
                                 span.nearest_map(span.tc_us + MOTION_PROBE_US), span.maps[ok[0]], span.maps[ok[-1]],
                                 len(names), preferred, shown=shown)
    if not candidates:
        return None, 0
    readings = [(k, read_line(span, line, judge=False)) for k, line in candidates]
    ranked = sorted((r for _, r in readings), key=lambda r: r.lag.evidence, reverse=True)
    mine = [r for k, r in readings if k == preferred]
    if mine:                                   # the selected object's best line first
        best = max(mine, key=lambda r: r.lag.evidence)
        ranked = [best] + [r for r in ranked if r is not best]
    read = [r for r in ranked[:JUDGED_LINES] if judge_reading(r).lag.readable]
    if not read:
        return ranked[0], len(readings)
    shown, lag = read[0], read[0].lag
    if any(abs(lag.lag_ms - r.lag.lag_ms) > AGREE_SIGMAS * np.hypot(lag.sigma_ms, r.lag.sigma_ms) for r in read[1:]):
        lag.lag_ms, lag.weak = None, DISAGREE
    return shown, len(readings)
