"""Synthetic E-POSE-like scenes with ground truth.

A DAVIS346 event camera on a robot arm moves over a table with objects. The camera follows
trajectory **A** (translation only) or **B** (translation and rotation, looking at the objects)
through random waypoints, with minimum-jerk segments that peak at the requested speed and stops
between them (the speed minima that clock synchronisation relies on). The rendered motion is
sampled finely (``motion_rate_hz``); the recorded trajectory holds its samples at the robot's
``pose_rate_hz``, so interpolating it is an approximation, as for a real arm. Frames are rendered with
the z-buffer rasteriser (Lambertian shading, procedural 3D texture on objects and table so there
are edges inside objects too), and events are simulated from the log intensity
(:mod:`core.evsim`).

The scene folder gets the *erroneous* values a user would start from (clock prior 0, object
poses with the injected error) and ``ground_truth.json`` the true ones.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from evpose.core.data.camera import CameraModel
from evpose.core.data.events import Cancelled, EventArray, EventWriter
from evpose.core.data.geometry import apply_T, inv_T, make_T
from evpose.core.data.objects import ObjectModel, box_model, cylinder_model
from evpose.core.data.os_errors import with_path
from evpose.core.data.scene import SCENE_FILENAME, ObjectSpec, SceneManifest
from evpose.core.data.trajectory import ClockModel, Trajectory
from evpose.core.label.raster import Rasterizer
from evpose.core.sim.evsim import EventSimulator, SensorParams

GROUND_TRUTH_FILENAME = "ground_truth.json"
GROUND_TRUTH_FORMAT = "evpose-ground-truth/1"
#: Pose clock origin of synthetic scenes: an epoch timestamp, so precision issues would show.
POSE_CLOCK_ORIGIN_US = 1_700_000_000_000_000
#: Where the objects stand, in the robot base frame (metres), as in E-POSE's scenes.
TABLE_CENTRE_BASE = np.array([0.0, -0.75, 0.0])
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf")


def _builtin(name: str) -> ObjectModel | None:
    if name.startswith("box"):
        return box_model(name, (0.09, 0.06, 0.15))
    if name.startswith("flatbox"):
        return box_model(name, (0.15, 0.10, 0.045))
    if name.startswith("cylinder"):
        return cylinder_model(name, radius_m=0.035, height_m=0.12)
    return None


BUILTIN_OBJECTS = ("box", "cylinder", "flatbox")


@dataclass
class SynthConfig:
    """Parameters of a synthetic scene (units in the names)."""

    objects: tuple[str, ...] = ("box", "cylinder")
    mesh_dir: str | None = None
    trajectory: str = "B"
    speed_mps: float = 0.5
    duration_s: float = 4.0
    offset_us: int = 0
    skew_ppm: float = 0.0
    pose_error_mm: float = 0.0
    pose_error_deg: float = 0.0
    seed: int = 0
    pose_rate_hz: float = 250.0      # the recorded trajectory's sample rate
    motion_rate_hz: float = 4000.0   # the rendered (true) motion's sample rate: smooth at the event time scale
    max_px_per_frame: float = 1.0
    max_frame_interval_us: int = 0   # > 0: render at least this often while moving (finer event timing)
    sensor: SensorParams = field(default_factory=SensorParams)
    camera: dict | None = None  # CameraModel.to_dict(); default DAVIS346

    def validate(self) -> None:
        if self.trajectory not in ("A", "B"):
            raise ValueError(f"trajectory: expected 'A' or 'B', got {self.trajectory!r}")
        if not (0 < self.speed_mps <= 3.0):
            raise ValueError(f"speed: expected 0 < speed <= 3 m/s, got {self.speed_mps}")
        if not (0 < self.duration_s <= 600):
            raise ValueError(f"duration: expected 0 < duration <= 600 s, got {self.duration_s}")
        if not self.objects:
            raise ValueError("objects: at least one object is needed")
        if len(set(self.objects)) != len(self.objects):
            raise ValueError(f"objects: names must be unique, got {list(self.objects)}")
        if not (0 < self.pose_rate_hz <= self.motion_rate_hz):
            raise ValueError(f"pose_rate_hz / motion_rate_hz: expected 0 < {self.pose_rate_hz} <= {self.motion_rate_hz}")
        if not self.max_px_per_frame > 0:
            raise ValueError(f"max_px_per_frame: expected > 0, got {self.max_px_per_frame}")
        if self.max_frame_interval_us < 0:
            raise ValueError(f"max_frame_interval_us: expected >= 0 (0: no limit), got {self.max_frame_interval_us}")


# ---------------------------------------------------------------------- objects
def load_objects(names, mesh_dir=None) -> list[ObjectModel]:
    """Built-in procedural objects (``box``, ``cylinder``, ``flatbox`` and numbered variants such as
    ``box2``) or meshes ``<mesh_dir>/<name>.<obj|stl|ply|...>`` in metres."""
    models = []
    for i, name in enumerate(names):
        if mesh_dir is not None:
            cands = [Path(mesh_dir) / f"{name}{s}" for s in MESH_SUFFIXES]
            found = [p for p in cands if p.is_file()]
            if not found:
                raise FileNotFoundError(f"{mesh_dir}: no mesh named {name} ({'/'.join(MESH_SUFFIXES)})")
            m = ObjectModel.from_file(found[0], name=name)
        else:
            m = _builtin(name)
            if m is None:
                raise ValueError(f"objects: unknown built-in object {name!r} (built-ins: {', '.join(BUILTIN_OBJECTS)};"
                                 " or give --mesh-dir)")
        m.class_id = i + 1
        models.append(m)
    return models


def _resting_rotation(model: ObjectModel, yaw_rad: float) -> np.ndarray:
    """Rotation that lays the object on its largest bounding-box face, then turns it by ``yaw``."""
    lo, hi = model.bbox_min_max
    up_axis = int(np.argmin(hi - lo))
    align = {0: Rotation.from_euler("y", -90, degrees=True), 1: Rotation.from_euler("x", 90, degrees=True),
             2: Rotation.identity()}[up_axis]
    return (Rotation.from_euler("z", yaw_rad) * align).as_matrix()


def place_objects(models: list[ObjectModel], rng: np.random.Generator) -> list[np.ndarray]:
    """Non-overlapping resting poses ``T_base_obj`` on the table (z = 0) around the table centre."""
    poses, discs = [], []
    for m in models:
        R = _resting_rotation(m, rng.uniform(-np.pi, np.pi))
        v = m.vertices_m @ R.T
        lo, hi = v.min(0), v.max(0)
        radius = 0.5 * float(np.hypot(*(hi - lo)[:2]))
        for attempt in range(2000):
            spread = 0.02 + 0.0002 * attempt
            xy = TABLE_CENTRE_BASE[:2] + rng.normal(scale=spread + 0.04 * (len(models) > 1), size=2)
            if all(np.hypot(*(xy - c)) >= radius + r + 0.01 for c, r in discs):
                break
        centre_xy = (lo[:2] + hi[:2]) / 2
        t = np.array([xy[0] - centre_xy[0], xy[1] - centre_xy[1], -lo[2]])
        poses.append(make_T(R, t))
        discs.append((xy, radius))
    return poses


def inject_pose_error(T_base_obj: np.ndarray, error_mm: float, error_deg: float, rng) -> np.ndarray:
    """``dT_base`` with a translation of ``error_mm`` and a rotation of ``error_deg`` about the
    object's origin, in random directions."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    R_err = Rotation.from_rotvec(axis * math.radians(error_deg)).as_matrix()
    o = T_base_obj[:3, 3]
    # rotate about the object origin, then translate: T' = dT @ T with dT = Trans(o + e) Rot Trans(-o)
    return make_T(R_err, o + direction * error_mm * 1e-3 - R_err @ o)


