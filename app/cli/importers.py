"""``evpose import FORMAT SRC... --out SCENE`` (DESIGN section 5): published data into a scene folder.

The command prints its summary on stdout (one JSON document with ``--json``), assumptions, repairs,
warnings and a progress bar on stderr. Bad input ends in ``evpose import: error: FILE: RECORD: FIELD:
problem`` (exit 2; :mod:`evpose.app.cli.errors`); a failed or cancelled import leaves no scene folder behind.
The readers are imported when the command runs, not when the parser is built.
"""
from __future__ import annotations

import argparse

from evpose.app.cli.errors import command
from evpose.app.cli.json_output import emit
from evpose.app.cli.options import check_float, check_int
from evpose.app.cli.progress import Progress

__all__ = ["add_import_parser", "cmd_import", "FORMAT_NAMES"]

#: The formats of :data:`evpose.core.importers.FORMATS`, in its order, named here so that building the
#: parser does not load the readers (a test keeps the two equal).
FORMAT_NAMES = ("epose-bag", "epose-export", "dsec", "rpg", "ycbev", "npz", "bop", "aedat4", "prophesee",
                "ros-events")

_EPILOG = """formats and their sources:
  epose-bag     REC.bag | ROS2_BAG_DIR | REC.mcap | REC.db3  [--assets DIR --scene S --sequence Q | --camera --objects]
  epose-export  FOLDER_WITH_NNNN_data.mat       [--assets DIR --scene S] [--objects] [--classes] [--one-based]
  dsec          events.h5 [traj.csv|txt] cam_to_cam.yaml (or a DSEC sequence folder) [--events-mode]
  rpg           FOLDER (events.txt [groundtruth.txt] calib.txt) or the files
  ycbev         SEQUENCE_FOLDER (scene_gt.json) [EVENTS.int32.zst] [calib_prophesee.json] [--models DIR]
  npz           REC.npz (x y t p [+ t_us position quaternion | T_base_cam] [+ K dist width height])
  bop           BOP_DIR | BOP_DIR/SPLIT --scene ID (or the scene folder) [--models DIR] [--frame-us N]:
                event frames read back as events; timing from scene_times.json when present
  aedat4        REC.aedat4 [TRAJECTORY [CALIB]]  (sensor size from the file; its pose stream without TRAJECTORY)
  prophesee     REC.raw|REC.dat [TRAJECTORY [CALIB]]  (EVT 2.0 / EVT 3.0 / DAT; sensor size from the header)
  ros-events    REC.bag | ROS2_BAG_DIR  [TRAJECTORY [CALIB]] [--events-topic T]  (event_camera_msgs/EventPacket of
                the ROS drivers, encodings evt3 and mono; clock prior from the first packet's stamp)
--objects takes name=mesh[:T_base_obj.json],... (T is a 4x4 JSON list, metres).
Without a trajectory (aedat4, prophesee, ros-events, npz, dsec, rpg) the scene is event-only: events and event
frames, no objects, no labels (calibration via --camera); evpose scene set-trajectory adds one later.
Every import writes import_report.json into the scene: what was assumed, repaired, dropped."""


