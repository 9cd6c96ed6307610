"""The validation-family scene folder: the same layout and ``ground_truth.json`` keys as ``evpose synth``
(:mod:`evpose.core.sim.synth`), so every command and benchmark reads both, made by independent machinery.

The folder holds what a user starts from (clock prior 0, object poses with the injected errors, a trajectory
with the hand-eye error); ``ground_truth.json`` the true clock, poses and corrections, plus the distractors'
poses (not in the manifest) and the generator's parameters.
"""
from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from evpose.core.data.clock import ClockModel
from evpose.core.data.event_writer import EventWriter
from evpose.core.data.events import Cancelled, EventArray
from evpose.core.data.manifest import SCENE_FILENAME, ObjectSpec, SceneManifest
from evpose.core.data.os_errors import with_path
from evpose.core.data.trajectory import Trajectory
from evpose.core.sim_validation.config import ValidationConfig
from evpose.core.sim_validation.profiles import CameraMotion
from evpose.core.sim_validation.raycaster import Raycaster
from evpose.core.sim_validation.sensor import LevelCrossingSensor
from evpose.core.sim_validation.stepping import STATIC_PX, FrameSteps
from evpose.core.sim_validation.world import World, build_world

GROUND_TRUTH_FILENAME = "ground_truth.json"
GROUND_TRUTH_FORMAT = "evpose-ground-truth/1"
GENERATOR_NAME = "raycast"
#: Bumped whenever a change makes the same configuration and seed give a different scene (the frozen
#: validation family, ``bench/validation_family.json``, names the version its scenes were made with).
GENERATOR_VERSION = 1


def rigid_error(T_base_obj: np.ndarray, error_mm: float, error_deg: float, rng: np.random.Generator) -> np.ndarray:
    """``dT_base``: a rotation of ``error_deg`` about the object's origin (random axis), then a translation of
    ``error_mm`` (random direction), both in the base frame; the erroneous pose is ``dT_base @ T_base_obj``."""
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    R = Rotation.from_rotvec(axis / np.linalg.norm(axis) * math.radians(error_deg)).as_matrix()
    o = T_base_obj[:3, 3]
    dT = np.eye(4)
    dT[:3, :3] = R
    dT[:3, 3] = o + direction / np.linalg.norm(direction) * error_mm * 1e-3 - R @ o
    return dT


