"""``evpose export SCENE --format epose|bop|h5 --out DIR``: the command-line front end of
:func:`evpose.core.export.export_scene`.

Atomic per file and resumable: after Ctrl-C (exit 130) the same command continues. ``--json`` prints
the summary as one JSON document on stdout; the progress bar (with ETA) and messages go to stderr.
Errors and exit codes: :mod:`evpose.app.cli.errors`.
"""
from __future__ import annotations

import argparse
import math

from evpose.app.cli.errors import CliError, command
from evpose.app.cli.json_output import emit
from evpose.app.cli.progress import Progress
from evpose.core.errors import InputError

__all__ = ["add_export_parser", "cmd_export", "summary_text", "format_options_from_args"]


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
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder (new, empty, or an earlier export to resume)")
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
    p.add_argument("--split", metavar="NAME", default=None,
                   help="bop: the split folder the scene goes into: test (default), train or val (optionally "
                        "with a _TYPE suffix)")
    p.add_argument("--skip", metavar="A,B", default=None, help=SKIP_HELP)
    add_bop_shards_arg(p)
    add_label_sigma_args(p)
    p.add_argument("--force", action="store_true",
                   help="replace an earlier evpose export of a different configuration in --out")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON document on stdout")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_export)
    return p


def summary_text(s) -> str:
    rate = s.written / s.runtime_s if s.runtime_s > 0 else 0.0
    lines = [f"exported {s.format} to {s.out_dir}: {s.written} windows written, {s.skipped_complete} already complete "
             f"(skipped), {s.unlabeled} unlabeled, {s.filtered_unverified} not verified (left out) of "
             f"{s.windows_total} windows in {s.runtime_s:.1f} s ({rate:.1f} windows/s, "
             f"{s.jobs} job{'s' * (s.jobs > 1)})"]
    if s.filtered_label_sigma:
        lines.append(f"  {s.filtered_label_sigma} windows left out: a label's sigma above --max-label-sigma-mm/-deg")
    if s.events_only:
        lines.append("  events only (no trajectory, no objects): event frames without labels")
    if s.review_marked:
        exported = s.review_marked - s.review_unused
        line = f"  verified marks touch {s.review_marked} window(s): {exported} exported"
        if s.review_unused:
            line += f", {s.review_unused} not used: " + "; ".join(
                f"{n} {r}" for r, n in s.review_unused_reasons.items())
        lines.append(line)
    for reason, n in s.unlabeled_reasons.items():
        ids = [u["index"] for u in s.unlabeled_windows if u["reason"] == reason]
        shown = ", ".join(map(str, ids[:10])) + (", ..." if len(ids) > 10 else "")
        lines.append(f"  unlabeled: {n} window(s): {reason} [{shown}]")
    return "\n".join(lines)


def window_us_from_args(args) -> int:
    """The window length in µs, after refusing nonsensical window, margin, jobs and object options."""
    from evpose.core.label.windows import DEFAULT_WINDOW_US, MIN_WINDOW_MS   # (imported late: --help loads no engine)

    window_us = DEFAULT_WINDOW_US
    if args.window_ms is not None:
        if not (math.isfinite(args.window_ms) and args.window_ms > 0):
            raise CliError(f"--window-ms: must be a positive number of milliseconds, got {args.window_ms}")
        if args.window_ms < MIN_WINDOW_MS:
            raise CliError(f"--window-ms: {args.window_ms:g} ms is shorter than the {MIN_WINDOW_MS:g} ms minimum "
                           "(poses are sampled every few ms; shorter windows only multiply the files)")
        window_us = int(round(args.window_ms * 1000))
    if args.window_events is not None and args.window_events <= 0:
        raise CliError(f"--window-events: must be a positive integer, got {args.window_events}")
    if not (math.isfinite(args.margin_mm) and args.margin_mm >= 0):
        raise CliError(f"--margin-mm: must be a number >= 0, got {args.margin_mm}")
    if args.jobs < 1:
        raise CliError(f"--jobs: must be >= 1, got {args.jobs}")
    return window_us


#: ``--skip``'s help (``export`` and ``dataset export``).
SKIP_HELP = ("epose: per-window products not to write, comma-separated: event_image, masks, segmented, "
             "three_channel, bbox (the .mat is always written); 5 objects: 16 files a window with all, 10 without "
             "segmented")


#: ``--bop-shards``'s N when not given: evpose.core.export.bop_shards.DEFAULT_SHARD_WINDOWS (a test checks), written
#: out here because building the parser imports no engine module.
BOP_SHARDS_DEFAULT = 200


def add_bop_shards_arg(p) -> None:
    """``--bop-shards [N]`` (``export`` and ``dataset export``)."""
    p.add_argument("--bop-shards", type=int, nargs="?", const=BOP_SHARDS_DEFAULT, default=None, metavar="N",
                   help=f"bop: images and masks in BOP-webdataset shards of N windows (default "
                        f"{BOP_SHARDS_DEFAULT}): SPLIT_web/shard-*.tar + key_to_shard.json, masks as RLE; one "
                        f"file per N windows instead of 1 + 2 per object per window")


