"""``evpose sync``, ``evpose refine`` and ``evpose score`` (DESIGN section 5).

:func:`add_align_parsers` registers the three sub-commands on the ``evpose`` sub-parser set;
each handler returns an exit status and prints exactly one JSON document on stdout with
``--json`` (messages go to stderr). ``--apply`` runs the change through a
:class:`evpose.core.document.history.History` as one undo step and saves ``corrections.json`` beside the scene through
:meth:`evpose.core.data.scene.Scene.save_corrections` (revision check: another program's edits saved meanwhile are
merged, a real conflict is refused with exit status 2 and one line naming the field and both values).
"""
from __future__ import annotations

import json
import math
import sys

__all__ = ["add_align_parsers", "cmd_sync", "cmd_refine", "cmd_score"]


def _emit(args, data: dict, text: str) -> None:
    if getattr(args, "json", False):
        sys.stdout.write(json.dumps(data, indent=1, default=_json_default) + "\n")
    else:
        sys.stdout.write(text.rstrip() + "\n")


def _json_default(o):
    import numpy as np

    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return None if not np.isfinite(o) else float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _open(path):
    from evpose.core.data.scene import Scene

    return Scene.open(path)


#: Option bounds (checked before the scene is opened; one error line naming the option).
MAX_RANGE_MS = 3_600_000.0      # sync search range: an hour either way (the lag scan is ~2 x range / bin long)
MAX_BIN_US = 1_000_000          # rate bins of a second already blur any motion
MAX_WINDOWS_OPT = 10_000        # --windows of sync --edges / refine: each costs a render per iteration


def _option_error(option: str, message: str):
    from evpose.app.cli.main import CliError

    return CliError(f"{option}: {message}")


def _check_int(option: str, value, lo: int, hi: int) -> None:
    if not lo <= value <= hi:
        raise _option_error(option, f"must be an integer in [{lo}, {hi}], got {value}")


def _check_window_ms(option: str, value: float) -> None:
    from evpose.core.label.annotate import MIN_WINDOW_MS

    if not (math.isfinite(value) and value >= MIN_WINDOW_MS):
        raise _option_error(option, f"must be at least {MIN_WINDOW_MS:g} ms (a finite number), got {value:g}")


def check_sync_args(args) -> None:
    """Refuse nonsensical ``sync`` options with one line naming the option (:class:`evpose.app.cli.main.CliError`)."""
    if not (math.isfinite(args.range_ms) and 0 < args.range_ms <= MAX_RANGE_MS):
        raise _option_error("--range-ms", f"must be a positive number of milliseconds up to {MAX_RANGE_MS:g}, "
                            f"got {args.range_ms:g}")
    if not (1000 <= args.bin_us <= MAX_BIN_US and args.bin_us % 1000 == 0):
        raise _option_error("--bin-us", f"must be a multiple of 1000 us between 1000 and {MAX_BIN_US} "
                            f"(the event rate comes from the millisecond index), got {args.bin_us}")
    _check_int("--windows", args.windows, 1, MAX_WINDOWS_OPT)


def check_refine_args(args) -> None:
    _check_int("--windows", args.windows, 1, MAX_WINDOWS_OPT)


def check_score_args(args) -> None:
    _check_window_ms("--window-ms", args.window_ms)


def _save(scene, data: dict) -> str:
    """Save the applied corrections through the one checked save path (revision check, merge with
    another program's edits saved meanwhile, or a refusal naming the conflict: raised as
    ``CorrectionsConflict``, a ``CorrectionsError``, so the CLI exits 2 with one line). Fills
    ``data["saved"]``, ``data["revision"]``, ``data["merged_from_disk"]``; returns the text line."""
    path = scene.save_corrections()
    report = scene.corrections.last_save
    data["saved"] = str(path)
    data["revision"] = report.revision
    data["merged_from_disk"] = list(report.from_disk)
    line = f"applied and saved to {path} (revision {report.revision})"
    if report.from_disk:
        line += f"; kept {', '.join(report.from_disk)} saved meanwhile by another program"
    return line


def _progress(args):
    if getattr(args, "quiet", False) or getattr(args, "json", False):
        return None

    def report(fraction, message=""):
        print(f"\r{100 * fraction:5.1f}% {message:60.60s}", end="", file=sys.stderr, flush=True)

    return report


