"""``evpose export``: the command-line front end of :func:`evpose.core.export.export_scene`.

Wire it into the main parser with :func:`add_export_parser`::

    sub = parser.add_subparsers(dest="command")
    add_export_parser(sub)          # sets func=cmd_export; main() calls args.func(args)

``cmd_export`` handles its own errors: a message naming the file or option on stderr and exit status 2
(bad scene or arguments), 130 when interrupted (Ctrl-C; the folder stays resumable). ``--json`` prints
exactly one JSON document on stdout; the progress bar (tqdm, with ETA) and messages go to stderr.
"""
from __future__ import annotations

import argparse
import json
import math
import sys

EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


def add_export_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``export`` on an ``argparse`` sub-parser collection; returns the new parser."""
    p = subparsers.add_parser(
        "export", help="export the corrected dataset (E-POSE layout, BOP or HDF5)",
        description="Export a scene's corrected labels. Atomic per file and resumable: rerunning the same "
                    "command into the same folder continues an interrupted export.")
    p.add_argument("scene", metavar="SCENE", help="scene folder or scene.toml (corrections.json beside it is applied)")
    p.add_argument("--format", required=True, choices=("epose", "bop", "h5"), dest="format",
                   help="epose: the published per-window layout; bop: BOP scene of undistorted frames; "
                        "h5: one HDF5 file per sequence")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (new, empty, or an earlier export to resume)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--window-ms", type=float, default=None, metavar="MS",
                   help="window length in milliseconds (default 10)")
    g.add_argument("--window-events", type=int, default=None, metavar="N", help="events per window instead")
    p.add_argument("--label-at", choices=("center", "end"), default="center",
                   help="label time: window centre (default) or end (E-POSE timing)")
    p.add_argument("--only-verified", action="store_true",
                   help="export only windows fully covered by 'verified' review marks (partly covered, partly "
                        "rejected/flagged and stale-marked windows are left out and counted in the summary)")
    p.add_argument("--include-stale", action="store_true",
                   help="with --only-verified: also use verified marks made before a later change of the clock "
                        "or of the object's pose (left out by default)")
    p.add_argument("--objects", metavar="A,B", help="comma-separated objects to export (default all)")
    p.add_argument("--margin-mm", type=float, default=0.0, metavar="X",
                   help="enlarge the 3D box by X mm on every side (keypoints)")
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="worker processes (default 1)")
    p.add_argument("--force", action="store_true",
                   help="replace an earlier evpose export of a different configuration in --out")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON document on stdout")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_export)
    return p


class _Bar:
    """tqdm bar on stderr (windows, with rate and ETA) driven by ``progress(fraction, message)``."""

    def __init__(self, desc: str, enabled: bool):
        self.bar = None
        self.enabled = enabled
        self.desc = desc

    def __call__(self, fraction: float, message: str = "") -> None:
        if not self.enabled:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=1000, desc=self.desc, file=sys.stderr, unit="‰", dynamic_ncols=True,
                            bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}{postfix}]")
        self.bar.update(max(0, int(round(fraction * 1000)) - self.bar.n))
        if message:
            self.bar.set_postfix_str(message, refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _error(msg: str) -> int:
    print(f"evpose export: error: {msg}", file=sys.stderr)
    return EXIT_BAD_INPUT


def _input_errors() -> tuple:
    from evpose.core.data.camera import CameraError
    from evpose.core.data.events import EventFileError
    from evpose.core.data.geometry import GeometryError
    from evpose.core.data.objects import ObjectModelError
    from evpose.core.data.scene import SceneError
    from evpose.core.data.trajectory import TrajectoryError
    from evpose.core.document.corrections import CorrectionsError
    from evpose.core.export.common import ExportError
    from evpose.core.label.annotate import WindowError

    return (ExportError, SceneError, CorrectionsError, EventFileError, TrajectoryError, CameraError,
            ObjectModelError, GeometryError, FileNotFoundError, FileExistsError, NotADirectoryError, WindowError)


def summary_text(s) -> str:
    rate = s.written / s.runtime_s if s.runtime_s > 0 else 0.0
    lines = [f"exported {s.format} to {s.out_dir}: {s.written} windows written, {s.skipped_complete} already complete "
             f"(skipped), {s.unlabeled} unlabeled, {s.filtered_unverified} not verified (left out) of "
             f"{s.windows_total} windows in {s.runtime_s:.1f} s ({rate:.1f} windows/s, {s.jobs} job{'s' * (s.jobs > 1)})"]
    if s.review_marked:
        exported = s.review_marked - s.review_unused
        line = f"  verified marks touch {s.review_marked} window(s): {exported} exported"
        if s.review_unused:
            line += f", {s.review_unused} not used: " + "; ".join(f"{n} {r}" for r, n in s.review_unused_reasons.items())
        lines.append(line)
    for reason, n in s.unlabeled_reasons.items():
        ids = [u["index"] for u in s.unlabeled_windows if u["reason"] == reason]
        shown = ", ".join(map(str, ids[:10])) + (", ..." if len(ids) > 10 else "")
        lines.append(f"  unlabeled: {n} window(s): {reason} [{shown}]")
    return "\n".join(lines)


def cmd_export(args) -> int:
    """Run ``evpose export`` from parsed arguments; returns the exit status."""
    from evpose.core.data.events import Cancelled
    from evpose.core.export import export_scene
    from evpose.core.label.annotate import MIN_WINDOW_MS

    if args.window_ms is not None:
        if not (math.isfinite(args.window_ms) and args.window_ms > 0):
            return _error(f"--window-ms: must be a positive number of milliseconds, got {args.window_ms}")
        if args.window_ms < MIN_WINDOW_MS:
            return _error(f"--window-ms: {args.window_ms:g} ms is shorter than the {MIN_WINDOW_MS:g} ms minimum "
                          "(poses are sampled every few ms; shorter windows only multiply the files)")
        window_us = int(round(args.window_ms * 1000))
    else:
        window_us = 10_000
    if args.window_events is not None and args.window_events <= 0:
        return _error(f"--window-events: must be a positive integer, got {args.window_events}")
    if not (math.isfinite(args.margin_mm) and args.margin_mm >= 0):
        return _error(f"--margin-mm: must be a number >= 0, got {args.margin_mm}")
    if args.jobs < 1:
        return _error(f"--jobs: must be >= 1, got {args.jobs}")
    objects = None
    if args.objects is not None:
        objects = [s.strip() for s in args.objects.split(",") if s.strip()]
        if not objects:
            return _error("--objects: expected a comma-separated list of object names")
    bar = _Bar(f"export {args.format}", not args.quiet)
    try:
        s = export_scene(args.scene, args.format, args.out, window_us=window_us, window_events=args.window_events,
                         label_at=args.label_at, only_verified=args.only_verified, objects=objects,
                         include_stale=args.include_stale,
                         margin_m=args.margin_mm * 1e-3, jobs=args.jobs, force=args.force, progress=bar)
    except KeyboardInterrupt:
        bar.close()
        print("evpose export: interrupted; rerun the same command to resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Cancelled as exc:
        bar.close()
        print(f"evpose export: {exc}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except _input_errors() as exc:
        bar.close()
        msg = str(exc)
        if args.objects is not None and msg.startswith("objects:"):
            msg = "--" + msg
        return _error(msg)
    finally:
        bar.close()
    if args.json:
        sys.stdout.write(json.dumps(s.to_json(with_files=False), indent=1) + "\n")
    else:
        sys.stdout.write(summary_text(s) + "\n")
    return EXIT_OK


def main(argv=None) -> int:
    """Stand-alone entry point: ``python -m evpose.app.cli.export SCENE --format ... --out ...``."""
    parser = argparse.ArgumentParser(prog="evpose")
    sub = parser.add_subparsers(dest="command", required=True)
    add_export_parser(sub)
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] != "export":
        argv = ["export"] + argv
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
