"""``evpose gui [SCENE]`` and ``evpose demo``: the commands that start the desktop app. Qt is imported
only inside them (building the parser, or any other command, loads no GUI library)."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from evpose.app.cli.errors import CliError, command
from evpose.app.cli.info import print_info
from evpose.app.cli.synth import default_demo_dir, ensure_demo_scene

__all__ = ["add_demo_parser", "add_gui_parser", "cmd_gui", "cmd_demo"]

#: ``--quit-after`` bound: a day.
MAX_QUIT_AFTER_S = 86_400


def check_quit_after(args) -> None:
    q = getattr(args, "quit_after", None)
    if q is not None and not (q >= 0 and q <= MAX_QUIT_AFTER_S):
        raise CliError(f"--quit-after: must be a number of seconds in [0, {MAX_QUIT_AFTER_S}], got {q}")


def dataset_path(path: str | None) -> str | None:
    """``path`` when it is a dataset (a folder without a scene.toml that opens as a dataset, or a
    dataset.toml), else None."""
    from evpose.core.data.manifest import SCENE_FILENAME
    from evpose.core.dataset.dataset import DATASET_FILENAME, Dataset
    from evpose.core.errors import InputError

    if not path:
        return None
    p = Path(path).expanduser()
    if not (p.name == DATASET_FILENAME and p.is_file()) and not (p.is_dir() and not (p / SCENE_FILENAME).exists()):
        return None
    try:
        Dataset.open(p)
    except InputError:
        return None        # not a dataset either: the scene's own error says what is missing
    return str(p)


def run_gui(scene: str | None, args, start_busiest: bool = False, dataset: str | None = None) -> int:
    """Open the main window on ``scene``, or the dataset view on ``dataset`` (see :func:`evpose.app.main.run_gui`);
    exit status of the app."""
    try:
        from evpose.app.main import run_gui as run_app
    except ImportError as exc:
        raise CliError(f"the desktop app cannot start: {exc}") from None
    return run_app(scene, screenshot=getattr(args, "screenshot", None), quit_after=getattr(args, "quit_after", None),
                   start_busiest=start_busiest, dataset=dataset, at_s=getattr(args, "at", None))


@command("demo")
def cmd_demo(args) -> int:
    check_quit_after(args)
    out = Path(args.out) if args.out else default_demo_dir()
    ensure_demo_scene(out, quiet=args.quiet)
    if args.no_gui:
        print(f"demo scene ready: {out}", file=sys.stderr)
        print_info(argparse.Namespace(scene=str(out), json=False))
        return 0
    return run_gui(str(out), args, start_busiest=True)


@command("gui")
def cmd_gui(args) -> int:
    if args.at is not None and not (math.isfinite(args.at) and args.at >= 0):
        raise CliError(f"--at: expected seconds >= 0 after the first event, got {args.at}")
    check_quit_after(args)
    dataset = dataset_path(args.scene)
    return run_gui(None if dataset else args.scene, args, dataset=dataset)


def add_demo_parser(subparsers) -> None:
    """Register ``demo`` on the ``evpose`` sub-parser set."""
    s = subparsers.add_parser("demo", help="build the demo scene (if missing) and open it")
    s.add_argument("--out", help="demo scene folder (default: ~/.local/share/evpose/demo_scene)")
    s.add_argument("--no-gui", action="store_true", help="only build the scene and print its summary")
    s.add_argument("--screenshot", help="save a screenshot of the main window to this PNG")
    s.add_argument("--quit-after", type=float, help="quit the app after this many seconds")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_demo)


def add_gui_parser(subparsers) -> None:
    """Register ``gui`` on the ``evpose`` sub-parser set."""
    s = subparsers.add_parser("gui", help="open the desktop app")
    s.add_argument("scene", nargs="?", help="a scene folder (or scene.toml), or a dataset folder (or dataset.toml)")
    s.add_argument("--screenshot", help="save a screenshot of the main window (the dataset view) to this PNG")
    s.add_argument("--quit-after", type=float, help="quit the app after this many seconds")
    s.add_argument("--at", type=float, metavar="SECONDS", help="open the scene at this time: seconds after its first "
                                                               "event (as the triage report names windows)")
    s.set_defaults(func=cmd_gui)
