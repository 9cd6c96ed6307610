"""``evpose sync SCENE [--edges] [--json] [--apply]``: the clock offset (and skew) from the event rate
against the camera motion, then optionally from event/edge alignment (DESIGN section 5: the JSON's top
level is the final rate estimate, the edge stage under ``"edges"``)."""
from __future__ import annotations

import math
import sys

from evpose.app.cli.errors import CliError, command
from evpose.app.cli.estimates import check_windows, edges_line, save_applied
from evpose.app.cli.json_output import emit
from evpose.app.cli.progress import Progress

__all__ = ["cmd_sync", "check_sync_args", "MAX_RANGE_MS", "MAX_BIN_US"]

#: Option bounds (checked before the scene is opened; one error line naming the option).
MAX_RANGE_MS = 3_600_000.0      # sync search range: an hour either way (the lag scan is ~2 x range / bin long)
MAX_BIN_US = 1_000_000          # rate bins of a second already blur any motion


def check_sync_args(args) -> None:
    """Refuse nonsensical ``sync`` options with one line naming the option (:class:`CliError`)."""
    if not (math.isfinite(args.range_ms) and 0 < args.range_ms <= MAX_RANGE_MS):
        raise CliError(f"--range-ms: must be a positive number of milliseconds up to {MAX_RANGE_MS:g}, "
                       f"got {args.range_ms:g}")
    if not (1000 <= args.bin_us <= MAX_BIN_US and args.bin_us % 1000 == 0):
        raise CliError(f"--bin-us: must be a multiple of 1000 us between 1000 and {MAX_BIN_US} "
                       f"(the event rate comes from the millisecond index), got {args.bin_us}")
    check_windows(args)


def _estimate(scene, args, data: dict):
    """Run the rate stage (and the edge stage with ``--edges``), apply with ``--apply``; fills ``data``.
    Returns ``(rate result, clock correction, edge result or None, saved line or "")``."""
    from evpose.core.align.apply import apply_offset_result, apply_sync, clock_correction
    from evpose.core.align.estimate import sync_scene
    from evpose.core.align.minima_baseline import sync_minima_baseline
    from evpose.core.document.history import History

    res = sync_scene(scene, range_ms=args.range_ms, bin_us=args.bin_us)
    data.update(res.to_json(curve=args.curve))
    corr = clock_correction(scene, res)
    data["correction"] = None if corr is None else {"offset_us": corr[0], "skew_ppm": corr[1]}
    if args.baseline:
        data["baseline"] = sync_minima_baseline(scene, range_ms=args.range_ms).to_json()
    edges = None
    if args.edges and res.reliable:
        from evpose.core.align.refine_result import RefineParams
        from evpose.core.align.sync_edges import refine_offset_from_sync

        with Progress("sync edges", not args.quiet) as progress:
            edges = refine_offset_from_sync(scene, res, params=RefineParams(n_windows=args.windows),
                                            progress=progress)
        data["edges"] = edges.to_json()
    applied, saved_line = False, ""
    if args.apply:
        if res.reliable:
            history = History(scene.corrections)
            applied = (apply_offset_result(history, scene, edges, "clock sync (rate, then edges)")
                       if edges is not None and edges.accepted else apply_sync(history, scene, res))
            if applied:
                saved_line = save_applied(scene, data)
        else:
            print(f"evpose sync: not applied: {res.reason}", file=sys.stderr)
    data["applied"] = applied
    return res, corr, edges, saved_line


def sync_text(res, corr, edges, data: dict, saved_line: str) -> str:
    """The text summary of a sync run."""
    if res.reliable:
        skew = "not estimated (kept)" if res.skew_ppm is None else f"{res.skew_ppm:.2f} ppm"
        std = res.offset_std_us
        pm = "" if std is None else (f" ± {std:.0f} us (1 sigma)" if math.isfinite(std)
                                     else " (not pinned by the rate)")
        text = (f"offset {res.offset_us} us{pm}, skew {skew}, confidence {res.confidence:.2f} "
                f"(peak NCC {res.peak:.3f}, second {res.second_peak:.3f}) in {res.runtime_s:.2f} s")
        if corr is not None:
            text += f"\ncorrection on top of the prior: offset {corr[0]} us, skew {corr[1]:.2f} ppm"
    else:
        text = f"no reliable estimate: {res.reason}"
    if edges is not None:
        text += "\n" + edges_line(edges)
    if "baseline" in data:
        b = data["baseline"]
        text += (f"\nbaseline (E-POSE minima matching): offset {b['offset_us']} us"
                 if b["reliable"] else f"\nbaseline: no estimate ({b['reason']})")
    if saved_line:
        text += "\n" + saved_line
    return text


@command("sync")
def cmd_sync(args) -> int:
    check_sync_args(args)
    from evpose.core.data.scene import Scene

    scene = Scene.open(args.scene)
    data: dict = {}
    try:
        res, corr, edges, saved_line = _estimate(scene, args, data)
    finally:
        scene.close()
    emit(args, data, sync_text(res, corr, edges, data, saved_line))
    return 0