# ---------------------------------------------------------------------- trajectory
def _look_at(position: np.ndarray, target: np.ndarray, roll_rad: float = 0.0) -> np.ndarray:
    """Rotation ``R_base_cam`` of an OpenCV camera at ``position`` looking at ``target``."""
    z = target - position
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)
    return R @ Rotation.from_rotvec([0, 0, roll_rad]).as_matrix()


def _min_jerk(tau: np.ndarray) -> np.ndarray:
    return tau**3 * (10 - 15 * tau + 6 * tau**2)


@dataclass
class Motion:
    """The camera's motion in a synthetic scene.

    Attributes
    ----------
    recorded : Trajectory
        What the robot reports: samples of ``true`` on a regular pose clock at ``pose_rate_hz``
        (written to ``trajectory.csv``; readers interpolate it with lerp + slerp).
    true : Trajectory
        The motion that is rendered: the minimum-jerk moves sampled at ``motion_rate_hz``, so the
        image moves smoothly, as under a real arm. (Rendering the recorded samples instead makes the
        camera's speed a staircase with a step at every pose sample, and the event rate shows it: an
        artificial 4 ms ripple in the likelihood of the clock offset at 250 Hz that no real
        recording has.)
    segments : list of (int, int)
        Pose-clock start and end of each move.
    """

    recorded: Trajectory
    true: Trajectory
    segments: list