# ---------------------------------------------------------------------------- sync
def cmd_sync(args) -> int:
    check_sync_args(args)
    from evpose.core.align.apply import apply_sync, clock_correction
    from evpose.core.align.estimate import sync_scene
    from evpose.core.align.minima_baseline import sync_minima_baseline
    from evpose.core.document.history import History

    scene = _open(args.scene)
    saved_line = ""
    try:
        res = sync_scene(scene, range_ms=args.range_ms, bin_us=args.bin_us)
        data = res.to_json(curve=args.curve)
        corr = clock_correction(scene, res)
        data["correction"] = None if corr is None else {"offset_us": corr[0], "skew_ppm": corr[1]}
        if args.baseline:
            data["baseline"] = sync_minima_baseline(scene, range_ms=args.range_ms).to_json()
        edges = None
        if args.edges and res.reliable:
            from evpose.core.align.refine_result import RefineParams
            from evpose.core.align.sync_edges import refine_offset_from_sync

            edges = refine_offset_from_sync(scene, res, params=RefineParams(n_windows=args.windows),
                                            progress=_progress(args))
            if not args.json and not args.quiet:
                print("", file=sys.stderr)
            data["edges"] = edges.to_json()
        applied = False
        if args.apply:
            if res.reliable:
                from evpose.core.align.apply import apply_offset_result

                history = History(scene.corrections)
                applied = (apply_offset_result(history, scene, edges, "clock sync (rate, then edges)")
                           if edges is not None and edges.accepted else apply_sync(history, scene, res))
                if applied:
                    saved_line = _save(scene, data)
            else:
                print(f"evpose sync: not applied: {res.reason}", file=sys.stderr)
        data["applied"] = applied
    finally:
        scene.close()
    if res.reliable:
        skew = "not estimated (kept)" if res.skew_ppm is None else f"{res.skew_ppm:.2f} ppm"
        std = res.offset_std_us
        pm = "" if std is None else (f" ± {std:.0f} us (1 sigma)" if math.isfinite(std) else " (not pinned by the rate)")
        text = (f"offset {res.offset_us} us{pm}, skew {skew}, confidence {res.confidence:.2f} "
                f"(peak NCC {res.peak:.3f}, second {res.second_peak:.3f}) in {res.runtime_s:.2f} s")
        if corr is not None:
            text += f"\ncorrection on top of the prior: offset {corr[0]} us, skew {corr[1]:.2f} ppm"
    else:
        text = f"no reliable estimate: {res.reason}"
    if edges is not None:
        text += "\n" + _edges_line(edges)
    if args.baseline:
        b = data["baseline"]
        text += (f"\nbaseline (E-POSE minima matching): offset {b['offset_us']} us"
                 if b["reliable"] else f"\nbaseline: no estimate ({b['reason']})")
    if applied:
        text += "\n" + saved_line
    _emit(args, data, text)
    return 0


def _edges_line(r, label: str = "edges") -> str:
    """One line for an offset refinement from edges."""
    if not r.accepted:
        return f"{label}: start kept ({r.reason})"
    std = r.offset_std_us
    pm = "" if std is None or not math.isfinite(std) else f" ± {std:.0f} us (1 sigma)"
    sk = f"{r.skew_ppm:.2f} ppm " + (f"(fitted, ± {r.skew_std_ppm:.1f} ppm)" if r.skew_estimated else "(kept)")
    return (f"{label}: offset {r.offset_us} us{pm}, skew {sk}; {r.n_windows} windows, {r.runtime_s:.1f} s "
            "(assumes the object poses are right)")


