"""``evpose dataset info|import|sync|refine|score|report|export``: the single-scene commands over every scene of a
dataset (:mod:`evpose.core.dataset`), run on Dask.

CLUSTER: ``--workers N`` starts a local Dask cluster of N worker processes (default: the machine's
cores) and stops it at the end; ``--scheduler ADDR`` uses an existing cluster (``dask scheduler`` +
``dask worker``, or dask-jobqueue on SLURM) whose workers see the dataset under the same paths.

``--json`` prints one document: ``scenes`` (name -> the single-scene command's JSON), ``failed``
(name -> the one-line error) and ``runtime_s``. A failing scene does not stop the others; the exit
status is then :data:`evpose.app.cli.errors.EXIT_PARTIAL` (3), so scripts notice.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from evpose.app.cli.errors import EXIT_PARTIAL, CliError, command
from evpose.app.cli.export import (
    SKIP_HELP,
    add_bop_shards_arg,
    add_label_sigma_args,
    format_options_from_args,
    label_sigma_from_args,
    objects_from_args,
    window_us_from_args,
)
from evpose.app.cli.json_output import emit
from evpose.app.cli.options import scheduler_option
from evpose.app.cli.progress import Progress

__all__ = ["add_dataset_parser"]


def _cluster_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("cluster (Dask)").add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, default=None, metavar="N",
                   help="a local Dask cluster of N worker processes (default: the machine's cores)")
    g.add_argument("--scheduler", metavar="ADDR", type=scheduler_option,
                   help="an existing Dask cluster: tcp://host:port or host:port, e.g. tcp://head:8786")
    p.add_argument("--json", action="store_true", help="print one JSON document (scenes, failed, runtime_s)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def _cluster(args):
    from evpose.core.dataset.cluster import ClusterSpec, open_client

    return open_client(ClusterSpec(workers=args.workers, scheduler=args.scheduler),
                       log=None if args.quiet else lambda line: print(f"evpose dataset: {line}", file=sys.stderr))


def _finish(args, result, text: str) -> int:
    """Print the result (one JSON document with ``--json``) and a line per failed scene on stderr."""
    for name, err in result.failed.items():
        print(f"evpose dataset {args.action}: {name}: failed: {err}", file=sys.stderr)
    lost = (result.cluster or {}).get("lost_workers") or []
    if lost:               # the output is the same (Dask reran their tasks), but a dying worker is worth knowing
        rerun = result.cluster.get("rerun_tasks", {})
        print(f"evpose dataset {args.action}: {len(lost)} worker(s) lost during the run ({', '.join(lost)}); "
              f"{sum(rerun.values())} task(s) rerun elsewhere"
              + (f" ({', '.join(f'{s}: {n}' for s, n in rerun.items())})" if rerun else "")
              + "; the results are complete", file=sys.stderr)
    emit(args, result.to_json(), text)
    return EXIT_PARTIAL if result.failed else 0


def _table(result, columns) -> str:
    """A text table: one row per scene, ``columns`` = [(header, fn(doc) -> str)]."""
    rows = [[h for h, _ in columns]] + [[fn(doc) for _, fn in columns] for doc in result.scenes.values()]
    rows = [[name] + r for name, r in zip(["scene"] + list(result.scenes), rows)]
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    lines.append(f"{len(result.scenes)} scene(s) done, {len(result.failed)} failed, {result.runtime_s:.1f} s")
    return "\n".join(lines)


def _open_dataset(args):
    from evpose.core.dataset.dataset import Dataset

    return Dataset.open(args.dataset)


def _flagged(args, ds):
    """``ds``, or with ``--only-flagged REPORT.json`` the scenes that report ranks for a cause this command fixes."""
    if not getattr(args, "only_flagged", None):
        return ds
    from evpose.core.dataset.report_files import FIXABLE, flagged_scenes

    names = [n for n in flagged_scenes(args.only_flagged, FIXABLE[args.action]) if n in {r.name for r in ds.scenes}]
    if not names and not args.quiet:
        print(f"evpose dataset {args.action}: {args.only_flagged} flags no scene of {ds.root} for "
              f"{' / '.join(FIXABLE[args.action])}: nothing to do", file=sys.stderr)
    return ds.only(names)


def _map(args, ds, task, *task_args, label: str):
    """``task`` over every scene of ``ds`` on the cluster of ``args``; unreadable scenes failed for their reason."""
    from evpose.core.dataset.batch import map_scenes

    with _cluster(args) as client, Progress(f"dataset {args.action}", not args.quiet) as progress:
        result = map_scenes(client, ds, task, *task_args, label=label, progress=progress)
    return ds.unreadable_failed(result)


# ------------------------------------------------------------------------------------------------- commands
@command("dataset info")
def cmd_info(args) -> int:
    from evpose.core.dataset.tasks import info_task

    result = _map(args, _open_dataset(args), info_task, label="info")
    return _finish(args, result, _table(result, [
        ("events", lambda d: f"{d['n_events']:,}"), ("duration_s", lambda d: f"{d['duration_s']:.2f}"),
        ("objects", lambda d: ",".join(d["objects"])), ("offset_us", lambda d: str(d["clock"]["offset_us"])),
        ("holes", lambda d: "events only" if d["trajectory"] is None else str(len(d["trajectory"]["holes"])))]))


@command("dataset sync")
def cmd_sync(args) -> int:
    from evpose.app.cli.sync import check_sync_args, sync_options
    from evpose.core.dataset.tasks import sync_task

    check_sync_args(args)
    result = _map(args, _flagged(args, _open_dataset(args)), sync_task, sync_options(args), label="sync")

    def offset(d):
        return "-" if d.get("offset_us") is None else str(d["offset_us"])

    def edges(d):
        e = (d.get("stages") or {}).get("edges")
        return "-" if not e else (str(e.get("offset_us")) if e.get("accepted") else "kept")

    return _finish(args, result, _table(result, [
        ("reliable", lambda d: "yes" if d.get("reliable") else "no"), ("offset_us", offset),
        ("sigma_us", lambda d: "-" if d.get("offset_std_us") is None else f"{d['offset_std_us']:.0f}"),
        ("edges_offset_us", edges), ("applied", lambda d: "yes" if d.get("applied") else "no")]))


def _changes_cell(d) -> str:
    changes = d.get("changes") or []
    return "; ".join(c["text"] for c in changes) if changes else "-"


@command("dataset refine")
def cmd_refine(args) -> int:
    from evpose.app.cli.estimates import check_windows
    from evpose.core.align.refine_run import JointRunOptions
    from evpose.core.dataset.tasks import refine_task

    check_windows(args)
    if args.shared:
        return _refine_campaign(args)
    opts = JointRunOptions(clock=not args.no_clock, hand_eye=args.hand_eye, windows=args.windows, apply=args.apply)
    result = _map(args, _flagged(args, _open_dataset(args)), refine_task, opts, label="refine")
    return _finish(args, result, _table(result, [("fit", _verdict), ("changes (+- sigma)", _changes_cell)]))


def _verdict(d) -> str:
    if not d.get("accepted"):
        return "kept start"
    changes = d.get("changes") or []
    if not changes:
        return "no change"
    if all(c["part"] == "sigma" for c in changes):       # values confirmed: only their sigma stored
        return "sigma stored" if d.get("applied") else "would store sigma"
    return "applied" if d.get("applied") else "would apply"


def _shared_kinds(text: str) -> set:
    from evpose.core.dataset.dataset import SHARED_KINDS

    kinds = {k.strip() for k in text.split(",") if k.strip()}
    for k in kinds:
        if k not in SHARED_KINDS:
            raise argparse.ArgumentTypeError(f"unknown kind {k!r} (allowed: {', '.join(SHARED_KINDS)})")
    if not kinds:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of {', '.join(SHARED_KINDS)}")
    return kinds


def _refine_campaign(args) -> int:
    """``dataset refine --joint --shared KINDS``: the groups' shared terms fitted together (one campaign fit)."""
    from evpose.core.align.joint_result import JointParams
    from evpose.core.dataset.campaign import check_record, record_campaign, run_campaign

    if args.only_flagged:
        raise CliError("--only-flagged and --shared: a campaign fit takes every scene of its groups")
    ds = _open_dataset(args)
    for kind in sorted(args.shared):
        if not any(kind in g.shared for g in ds.groups):
            raise CliError(f"{ds.root}: no [[groups]] in its dataset.toml shares {kind} (see --shared)")
    if args.apply:
        check_record(ds)                        # a foreign campaign_fit.json: refused before anything is stored
    params = JointParams(clock=not args.no_clock, skew="fixed", hand_eye=args.hand_eye or "hand-eye" in args.shared,
                         n_windows=args.windows)
    with _cluster(args) as client, Progress("dataset refine", not args.quiet) as progress:
        fit, result = run_campaign(client, ds, args.shared, params, apply=args.apply, progress=progress)
    doc = {"campaign": fit.to_json()}
    if args.apply:
        doc["recorded"] = str(record_campaign(ds, fit, result))
    result.extra = doc
    lines = _campaign_lines(fit)
    return _finish(args, result, "\n".join(lines + [_table(result, [("fit", _verdict),
                                                                    ("changes (+- sigma)", _changes_cell)])]))


