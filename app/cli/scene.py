"""``evpose scene set-trajectory|add-objects``: turn an event-only scene into a labelled one (issue 26.4).

``set-trajectory SCENE TRAJECTORY`` reads the trajectory with the importers' readers, copies it into the scene
folder as ``trajectory.csv`` and adds ``[trajectory]`` to ``scene.toml``; ``add-objects SCENE --objects
name=mesh:T_base_obj.json,...`` copies the meshes into ``models/`` and adds ``[[objects]]``. ``scene.toml`` is
replaced atomically and only when nobody changed it since it was read (:mod:`evpose.core.importers.scene_edit`).
Assumptions and warnings go to stderr; ``--json`` prints the summary as one JSON document.
"""
from __future__ import annotations

import argparse
import sys

from evpose.app.cli.errors import command
from evpose.app.cli.json_output import emit
from evpose.app.cli.options import check_float, check_int

__all__ = ["add_scene_parser", "cmd_set_trajectory", "cmd_add_objects"]

#: :data:`evpose.core.importers.scene_edit.TRAJECTORY_FORMATS`, named here so that building the parser loads no
#: reader (a test keeps the two equal).
TRAJECTORY_FORMATS = ("auto", "csv", "tum", "rpg", "npz")


def _log(quiet: bool):
    def log(line: str) -> None:
        if not quiet or line.startswith("warning"):
            print(f"evpose scene: {line}", file=sys.stderr, flush=True)
    return log


def _options(args):
    from evpose.core.importers import ImportOptions

    return ImportOptions(repair=args.repair, time_unit=getattr(args, "time_unit", None),
                         offset_us=getattr(args, "offset_us", None), objects=getattr(args, "objects", None),
                         mesh_scale=getattr(args, "mesh_scale", None))


@command("scene set-trajectory")
def cmd_set_trajectory(args) -> int:
    from evpose.core.data.clock import MAX_ABS_TIME_US
    from evpose.core.importers.scene_edit import set_trajectory

    check_int("--offset-us", args.offset_us, -MAX_ABS_TIME_US, MAX_ABS_TIME_US)
    s = set_trajectory(args.scene, args.trajectory, _options(args), fmt=args.format, log=_log(args.quiet))
    emit(args, s, f"{s['scene']}: trajectory of {s['n_poses']} poses, {s['t0_us']}..{s['t1_us']} us (pose clock), "
                  f"written to {s['trajectory']}; the scene is labelled once it has objects "
                  "(evpose scene add-objects SCENE --objects name=mesh:T_base_obj.json)")
    return 0


@command("scene add-objects")
def cmd_add_objects(args) -> int:
    from evpose.core.importers.scene_edit import add_objects

    check_float("--mesh-scale", args.mesh_scale, 0.0, 1e6, lo_open=True)
    s = add_objects(args.scene, _options(args), log=_log(args.quiet))
    emit(args, s, f"{s['scene']}: added {', '.join(s['objects'])}")
    return 0


def add_scene_parser(subparsers) -> None:
    """Register ``scene`` and its sub-commands on the ``evpose`` sub-parser set."""
    d = subparsers.add_parser("scene", help="change a scene: add a trajectory or objects to it",
                              description="Edit a scene folder in place: scene.toml is replaced atomically, and "
                                          "only when nobody changed it since it was read.")
    sub = d.add_subparsers(dest="action", required=True, metavar="ACTION")
    p = sub.add_parser("set-trajectory", help="give an event-only scene its camera trajectory",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Read TRAJECTORY (T_base_cam: the camera in the base frame, metres) with the "
                                   "importers' readers, copy it into the scene as trajectory.csv and add "
                                   "[trajectory] to scene.toml.",
                       epilog="formats: auto (.npz by its suffix, else text), csv (t_us,x,y,z,qx,qy,qz,qw), tum "
                              "(t x y z qx qy qz qw; time unit from the header or guessed), rpg (groundtruth.txt, "
                              "seconds), npz (t_us or pose_t + position/quaternion or T_base_cam)")
    p.add_argument("scene", metavar="SCENE", help="scene folder or scene.toml")
    p.add_argument("trajectory", metavar="TRAJECTORY", help="trajectory file (never modified)")
    p.add_argument("--format", choices=TRAJECTORY_FORMATS, default="auto")
    p.add_argument("--time-unit", choices=("s", "ms", "us", "ns"), help="unit of the times (default: from the "
                   "header, else guessed and reported)")
    p.add_argument("--offset-us", type=int, help="clock prior offset (pose minus event time) in µs, into [clock]")
    p.add_argument("--repair", action="store_true", help="sort pose samples, normalise quaternions (reported)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON document on stdout")
    p.add_argument("-q", "--quiet", action="store_true", help="no 'assumed'/'repaired' lines")
    p.set_defaults(func=cmd_set_trajectory)

    p = sub.add_parser("add-objects", help="add objects (meshes and their poses in the base frame) to a scene")
    p.add_argument("scene", metavar="SCENE", help="scene folder or scene.toml (with a trajectory)")
    p.add_argument("--objects", required=True, metavar="SPEC",
                   help="name=mesh:T_base_obj.json,... (T: 4x4 JSON, metres), as for evpose import")
    p.add_argument("--mesh-scale", type=float, help="mesh units to metres (default 1; 0.001 for mm meshes)")
    p.add_argument("--repair", action="store_true", help="accept rotations that are not orthonormal (projected)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON document on stdout")
    p.add_argument("-q", "--quiet", action="store_true", help="no 'assumed'/'repaired' lines")
    p.set_defaults(func=cmd_add_objects)