def add_label_sigma_args(p) -> None:
    """``--label-sigma`` and its limits (``export`` and ``dataset export``)."""
    p.add_argument("--label-sigma", metavar="auto|K=V,...", default=None,
                   help="write each label's 1-sigma (t mm, rotation deg, contour px) propagated from these input "
                        "sigmas: offset_us, skew_ppm, pose_mm, pose_deg, hand_eye_mm, hand_eye_deg (RMS of 3D "
                        "errors; unnamed inputs 0; the trajectory's interpolation error always added), e.g. "
                        "offset_us=2000,pose_mm=2,pose_deg=1; auto: each object's from the sigmas its applied "
                        "estimates stored in corrections.json (inputs without one count as exact)")
    p.add_argument("--max-label-sigma-mm", type=float, default=None, metavar="X",
                   help="with --label-sigma: leave out (and count) windows where a label's sigma_t exceeds X mm")
    p.add_argument("--max-label-sigma-deg", type=float, default=None, metavar="Y",
                   help="with --label-sigma: leave out (and count) windows where a label's sigma_R exceeds Y deg")


def label_sigma_from_args(args):
    """``--label-sigma`` and ``--max-label-sigma-*`` as an export's LabelSigmaOptions (None: not asked for)."""
    text = getattr(args, "label_sigma", None)
    limits = (getattr(args, "max_label_sigma_mm", None), getattr(args, "max_label_sigma_deg", None))
    if text is None:
        if any(v is not None for v in limits):
            raise CliError("--max-label-sigma-mm/-deg: need --label-sigma (the input sigmas the labels' sigma is "
                           "computed from)")
        return None
    from evpose.core.label.uncertainty import InputSigmas, LabelSigmaOptions

    if text.strip() == "auto":
        return LabelSigmaOptions(None, *limits)
    fields = {}
    for item in (s.strip() for s in text.split(",") if s.strip()):
        key, sep, value = item.partition("=")
        if not sep or key.strip() not in InputSigmas.__dataclass_fields__ or key.strip() == "interpolation":
            raise CliError(f"--label-sigma: {item!r}: expected KEY=VALUE with KEY one of offset_us, skew_ppm, "
                           "pose_mm, pose_deg, hand_eye_mm, hand_eye_deg")
        try:
            fields[key.strip()] = float(value)
        except ValueError:
            raise CliError(f"--label-sigma: {item!r}: {value!r} is not a number") from None
    try:
        return LabelSigmaOptions(InputSigmas(**fields), *limits)
    except ValueError as exc:
        raise CliError(f"--label-sigma: {exc}") from None


def format_options_from_args(args) -> dict | None:
    """``--split`` and ``--bop-shards`` as the BOP writer's options, ``--skip`` as the E-POSE writer's (each refused
    for the other formats)."""
    opts = {}
    if getattr(args, "split", None) is not None:
        if args.format != "bop":
            raise CliError(f"--split: only for --format bop, not {args.format}")
        opts["split"] = args.split
    if getattr(args, "bop_shards", None) is not None:
        if args.format != "bop":
            raise CliError(f"--bop-shards: only for --format bop, not {args.format}")
        from evpose.core.export.bop_shards import MAX_SHARD_WINDOWS

        if not 1 <= args.bop_shards <= MAX_SHARD_WINDOWS:
            raise CliError(f"--bop-shards: must be a number of windows from 1 to {MAX_SHARD_WINDOWS}, "
                           f"got {args.bop_shards}")
        opts["shard_windows"] = args.bop_shards
    if getattr(args, "skip", None) is not None:
        if args.format != "epose":
            raise CliError(f"--skip: only for --format epose, not {args.format}")
        from evpose.core.export.epose import check_skip

        try:
            opts["skip"] = list(check_skip(args.skip))
        except ValueError as exc:
            raise CliError(f"--skip: {str(exc).removeprefix('skip: ')}") from None
    return opts or None


def objects_from_args(args) -> list[str] | None:
    """``--objects a,b`` as a list (None: all objects)."""
    if args.objects is None:
        return None
    objects = [s.strip() for s in args.objects.split(",") if s.strip()]
    if not objects:
        raise CliError("--objects: expected a comma-separated list of object names")
    return objects


@command("export", interrupted="interrupted; rerun the same command to resume")
def cmd_export(args) -> int:
    """Run ``evpose export`` from parsed arguments; returns the exit status."""
    from evpose.core.export import export_scene
    from evpose.core.export.out_folder import check_export_out

    window_us = window_us_from_args(args)
    objects = objects_from_args(args)
    format_options = format_options_from_args(args)
    label_sigma = label_sigma_from_args(args)
    check_export_out(args.out, args.scene)
    try:
        with Progress(f"export {args.format}", not args.quiet) as progress:
            s = export_scene(args.scene, args.format, args.out, window_us=window_us, window_events=args.window_events,
                             label_at=args.label_at, only_verified=args.only_verified, objects=objects,
                             include_stale=args.include_stale, format_options=format_options,
                             margin_m=args.margin_mm * 1e-3, jobs=args.jobs, force=args.force, progress=progress,
                             label_sigma=label_sigma)
    except InputError as exc:
        if objects is not None and str(exc).startswith("objects:"):
            raise CliError(f"--{exc}") from None        # the scene's objects were chosen by --objects
        raise
    emit(args, s.to_json(with_files=False), summary_text(s))
    return 0
