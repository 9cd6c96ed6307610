"""Synthetic E-POSE-like scenes with ground truth.

A DAVIS346 event camera on a robot arm moves over a table with objects. The camera follows
trajectory **A** (translation only) or **B** (translation and rotation, looking at the objects)
through random waypoints, with minimum-jerk segments that peak at the requested speed and stops
between them (the speed minima that clock synchronisation relies on). The rendered motion is
sampled finely (``motion_rate_hz``); the recorded trajectory holds its samples at the robot's
``pose_rate_hz``, so interpolating it is an approximation, as for a real arm. Frames are rendered with
the z-buffer rasteriser (Lambertian shading, procedural 3D texture on objects and table so there
are edges inside objects too), and events are simulated from the log intensity
(:mod:`evpose.core.sim.evsim`).

The scene folder gets the *erroneous* values a user would start from (clock prior 0, object
poses with the injected error) and ``ground_truth.json`` the true ones.

The steps live in their own modules: :mod:`~evpose.core.sim.synth_config` (parameters),
:mod:`~evpose.core.sim.synth_objects` (objects and their poses), :mod:`~evpose.core.sim.motion` (the camera's
motion), :mod:`~evpose.core.sim.renderer` (frames), :mod:`~evpose.core.sim.simulate` (the event loop); this
module builds the scene folder from them.
"""
from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from evpose.core.data.camera import CameraModel
from evpose.core.data.clock import ClockModel
from evpose.core.data.manifest import SCENE_FILENAME, ObjectSpec, SceneManifest
from evpose.core.data.objects import ObjectModel
from evpose.core.data.os_errors import with_path
from evpose.core.sim.evsim import EventSimulator
from evpose.core.sim.motion import Motion, make_motion
from evpose.core.sim.renderer import SceneRenderer
from evpose.core.sim.simulate import simulate_events
from evpose.core.sim.synth_config import SynthConfig
from evpose.core.sim.synth_objects import inject_pose_error, load_objects, place_objects

GROUND_TRUTH_FILENAME = "ground_truth.json"
GROUND_TRUTH_FORMAT = "evpose-ground-truth/1"


@dataclass
class _World:
    """Everything a run draws from its seed before anything is written (in the order the draws happen)."""

    rng: np.random.Generator
    camera: CameraModel
    models: list[ObjectModel]
    T_true: list[np.ndarray]          # true T_base_obj per object
    motion: Motion
    e0: int                           # first event time (event clock, µs): t_ref of the true clock
    e1: int
    clock_true: ClockModel
    renderer: SceneRenderer
    sim: EventSimulator
    hand_eye_error: np.ndarray        # camera mounting error E written into the trajectory (identity: none)


def _world(cfg: SynthConfig) -> _World:
    rng = np.random.default_rng(cfg.seed)
    camera = CameraModel.from_dict(cfg.camera, source="synth camera") if cfg.camera else CameraModel.davis346()
    models = load_objects(cfg.objects, cfg.mesh_dir)
    T_true = place_objects(models, rng)
    margin_s = max(0.3, abs(cfg.offset_us) * 1e-6 + 0.2)
    motion = make_motion(cfg, rng, margin_s)
    e0 = motion.recorded.t_first_us + int(margin_s * 1e6) - int(cfg.offset_us)
    e1 = e0 + int(round(cfg.duration_s * 1e6))
    clock_true = ClockModel(int(cfg.offset_us), float(cfg.skew_ppm), e0)
    renderer = SceneRenderer(camera, models, T_true, rng, texture=cfg.texture)
    sim = EventSimulator(camera.width, camera.height, cfg.sensor, rng)
    E = np.eye(4)
    if cfg.hand_eye_error_mm or cfg.hand_eye_error_deg:      # its own generator: the other draws stay as they were
        E = inject_pose_error(np.eye(4), cfg.hand_eye_error_mm, cfg.hand_eye_error_deg,
                              np.random.default_rng([cfg.seed, 7919]))
    return _World(rng, camera, models, T_true, motion, e0, e1, clock_true, renderer, sim, E)


def generate(out_dir, cfg: SynthConfig, *, overwrite: bool = False,
             progress: Callable[[float, str], None] | None = None,
             cancel: Callable[[], bool] | None = None) -> dict:
    """Simulate a scene into ``out_dir`` and return a summary (also stored in ground_truth.json).

    The folder is built beside ``out_dir`` under a hidden, locked name and renamed at the end
    (:class:`evpose.core.data.scene_folder.StagingFolder`), so a cancelled or failed run leaves nothing behind, and
    the leftovers of a killed run are removed by the next. ``overwrite`` replaces an existing scene
    folder only when it holds nothing but files evpose wrote (and not ``cfg.mesh_dir``); otherwise
    :class:`evpose.core.data.scene_folder.NotOurs` (a ``FileExistsError``) names what is in the way. A full or
    read-only disk raises ``OSError`` naming ``out_dir``.
    """
    from evpose.core.data.owned_files import input_paths
    from evpose.core.data.scene_folder import StagingFolder, check_scene_out

    cfg.validate()
    inputs = input_paths(cfg.mesh_dir)
    out_dir = check_scene_out(out_dir, inputs, overwrite)
    t_start = time.perf_counter()
    world = _world(cfg)

    staging = StagingFolder(out_dir, "synth", "synth")
    try:
        tmp = staging.create()
    except OSError as exc:
        staging.abort()
        raise with_path(exc, out_dir, replace_temp=staging.path) from None
    try:
        (tmp / "models").mkdir()
        n_events, frames_rendered = simulate_events(
            tmp / "events.h5", world.motion, world.clock_true, world.e0, world.e1, world.renderer, world.sim,
            max_px_per_frame=cfg.max_px_per_frame, max_frame_interval_us=cfg.max_frame_interval_us,
            progress=progress, cancel=cancel)
        injected = _write_scene(tmp, out_dir, cfg, world)
        summary = _ground_truth(cfg, world, injected, n_events, frames_rendered, t_start)
        (tmp / GROUND_TRUTH_FILENAME).write_text(json.dumps(summary, indent=1) + "\n")
        staging.commit(inputs, overwrite)
    except BaseException as exc:
        staging.abort()
        if isinstance(exc, OSError) and exc.errno is not None and str(exc.filename or "").startswith(str(tmp)):
            raise OSError(exc.errno, f"{exc.strerror} (while writing {Path(exc.filename).name}; nothing was written)",
                          str(out_dir)) from None
        if isinstance(exc, OSError) and exc.errno is not None and exc.filename is None:
            raise with_path(exc, out_dir) from None
        raise
    return summary