# ---------------------------------------------------------------------------- refine
def cmd_refine(args) -> int:
    check_refine_args(args)
    from evpose.core.align.apply import apply_offset_result
    from evpose.core.align.clock_refine import refine_offset
    from evpose.core.align.pose_refine import refine_object
    from evpose.core.align.refine_result import RefineParams
    from evpose.core.document.history import History

    scene = _open(args.scene)
    out = {"objects": {}}
    lines = []
    try:
        names = [args.object] if args.object else scene.object_names
        for n in names:
            if n not in scene.object_names:
                from evpose.app.cli.main import CliError

                raise CliError(f"{scene.manifest.path}: objects: no object named {n!r} "
                               f"(have {', '.join(scene.object_names) or 'none'})")
        params = RefineParams(n_windows=args.windows)
        history = History(scene.corrections)
        changed = False
        clock = None
        with history.group("refine from events"):
            if args.offset:
                r = refine_offset(scene, params=params, progress=_progress(args))
                out["offset"] = r.to_json()
                lines.append(_edges_line(r, "offset from edges")
                             + f"; objective {r.objective_before:.4f} -> {r.objective_after:.4f}")
                if r.accepted:
                    clock = scene.clock_with(offset_us=int(r.offset_us), skew_ppm=r.skew_ppm)  # poses fit on it
                if args.apply:
                    changed |= apply_offset_result(history, scene, r)
            for n in names:
                r = refine_object(scene, n, params=params, clock=clock, progress=_progress(args))
                out["objects"][n] = r.to_json()
                sb = "n/a" if r.score_before is None else f"{r.score_before:.3f}"
                sa = "n/a" if r.score_after is None else f"{r.score_after:.3f}"
                lines.append(f"{n}: {'accepted' if r.accepted else 'kept start'}: dR {r.dR_deg:.3f} deg, dt "
                             f"{r.dt_mm:.2f} mm; score {sb} -> {sa}; {r.n_windows} windows, {r.iterations} "
                             f"iterations, {r.runtime_s:.1f} s" + (f" ({r.reason})" if r.reason else ""))
                if args.apply and r.accepted:
                    history.set(("object", n), r.dT_base)
                    changed = True
        if getattr(args, "quiet", False) is False and not args.json:
            print("", file=sys.stderr)
        out["applied"] = bool(args.apply and changed)
        if out["applied"]:
            lines.append(_save(scene, out))
    finally:
        scene.close()
    _emit(args, out, "\n".join(lines))
    return 0


# ---------------------------------------------------------------------------- score
def cmd_score(args) -> int:
    check_score_args(args)
    from evpose.core.align.score_table import score_windows

    scene = _open(args.scene)
    try:
        table = score_windows(scene, window_us=int(round(args.window_ms * 1000)), progress=_progress(args))
    finally:
        scene.close()
    if not args.json and not getattr(args, "quiet", False):
        print("", file=sys.stderr)
    data = table.to_json()
    lines = [f"{len(table)} windows of {args.window_ms:g} ms scored in {table.runtime_s:.2f} s"]
    for n, s in data["summary"].items():
        ms = "n/a" if s["mean_score"] is None else f"{s['mean_score']:.3f}"
        worst = "none" if s["worst_window"] is None else f"window {s['worst_window']} (t {s['worst_t_label_us']} us)"
        lines.append(f"{n}: mean score {ms} over {s['n_valid']} valid windows; worst {worst}")
    for reason, k in data["unlabeled_reasons"].items():
        lines.append(f"no score (no pose) in {k} window(s): {reason}")
    _emit(args, data, "\n".join(lines))
    return 0


# ---------------------------------------------------------------------------- parsers
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
                   help="then refine offset (and skew) from event/edge alignment within 3 standard errors of the "
                        "rate estimate (needs right object poses; reported under 'edges', applied with --apply)")
    s.add_argument("--windows", type=int, default=24, help="event windows used by --edges")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_sync)

    s = subparsers.add_parser("refine", help="refine object poses (and the clock offset) from event/edge alignment")
    s.add_argument("scene")
    s.add_argument("--object", help="only this object (default: all)")
    s.add_argument("--offset", action="store_true", help="also refine the clock offset (before the poses)")
    s.add_argument("--windows", type=int, default=12, help="number of event windows used")
    s.add_argument("--json", action="store_true", help="print one JSON document")
    s.add_argument("--apply", action="store_true", help="store accepted results as corrections and save")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_refine)

    s = subparsers.add_parser("score", help="alignment score of every window and object")
    s.add_argument("scene")
    s.add_argument("--window-ms", type=float, default=10.0, help="window length (ms)")
    s.add_argument("--json", action="store_true", help="print one JSON document")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_score)