def _campaign_lines(fit) -> list:
    """One line per shared unit of a group: its change and standard errors, and the scenes that share it."""
    lines = [] if fit.accepted else [f"campaign fit not accepted: {fit.reason}"]
    for unit, f in fit.hand_eye.items():
        if unit.startswith("group:"):
            lines.append(f"{unit[6:]}: hand-eye {f.dt_mm:.2f} mm (+- {f.std_mm:.2f}), {f.dR_deg:.3f} deg "
                         f"(+- {f.std_deg:.3f}) from {len(f.scenes)} scenes" + ("" if f.fitted else f"; {f.reason}"))
    for unit, objs in fit.placements.items():
        if unit.startswith("group:"):
            for nm, f in objs.items():
                lines.append(f"{unit[6:]}: {nm} {f.dt_mm:.2f} mm (+- {f.std_mm:.2f}), {f.dR_deg:.2f} deg "
                             f"(+- {f.std_deg:.2f}) from {len(f.scenes)} scenes" + ("" if f.fitted else f"; {f.reason}"))
    return lines + [f"{note}" for note in fit.notes]


@command("dataset score")
def cmd_score(args) -> int:
    from evpose.core.dataset.tasks import score_task

    if not args.window_ms > 0:
        raise CliError(f"--window-ms: must be a positive number of milliseconds, got {args.window_ms}")
    result = _map(args, _open_dataset(args), score_task, int(round(args.window_ms * 1000)), label="score")

    def means(d):
        return ", ".join(f"{n} {'n/a' if s['mean_score'] is None else format(s['mean_score'], '.3f')}"
                         for n, s in d["summary"].items())

    return _finish(args, result, _table(result, [("windows", lambda d: str(d["n_windows"])), ("mean score", means)]))