def make_motion(cfg: SynthConfig, rng: np.random.Generator, margin_s: float) -> Motion:
    """Camera motion ``T_base_cam`` on the pose clock covering ``duration + 2 margin``: moves
    between random waypoints with minimum-jerk profiles (peak speed ``speed_mps``) and dwells."""
    c = TABLE_CENTRE_BASE

    def sample_position(d_range=(0.33, 0.5)):
        d = rng.uniform(*d_range)
        el = math.radians(rng.uniform(45, 72))
        az = math.radians(90 + rng.uniform(-35, 35))
        return c + d * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])

    if cfg.trajectory == "A":
        p_mean = sample_position((0.38, 0.42))
        R_fixed = _look_at(p_mean, c)

        def waypoint():
            offs = R_fixed @ np.array([rng.uniform(-0.09, 0.09), rng.uniform(-0.06, 0.06), rng.uniform(-0.05, 0.05)])
            return p_mean + offs, R_fixed
    else:
        def waypoint():
            p = sample_position()
            return p, _look_at(p, c + rng.normal(scale=0.02, size=3), math.radians(rng.uniform(-12, 12)))

    total_s = cfg.duration_s + 2 * margin_s
    p, R = waypoint()
    t = round(margin_s * 0.7 * 1e6) * 1e-6
    knots_t, knots_p, knots_R, segments = [np.array([0.0, t])], [np.array([p, p])], [Rotation.from_matrix([R, R])], []
    while t < total_s:
        p_next, R_next = waypoint()
        length = float(np.linalg.norm(p_next - p))
        if length < 0.06:
            continue
        T_seg = 1.875 * length / cfg.speed_mps  # min-jerk peak speed = 1.875 L / T
        segments.append((t, t + T_seg))
        taus = np.linspace(0, 1, max(int(T_seg * cfg.motion_rate_hz), 2) + 1)[1:]
        # whole-µs knot times, and the profile evaluated at exactly those times (rounding after
        # evaluating would add a 0.2 % jitter to the speed between 250 µs knots)
        t_knot = np.rint((t + taus * T_seg) * 1e6) * 1e-6
        s = np.clip(_min_jerk(np.clip((t_knot - t) / T_seg, 0.0, 1.0)), 0.0, 1.0)
        knots_t.append(t_knot)
        knots_p.append(p + s[:, None] * (p_next - p))
        knots_R.append(Slerp([0.0, 1.0], Rotation.from_matrix([R, R_next]))(s))
        t = float(t_knot[-1])
        t = round((t + rng.uniform(0.15, 0.45)) * 1e6) * 1e-6     # dwell
        knots_t.append(np.array([t]))
        knots_p.append(p_next[None])
        knots_R.append(Rotation.from_matrix([R_next]))
        p, R = p_next, R_next
    kt_us = np.concatenate(knots_t) * 1e6
    kp = np.concatenate(knots_p)
    kR = Rotation.concatenate(knots_R)
    keep = np.r_[True, np.diff(np.rint(kt_us)) > 0]      # strictly increasing whole µs
    kt_us, kp, kR = np.rint(kt_us[keep]).astype(np.int64), kp[keep], kR[keep]
    true = Trajectory(kt_us + POSE_CLOCK_ORIGIN_US, kp, kR.as_quat(), source="synthetic (true motion)")
    # resample on a regular pose clock grid (a robot controller publishing at pose_rate_hz)
    dt_us = int(round(1e6 / cfg.pose_rate_hz))
    t_us = np.arange(0, int(kt_us[-1]) + 1, dt_us, dtype=np.int64)
    rots = Slerp(kt_us.astype(float), kR)(t_us.astype(float))
    pos = np.stack([np.interp(t_us, kt_us, kp[:, i]) for i in range(3)], axis=1)
    recorded = Trajectory(t_us + POSE_CLOCK_ORIGIN_US, pos, rots.as_quat(), source="synthetic")
    segs = [(POSE_CLOCK_ORIGIN_US + int(a * 1e6), POSE_CLOCK_ORIGIN_US + int(b * 1e6)) for a, b in segments]
    return Motion(recorded, true, segs)


