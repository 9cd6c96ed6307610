"""The align group: ``evpose sync``, ``evpose refine`` and ``evpose score`` (DESIGN section 5).

:func:`add_align_parsers` registers the three sub-commands; ``sync`` and ``refine`` live in
:mod:`evpose.app.cli.sync` and :mod:`evpose.app.cli.refine`, ``score`` (per window and object alignment
scores) here. Each prints one JSON document on stdout with ``--json``; messages go to stderr.
"""
from __future__ import annotations

import math

from evpose.app.cli.errors import CliError, command
from evpose.app.cli.json_output import emit
from evpose.app.cli.progress import Progress
from evpose.app.cli.refine import cmd_refine
from evpose.app.cli.sync import cmd_sync

__all__ = ["add_align_parsers", "cmd_sync", "cmd_refine", "cmd_score"]


def check_score_args(args) -> None:
    from evpose.core.label.windows import MIN_WINDOW_MS

    if not (math.isfinite(args.window_ms) and args.window_ms >= MIN_WINDOW_MS):
        raise CliError(f"--window-ms: must be at least {MIN_WINDOW_MS:g} ms (a finite number), got {args.window_ms:g}")


def score_text(table, data: dict, window_ms: float) -> str:
    """The text summary of a score table: per object its mean, its low-evidence windows and its worst window
    (with evidence), then the windows without a pose."""
    lines = [f"{len(table)} windows of {window_ms:g} ms scored in {table.runtime_s:.2f} s"]
    for n, s in data["summary"].items():
        ms = "n/a" if s["mean_score"] is None else f"{s['mean_score']:.3f}"
        worst = (f"none ({s['worst_note']})" if s["worst_window"] is None
                 else f"window {s['worst_window']} (t {s['worst_t_label_us']} us)")
        lines.append(f"{n}: mean score {ms} over {s['n_valid']} valid windows ({s['n_low_evidence']} of them low "
                     f"evidence); worst {worst}")
    for reason, k in data["unlabeled_reasons"].items():
        lines.append(f"no score (no pose) in {k} window(s): {reason}")
    return "\n".join(lines)


@command("score")
def cmd_score(args) -> int:
    check_score_args(args)
    from evpose.core.align.score_table import score_windows
    from evpose.core.data.scene import Scene

    scene = Scene.open(args.scene)
    try:
        with Progress("score", not args.quiet) as progress:
            table = score_windows(scene, window_us=int(round(args.window_ms * 1000)), progress=progress)
    finally:
        scene.close()
    data = table.to_json()
    emit(args, data, score_text(table, data, args.window_ms))
    return 0


def add_align_parsers(subparsers) -> None:
    """Register ``sync``, ``refine`` and ``score`` on an argparse sub-parser set."""
    s = subparsers.add_parser("sync", help="estimate the clock offset/skew from the event rate vs the camera motion")
    s.add_argument("scene")
    s.add_argument("--json", action="store_true", help="print one JSON document")
    s.add_argument("--apply", action="store_true", help="store a reliable estimate as corrections (one undo step) "
                   "and save corrections.json")
    s.add_argument("--range-ms", type=float, default=500.0, help="search range around the clock in effect (ms)")
    s.add_argument("--bin-us", type=int, default=1000, help="event-rate bin (multiple of 1000 us)")
    s.add_argument("--baseline", action="store_true",
                   help="also run the original E-POSE minima-matching method and report it under 'baseline'")
    s.add_argument("--curve", action="store_true", help="include the correlation curve in the JSON")
    s.add_argument("--edges", action="store_true",
                   help="then fit offset (and skew) together with the object poses from event/edge alignment, "
                        "started at the rate estimate; refused when it moves further than 3 of the rate's standard "
                        "errors or 5 ms, whichever is larger (the final estimate is the top level of the JSON, each "
                        "stage under 'stages'; --apply stores the clock)")
    s.add_argument("--windows", type=int, default=24, help="event windows used by --edges")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_sync)

    s = subparsers.add_parser("refine", help="refine object poses (and the clock offset) from event/edge alignment")
    s.add_argument("scene")
    s.add_argument("--object", help="only this object (default: all)")
    s.add_argument("--offset", action="store_true", help="also refine the clock offset (before the poses)")
    s.add_argument("--joint", action="store_true",
                   help="fit the clock (offset, and skew when the windows pin it) and the object poses together "
                        "(one document: 'clock', 'objects', 'hand_eye'; --apply stores all of it as one undo step); "
                        "when the fit shows a camera-mounting error, the hand-eye is fitted and proposed too, instead "
                        "of a clock and poses bent to absorb it")
    s.add_argument("--hand-eye", action="store_true",
                   help="with --joint: also fit a hand-eye correction (camera frame) shared by all objects")
    s.add_argument("--no-clock", action="store_true", help="with --joint: keep the clock in effect")
    s.add_argument("--windows", type=int, default=None, help="number of event windows used (default 12; 24 with --joint)")
    s.add_argument("--json", action="store_true", help="print one JSON document")
    s.add_argument("--apply", action="store_true", help="store accepted results as corrections and save")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_refine)

    s = subparsers.add_parser("score", help="alignment score of every window and object, with its evidence "
                              "(low-evidence windows are never the worst)")
    s.add_argument("scene")
    s.add_argument("--window-ms", type=float, default=10.0, help="window length (ms)")
    s.add_argument("--json", action="store_true", help="print one JSON document")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_score)