class _Run:
    """One generation: the world, the motion and the clocks, drawn from the seed in a fixed order."""

    def __init__(self, cfg: ValidationConfig):
        self.cfg = cfg
        self.rng = np.random.default_rng([cfg.seed, 0x5EED])
        self.world: World = build_world(cfg, self.rng)
        self.margin_s = 0.4 + abs(cfg.offset_us) * 1e-6
        span = 2 * self.margin_s + cfg.duration_s * (1 + abs(cfg.skew_ppm) * 1e-6) + 0.05
        self.origin_us = 1_600_000_000_000_000 + int(self.rng.integers(0, 10**14))
        self.motion = CameraMotion(cfg, self.world.target, self.rng, span, self.origin_us, self.world.obstacles)
        self.span_s = span
        self.e0 = self.origin_us + int(self.margin_s * 1e6) - int(cfg.offset_us)
        self.e1 = self.e0 + int(round(cfg.duration_s * 1e6))
        self.clock = ClockModel(int(cfg.offset_us), float(cfg.skew_ppm), self.e0)
        self.raycaster = Raycaster(self.world, cfg.supersample, self.rng, cfg.sensor.dark_level, cfg.shadows)
        cam = self.world.camera
        self.sensor = LevelCrossingSensor(cam.width, cam.height, cfg.sensor, self.rng)
        self.E = np.eye(4)
        if cfg.hand_eye_error_mm or cfg.hand_eye_error_deg:
            self.E = rigid_error(np.eye(4), cfg.hand_eye_error_mm, cfg.hand_eye_error_deg,
                                 np.random.default_rng([cfg.seed, 0xE7E]))

    def pose_at(self, t_event_us) -> np.ndarray:
        t = self.clock.pose_time_rel(np.atleast_1d(np.asarray(t_event_us, dtype=np.int64)), self.origin_us) * 1e-6
        return self.motion.poses(t)

    def boundaries(self) -> np.ndarray:
        """Event times of every move's start and end within ``(e0, e1)``, and ``e1``."""
        b = self.clock.event_time(np.array([t for seg in self.motion.segments_us for t in seg], np.int64))
        return np.unique(np.r_[b[(b > self.e0) & (b < self.e1)], self.e1])

    def simulate(self, path: Path, progress=None, cancel=None) -> tuple[int, int, int]:
        """Events of ``[e0, e1]`` into ``path``; returns ``(events, frames rendered, sensor steps)``."""
        steps = FrameSteps(self.world.camera.K, self.world.camera.dist, self.world.camera.width,
                           self.world.camera.height, self.cfg.max_px_per_frame)
        T_last = self.pose_at(self.e0)[0]
        L_prev, points = self.raycaster.render(T_last)
        self.sensor.reset(L_prev, self.e0)
        first = int(self.rng.integers(0, L_prev.size))        # the recording's first event defines t_ref
        bounds, t, dt, n_ev, frames, n_steps = self.boundaries(), self.e0, 1000, 1, 1, 0
        with EventWriter(path, time_dtype="int64", cancel=cancel) as writer:
            w = self.world.camera.width
            writer.append(EventArray(np.array([first % w], np.uint16), np.array([first // w], np.uint16),
                                     np.array([self.e0], np.int64), np.array([1], np.uint8)))
            while t < self.e1:
                nb = int(bounds[np.searchsorted(bounds, t, side="right")])
                t_next, T, disp = steps.next_step(t, dt, nb, points, T_last, lambda s: self.pose_at(s)[0])
                L_new = L_prev
                if disp >= STATIC_PX:
                    L_new, points = self.raycaster.render(T)
                    T_last, frames = T, frames + 1
                ev = self.sensor.step(L_prev, L_new, t, t_next)
                if len(ev):
                    writer.append(ev)
                    n_ev += len(ev)
                L_prev, dt, t, n_steps = L_new, t_next - t, t_next, n_steps + 1
                if progress is not None and n_steps % 50 == 0:
                    progress((t - self.e0) / (self.e1 - self.e0), f"{(t - self.e0) / 1e6:.2f} s, {n_ev} events, "
                                                                 f"{frames} frames")
                if cancel is not None and cancel():
                    raise Cancelled("synthesis cancelled")
        return n_ev, frames, n_steps

    def recorded(self) -> Trajectory:
        """The robot's poses at ``pose_rate_hz`` (jittered sample instants, no ringing), with the mounting error."""
        n = int(self.span_s * self.cfg.pose_rate_hz) + 1
        t_rel = np.rint(np.arange(n) * 1e6 / self.cfg.pose_rate_hz).astype(np.int64)
        jitter = self.rng.normal(0.0, self.cfg.pose_jitter_us, n) if self.cfg.pose_jitter_us > 0 else np.zeros(n)
        T = self.motion.poses(np.clip(t_rel + jitter, 0, None) * 1e-6, ringing=False) @ self.E
        return Trajectory.from_T(t_rel + self.origin_us, T, source="validation (recorded)")


def generate(out_dir, cfg: ValidationConfig, *, overwrite: bool = False,
             progress: Callable[[float, str], None] | None = None,
             cancel: Callable[[], bool] | None = None) -> dict:
    """Simulate a validation scene into ``out_dir`` and return its ground truth (also in ``ground_truth.json``).

    Built in a locked staging folder and swapped in at the end, with the same guarantees as
    :func:`evpose.core.sim.synth.generate` (nothing left behind on cancel or failure; ``overwrite`` replaces
    only a folder evpose wrote).
    """
    from evpose.core.data.owned_files import input_paths
    from evpose.core.data.scene_folder import StagingFolder, check_scene_out

    cfg.validate()
    inputs = input_paths(cfg.mesh_dir)
    out_dir = check_scene_out(out_dir, inputs, overwrite)
    t_start = time.perf_counter()
    run = _Run(cfg)
    staging = StagingFolder(out_dir, "synth", "synth")
    try:
        tmp = staging.create()
    except OSError as exc:
        staging.abort()
        raise with_path(exc, out_dir, replace_temp=staging.path) from None
    try:
        (tmp / "models").mkdir()
        n_ev, frames, n_steps = run.simulate(tmp / "events.h5", progress, cancel)
        run.recorded().save_csv(tmp / "trajectory.csv")
        injected = _write_manifest(tmp, out_dir, run)
        summary = _ground_truth(run, injected, n_ev, frames, n_steps, time.perf_counter() - t_start)
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


def _write_manifest(tmp: Path, out_dir: Path, run: _Run) -> dict:
    import trimesh

    cfg, specs, injected = run.cfg, [], {}
    err_rng = np.random.default_rng([cfg.seed, 0x0B1])
    for m, T in zip(run.world.models, run.world.T_true):
        mesh_path = tmp / "models" / f"{m.name}.ply"
        trimesh.Trimesh(m.vertices_m, m.faces, process=False).export(mesh_path)
        dT = (rigid_error(T, cfg.pose_error_mm, cfg.pose_error_deg, err_rng)
              if (cfg.pose_error_mm or cfg.pose_error_deg) else np.eye(4))
        injected[m.name] = {"dT_base": dT.tolist(), "dt_mm": float(cfg.pose_error_mm),
                            "dR_deg": float(cfg.pose_error_deg)}
        specs.append(ObjectSpec(m.name, out_dir / "models" / mesh_path.name, dT @ T, 1.0, m.class_id, False))
    SceneManifest(out_dir / SCENE_FILENAME, out_dir.name, run.world.camera, out_dir / "events.h5",
                  out_dir / "trajectory.csv", "cam", None, 0, 0.0, specs).save(tmp / SCENE_FILENAME)
    return injected


def _ground_truth(run: _Run, injected: dict, n_ev: int, frames: int, n_steps: int, runtime_s: float) -> dict:
    cfg, w = run.cfg, run.world
    duration = (run.e1 - run.e0) / 1e6
    gen = {k: v for k, v in asdict(cfg).items() if k not in ("camera", "sensor")}
    return {
        "format": GROUND_TRUTH_FORMAT,
        "clock": {"offset_us": int(cfg.offset_us), "skew_ppm": float(cfg.skew_ppm), "t_ref_us": int(run.e0)},
        "objects": {m.name: {"T_base_obj": T.tolist(), "class_id": m.class_id, "mesh_source": m.source}
                    for m, T in zip(w.models, w.T_true)},
        "injected": {"offset_us": int(cfg.offset_us), "skew_ppm": float(cfg.skew_ppm),
                     "pose_error_mm": float(cfg.pose_error_mm), "pose_error_deg": float(cfg.pose_error_deg),
                     "hand_eye_error_mm": float(cfg.hand_eye_error_mm),
                     "hand_eye_error_deg": float(cfg.hand_eye_error_deg), "objects": injected},
        "hand_eye": {"dT_cam": np.linalg.inv(run.E).tolist()},
        "moving_segments_pose_us": run.motion.segments_us,
        "clutter": {name: {"T_base_obj": T.tolist()} for name, T in w.clutter},
        "generator": {**gen, "name": GENERATOR_NAME, "version": GENERATOR_VERSION, "objects": list(cfg.objects),
                      "sensor": asdict(cfg.sensor),
                      "camera": w.camera.to_dict(),
                      "moves": [{"kind": m.kind, "path": m.path[0], "t0_s": m.t0, "duration_s": m.T}
                                for m in run.motion.moves]},
        "stats": {"n_events": int(n_ev), "duration_s": duration, "event_rate_hz": n_ev / duration,
                  "frames_rendered": int(frames), "sensor_steps": int(n_steps), "runtime_s": runtime_s},
    }


def load_ground_truth(scene_dir) -> dict:
    """Read ``ground_truth.json`` of a generated scene."""
    return json.loads((Path(scene_dir) / GROUND_TRUTH_FILENAME).read_text())