def add_import_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``import`` subcommand on an ``argparse`` subparsers object; returns its parser."""
    s = subparsers.add_parser("import", help="turn published data into a scene folder",
                              description="Import published event-camera data into a scene folder.",
                              epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("format", metavar="FORMAT", choices=sorted(FORMAT_NAMES), help=", ".join(FORMAT_NAMES))
    s.add_argument("src", metavar="SRC", nargs="+", help="input files or folders (never modified)")
    s.add_argument("--out", required=True, help="scene folder to create")
    g = s.add_argument_group("common")
    g.add_argument("--repair", action="store_true", help="repair what can be repaired instead of refusing: drop "
                   "events off the sensor, with NaN values or out of time order beyond --reorder-window-ms, project "
                   "rotations onto SO(3), sort pose samples; every change is counted in import_report.json")
    g.add_argument("--force", action="store_true", help="replace a scene evpose made in --out (removes "
                   "only the files it wrote; never a folder holding a SRC; refuses when anything else is in it)")
    g.add_argument("--json", action="store_true", help="print the summary as one JSON document on stdout")
    g.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no 'assumed'/'repaired' lines "
                   "(warnings still go to stderr)")
    g.add_argument("--name", help="scene name (default: the --out folder name)")
    g.add_argument("--camera", help="calibration: evpose JSON, OpenCV JSON, DSEC/Kalibr YAML or RPG calib.txt")
    g.add_argument("--width", type=int, help="sensor width in pixels (overrides the calibration)")
    g.add_argument("--height", type=int, help="sensor height in pixels")
    g.add_argument("--objects", help="name=mesh[:T_base_obj.json],... (T: 4x4 JSON, metres)")
    g.add_argument("--time-unit", choices=("s", "ms", "us", "ns"), help="unit of guessable times (default: guessed "
                   "and reported)")
    g.add_argument("--offset-us", type=int, help="clock prior offset (pose minus event time) in µs")
    g.add_argument("--max-span-s", type=float, default=4 * 3600.0,
                   help="refuse event times spanning more than this (corrupt stamps, wrong units); default 14400")
    g.add_argument("--reorder-window-ms", type=float, default=100.0,
                   help="events out of time order by at most this much are put in order (times unchanged, counted "
                        "in import_report.json; further ones are refused, or dropped with --repair); default 100, "
                        "0 accepts no disorder")
    g = s.add_argument_group("epose-bag / epose-export")
    g.add_argument("--assets",
                   help="E-POSE assets folder (camera_davis346.json, models/, scenes.json, time_shifts.csv)")
    g.add_argument("--scene", help="scene in scenes.json, e.g. five_obj_clut (aliases accepted)")
    g.add_argument("--sequence", help="sequence in time_shifts.csv, e.g. R_05_ml (case-insensitive)")
    g.add_argument("--events-topic", default="/dvs/events")
    g.add_argument("--pose-topic", default="/dvs/pose")
    g.add_argument("--pose-time", choices=("header", "bag"), default="header",
                   help="pose sample time: PoseStamped header stamp (default) or bag record time")
    g.add_argument("--one-based", action="store_true", help="epose-export: event x/y are 1-based")
    g.add_argument("--classes", help="epose-export: cls_index=name,... for the pose blocks")
    g = s.add_argument_group("dsec")
    g.add_argument("--events-mode", choices=("copy", "link", "reference"), default="copy",
                   help="copy (validate and rewrite, default), link (symlink) or reference (absolute path)")
    g.add_argument("--camera-key", default="cam0", help="camera in cam_to_cam.yaml (default cam0)")
    g = s.add_argument_group("ycbev")
    g.add_argument("--models", help="BOP models folder (obj_XXXXXX.ply)")
    g.add_argument("--mesh-scale", type=float, help="mesh units to metres (default 0.001 for BOP meshes)")
    g.add_argument("--frame-us", type=int, default=33333, help="image period in µs (default 33333)")
    g.add_argument("--frame-index-offset", type=int, default=1,
                   help="image j at time-origin + (j + offset) * frame-us (default 1)")
    g.add_argument("--time-origin-us", type=int, default=0, help="added to all YCB-Ev times, µs")
    g.add_argument("--rgb-to-event", default="auto",
                   help="calib_stereo_c2ev.json to move poses into the event camera; 'auto' (found beside the "
                        "sequence) or 'none'")
    s.set_defaults(func=cmd_import)
    return s


def check_args(args) -> None:
    """Refuse the first nonsensical numeric option with one line naming it, before anything is read.
    Deeper checks (units, calibration) stay with :class:`~evpose.core.importers.options.ImportOptions`
    and the formats."""
    from evpose.core.data.camera import MAX_SIDE_PX
    from evpose.core.data.clock import MAX_ABS_TIME_US

    check_float("--max-span-s", args.max_span_s, 0.0, 10 * 365 * 86400.0, lo_open=True)
    check_float("--reorder-window-ms", args.reorder_window_ms, 0.0, 3_600_000.0)
    check_float("--mesh-scale", args.mesh_scale, 0.0, 1e6, lo_open=True)
    check_int("--width", args.width, 1, MAX_SIDE_PX)
    check_int("--height", args.height, 1, MAX_SIDE_PX)
    check_int("--offset-us", args.offset_us, -MAX_ABS_TIME_US, MAX_ABS_TIME_US)
    check_int("--time-origin-us", args.time_origin_us, -MAX_ABS_TIME_US, MAX_ABS_TIME_US)
    check_int("--frame-us", args.frame_us, 1, 10**9)
    check_int("--frame-index-offset", args.frame_index_offset, -10**9, 10**9)


def options_from_args(args):
    from evpose.core.importers import ImportOptions

    return ImportOptions(
        repair=args.repair, force=args.force, name=args.name, camera=args.camera, width=args.width,
        height=args.height, objects=args.objects, time_unit=args.time_unit, offset_us=args.offset_us,
        reorder_window_us=int(round(args.reorder_window_ms * 1000)), max_span_s=args.max_span_s, assets=args.assets,
        scene=args.scene,
        sequence=args.sequence, events_topic=args.events_topic, pose_topic=args.pose_topic, pose_time=args.pose_time,
        one_based=args.one_based, classes=args.classes, events_mode=args.events_mode, camera_key=args.camera_key,
        models=args.models, mesh_scale=args.mesh_scale, frame_us=args.frame_us,
        frame_index_offset=args.frame_index_offset, time_origin_us=args.time_origin_us, rgb_to_event=args.rgb_to_event)


def summary_text(summary: dict) -> str:
    what = (f"{summary['n_poses']} poses, objects: {', '.join(summary['objects']) or '(none)'}"
            if not summary.get("events_only") else "events only (no trajectory, no objects)")
    return (f"wrote {summary['scene']}: {summary.get('n_events'):,} events, {what} in {summary['runtime_s']:.2f} s "
            f"({len(summary['assumptions'])} assumptions, {len(summary['repairs'])} repairs, "
            f"{len(summary['warnings'])} warnings: see {summary['report']})")


@command("import", cancelled="cancelled (nothing written)")
def cmd_import(args) -> int:
    from evpose.core.importers import import_scene

    quiet = getattr(args, "quiet", False)
    check_args(args)
    with Progress(f"import {args.format}", not quiet, leave=False) as progress:
        def log(line: str) -> None:
            if not quiet or line.startswith("warning"):
                progress.write(f"evpose import: {line}")

        summary = import_scene(args.format, args.src, args.out, options_from_args(args), progress=progress, log=log)
    emit(args, summary, summary_text(summary))
    return 0
