"""One object's alignment scores over a scene, summarised for the triage report, and the scene's unlabeled
windows split by cause.

Reads the ``evpose score --json`` document (:meth:`evpose.core.align.score_table.ScoreTable.to_json`):
per window ``objects[name]`` with ``score`` (higher is better, 0 = no better than noise, in [-1, 1]),
``n_events_near`` and ``valid``.
"""
from __future__ import annotations

import numpy as np

from evpose.core.data.trajectory_holes import REASON_AFTER, REASON_BEFORE

__all__ = ["HIST_EDGES", "MIN_EVENTS_NEAR", "QUANTILES", "WORST_WINDOWS", "object_scores", "unlabeled_counts"]

#: A window whose object has fewer events near its silhouette than this is too thin evidence to be named
#: among the object's worst windows (its score is still in the distribution).
MIN_EVENTS_NEAR = 100
#: How many worst windows are named per object.
WORST_WINDOWS = 5
#: Score histogram bin edges, the same for every object and scene (so they compare); scores beyond the
#: ends are counted in the end bins.
HIST_EDGES = tuple(round(-0.2 + 0.05 * k, 2) for k in range(17))
#: Reported quantiles (name -> q).
QUANTILES = {"min": 0.0, "p10": 0.1, "p25": 0.25, "p50": 0.5, "p75": 0.75, "p90": 0.9, "max": 1.0}


def object_scores(score: dict, name: str) -> dict:
    """Distribution and worst windows of object ``name`` in a score document.

    Returns
    -------
    dict
        ``n_valid`` (windows with a score), ``n_evidence`` (of those, with at least :data:`MIN_EVENTS_NEAR`
        events near the object), ``mean``, ``quantiles`` (:data:`QUANTILES`; None without a score),
        ``histogram`` (``edges``, ``counts``) and ``worst``: up to :data:`WORST_WINDOWS` evidence windows,
        lowest score first, each ``index``, ``t_label_us``, ``score``, ``n_events_near``.
    """
    idx, t_label, values, near = [], [], [], []
    for w in score["windows"]:
        o = w["objects"][name]
        if o["valid"] and o["score"] is not None:
            idx.append(int(w["index"]))
            t_label.append(int(w["t_label_us"]))
            values.append(float(o["score"]))
            near.append(int(o["n_events_near"]))
    s = np.asarray(values, dtype=np.float64)
    near_a = np.asarray(near, dtype=np.int64)
    edges = np.asarray(HIST_EDGES)
    counts = np.histogram(np.clip(s, edges[0], edges[-1]), bins=edges)[0] if len(s) else np.zeros(len(edges) - 1)
    evidence = np.flatnonzero(near_a >= MIN_EVENTS_NEAR)
    order = evidence[np.lexsort((np.asarray(idx)[evidence], s[evidence]))] if len(evidence) else evidence
    worst = [{"index": idx[k], "t_label_us": t_label[k], "score": values[k], "n_events_near": near[k]}
             for k in order[:WORST_WINDOWS]]
    return {"n_valid": len(s), "n_evidence": len(evidence), "mean": float(s.mean()) if len(s) else None,
            "quantiles": {q: float(np.quantile(s, v)) for q, v in QUANTILES.items()} if len(s) else None,
            "histogram": {"edges": list(HIST_EDGES), "counts": [int(c) for c in counts]}, "worst": worst}


def unlabeled_counts(score: dict) -> tuple[int, int]:
    """``(in trajectory holes, outside the trajectory)``: the score document's windows without a pose, by
    cause (its ``unlabeled_reasons``: before the first / after the last pose is outside, any other
    reason a hole)."""
    reasons = score.get("unlabeled_reasons") or {}
    outside = sum(int(k) for r, k in reasons.items() if r in (REASON_BEFORE, REASON_AFTER))
    return int(score["unlabeled"]) - outside, outside
