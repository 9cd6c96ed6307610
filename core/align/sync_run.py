"""One ``sync`` run on a scene, as ``evpose sync`` and ``evpose dataset sync`` both do it: the rate stage,
optionally the E-POSE minima baseline and the edge stage, and with ``apply`` the reliable estimate stored
as one undo step and saved. The result's :attr:`SyncRun.data` is the command's JSON document (DESIGN
section 5), so the dataset layer reports exactly what the single-scene command prints."""
from __future__ import annotations

import sys
from dataclasses import dataclass, field

from evpose.core.align.apply import apply_offset_result, apply_sync, clock_correction, save_applied

__all__ = ["SyncOptions", "SyncRun", "run_sync"]


@dataclass(frozen=True)
class SyncOptions:
    """The options of a sync run (the CLI's flags; defaults are the CLI's)."""

    range_ms: float = 500.0      # search range around the clock in effect (ms)
    bin_us: int = 1000           # event-rate bin (multiple of 1000 us)
    edges: bool = False          # refine from event/edge alignment after a reliable rate estimate
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
    edges: object = None                # RefineResult of the edge stage, or None
    saved_line: str = ""                # "applied and saved to ..." when --apply saved


def run_sync(scene, opts: SyncOptions, *, progress=None, edge_progress=None) -> SyncRun:
    """Run the rate stage (and the edge stage with ``opts.edges``), apply with ``opts.apply``.

    ``edge_progress(fraction, message)`` reports the edge stage (the rate stage takes seconds).
    A rate estimate that is not reliable is never applied (the reason goes to stderr and
    ``data["applied"]`` is False)."""
    from evpose.core.align.estimate import sync_scene
    from evpose.core.align.minima_baseline import sync_minima_baseline
    from evpose.core.document.history import History

    run = SyncRun()
    data = run.data
    res = run.result = sync_scene(scene, range_ms=opts.range_ms, bin_us=opts.bin_us)
    data.update(res.to_json(curve=opts.curve))
    corr = run.correction = clock_correction(scene, res)
    data["correction"] = None if corr is None else {"offset_us": corr[0], "skew_ppm": corr[1]}
    if opts.baseline:
        data["baseline"] = sync_minima_baseline(scene, range_ms=opts.range_ms).to_json()
    if opts.edges and res.reliable:
        from evpose.core.align.refine_result import RefineParams
        from evpose.core.align.sync_edges import refine_offset_from_sync

        run.edges = refine_offset_from_sync(scene, res, params=RefineParams(n_windows=opts.windows),
                                            progress=edge_progress)
        data["edges"] = run.edges.to_json()
    applied = False
    if opts.apply:
        if res.reliable:
            history = History(scene.corrections)
            edges = run.edges
            applied = (apply_offset_result(history, scene, edges, "clock sync (rate, then edges)")
                       if edges is not None and edges.accepted else apply_sync(history, scene, res))
            if applied:
                run.saved_line = save_applied(scene, data)
        else:
            print(f"evpose sync: {scene.name}: not applied: {res.reason}", file=sys.stderr)
    data["applied"] = applied
    return run