@command("dataset report")
def cmd_report(args) -> int:
    from evpose.core.align.sync_run import SyncOptions
    from evpose.core.data.owned_files import check_out_path
    from evpose.core.dataset.report_files import check_report_siblings, write_report_files
    from evpose.core.dataset.tasks import triage_task
    from evpose.core.dataset.triage import triage

    if args.edges:
        from evpose.app.cli.estimates import check_windows

        check_windows(args)
    ds = _open_dataset(args)
    check_out_path(args.out, "file", ds.input_folders(args.out))        # before minutes of work, and never a device
    for sibling in (Path(args.out).with_suffix(".csv"), Path(args.out).with_suffix(".json")):
        check_out_path(sibling, "file", ds.input_folders(sibling))
    previous = check_report_siblings(args.out)                             # another program's file: refused now
    result = _map(args, ds, triage_task, SyncOptions(edges=args.edges, windows=args.windows), label="triage")
    doc = triage(result.to_json(), order=[ref.name for ref in ds.scenes],
                 paths={ref.name: str(ref.path) for ref in ds.scenes})
    doc["options"] = {"edges": bool(args.edges), "windows": int(args.windows) if args.edges else None}
    path = write_report_files(doc, args.out, previous)
    for name, err in result.failed.items():
        print(f"evpose dataset report: {name}: failed: {err}", file=sys.stderr)
    # the dataset contract (scenes by name, failed, runtime_s) around the report's own data
    data = {"dataset": doc["dataset"], "report": str(path),
            "scenes": {sc["name"]: sc for sc in doc["scenes"] if sc["status"] == "ok"}, "failed": result.failed,
            "runtime_s": result.runtime_s, **{k: v for k, v in doc.items() if k not in ("dataset", "scenes", "runtime_s")}}
    text = (f"wrote {path} (and its .csv, .json): {len(result.scenes)} scene(s), {len(result.failed)} failed, "
            f"{result.runtime_s:.1f} s")
    if doc["since_last"] is not None:
        s = doc["since_last"]
        text += (f"\nsince the last report: {len(s['new'])} newly flagged, {len(s['resolved'])} no longer flagged, "
                 f"{len(s['changed'])} flagged for another cause")
        if "options_changed" in s:
            text += (f" (the last report was made with other options: {s['options_changed']['was']}; flags differ "
                     "for that too)")
    emit(args, data, text)
    return EXIT_PARTIAL if result.failed else 0


