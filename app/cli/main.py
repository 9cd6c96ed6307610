"""The ``evpose`` command (DESIGN section 5).

``--json`` prints exactly one JSON document on stdout; messages and progress go to stderr.
Errors name the file and the field and exit with a non-zero status (2 for bad input, 1 when the system
refuses a write or read -- full disk, read-only file system, permission --, 130 when
interrupted).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
#: The system refused a write or a read (full disk, read-only file system, permission): one line naming the path.
EXIT_OS_ERROR = 1


class CliError(Exception):
    """A user-facing error: printed without a traceback."""


def _input_errors() -> tuple[type[BaseException], ...]:
    from evpose.core.data.camera import CameraError
    from evpose.core.data.events import EventFileError
    from evpose.core.data.geometry import GeometryError
    from evpose.core.data.input_files import InputFileError
    from evpose.core.data.objects import ObjectModelError
    from evpose.core.data.scene import SceneError
    from evpose.core.data.trajectory import TrajectoryError
    from evpose.core.document.corrections import CorrectionsError
    from evpose.core.export.common import ExportError
    from evpose.core.importers.common import ImportFailure
    from evpose.core.label.annotate import WindowError

    return (CliError, SceneError, CorrectionsError, EventFileError, TrajectoryError, CameraError,
            ObjectModelError, GeometryError, ExportError, ImportFailure, FileNotFoundError, FileExistsError,
            WindowError, InputFileError)


def _progress_bar(desc: str, enabled: bool = True):
    """A tqdm bar on stderr driven by ``progress(fraction, message)`` callbacks."""
    from tqdm import tqdm

    bar = tqdm(total=1000, desc=desc, unit="‰", file=sys.stderr, disable=not enabled,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining} {postfix}")

    def update(fraction: float, message: str = "") -> None:
        bar.update(int(fraction * 1000) - bar.n)
        if message:
            bar.set_postfix_str(message, refresh=False)

    return bar, update


def _emit(args, data: dict, text: str) -> None:
    if getattr(args, "json", False):
        sys.stdout.write(json.dumps(data, indent=1, default=float) + "\n")
    else:
        sys.stdout.write(text.rstrip() + "\n")


# ---------------------------------------------------------------------- commands
def cmd_synth(args) -> int:
    from evpose.core.sim.evsim import SensorParams
    from evpose.core.sim.synth import SynthConfig, generate

    cfg = SynthConfig(
        objects=tuple(s.strip() for s in args.objects.split(",") if s.strip()),
        mesh_dir=args.mesh_dir, trajectory=args.trajectory, speed_mps=args.speed, duration_s=args.duration,
        offset_us=args.offset_us, skew_ppm=args.skew_ppm, pose_error_mm=args.pose_error_mm,
        pose_error_deg=args.pose_error_deg, seed=args.seed, sensor=SensorParams(contrast=args.contrast))
    try:
        cfg.validate()
    except ValueError as exc:
        raise CliError(str(exc)) from None
    bar, update = _progress_bar(f"synth {args.out}", not args.quiet)
    try:
        summary = generate(args.out, cfg, overwrite=args.force, progress=update)
    finally:
        bar.close()
    st = summary["stats"]
    _emit(args, {"scene": str(Path(args.out).resolve()), **summary["stats"], "ground_truth": summary["clock"]},
          f"wrote {args.out}: {st['n_events']:,} events over {st['duration_s']:.2f} s "
          f"({st['event_rate_hz'] / 1e6:.2f} M ev/s), {st['frames_rendered']} frames rendered in {st['runtime_s']:.1f} s")
    return 0


#: ``info`` counts the windows without a label because of trajectory holes for this tiling (the export default).
HOLE_WINDOW_US = 10_000


def scene_info(scene) -> dict:
    """Summary of a scene (the ``info --json`` document)."""
    ev = scene.events
    traj = scene.trajectory
    clock = scene.clock
    t0, t1 = ev.t_first_us, ev.t_last_us
    duration = 0.0 if t0 is None else (t1 - t0) * 1e-6
    objects = []
    for spec in scene.manifest.objects:
        objects.append({"name": spec.name, "class_id": spec.class_id, "mesh": str(spec.mesh),
                        "rotation_residual": spec.rotation_residual,
                        "corrected": spec.name in scene.corrections.object_deltas})
    holes = scene.trajectory_holes(clock, window_us=HOLE_WINDOW_US)
    # fraction of event time covered by the trajectory under the clock in effect
    if t0 is not None:
        _, valid = traj.at_event_time([t0, t1], clock)
        coverage = [bool(v) for v in valid]
    else:
        coverage = []
    return {
        "name": scene.name,
        "path": str(scene.root),
        "duration_s": duration,
        "n_events": int(ev.n_events),
        "event_rate_hz": (ev.n_events / duration) if duration > 0 else 0.0,
        "t0_us": t0,
        "t1_us": t1,
        "camera": scene.camera.to_dict(),
        "n_poses": len(traj),
        "trajectory": {"frame": scene.manifest.trajectory_frame, "t0_us": traj.t_first_us,
                       "t1_us": traj.t_last_us, "rate_hz": (len(traj) - 1) / max((traj.t_last_us - traj.t_first_us) * 1e-6, 1e-9),
                       "notes": traj.notes, "covers_first_last_event": coverage,
                       "max_gap_us": traj.max_gap_us,
                       "max_gap_source": "scene.toml" if scene.manifest.trajectory_max_gap_us is not None else "default",
                       "holes": holes, "hole_window_us": HOLE_WINDOW_US,
                       "windows_in_holes": sum(h["n_windows"] for h in holes)},
        "objects": [o["name"] for o in objects],
        "object_details": objects,
        "clock": {"offset_us": clock.offset_us, "skew_ppm": clock.skew_ppm, "t_ref_us": clock.t_ref_us,
                  "prior_offset_us": scene.manifest.clock_offset_us, "prior_skew_ppm": scene.manifest.clock_skew_ppm},
        "corrections": str(scene.corrections_path) if scene.corrections_path.exists() else None,
        "warnings": scene.manifest.warnings,
    }


def cmd_info(args) -> int:
    from evpose.core.data.scene import Scene

    scene = Scene.open(args.scene)
    try:
        info = scene_info(scene)
    finally:
        scene.close()
    c = info["clock"]
    lines = [
        f"scene      {info['name']}  ({info['path']})",
        f"events     {info['n_events']:,} over {info['duration_s']:.3f} s  ({info['event_rate_hz'] / 1e6:.3f} M ev/s)",
        f"           t0 {info['t0_us']} us, t1 {info['t1_us']} us (event clock)",
        f"camera     {info['camera']['width']}x{info['camera']['height']}, dist {info['camera']['dist']}",
        f"trajectory {info['n_poses']} poses of '{info['trajectory']['frame']}' at {info['trajectory']['rate_hz']:.1f} Hz,"
        f" {info['trajectory']['t0_us']}..{info['trajectory']['t1_us']} us (pose clock)",
        f"clock      offset {c['offset_us']} us, skew {c['skew_ppm']} ppm in effect "
        f"(prior {c['prior_offset_us']} us, {c['prior_skew_ppm']} ppm)",
        f"objects    {', '.join(info['objects']) or '(none)'}",
    ]
    tr = info["trajectory"]
    if tr["holes"]:
        lines.append(f"holes      {len(tr['holes'])} in the trajectory (gaps over max_gap_us = {tr['max_gap_us']}, "
                     f"{tr['max_gap_source']}): {tr['windows_in_holes']} windows of {HOLE_WINDOW_US // 1000} ms "
                     "get no label")
        for h in tr["holes"][:20]:
            lines.append(f"           [{h['t0_pose_us']}, {h['t1_pose_us']}] us pose clock = [{h['t0_us']}, {h['t1_us']}] "
                         f"us event clock: {h['gap_ms']:g} ms without a pose, {h['n_windows']} windows")
        if len(tr["holes"]) > 20:
            lines.append(f"           ... and {len(tr['holes']) - 20} more (see --json)")
    else:
        lines.append(f"holes      none (max_gap_us = {tr['max_gap_us']}, {tr['max_gap_source']})")
    lines += [f"warning    {w}" for w in info["warnings"]]
    _emit(args, info, "\n".join(lines))
    return 0


def default_demo_dir() -> Path:
    base = Path(os.environ.get("XDG_DATA_HOME", Path.home() / ".local" / "share"))
    return base / "evpose" / "demo_scene"


def ensure_demo_scene(out: Path, quiet: bool = False) -> Path:
    """Build the demo scene once (3 objects, injected clock offset and pose error)."""
    from evpose.core.sim.synth import SynthConfig, generate

    if (out / "scene.toml").is_file() and (out / "ground_truth.json").is_file():
        return out
    cfg = SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5, duration_s=3.0,
                      offset_us=35_000, skew_ppm=0.0, pose_error_mm=5.0, pose_error_deg=3.0, seed=7)
    out.parent.mkdir(parents=True, exist_ok=True)
    bar, update = _progress_bar("building demo scene (first run only)", not quiet)
    try:
        generate(out, cfg, overwrite=True, progress=update)
    finally:
        bar.close()
    return out


def cmd_demo(args) -> int:
    _check_quit_after(args)
    out = Path(args.out) if args.out else default_demo_dir()
    ensure_demo_scene(out, quiet=args.quiet)
    if args.no_gui:
        print(f"demo scene ready: {out}", file=sys.stderr)
        return cmd_info(argparse.Namespace(scene=str(out), json=False))
    return _run_gui(str(out), args, start_busiest=True)


def _run_gui(scene: str | None, args, start_busiest: bool = False) -> int:
    try:
        from evpose.app.main import run_gui
    except ImportError as exc:
        raise CliError(f"the desktop app cannot start: {exc}") from None
    return run_gui(scene, screenshot=getattr(args, "screenshot", None), quit_after=getattr(args, "quit_after", None),
                   start_busiest=start_busiest)


def _check_quit_after(args) -> None:
    q = getattr(args, "quit_after", None)
    if q is not None and not (q >= 0 and q <= 86_400):
        raise CliError(f"--quit-after: must be a number of seconds in [0, 86400], got {q}")


def cmd_gui(args) -> int:
    _check_quit_after(args)
    return _run_gui(args.scene, args)


# ---------------------------------------------------------------------- parser
class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr (``evpose CMD: error: ...``, exit 2),
    like every other evpose error; the usage is one ``--help`` away. Sub-parsers inherit the class."""

    def error(self, message: str):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="evpose", description="Verify, correct and export 6D object-pose "
                      "annotations of event-camera recordings.")
    p.add_argument("--version", action="version", version="evpose 0.1.0")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("demo", help="build the demo scene (if missing) and open it")
    s.add_argument("--out", help="demo scene folder (default: ~/.local/share/evpose/demo_scene)")
    s.add_argument("--no-gui", action="store_true", help="only build the scene and print its summary")
    s.add_argument("--screenshot", help="save a screenshot of the main window to this PNG")
    s.add_argument("--quit-after", type=float, help="quit the app after this many seconds")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_demo)

    s = sub.add_parser("synth", help="simulate an E-POSE-like scene with ground truth")
    s.add_argument("out", help="scene folder to create")
    s.add_argument("--objects", default="box,cylinder",
                   help="comma-separated names: built-ins box, cylinder, flatbox (and box2, ...) or mesh names in --mesh-dir")
    s.add_argument("--mesh-dir", help="folder with <name>.obj/.stl/.ply meshes in metres")
    s.add_argument("--trajectory", choices=("A", "B"), default="B",
                   help="A: translation only; B: translation and rotation (default)")
    s.add_argument("--speed", type=float, default=0.5, help="top speed in m/s (E-POSE: 0.1, 0.5, 1.0)")
    s.add_argument("--duration", type=float, default=4.0, help="recording length in seconds")
    s.add_argument("--offset-us", type=int, default=0, help="true clock offset (pose minus event time), us")
    s.add_argument("--skew-ppm", type=float, default=0.0, help="true clock skew, ppm")
    s.add_argument("--pose-error-mm", type=float, default=0.0, help="error injected into each T_base_obj, mm")
    s.add_argument("--pose-error-deg", type=float, default=0.0, help="rotation error injected, degrees")
    s.add_argument("--contrast", type=float, default=0.2, help="mean contrast threshold (log intensity)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--force", action="store_true", help="replace a scene folder evpose made (removes only the files it wrote; "
                   "refuses when anything else is in it)")
    s.add_argument("--json", action="store_true", help="print the summary as JSON")
    s.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=cmd_synth)

    s = sub.add_parser("info", help="summary of a scene")
    s.add_argument("scene")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_info)

    s = sub.add_parser("gui", help="open the desktop app")
    s.add_argument("scene", nargs="?")
    s.add_argument("--screenshot", help="save a screenshot of the main window to this PNG")
    s.add_argument("--quit-after", type=float, help="quit the app after this many seconds")
    s.set_defaults(func=cmd_gui)

    from evpose.app.cli.align import add_align_parsers
    from evpose.app.cli.export import add_export_parser
    from evpose.app.cli.importers import add_import_parser

    add_export_parser(sub)
    add_import_parser(sub)
    add_align_parsers(sub)
    return p


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Python warnings (e.g. an unknown object name in corrections.json) as one line on stderr."""
    print(f"evpose: warning: {message}", file=sys.stderr if file is None else file)


def main(argv=None) -> int:
    import warnings

    warnings.showwarning = _show_warning
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("evpose: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except _input_errors() as exc:
        print(f"evpose {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:          # the system refused a write or read: full disk, read-only, permission
        from evpose.core.data.os_errors import describe_os_error

        print(f"evpose {args.command}: error: {describe_os_error(exc)}", file=sys.stderr)
        return EXIT_OS_ERROR


if __name__ == "__main__":
    sys.exit(main())