def _write_scene(tmp: Path, out_dir: Path, cfg: SynthConfig, world: _World) -> dict:
    """The trajectory, the meshes and the manifest (with the injected pose errors) into the staging folder
    ``tmp`` of ``out_dir``; returns the injected error per object."""
    import trimesh

    recorded = world.motion.recorded
    if cfg.hand_eye_error_mm or cfg.hand_eye_error_deg:
        recorded = _with_mounting_error(recorded, world.hand_eye_error)
    recorded.save_csv(tmp / "trajectory.csv")
    specs, injected = [], {}
    rng = world.rng if cfg.pose_error_seed is None else np.random.default_rng([cfg.pose_error_seed, 104729])
    for m, T in zip(world.models, world.T_true):
        mesh_path = tmp / "models" / f"{m.name}.ply"
        trimesh.Trimesh(m.vertices_m, m.faces, process=False).export(mesh_path)
        dT = (inject_pose_error(T, cfg.pose_error_mm, cfg.pose_error_deg, rng)
              if (cfg.pose_error_mm or cfg.pose_error_deg) else np.eye(4))
        T_wrong = dT @ T
        injected[m.name] = {"dT_base": dT.tolist(), "dt_mm": float(cfg.pose_error_mm),
                            "dR_deg": float(cfg.pose_error_deg)}
        specs.append(ObjectSpec(m.name, out_dir / "models" / mesh_path.name, T_wrong, 1.0, m.class_id, False))
    manifest = SceneManifest(out_dir / SCENE_FILENAME, out_dir.name, world.camera, out_dir / "events.h5",
                             out_dir / "trajectory.csv", "cam", None, 0, 0.0, specs)
    manifest.save(tmp / SCENE_FILENAME)
    return injected


def _with_mounting_error(traj, E: np.ndarray):
    """The trajectory ``T_base_cam @ E`` (a camera mounted off by ``E``, camera frame): the correction that
    undoes it is ``dT_cam = inv(E)``."""
    from evpose.core.data.trajectory import Trajectory

    return Trajectory.from_T(traj.t_us.copy(), traj.T() @ E, source=traj.source, max_gap_us=traj.max_gap_us)


def _ground_truth(cfg: SynthConfig, world: _World, injected: dict, n_events: int, frames_rendered: int,
                  t_start: float) -> dict:
    """The content of ``ground_truth.json``: true clock and poses, what was injected, the moves, the
    generator's parameters and the run's statistics."""
    duration = (world.e1 - world.e0) / 1e6
    return {
        "format": GROUND_TRUTH_FORMAT,
        "clock": {"offset_us": int(cfg.offset_us), "skew_ppm": float(cfg.skew_ppm), "t_ref_us": int(world.e0)},
        "objects": {m.name: {"T_base_obj": T.tolist(), "class_id": m.class_id}
                    for m, T in zip(world.models, world.T_true)},
        "injected": {"offset_us": int(cfg.offset_us), "skew_ppm": float(cfg.skew_ppm),
                     "pose_error_mm": float(cfg.pose_error_mm), "pose_error_deg": float(cfg.pose_error_deg),
                     "hand_eye_error_mm": float(cfg.hand_eye_error_mm),
                     "hand_eye_error_deg": float(cfg.hand_eye_error_deg), "objects": injected},
        "hand_eye": {"dT_cam": np.linalg.inv(world.hand_eye_error).tolist()},
        "moving_segments_pose_us": world.motion.segments,
        "generator": {**{k: v for k, v in asdict(cfg).items() if k not in ("sensor", "camera")},
                      "objects": list(cfg.objects), "sensor": asdict(cfg.sensor), "camera": world.camera.to_dict()},
        "stats": {"n_events": int(n_events), "duration_s": duration, "event_rate_hz": n_events / duration,
                  "frames_rendered": int(frames_rendered), "runtime_s": time.perf_counter() - t_start},
    }


def load_ground_truth(scene_dir) -> dict:
    """Read ``ground_truth.json`` of a synthetic scene (true clock and object poses)."""
    return json.loads((Path(scene_dir) / GROUND_TRUTH_FILENAME).read_text())
