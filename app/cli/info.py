"""``evpose info SCENE [--json]``: a scene's summary (DESIGN section 5: ``info --json`` has at least
``name``, ``duration_s``, ``n_events``, ``t0_us``, ``t1_us``, ``n_poses``, ``objects`` and ``clock``)."""
from __future__ import annotations

from evpose.app.cli.errors import command
from evpose.app.cli.json_output import emit

__all__ = ["add_info_parser", "cmd_info", "print_info", "info_text"]

#: Holes listed one per line in the text summary (all of them are in the JSON).
HOLES_SHOWN = 20


def info_text(info: dict) -> str:
    """The text summary of :func:`evpose.core.data.scene_summary.scene_info`'s document."""
    c, tr = info["clock"], info["trajectory"]
    lines = [
        f"scene      {info['name']}  ({info['path']})",
        f"events     {info['n_events']:,} over {info['duration_s']:.3f} s  ({info['event_rate_hz'] / 1e6:.3f} M ev/s)",
        f"           t0 {info['t0_us']} us, t1 {info['t1_us']} us (event clock)",
        f"camera     {info['camera']['width']}x{info['camera']['height']}, dist {info['camera']['dist']}",
    ]
    if tr is None:
        lines += [f"labels     {info['labels']} (evpose scene set-trajectory SCENE TRAJECTORY adds a trajectory)",
                  f"clock      offset {c['offset_us']} us, skew {c['skew_ppm']} ppm in effect "
                  f"(prior {c['prior_offset_us']} us, {c['prior_skew_ppm']} ppm)"]
        lines += [f"warning    {w}" for w in info["warnings"]]
        return "\n".join(lines)
    lines += [
        f"trajectory {info['n_poses']} poses of '{tr['frame']}' at {tr['rate_hz']:.1f} Hz,"
        f" {tr['t0_us']}..{tr['t1_us']} us (pose clock)",
        f"clock      offset {c['offset_us']} us, skew {c['skew_ppm']} ppm in effect "
        f"(prior {c['prior_offset_us']} us, {c['prior_skew_ppm']} ppm)",
        f"objects    {', '.join(info['objects']) or '(none)'}",
    ]
    if tr["holes"]:
        lines.append(f"holes      {len(tr['holes'])} in the trajectory (gaps over max_gap_us = {tr['max_gap_us']}, "
                     f"{tr['max_gap_source']}): {tr['windows_in_holes']} windows of {tr['hole_window_us'] // 1000} ms "
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
    from evpose.core.data.scene_summary import scene_info

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
