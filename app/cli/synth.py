"""``evpose synth OUT ...``: simulate an E-POSE-like scene with ground truth, and the demo scene that
``evpose demo`` opens (built once)."""
from __future__ import annotations

import os
from pathlib import Path

from evpose.app.cli.errors import CliError, command
from evpose.app.cli.json_output import emit
from evpose.app.cli.progress import Progress

__all__ = ["add_synth_parser", "cmd_synth", "default_demo_dir", "ensure_demo_scene"]


@command("synth")
def cmd_synth(args) -> int:
    objects = tuple(s.strip() for s in args.objects.split(",") if s.strip())
    if args.generator == "raycast":
        from evpose.core.sim_validation.assemble import generate

        cfg = _raycast_config(args, objects)
    else:
        from evpose.core.sim.evsim import SensorParams
        from evpose.core.sim.synth import generate
        from evpose.core.sim.synth_config import SynthConfig

        for opt in ("clutter", "profile"):
            if getattr(args, opt) is not None:
                raise CliError(f"--{opt}: only with --generator raycast")
        cfg = SynthConfig(
            objects=objects, mesh_dir=args.mesh_dir, trajectory=args.trajectory, speed_mps=args.speed,
            duration_s=args.duration, offset_us=args.offset_us, skew_ppm=args.skew_ppm,
            pose_error_mm=args.pose_error_mm, pose_error_deg=args.pose_error_deg,
            hand_eye_error_mm=args.hand_eye_error_mm, hand_eye_error_deg=args.hand_eye_error_deg, seed=args.seed,
            sensor=SensorParams(contrast=0.2 if args.contrast is None else args.contrast),
            **({} if args.pose_rate_hz is None else {"pose_rate_hz": args.pose_rate_hz}))
    try:
        cfg.validate()
    except ValueError as exc:
        raise CliError(str(exc)) from None
    with Progress(f"synth {args.out}", not args.quiet) as progress:
        summary = generate(args.out, cfg, overwrite=args.force, progress=progress)
    st = summary["stats"]
    emit(args, {"scene": str(Path(args.out).resolve()), **summary["stats"], "ground_truth": summary["clock"]},
         f"wrote {args.out}: {st['n_events']:,} events over {st['duration_s']:.2f} s "
         f"({st['event_rate_hz'] / 1e6:.2f} M ev/s), {st['frames_rendered']} frames rendered in "
         f"{st['runtime_s']:.1f} s")
    return 0


def _raycast_config(args, objects):
    """The validation-family generator's parameters (:mod:`evpose.core.sim_validation`) from the options."""
    from evpose.core.sim_validation.config import SensorModel, ValidationConfig

    return ValidationConfig(
        objects=objects, mesh_dir=args.mesh_dir, trajectory=args.trajectory, speed_mps=args.speed,
        duration_s=args.duration, offset_us=args.offset_us, skew_ppm=args.skew_ppm, pose_error_mm=args.pose_error_mm,
        pose_error_deg=args.pose_error_deg, hand_eye_error_mm=args.hand_eye_error_mm,
        hand_eye_error_deg=args.hand_eye_error_deg, seed=args.seed, clutter=args.clutter or 0,
        profile=args.profile or "mixed", pose_rate_hz=100.0 if args.pose_rate_hz is None else args.pose_rate_hz,
        sensor=SensorModel(**({} if args.contrast is None else {"contrast": args.contrast})))


def default_demo_dir() -> Path:
    """Where ``evpose demo`` keeps its scene: ``$XDG_DATA_HOME/evpose/demo_scene``."""
    base = Path(os.environ.get("XDG_DATA_HOME", Path.home() / ".local" / "share"))
    return base / "evpose" / "demo_scene"


def ensure_demo_scene(out: Path, quiet: bool = False) -> Path:
    """Build the demo scene once (3 objects, injected clock offset and pose error)."""
    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    if (out / "scene.toml").is_file() and (out / "ground_truth.json").is_file():
        return out
    cfg = SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5, duration_s=3.0,
                      offset_us=35_000, skew_ppm=0.0, pose_error_mm=5.0, pose_error_deg=3.0, seed=7)
    out.parent.mkdir(parents=True, exist_ok=True)
    with Progress("building demo scene (first run only)", not quiet) as progress:
        generate(out, cfg, overwrite=True, progress=progress)
    return out


def add_synth_parser(subparsers) -> None:
    """Register ``synth`` on the ``evpose`` sub-parser set."""
    s = subparsers.add_parser("synth", help="simulate an E-POSE-like scene with ground truth")
    s.add_argument("out", help="scene folder to create")
    s.add_argument("--objects", default="box,cylinder",
                   help="comma-separated names: built-ins box, cylinder, flatbox (and box2, ...) "
                        "or mesh names in --mesh-dir")
    s.add_argument("--mesh-dir", help="folder with <name>.obj/.stl/.ply meshes in metres")
    s.add_argument("--trajectory", choices=("A", "B"), default="B",
                   help="A: translation only; B: translation and rotation (default)")
    s.add_argument("--speed", type=float, default=0.5, help="top speed in m/s (E-POSE: 0.1, 0.5, 1.0)")
    s.add_argument("--duration", type=float, default=4.0, help="recording length in seconds")
    s.add_argument("--offset-us", type=int, default=0, help="true clock offset (pose minus event time), us")
    s.add_argument("--skew-ppm", type=float, default=0.0, help="true clock skew, ppm")
    s.add_argument("--pose-error-mm", type=float, default=0.0, help="error injected into each T_base_obj, mm")
    s.add_argument("--pose-error-deg", type=float, default=0.0, help="rotation error injected, degrees")
    s.add_argument("--hand-eye-error-mm", type=float, default=0.0,
                   help="camera mounting error written into the trajectory (camera frame), mm")
    s.add_argument("--hand-eye-error-deg", type=float, default=0.0, help="its rotation, degrees")
    s.add_argument("--contrast", type=float, help="mean contrast threshold, log intensity (default 0.2; raycast 0.25)")
    s.add_argument("--generator", choices=("raster", "raycast"), default="raster",
                   help="raster: the default simulator; raycast: the independent validation-family generator "
                        "(ray-cast lens, solid textures, clutter, level-crossing sensor with leak and shot noise)")
    s.add_argument("--pose-rate-hz", type=float, help="recorded robot pose rate (default 250; raycast 100)")
    s.add_argument("--clutter", type=int, help="raycast: distractor objects not in the manifest (default 0)")
    s.add_argument("--profile", choices=("mixed", "trapezoid", "sine", "sweep"),
                   help="raycast: the moves' speed profiles (default mixed)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--force", action="store_true", help="replace a scene folder evpose made (removes only the "
                   "files it wrote; refuses when anything else is in it)")
    s.add_argument("--json", action="store_true", help="print the summary as JSON")
    s.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=cmd_synth)