@command("dataset export", interrupted="interrupted; rerun the same command to resume")
def cmd_export(args) -> int:
    from evpose.core.dataset.export import check_dataset_export, export_dataset

    window_us = window_us_from_args(args)
    objects = objects_from_args(args)
    label_sigma = label_sigma_from_args(args)
    ds = _open_dataset(args)
    check_dataset_export(ds, args.out, args.format, objects)          # before the cluster starts
    with _cluster(args) as client, Progress(f"dataset export {args.format}", not args.quiet) as progress:
        result = export_dataset(client, ds, args.format, args.out, progress=progress, window_us=window_us,
                                window_events=args.window_events, label_at=args.label_at,
                                only_verified=args.only_verified, include_stale=args.include_stale, objects=objects,
                                margin_m=args.margin_mm * 1e-3, force=args.force,
                                format_options=format_options_from_args(args), label_sigma=label_sigma)
    text = _table(result, [
        ("written", lambda d: str(d["written"])), ("complete", lambda d: str(d["skipped_complete"])),
        ("unlabeled", lambda d: str(d["unlabeled"])), ("windows", lambda d: str(d["windows_total"]))])
    return _finish(args, result, text + _bop_line(args, result))


def _bop_line(args, result) -> str:
    """For BOP: what ``OUT/bop`` holds, saying which scenes it lacks (never a silently shorter dataset)."""
    from pathlib import Path

    from evpose.core.dataset.bop_dataset import BOP_DIR, read_names

    if args.format != "bop" or "bop" in result.failed:
        return ""
    bop = Path(args.out) / BOP_DIR
    doc = read_names(bop)
    if doc is None:
        return ""
    missing = f"; without {', '.join(doc['missing'])} (failed: scene ids kept free)" if doc.get("missing") else ""
    return f"\n{bop}: one BOP dataset of {len(doc['scenes'])} scene(s){missing}"


@command("dataset import")
def cmd_import(args) -> int:
    from evpose.core.data.owned_files import check_out_path, scene_folders_around
    from evpose.core.dataset.import_bags import import_dataset

    check_out_path(args.out, "folder", [(args.raw_dir, "the folder of the bags"), (args.assets, "the assets folder"),
                                        *scene_folders_around(args.out)])
    with _cluster(args) as client, Progress("dataset import", not args.quiet) as progress:
        result = import_dataset(client, args.raw_dir, args.assets, args.out, progress=progress)
    return _finish(args, result, _table(result, [
        ("bag", lambda d: str(d.get("bag", ""))), ("status", lambda d: "complete (skipped)" if d.get("skipped") else "imported")]))


