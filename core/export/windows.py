"""The windows of an export: the tiling of the recording, the windows ``--only-verified`` keeps, and why
a window has no label.

Vocabulary
----------
*window*
    One half-open event-time interval ``[t0_us, t1_us)`` of the tiling
    (:func:`evpose.core.label.windows.time_windows` or :func:`evpose.core.label.windows.count_windows`);
    ``index`` is its position in the tiling and names its files.
*selected*
    Windows that pass ``only_verified`` (all windows when it is off): :func:`review_usage`.
*unlabeled*
    Selected windows whose label time falls outside the trajectory under the clock in effect, or inside a
    hole of it (samples more than ``max_gap_us`` apart): no labels (no extrapolation, no bridging of holes);
    listed with the reason (:func:`unlabeled_windows`) in the summary and the manifest.
"""
from __future__ import annotations

import numpy as np

from evpose.core.data.trajectory_holes import REASON_AFTER, REASON_BEFORE
from evpose.core.export.options import ExportError
from evpose.core.label.windows import DEFAULT_WINDOW_US, Window, count_windows, time_windows

__all__ = ["UNLABELED_BEFORE", "UNLABELED_AFTER", "UNLABELED_OTHER", "REVIEW_PARTLY", "REVIEW_MIXED", "REVIEW_STALE",
           "REVIEW_NO_LABEL", "build_windows", "review_usage", "verified_mask", "scene_staleness",
           "unlabeled_reason", "unlabeled_windows"]

UNLABELED_BEFORE = REASON_BEFORE     # "label time outside the trajectory: pose time before its first pose ..."
UNLABELED_AFTER = REASON_AFTER       # holes: evpose.core.data.trajectory_holes.hole_reason, "label time in a trajectory hole [a, b] us ..."
UNLABELED_OTHER = "label time outside the trajectory (no extrapolation)"


def build_windows(store, *, window_us=DEFAULT_WINDOW_US, window_events=None, label_at="center") -> list[Window]:
    """The tiling of the recording: by time (``window_us``) or by count (``window_events``)."""
    if label_at not in ("center", "end"):
        raise ExportError(f"label_at: expected 'center' or 'end', got {label_at!r}")
    if window_events is not None:
        if isinstance(window_events, bool) or int(window_events) != window_events or window_events <= 0:
            raise ExportError(f"window_events: must be a positive integer, got {window_events!r}")
        return count_windows(store, int(window_events), label_at=label_at)
    if window_us is None or isinstance(window_us, bool) or int(window_us) != window_us or window_us <= 0:
        raise ExportError(f"window_us: must be a positive integer number of microseconds, got {window_us!r}")
    return time_windows(store, int(window_us), label_at=label_at)


#: Why a window touched by a verified mark is not exported (summary ``review_unused_reasons``).
REVIEW_PARTLY = "partly covered: the verified marks do not cover the whole window (marks off this export's window grid)"
REVIEW_MIXED = "partly rejected or flagged"
REVIEW_STALE = "stale: verified before a later change of the clock or of the object's pose"
REVIEW_NO_LABEL = "no label: label time outside the trajectory"
#: Piece categories of :func:`_status_pieces`.
_NONE, _FRESH, _STALE, _OTHER = 0, 1, 2, 3


def _status_pieces(reviews, obj: str, is_stale=None) -> tuple[np.ndarray, np.ndarray]:
    """Piecewise-constant effective review status of one object: breakpoints (sorted int64) and a
    category per piece ``[b[j], b[j+1])``: none, verified, verified but stale (``is_stale(mark, obj)``),
    rejected/flagged. The effective mark is the object's own mark, else the all-objects mark (the rule
    of :func:`evpose.core.document.review.effective_status`; later marks win within a scope)."""
    marks = [m for m in reviews if m.object is None or m.object == obj]
    if not marks:
        return np.zeros(0, np.int64), np.zeros(0, np.int8)
    b = np.unique(np.array([v for m in marks for v in (m.t0_us, m.t1_us)], np.int64))
    cat = np.zeros(max(len(b) - 1, 0), np.int8)
    winner = [None] * len(cat)
    rank = [-1] * len(cat)
    for order, m in enumerate(marks):          # later in the list wins within a scope
        own = 1 if m.object is not None else 0
        j0, j1 = np.searchsorted(b, m.t0_us), np.searchsorted(b, m.t1_us)
        for j in range(j0, j1):
            r = own * (len(marks) + 1) + order
            if r > rank[j]:
                rank[j], winner[j] = r, m
    for j, m in enumerate(winner):
        if m is None:
            continue
        if m.status != "verified":
            cat[j] = _OTHER
        else:
            cat[j] = _STALE if (is_stale is not None and is_stale(m, obj)) else _FRESH
    return b, cat


