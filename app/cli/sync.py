"""``evpose sync SCENE [--edges] [--json] [--apply]``: the clock offset (and skew) from the event rate
against the camera motion, then optionally from event/edge alignment fitted jointly with the object poses
(DESIGN section 5: the JSON's top level is the final estimate, each stage under ``"stages"``;
:mod:`evpose.core.align.sync_run`). ``--apply`` stores the clock only; ``evpose refine --joint --apply`` stores
the poses too."""
from __future__ import annotations

import math

from evpose.app.cli.errors import CliError, command
from evpose.app.cli.estimates import change_lines, check_windows, joint_lines
from evpose.app.cli.json_output import emit
from evpose.app.cli.progress import Progress

__all__ = ["cmd_sync", "check_sync_args", "sync_options", "MAX_RANGE_MS", "MAX_BIN_US"]

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
        text += "\n" + "\n".join(joint_lines(edges))
        if edges.accepted:
            text += f"\nfinal: offset {data['offset_us']} us ({data['method']})"
    if "baseline" in data:
        b = data["baseline"]
        text += (f"\nbaseline (E-POSE minima matching): offset {b['offset_us']} us"
                 if b["reliable"] else f"\nbaseline: no estimate ({b['reason']})")
    if data.get("changes") is not None:
        text += "\n" + "\n".join(change_lines(data, bool(data.get("applied"))))
    if saved_line:
        text += "\n" + saved_line
    return text


def sync_options(args):
    """The :class:`~evpose.core.align.sync_run.SyncOptions` of parsed ``sync`` arguments."""
    from evpose.core.align.sync_run import SyncOptions

    return SyncOptions(range_ms=args.range_ms, bin_us=args.bin_us, edges=args.edges, windows=args.windows,
                       apply=args.apply, baseline=args.baseline, curve=args.curve)


@command("sync")
def cmd_sync(args) -> int:
    check_sync_args(args)
    from evpose.core.align.sync_run import run_sync
    from evpose.core.data.scene import Scene

    scene = Scene.open(args.scene)
    try:
        with Progress("sync edges", not args.quiet) as progress:
            run = run_sync(scene, sync_options(args), edge_progress=progress)
    finally:
        scene.close()
    emit(args, run.data, sync_text(run.result, run.correction, run.edges, run.data, run.saved_line))
    return 0