# ------------------------------------------------------------------------------------------------- parser
def add_dataset_parser(subparsers) -> None:
    """Register ``dataset`` and its sub-commands on the ``evpose`` sub-parser set."""
    d = subparsers.add_parser("dataset", help="the commands over every scene of a dataset (Dask)",
                              description="A dataset is a folder whose subfolders holding a scene.toml are its "
                                          "scenes (name order), or a dataset.toml listing them. Each command runs "
                                          "on a local Dask cluster (--workers N, default: the machine's cores) or "
                                          "an existing one (--scheduler ADDR) whose workers see the same paths.")
    sub = d.add_subparsers(dest="action", required=True, metavar="ACTION")

    p = sub.add_parser("info", help="every scene's summary (evpose info)")
    p.add_argument("dataset", metavar="DATASET")
    _cluster_args(p)
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("import", help="import raw recordings into a dataset folder (one scene each)")
    p.add_argument("format", choices=("epose-bag",), help="epose-bag: every E-POSE ROS1 bag under RAW_DIR")
    p.add_argument("raw_dir", metavar="RAW_DIR")
    p.add_argument("--assets", required=True, metavar="DIR", help="E-POSE assets (camera, models, scenes.json, "
                   "time_shifts.csv: the published prior time shift of each sequence)")
    p.add_argument("--out", required=True, metavar="DATASET", help="the dataset folder to create or complete")
    _cluster_args(p)
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("sync", help="clock estimate of every scene (evpose sync)")
    p.add_argument("dataset", metavar="DATASET")
    p.add_argument("--edges", action="store_true", help="then refine from event/edge alignment (see evpose sync)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--dry-run", action="store_true", help="print what --apply would store (the default)")
    g.add_argument("--apply", action="store_true", help="store each reliable estimate beyond its sigma of the clock in "
                                                        "effect in the scene's corrections.json (one undo step)")
    p.add_argument("--range-ms", type=float, default=500.0, help="search range around the clock in effect (ms)")
    p.add_argument("--bin-us", type=int, default=1000, help="event-rate bin (multiple of 1000 us)")
    p.add_argument("--windows", type=int, default=24, help="event windows used by --edges")
    p.add_argument("--only-flagged", metavar="REPORT.json", help="only the scenes that report (dataset report's JSON) "
                   "ranks for the clock or low scores")
    p.set_defaults(baseline=False, curve=False)
    _cluster_args(p)
    p.set_defaults(func=cmd_sync)

    p = sub.add_parser("refine", help="clock and poses (and hand-eye) of every scene fitted from edges (evpose "
                                      "refine --joint): a dry run by default, --apply stores them")
    p.add_argument("dataset", metavar="DATASET")
    p.add_argument("--joint", action="store_true", help="the joint fit of clock and poses (the only mode; accepted "
                                                       "for symmetry with evpose refine)")
    p.add_argument("--hand-eye", action="store_true", help="fit a hand-eye correction too (without it, a scene whose "
                                                           "fit shows a camera-mounting error gets the hand-eye fitted "
                                                           "and proposed anyway)")
    p.add_argument("--no-clock", action="store_true", help="keep each scene's clock")
    p.add_argument("--shared", type=_shared_kinds, metavar="KINDS", help="hand-eye,placement: fit the scenes of "
                   "dataset.toml's [[groups]] together, sharing these terms (one campaign fit of the grouped scenes; "
                   "each scene's clock fitted on its own; --apply stores every scene's share as one undo step and "
                   "records campaign_fit.json)")
    p.add_argument("--windows", type=int, default=24, help="event windows of each fit")
    p.add_argument("--only-flagged", metavar="REPORT.json", help="only the scenes that report (dataset report's JSON) "
                   "ranks for the clock, a pose, the mounting or low scores")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--dry-run", action="store_true", help="print what --apply would store (the default)")
    g.add_argument("--apply", action="store_true", help="store each scene's changes beyond their sigma as one undo "
                                                        "step in its corrections.json")
    _cluster_args(p)
    p.set_defaults(func=cmd_refine)

    p = sub.add_parser("score", help="alignment scores of every scene (evpose score)")
    p.add_argument("dataset", metavar="DATASET")
    p.add_argument("--window-ms", type=float, default=10.0, help="window length (ms)")
    _cluster_args(p)
    p.set_defaults(func=cmd_score)

    p = sub.add_parser("report", help="the triage report: one self-contained HTML file")
    p.add_argument("dataset", metavar="DATASET")
    p.add_argument("--out", required=True, metavar="REPORT.html")
    p.add_argument("--edges", action="store_true", help="also fit each scene's clock and poses from the event edges "
                   "(evpose sync --edges: tens of seconds per scene): pose and camera-mounting verdicts")
    p.add_argument("--windows", type=int, default=24, help="event windows used by --edges")
    _cluster_args(p)
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("export", help="export every scene (evpose export), BOP as one dataset")
    p.add_argument("dataset", metavar="DATASET")
    p.add_argument("--format", required=True, choices=("epose", "bop", "h5"))
    p.add_argument("--out", required=True, metavar="DIR", help="OUT/<scene> per scene (and OUT/bop for BOP)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--window-ms", type=float, default=None, metavar="MS", help="window length (default 10 ms)")
    g.add_argument("--window-events", type=int, default=None, metavar="N", help="events per window instead")
    p.add_argument("--label-at", choices=("center", "end"), default="center")
    p.add_argument("--only-verified", action="store_true", help="only windows verified in review (see evpose export)")
    p.add_argument("--include-stale", action="store_true", help="with --only-verified: also stale verified marks")
    p.add_argument("--objects", metavar="A,B", help="comma-separated objects to export (default all)")
    p.add_argument("--margin-mm", type=float, default=0.0, metavar="X", help="enlarge the 3D box by X mm")
    p.add_argument("--force", action="store_true",
                   help="replace earlier evpose exports of a different configuration (see evpose export)")
    p.add_argument("--split", metavar="NAME", default=None,
                   help="bop: split folder of the scenes, test (default), train or val (see evpose export)")
    p.add_argument("--skip", metavar="A,B", default=None, help=SKIP_HELP)
    add_bop_shards_arg(p)
    add_label_sigma_args(p)
    p.set_defaults(jobs=1)
    _cluster_args(p)
    p.set_defaults(func=cmd_export)