def review_usage(windows, reviews, objects, is_stale=None) -> tuple[np.ndarray, np.ndarray, list]:
    """Which windows ``--only-verified`` exports, and why windows touched by verified marks are not.

    A window ``[t0, t1)`` is exported iff, for every exported object and at every instant of
    ``[t0, t1)``, the effective review status (:func:`evpose.core.document.review.effective_status`) is ``verified``
    by a mark that is not stale (``is_stale(mark, obj)``; None: no mark is stale). **Partly covered
    windows are never exported**: a window must be covered entirely by verified marks, and a
    rejected or flagged mark over any part of it excludes it. Empty windows (``t1 <= t0``) are never
    exported.

    Returns
    -------
    keep : (N,) bool
    touched : (N,) bool
        Windows that a verified mark (fresh or stale) overlaps for some exported object.
    reasons : list of str or None
        For each window touched but not kept: :data:`REVIEW_MIXED`, :data:`REVIEW_PARTLY` or
        :data:`REVIEW_STALE` (the first that applies); None otherwise.
    """
    n = len(windows)
    t0 = np.array([w.t0_us for w in windows], np.int64)
    t1 = np.array([w.t1_us for w in windows], np.int64)
    nonempty = t1 > t0
    any_none = np.zeros(n, bool)
    any_other = np.zeros(n, bool)
    any_stale = np.zeros(n, bool)
    touched = np.zeros(n, bool)
    if not objects:
        any_none[:] = True
    for obj in objects:
        b, cat = _status_pieces(reviews, obj, is_stale)
        if len(b) < 2:
            any_none[:] = True
            continue
        # first / last piece that the window touches: piece j spans [b[j], b[j+1])
        j0 = np.clip(np.searchsorted(b, t0, side="right") - 1, 0, len(cat) - 1)
        j1 = np.clip(np.searchsorted(b, t1 - 1, side="right") - 1, 0, len(cat) - 1)
        outside = (t0 < b[0]) | (t1 - 1 >= b[-1])
        counts = {}
        for c in (_NONE, _FRESH, _STALE, _OTHER):
            pre = np.concatenate([[0], np.cumsum(cat == c)])
            counts[c] = pre[j1 + 1] - pre[j0]
        meets = (t1 > b[0]) & (t0 < b[-1]) & nonempty     # overlaps the span of the breakpoints at all
        any_none |= outside | (counts[_NONE] > 0)
        any_other |= meets & (counts[_OTHER] > 0)
        any_stale |= meets & (counts[_STALE] > 0)
        touched |= meets & ((counts[_FRESH] > 0) | (counts[_STALE] > 0))
    keep = nonempty & ~any_none & ~any_other & ~any_stale
    reasons = [None] * n
    for i in np.flatnonzero(touched & ~keep):
        reasons[i] = REVIEW_MIXED if any_other[i] else REVIEW_PARTLY if any_none[i] else REVIEW_STALE
    return keep, touched, reasons


def verified_mask(windows, reviews, objects, is_stale=None) -> np.ndarray:
    """Which windows ``--only-verified`` exports (the ``keep`` of :func:`review_usage`)."""
    return review_usage(windows, reviews, objects, is_stale)[0]


def scene_staleness(scene):
    """``is_stale(mark, obj)`` for :func:`review_usage`: the mark was made under another clock or
    another pose of ``obj`` than ``scene`` has now (:func:`evpose.core.document.review.stale_reasons`)."""
    from evpose.core.document.review import mark_state, stale_reasons

    now = mark_state(scene)
    return lambda mark, obj: bool(stale_reasons(scene, mark, obj, now=now))


def unlabeled_reason(scene, t_label_us: int) -> str:
    """Why a window has no label: its label time maps before or after the trajectory, or into a hole
    of it (``in a trajectory hole [a, b] us``; see :meth:`evpose.core.data.scene.Scene.unlabeled_reasons`)."""
    reasons = getattr(scene, "unlabeled_reasons", None)
    r = reasons(np.array([t_label_us], np.int64))[0] if reasons is not None else None
    return r or UNLABELED_OTHER


def unlabeled_windows(scene, selected, valid) -> list[dict]:
    """``{"index", "t_label_us", "reason"}`` of every selected window without a label (``valid`` False)."""
    return [{"index": w.index, "t_label_us": w.t_label_us, "reason": unlabeled_reason(scene, w.t_label_us)}
            for w, v in zip(selected, valid) if not v]