def make_trajectory(cfg: SynthConfig, rng: np.random.Generator, margin_s: float) -> tuple[Trajectory, list]:
    """The recorded trajectory and the moves of :func:`make_motion`."""
    m = make_motion(cfg, rng, margin_s)
    return m.recorded, m.segments


# ---------------------------------------------------------------------- rendering
def _checker(p: np.ndarray, cell_m: float) -> np.ndarray:
    """0/1 checkerboard of cubes (or squares) of side ``cell_m`` over points ``(N, D)``."""
    return (np.floor(p * np.float32(1.0 / cell_m)).astype(np.int32).sum(axis=1) & 1).astype(np.float32)


class SceneRenderer:
    """Renders log intensity of the table and objects for a camera pose.

    Objects have a base albedo with a 3D checker texture (two scales), the table a coarser,
    lower-contrast checker; Lambertian shading under a fixed directional light in the base frame.
    """

    def __init__(self, camera: CameraModel, models: list[ObjectModel], T_base_obj: list[np.ndarray],
                 rng: np.random.Generator, light_base=(0.3, 0.5, 1.0)):
        self.camera = camera
        self.raster = Rasterizer(camera)
        xy = camera.pixel_rays()[0].reshape(-1, 2)
        self.rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1).astype(np.float32)  # (x, y, 1) per pixel
        self.models = models
        self.T_base_obj = [np.asarray(T) for T in T_base_obj]
        half = 1.2
        c = TABLE_CENTRE_BASE
        self.table_v = np.array([[c[0] - half, c[1] - half, 0], [c[0] + half, c[1] - half, 0],
                                 [c[0] + half, c[1] + half, 0], [c[0] - half, c[1] + half, 0]])
        self.table_f = np.array([[0, 1, 2], [0, 2, 3]])
        self.light = np.asarray(light_base, dtype=np.float64) / np.linalg.norm(light_base)
        self.normals = []
        for m in models:
            v = m.vertices_m[m.faces]
            n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
            self.normals.append((n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-15)).astype(np.float32))
        self.tex = [dict(albedo=rng.uniform(0.35, 0.7), cell=rng.uniform(0.018, 0.03), phase=rng.uniform(0, 0.05, 3),
                         R=Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()) for _ in models]

    def render(self, T_base_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Log intensity ``(H, W) float32`` and depth ``(H, W) float32`` (inf where empty)."""
        T_cam_base = inv_T(T_base_cam)
        T_cam_obj = [T_cam_base @ T for T in self.T_base_obj]
        meshes = [(apply_T(T, m.vertices_m), m.faces) for T, m in zip(T_cam_obj, self.models)]
        meshes.append((apply_T(T_cam_base, self.table_v), self.table_f))
        res = self.raster.render(meshes, want_faces=True)
        H, W = res.depth_m.shape
        intensity = np.full(H * W, 0.08, dtype=np.float32)
        obj = res.obj_index.ravel()
        depth = res.depth_m.ravel()
        face = res.face_index.ravel()
        light_cam = (T_cam_base[:3, :3] @ self.light).astype(np.float32)
        R_cb = T_cam_base[:3, :3].astype(np.float32)
        t_cb = T_cam_base[:3, 3].astype(np.float32)
        for k in range(len(meshes)):
            pix = np.flatnonzero(obj == k)
            if len(pix) == 0:
                continue
            ray = self.rays[pix]
            p_cam = ray * depth[pix, None]
            if k < len(self.models):
                T = T_cam_obj[k].astype(np.float32)
                tex = self.tex[k]
                p_obj = (p_cam - T[:3, 3]) @ T[:3, :3]  # inv(T_cam_obj) applied to camera points
                p_tex = p_obj @ tex["R"].T.astype(np.float32) + tex["phase"].astype(np.float32)
                albedo = tex["albedo"] * (0.55 + 0.9 * _checker(p_tex, tex["cell"])) * (
                    0.9 + 0.2 * _checker(p_tex, tex["cell"] / 3.1))
                n = self.normals[k][face[pix]] @ T[:3, :3].T
                lambert = n @ light_cam
                # visible back faces of open meshes: flip the normal towards the camera
                lambert = np.where(np.einsum("ij,ij->i", n, ray) > 0, -lambert, lambert)
            else:
                p_base_xy = ((p_cam - t_cb) @ R_cb)[:, :2]
                albedo = 0.4 * (0.8 + 0.4 * _checker(p_base_xy, 0.06))
                n_table = R_cb[:, 2]  # the table normal (base z) in the camera frame
                lambert = float(abs(n_table @ light_cam))
            intensity[pix] = albedo * (0.3 + 0.7 * np.clip(lambert, 0.0, None))
        return np.log(intensity + 0.02).reshape(H, W), res.depth_m


# ---------------------------------------------------------------------- scene generation
#: The simulator steps at least this often (µs), so static stretches still get sensor noise.
NOISE_STEP_US = 10_000


def _render_times(traj: Trajectory, clock: ClockModel, e0: int, e1: int, f_px: float, z_min_m: float,
                  max_px: float, max_interval_us: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Simulator steps (event-clock µs, ascending, in ``(e0, e1]``) and which of them render a frame.

    While the camera moves, frames are rendered so that the image moves at most ``max_px``
    between them (and, when ``max_interval_us`` > 0, at most that long apart); each run of motion
    gets a frame where it starts, and every noise step that falls inside a motion is rendered
    too. Otherwise the simulator would interpolate the brightness change of the next frame from
    an earlier "unchanged" step and emit the events of that interval late (by ~0.5 ms on average
    at 2 px per frame, before this was fixed) or, at a motion start, up to a noise step early.
    While the camera stands still only the noise steps (every :data:`NOISE_STEP_US`) are taken.
    """
    v, w, _ = traj.speed()
    px_per_s = f_px * (v / z_min_m + w)
    moving = px_per_s > 1e-6
    seg_ev = clock.event_time(traj.t_us)
    times = []
    for k in np.flatnonzero(moving):
        a, b = max(seg_ev[k], e0), min(seg_ev[k + 1], e1)
        if b <= a:
            continue
        n = max(1, int(math.ceil(px_per_s[k] * (b - a) * 1e-6 / max_px)))
        if max_interval_us > 0:
            n = max(n, int(math.ceil((b - a) / max_interval_us)))
        times.append(np.linspace(a, b, n + 1)[1:])
    grid = np.append(np.arange(e0 + NOISE_STEP_US, e1 + 1, NOISE_STEP_US, dtype=np.int64), np.int64(e1))
    k = np.searchsorted(seg_ev, grid, side="left") - 1       # pose interval holding each noise step
    in_motion = (k >= 0) & (k < len(moving)) & moving[np.clip(k, 0, len(moving) - 1)]
    starts = seg_ev[:-1][moving & ~np.r_[False, moving[:-1]]]  # where each run of motion begins
    render = np.unique(np.rint(np.concatenate(times + [grid[in_motion], starts])).astype(np.int64))
    render = render[(render > e0) & (render <= e1)]
    steps = np.union1d(render, grid)
    return steps, np.isin(steps, render)


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
    rng = np.random.default_rng(cfg.seed)
    camera = CameraModel.from_dict(cfg.camera, source="synth camera") if cfg.camera else CameraModel.davis346()
    models = load_objects(cfg.objects, cfg.mesh_dir)
    T_true = place_objects(models, rng)
    margin_s = max(0.3, abs(cfg.offset_us) * 1e-6 + 0.2)
    motion = make_motion(cfg, rng, margin_s)
    traj, segments = motion.recorded, motion.segments
    e0 = traj.t_first_us + int(margin_s * 1e6) - int(cfg.offset_us)
    e1 = e0 + int(round(cfg.duration_s * 1e6))
    clock_true = ClockModel(int(cfg.offset_us), float(cfg.skew_ppm), e0)
    renderer = SceneRenderer(camera, models, T_true, rng)
    sim = EventSimulator(camera.width, camera.height, cfg.sensor, rng)

    staging = StagingFolder(out_dir, "synth", "synth")
    try:
        tmp = staging.create()
    except OSError as exc:
        staging.abort()
        raise with_path(exc, out_dir, replace_temp=staging.path) from None
    try:
        (tmp / "models").mkdir()
        T0, _ = motion.true.at_event_time(np.array([e0]), clock_true)
        log0, depth0 = renderer.render(T0[0])
        z_min = float(np.percentile(depth0[np.isfinite(depth0)], 1)) if np.isfinite(depth0).any() else 0.3
        steps, is_render = _render_times(traj, clock_true, e0, e1, float(camera.K[0, 0]), max(0.1, 0.8 * z_min),
                                         cfg.max_px_per_frame, cfg.max_frame_interval_us)
        sim.reset(log0, e0)
        n_events = 0
        with EventWriter(tmp / "events.h5", time_dtype="int64", cancel=cancel) as writer:
            writer.append(EventArray(np.array([sim.hot[0] % camera.width], np.uint16),
                                     np.array([sim.hot[0] // camera.width], np.uint16),
                                     np.array([e0], np.int64), np.array([1], np.uint8)))  # first event defines t_ref
            n_events += 1
            Ts, valid = motion.true.at_event_time(steps[is_render], clock_true)
            if not valid.all():
                raise RuntimeError("internal: render time outside the trajectory")
            k_render = 0
            for i, t in enumerate(steps):
                if is_render[i]:
                    log_frame, _ = renderer.render(Ts[k_render])
                    k_render += 1
                else:
                    log_frame = None
                ev = sim.step(log_frame, int(t))
                if len(ev):
                    writer.append(ev)
                    n_events += len(ev)
                if progress is not None and (i % 50 == 0 or i == len(steps) - 1):
                    progress((i + 1) / len(steps), f"simulated {(t - e0) / 1e6:.2f} s, {n_events} events")
                if cancel is not None and cancel():
                    raise Cancelled("synthesis cancelled")

        traj.save_csv(tmp / "trajectory.csv")
        specs = []
        T_manifest, injected = [], {}
        for m, T in zip(models, T_true):
            mesh_path = tmp / "models" / f"{m.name}.ply"
            import trimesh

            trimesh.Trimesh(m.vertices_m, m.faces, process=False).export(mesh_path)
            dT = (inject_pose_error(T, cfg.pose_error_mm, cfg.pose_error_deg, rng)
                  if (cfg.pose_error_mm or cfg.pose_error_deg) else np.eye(4))
            T_wrong = dT @ T
            T_manifest.append(T_wrong)
            injected[m.name] = {"dT_base": dT.tolist(), "dt_mm": float(cfg.pose_error_mm),
                                "dR_deg": float(cfg.pose_error_deg)}
            specs.append(ObjectSpec(m.name, out_dir / "models" / mesh_path.name, T_wrong, 1.0, m.class_id, False))
        manifest = SceneManifest(out_dir / SCENE_FILENAME, out_dir.name, camera, out_dir / "events.h5",
                                 out_dir / "trajectory.csv", "cam", None, 0, 0.0, specs)
        manifest.save(tmp / SCENE_FILENAME)
        duration = (e1 - e0) / 1e6
        summary = {
            "format": GROUND_TRUTH_FORMAT,
            "clock": {"offset_us": int(cfg.offset_us), "skew_ppm": float(cfg.skew_ppm), "t_ref_us": int(e0)},
            "objects": {m.name: {"T_base_obj": T.tolist(), "class_id": m.class_id} for m, T in zip(models, T_true)},
            "injected": {"offset_us": int(cfg.offset_us), "skew_ppm": float(cfg.skew_ppm),
                         "pose_error_mm": float(cfg.pose_error_mm), "pose_error_deg": float(cfg.pose_error_deg),
                         "objects": injected},
            "moving_segments_pose_us": segments,
            "generator": {**{k: v for k, v in asdict(cfg).items() if k not in ("sensor", "camera")},
                          "objects": list(cfg.objects), "sensor": asdict(cfg.sensor), "camera": camera.to_dict()},
            "stats": {"n_events": int(n_events), "duration_s": duration, "event_rate_hz": n_events / duration,
                      "frames_rendered": int(is_render.sum()), "runtime_s": time.perf_counter() - t_start},
        }
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


def load_ground_truth(scene_dir) -> dict:
    """Read ``ground_truth.json`` of a synthetic scene (true clock and object poses)."""
    return json.loads((Path(scene_dir) / GROUND_TRUTH_FILENAME).read_text())
