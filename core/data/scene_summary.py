"""A scene's summary: the document ``evpose info --json`` prints (DESIGN section 5: at least ``name``,
``duration_s``, ``n_events``, ``t0_us``, ``t1_us``, ``n_poses``, ``objects`` and ``clock``), shared by the
single-scene command and the dataset layer (:mod:`evpose.core.dataset`).

An event-only scene (no ``[trajectory]``, no objects) has ``"events_only": true``, ``n_poses`` 0, ``trajectory``
null and ``labels`` saying so; a labelled scene has ``"events_only": false`` and ``labels`` null."""
from __future__ import annotations
from evpose.core.data.manifest import EVENTS_ONLY
from evpose.core.label.windows import DEFAULT_WINDOW_US

__all__ = ["HOLE_WINDOW_US", "scene_info"]

#: ``info`` counts the windows without a label because of trajectory holes for this tiling (the export default).
HOLE_WINDOW_US = DEFAULT_WINDOW_US


def scene_info(scene) -> dict:
    """Summary of an open :class:`~evpose.core.data.scene.Scene`; times in µs, event clock unless named."""
    ev = scene.events
    clock = scene.clock
    t0, t1 = ev.t_first_us, ev.t_last_us
    duration = 0.0 if t0 is None else (t1 - t0) * 1e-6
    objects = []
    for spec in scene.manifest.objects:
        objects.append({"name": spec.name, "class_id": spec.class_id, "mesh": str(spec.mesh),
                        "rotation_residual": spec.rotation_residual,
                        "corrected": spec.name in scene.corrections.object_deltas})
    trajectory = _trajectory_info(scene, clock, t0, t1) if scene.has_poses else None
    return {
        "name": scene.name,
        "path": str(scene.root),
        "duration_s": duration,
        "n_events": int(ev.n_events),
        "event_rate_hz": (ev.n_events / duration) if duration > 0 else 0.0,
        "t0_us": t0,
        "t1_us": t1,
        "camera": scene.camera.to_dict(),
        "events_only": trajectory is None,
        "labels": EVENTS_ONLY if trajectory is None else None,
        "n_poses": 0 if trajectory is None else trajectory.pop("n"),
        "trajectory": trajectory,
        "objects": [o["name"] for o in objects],
        "object_details": objects,
        "clock": {"offset_us": clock.offset_us, "skew_ppm": clock.skew_ppm, "t_ref_us": clock.t_ref_us,
                  "prior_offset_us": scene.manifest.clock_offset_us, "prior_skew_ppm": scene.manifest.clock_skew_ppm},
        "corrections": str(scene.corrections_path) if scene.corrections_path.exists() else None,
        "warnings": scene.manifest.warnings,
    }


def _trajectory_info(scene, clock, t0, t1) -> dict:
    """The ``trajectory`` entry of :func:`scene_info` (plus ``n``, the number of poses)."""
    traj = scene.trajectory
    holes = scene.trajectory_holes(clock, window_us=HOLE_WINDOW_US)
    # fraction of event time covered by the trajectory under the clock in effect
    if t0 is not None:
        _, valid = traj.at_event_time([t0, t1], clock)
        coverage = [bool(v) for v in valid]
    else:
        coverage = []
    pose_span_s = max((traj.t_last_us - traj.t_first_us) * 1e-6, 1e-9)
    gap_source = "scene.toml" if scene.manifest.trajectory_max_gap_us is not None else "default"
    return {"n": len(traj), "frame": scene.manifest.trajectory_frame, "t0_us": traj.t_first_us,
            "t1_us": traj.t_last_us, "rate_hz": (len(traj) - 1) / pose_span_s,
            "notes": traj.notes, "covers_first_last_event": coverage,
            "max_gap_us": traj.max_gap_us,
            "max_gap_source": gap_source,
            "holes": holes, "hole_window_us": HOLE_WINDOW_US,
            "windows_in_holes": sum(h["n_windows"] for h in holes)}
