"""``evpose info SCENE [--json]``: a scene's summary (DESIGN section 5: ``info --json`` has at least
``name``, ``duration_s``, ``n_events``, ``t0_us``, ``t1_us``, ``n_poses``, ``objects`` and ``clock``)."""
from __future__ import annotations

from evpose.app.cli.errors import command
from evpose.app.cli.json_output import emit

__all__ = ["add_info_parser", "cmd_info", "print_info", "scene_info", "info_text", "HOLE_WINDOW_US"]

#: ``info`` counts the windows without a label because of trajectory holes for this tiling (the export default).
HOLE_WINDOW_US = 10_000
#: Holes listed one per line in the text summary (all of them are in the JSON).
HOLES_SHOWN = 20


def scene_info(scene) -> dict:
    """Summary of a scene (the ``info --json`` document); times in µs, event clock unless named."""
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
    pose_span_s = max((traj.t_last_us - traj.t_first_us) * 1e-6, 1e-9)
    gap_source = "scene.toml" if scene.manifest.trajectory_max_gap_us is not None else "default"
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
                       "t1_us": traj.t_last_us, "rate_hz": (len(traj) - 1) / pose_span_s,
                       "notes": traj.notes, "covers_first_last_event": coverage,
                       "max_gap_us": traj.max_gap_us,
                       "max_gap_source": gap_source,
                       "holes": holes, "hole_window_us": HOLE_WINDOW_US,
                       "windows_in_holes": sum(h["n_windows"] for h in holes)},
        "objects": [o["name"] for o in objects],
        "object_details": objects,
        "clock": {"offset_us": clock.offset_us, "skew_ppm": clock.skew_ppm, "t_ref_us": clock.t_ref_us,
                  "prior_offset_us": scene.manifest.clock_offset_us, "prior_skew_ppm": scene.manifest.clock_skew_ppm},
        "corrections": str(scene.corrections_path) if scene.corrections_path.exists() else None,
        "warnings": scene.manifest.warnings,
    }


def info_text(info: dict) -> str:
    """The text summary of :func:`scene_info`'s document."""
    c, tr = info["clock"], info["trajectory"]
    lines = [
        f"scene      {info['name']}  ({info['path']})",
        f"events     {info['n_events']:,} over {info['duration_s']:.3f} s  ({info['event_rate_hz'] / 1e6:.3f} M ev/s)",
        f"           t0 {info['t0_us']} us, t1 {info['t1_us']} us (event clock)",
        f"camera     {info['camera']['width']}x{info['camera']['height']}, dist {info['camera']['dist']}",
        f"trajectory {info['n_poses']} poses of '{tr['frame']}' at {tr['rate_hz']:.1f} Hz,"
        f" {tr['t0_us']}..{tr['t1_us']} us (pose clock)",
        f"clock      offset {c['offset_us']} us, skew {c['skew_ppm']} ppm in effect "
        f"(prior {c['prior_offset_us']} us, {c['prior_skew_ppm']} ppm)",
        f"objects    {', '.join(info['objects']) or '(none)'}",
    ]
    if tr["holes"]:
        lines.append(f"holes      {len(tr['holes'])} in the trajectory (gaps over max_gap_us = {tr['max_gap_us']}, "
                     f"{tr['max_gap_source']}): {tr['windows_in_holes']} windows of {HOLE_WINDOW_US // 1000} ms "
                     "get no label")
        for h in tr["holes"][:HOLES_SHOWN]:
            lines.append(f"           [{h['t0_pose_us']}, {h['t1_pose_us']}] us pose clock = "
                         f"[{h['t0_us']}, {h['t1_us']}] us event clock: {h['gap_ms']:g} ms without a pose, "
                         f"{h['n_windows']} windows")
        if len(tr["holes"]) > HOLES_SHOWN:
            lines.append(f"           ... and {len(tr['holes']) - HOLES_SHOWN} more (see --json)")
    else:
        lines.append(f"holes      none (max_gap_us = {tr['max_gap_us']}, {tr['max_gap_source']})")
    lines += [f"warning    {w}" for w in info["warnings"]]
    return "\n".join(lines)


def print_info(args) -> None:
    """Open ``args.scene`` and print its summary (JSON with ``args.json``)."""
    from evpose.core.data.scene import Scene

    scene = Scene.open(args.scene)
    try:
        info = scene_info(scene)
    finally:
        scene.close()
    emit(args, info, info_text(info))


@command("info")
def cmd_info(args) -> int:
    print_info(args)
    return 0


def add_info_parser(subparsers) -> None:
    """Register ``info`` on the ``evpose`` sub-parser set."""
    s = subparsers.add_parser("info", help="summary of a scene")
    s.add_argument("scene")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_info)
