"""One ``sync`` run on a scene, as ``evpose sync`` and ``evpose dataset sync`` both do it: the rate stage,
optionally the E-POSE minima baseline and the edge stage, and with ``apply`` the reliable estimate stored
as one undo step and saved. The result's :attr:`SyncRun.data` is the command's JSON document (DESIGN
section 5), so the dataset layer reports exactly what the single-scene command prints.

The document's top level is the **final** estimate (``offset_us``, ``skew_ppm``, ``offset_std_us``,
``skew_std_ppm``, ``offset_pinned``, ``reliable``, ``reason``, ``confidence``, ``method`` = ``"rate"`` or
``"rate+edges"``, ``runtime_s`` of the whole run, ``correction``), and each stage's own document is nested
under ``stages``: ``stages.rate`` (:meth:`~evpose.core.align.sync_result.SyncResult.to_json`) and, with
``edges``, ``stages.edges`` (:meth:`~evpose.core.align.joint_result.JointResult.to_json`: the clock fitted
jointly with the object poses, which are reported there but not applied by ``sync``)."""
from __future__ import annotations

import sys
from dataclasses import dataclass, field

from evpose.core.align.apply import apply_joint_result, apply_sync, save_applied
from evpose.core.document.estimates import clock_correction_for

__all__ = ["EDGE_MIN_RANGE_US", "SyncOptions", "SyncRun", "edge_stage", "final_estimate", "run_sync"]


@dataclass(frozen=True)
class SyncOptions:
    """The options of a sync run (the CLI's flags; defaults are the CLI's)."""

    range_ms: float = 500.0      # search range around the clock in effect (ms)
    bin_us: int = 1000           # event-rate bin (multiple of 1000 us)
    edges: bool = False          # then fit clock and object poses jointly from event/edge alignment
    windows: int = 24            # event windows used by the edge stage
    apply: bool = False          # store a reliable estimate as corrections and save corrections.json
    baseline: bool = False       # also run the E-POSE minima-matching method
    curve: bool = False          # include the correlation curve in the document


@dataclass
class SyncRun:
    """What a sync run produced: the JSON document and the objects its text summary is made from."""

    data: dict = field(default_factory=dict)
    result: object = None               # SyncResult of the rate stage
    correction: tuple | None = None     # (offset_us, skew_ppm) on top of the prior, or None
    edges: object = None                # JointResult of the edge stage, or None
    saved_line: str = ""                # "applied and saved to ..." when --apply saved


def run_sync(scene, opts: SyncOptions, *, progress=None, edge_progress=None, cancel=None) -> SyncRun:
    """Run the rate stage (and the edge stage with ``opts.edges``), apply with ``opts.apply``.

    ``edge_progress(fraction, message)`` reports the edge stage (the rate stage takes a fraction of a second).
    A rate estimate that is not reliable is never applied (the reason goes to stderr and ``data["applied"]``
    is False); the edge stage runs only after a reliable one, and its clock is taken when the fit improved the
    objective and stayed within :func:`~evpose.core.align.sync_edges.sync_edge_half_range_us` of the rate
    estimate."""
    import time

    from evpose.core.align.estimate import sync_scene
    from evpose.core.align.minima_baseline import sync_minima_baseline
    from evpose.core.document.history import History

    t_start = time.perf_counter()
    run = SyncRun()
    data = run.data
    res = run.result = sync_scene(scene, range_ms=opts.range_ms, bin_us=opts.bin_us)
    stages = {"rate": res.to_json(curve=opts.curve)}
    if opts.baseline:
        data["baseline"] = sync_minima_baseline(scene, range_ms=opts.range_ms).to_json()
    if opts.edges and res.reliable:
        run.edges = edge_stage(scene, res, opts.windows, progress=edge_progress, cancel=cancel)
        stages["edges"] = run.edges.to_json()
    data.update(final_estimate(res, run.edges))
    data["stages"] = stages
    corr = run.correction = (None if data["offset_us"] is None else
                             clock_correction_for(scene, data["offset_us"], data["skew_ppm"]))
    data["correction"] = None if corr is None else {"offset_us": corr[0], "skew_ppm": corr[1]}
    applied = False
    if opts.apply:
        if res.reliable:
            history = History(scene.corrections)
            edges = run.edges if run.edges is not None and run.edges.accepted else None
            applied = (apply_joint_result(history, scene, edges, "clock sync (rate, then edges)", poses=False)
                       if edges is not None else apply_sync(history, scene, res))
            if applied:
                run.saved_line = save_applied(scene, data)
        else:
            print(f"evpose sync: {scene.name}: not applied: {res.reason}", file=sys.stderr)
    data["applied"] = applied
    data["runtime_s"] = time.perf_counter() - t_start
    return run


#: The edge stage's clock may move at least this far from the rate estimate (µs): the rate's standard error counts
#: the Poisson noise of the rate only, while its model error is ~0.4-1 ms at 0.5-1 m/s and 5-10 ms on slow moves
#: (docs/sync.md), so 3 of its standard errors alone would refuse right answers.
EDGE_MIN_RANGE_US = 5000.0


def edge_stage(scene, rate, n_windows: int, *, progress=None, cancel=None):
    """The joint edge fit (clock and every object's pose, :func:`~evpose.core.align.joint_fit.refine_joint`)
    started at the rate estimate ``rate``; not accepted (``reason`` says why) when its clock moves further from the
    rate estimate than :func:`~evpose.core.align.sync_edges.sync_edge_half_range_us` or :data:`EDGE_MIN_RANGE_US`,
    whichever is larger (a far-off local optimum)."""
    from evpose.core.align.joint_fit import refine_joint
    from evpose.core.align.joint_result import JointParams
    from evpose.core.align.sync_edges import sync_edge_half_range_us

    res = refine_joint(scene, params=JointParams(n_windows=n_windows), clock=rate.clock(), progress=progress,
                       cancel=cancel)
    half = max(sync_edge_half_range_us(rate), EDGE_MIN_RANGE_US)
    if res.accepted and abs(res.offset_us - rate.offset_us) > half:
        res.accepted = False
        res.reason = (f"the edges moved the clock {(res.offset_us - rate.offset_us) / 1000:+.1f} ms from the rate "
                      f"estimate, beyond its search range of ± {half / 1000:.1f} ms; rate estimate kept")
    return res


def final_estimate(rate, edges) -> dict:
    """The top level of the sync document: the edge stage's clock when it was accepted, else the rate's."""
    import math

    from evpose.core.align.joint_result import json_number as num

    d = {"method": "rate", "offset_us": rate.offset_us, "skew_ppm": num(rate.skew_ppm),
         "offset_std_us": num(rate.offset_std_us) if rate.offset_std_us is not None else None,
         "skew_std_ppm": None,
         "offset_pinned": None if rate.offset_std_us is None else bool(math.isfinite(rate.offset_std_us)),
         "confidence": float(rate.confidence), "reliable": bool(rate.reliable), "reason": rate.reason,
         "prior_offset_us": int(rate.prior_offset_us), "prior_skew_ppm": float(rate.prior_skew_ppm),
         "t_ref_us": int(rate.t_ref_us)}
    if edges is not None and edges.accepted:
        std = edges.offset_std_us
        d.update(method="rate+edges", offset_us=int(edges.offset_us), offset_std_us=num(std),
                 offset_pinned=None if std is None else bool(math.isfinite(std)))
        if edges.skew_estimated:
            d.update(skew_ppm=float(edges.skew_ppm), skew_std_ppm=num(edges.skew_std_ppm))
    return d
