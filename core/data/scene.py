"""Scene manifest (``scene.toml``, DESIGN section 4) and the :class:`Scene` that combines it with
the user's corrections into labels ``T_cam_obj(t)``.

Loading validates everything and raises :class:`SceneError` whose message names the file and the
field, e.g. ``scene.toml: objects[1].T_base_obj: rotation is not orthonormal (...)``. Event,
trajectory and mesh files are opened lazily, when first needed.

Paths (``events.path``, ``trajectory.path``, ``objects[i].mesh``): relative paths are relative to the
scene folder and must stay inside it (``../x`` is refused: a relative path promises that the file
travels with the folder, and a downloaded scene must not reach out to ``../../etc/passwd`` by
accident); absolute and ``~`` paths are allowed on purpose (shared model libraries, sources of
reference-mode imports; evpose itself writes files outside the folder as absolute paths). Every
path must name a regular file: folders, FIFOs and devices are refused before they are opened.
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from evpose.core.data.atomic import atomic_write_text
from evpose.core.data.camera import CameraError, CameraModel
from evpose.core.data.geometry import (
    ROTATION_TOLERANCE,
    GeometryError,
    inv_T,
    validate_T,
)
from evpose.core.data.input_files import (
    MAX_MANIFEST_BYTES,
    InputFileError,
    check_regular,
    open_regular,
)
from evpose.core.data.objects import ObjectModel, ObjectModelError, raster_friendly
from evpose.core.data.trajectory import (
    MAX_ABS_TIME_US,
    ClockModel,
    Trajectory,
    TrajectoryError,
)
from evpose.core.document.corrections import CORRECTIONS_FILENAME, Corrections
from evpose.core.errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SCENE_FORMAT = "evpose-scene/1"
#: Largest accepted clock skew prior: crystal clocks differ by tens of ppm; 10**5 ppm (10 %) is not a
#: clock drift but a wrong time unit, and much larger values overflow the clock model's µs arithmetic.
MAX_SKEW_PPM = 1e5
SCENE_FILENAME = "scene.toml"
TRAJECTORY_FRAMES = ("cam", "tcp")
_KNOWN = {
    "": {"format", "name", "camera", "events", "trajectory", "clock", "objects"},
    "camera": {"width", "height", "K", "dist"},
    "events": {"path"},
    "trajectory": {"path", "frame", "hand_eye", "max_gap_us"},
    "clock": {"offset_us", "skew_ppm"},
    "objects": {"name", "mesh", "mesh_scale", "T_base_obj", "class_id", "symmetric", "repair_rotation"},
}


class SceneError(InputError):
    """Invalid scene input; ``file`` and ``field`` say where."""

    def __init__(self, file, fld: str, message: str):
        self.file = str(file)
        self.field = fld
        super().__init__(f"{file}: {fld}: {message}" if fld else f"{file}: {message}")


@dataclass
class ObjectSpec:
    """One ``[[objects]]`` entry: where the mesh is and where the object stands in the base frame."""

    name: str
    mesh: Path
    T_base_obj: np.ndarray
    mesh_scale: float = 1.0
    class_id: int = 0
    symmetric: bool = False
    repair_rotation: bool = False
    rotation_residual: float = 0.0
    T_base_obj_raw: np.ndarray | None = None  # as written in the file (kept to write it back unchanged)


@dataclass
class SceneManifest:
    """The validated content of a ``scene.toml``."""

    path: Path
    name: str
    camera: CameraModel
    events_path: Path
    trajectory_path: Path
    trajectory_frame: str = "cam"
    hand_eye: np.ndarray | None = None  # T_tcp_cam, required when trajectory_frame == "tcp"
    clock_offset_us: int = 0
    clock_skew_ppm: float = 0.0
    objects: list[ObjectSpec] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    trajectory_max_gap_us: int | None = None  # None: derived from the sampling interval (default_max_gap_us)

    @property
    def root(self) -> Path:
        return self.path.parent

    def object(self, name: str) -> ObjectSpec:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(f"{self.path}: objects: no object named {name!r}")

    # ------------------------------------------------------------------ writing
    def to_toml_dict(self) -> dict:
        def rel(p: Path) -> str:
            try:
                return Path(os.path.abspath(p)).relative_to(os.path.abspath(self.root)).as_posix()
            except ValueError:
                return str(p)

        traj = {"path": rel(self.trajectory_path), "frame": self.trajectory_frame}
        if self.hand_eye is not None:
            traj["hand_eye"] = np.asarray(self.hand_eye).tolist()
        if self.trajectory_max_gap_us is not None:
            traj["max_gap_us"] = int(self.trajectory_max_gap_us)
        objs = []
        for o in self.objects:
            d = {"name": o.name, "mesh": rel(o.mesh), "mesh_scale": float(o.mesh_scale),
                 "T_base_obj": np.asarray(o.T_base_obj_raw if o.T_base_obj_raw is not None else o.T_base_obj).tolist(),
                 "class_id": int(o.class_id), "symmetric": bool(o.symmetric)}
            if o.repair_rotation:
                d["repair_rotation"] = True
            objs.append(d)
        return {
            "format": SCENE_FORMAT,
            "name": self.name,
            "camera": {"width": self.camera.width, "height": self.camera.height,
                       "K": self.camera.K.tolist(), "dist": self.camera.dist.tolist()},
            "events": {"path": rel(self.events_path)},
            "trajectory": traj,
            "clock": {"offset_us": int(self.clock_offset_us), "skew_ppm": float(self.clock_skew_ppm)},
            "objects": objs,
        }

    def save(self, path=None) -> Path:
        """Write the manifest atomically (default: its own path)."""
        import tomli_w

        path = Path(path) if path is not None else self.path
        return atomic_write_text(path, tomli_w.dumps(self.to_toml_dict()))


# ---------------------------------------------------------------------- loading
def _table(data: dict, key: str, file) -> dict:
    value = data.get(key)
    if value is None:
        raise SceneError(file, f"[{key}]", "missing table")
    if not isinstance(value, dict):
        raise SceneError(file, key, f"expected a table, got {type(value).__name__}")
    return value


def _number(table: dict, key: str, file, fld: str, *, integer=False, default=None, positive=False):
    if key not in table:
        if default is not None:
            return default
        raise SceneError(file, fld, "missing")
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SceneError(file, fld, f"expected a number, got {v!r}")
    if not math.isfinite(v):
        raise SceneError(file, fld, f"must be finite, got {v}")
    if integer:
        if isinstance(v, float) and not v.is_integer():
            raise SceneError(file, fld, f"expected an integer, got {v}")
        v = int(v)
    if positive and v <= 0:
        raise SceneError(file, fld, f"must be positive, got {v}")
    return v


def _path(table: dict, key: str, root: Path, file, fld: str, must_exist=True) -> Path:
    """A file path of the manifest (see the module docstring for the rule); with ``must_exist``
    it must name a regular file (checked by ``stat``: FIFOs and devices are never opened here)."""
    v = table.get(key)
    if v is None:
        raise SceneError(file, fld, "missing")
    if not isinstance(v, str) or not v or "\0" in v:
        raise SceneError(file, fld, f"expected a file path string, got {v!r}")
    p = Path(v).expanduser()
    if not p.is_absolute():
        if os.path.normpath(v).split(os.sep)[0] == os.pardir:
            raise SceneError(file, fld, f"relative path {v!r} leaves the scene folder; write it as an absolute "
                             "path if the file is meant to live outside the scene")
        p = root / p
    if must_exist:
        try:
            check_regular(p)
        except InputFileError as exc:
            raise SceneError(file, fld, str(exc)) from None
    return p


def _matrix(value, file, fld: str, **kwargs) -> tuple[np.ndarray, float]:
    try:
        return validate_T(value, fld, **kwargs)
    except GeometryError as exc:
        raise SceneError(file, "", str(exc)) from None


def _unknown_fields(data: dict, path: Path) -> list[str]:
    out = []
    for table, known in _KNOWN.items():
        if table == "objects":
            continue  # checked per entry
        content = data if table == "" else data.get(table)
        if isinstance(content, dict):
            prefix = "" if table == "" else f"{table}."
            out += [f"{path}: {prefix}{k}: unknown field (ignored)" for k in content if k not in known]
    return out


def load_manifest(path, *, check_files: bool = True) -> SceneManifest:
    """Read and validate ``scene.toml`` (``path`` may be the file or its folder).

    Parameters
    ----------
    check_files : bool
        Check that the events, trajectory and mesh files exist.
    """
    path = Path(path)
    if path.is_dir():
        path = path / SCENE_FILENAME
    if not path.exists():
        raise SceneError(path, "", "scene manifest not found (expected a scene folder or a scene.toml)")
    try:
        with open_regular(path, "rb", max_bytes=MAX_MANIFEST_BYTES) as f:
            raw = f.read()
        data = tomllib.loads(raw.decode("utf-8"))
    except InputFileError as exc:
        raise SceneError(path, "", f"cannot read the scene manifest: {exc.reason}") from None
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise SceneError(path, "", f"line {line}: not UTF-8 text") from None
    except OSError as exc:
        raise SceneError(path, "", f"cannot read ({exc.strerror or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(path, "", f"not valid TOML ({exc})") from None
    root = path.parent
    warnings = _unknown_fields(data, path)

    fmt = data.get("format")
    if fmt != SCENE_FORMAT:
        raise SceneError(path, "format", f"expected {SCENE_FORMAT!r}, got {fmt!r}")
    name = data.get("name", root.name)
    if not isinstance(name, str) or not name:
        raise SceneError(path, "name", f"expected a non-empty string, got {name!r}")

    cam_t = _table(data, "camera", path)
    width = _number(cam_t, "width", path, "camera.width", integer=True, positive=True)
    height = _number(cam_t, "height", path, "camera.height", integer=True, positive=True)
    if "K" not in cam_t:
        raise SceneError(path, "camera.K", "missing")
    try:
        camera = CameraModel(cam_t["K"], cam_t.get("dist", []), width, height, source=f"{path}: camera")
    except CameraError as exc:
        raise SceneError(path, "", str(exc).replace(f"{path}: ", "", 1)) from None

    ev_t = _table(data, "events", path)
    events_path = _path(ev_t, "path", root, path, "events.path", check_files)

    tr_t = _table(data, "trajectory", path)
    trajectory_path = _path(tr_t, "path", root, path, "trajectory.path", check_files)
    frame = tr_t.get("frame", "cam")
    if frame not in TRAJECTORY_FRAMES:
        raise SceneError(path, "trajectory.frame", f"unknown frame {frame!r} (expected one of {TRAJECTORY_FRAMES})")
    hand_eye = None
    if "hand_eye" in tr_t:
        hand_eye, _ = _matrix(tr_t["hand_eye"], path, "trajectory.hand_eye")
    elif frame == "tcp":
        raise SceneError(path, "trajectory.hand_eye", "required when trajectory.frame = \"tcp\" (T_tcp_cam, 4x4)")
    max_gap_us = None
    if "max_gap_us" in tr_t:
        max_gap_us = _number(tr_t, "max_gap_us", path, "trajectory.max_gap_us", integer=True, positive=True)
        if max_gap_us > MAX_ABS_TIME_US:
            raise SceneError(path, "trajectory.max_gap_us", f"{max_gap_us} is out of range (at most 2**53 us)")

    clk = data.get("clock", {})
    if not isinstance(clk, dict):
        raise SceneError(path, "clock", "expected a table")
    offset_us = _number(clk, "offset_us", path, "clock.offset_us", integer=True, default=0)
    if abs(offset_us) > MAX_ABS_TIME_US:
        raise SceneError(path, "clock.offset_us", f"{offset_us} is out of range (|offset_us| must be at most "
                         f"2**53 = {MAX_ABS_TIME_US} us, about 285 years)")
    skew_ppm = float(_number(clk, "skew_ppm", path, "clock.skew_ppm", default=0.0))
    if abs(skew_ppm) > MAX_SKEW_PPM:
        raise SceneError(path, "clock.skew_ppm", f"{skew_ppm} is out of range (|skew_ppm| must be at most "
                         f"{MAX_SKEW_PPM:g}; clocks of real devices differ by tens of ppm)")

    raw_objs = data.get("objects", [])
    if not isinstance(raw_objs, list):
        raise SceneError(path, "objects", "expected an array of tables ([[objects]])")
    objects: list[ObjectSpec] = []
    for i, o in enumerate(raw_objs):
        fld = f"objects[{i}]"
        if not isinstance(o, dict):
            raise SceneError(path, fld, "expected a table")
        warnings += [f"{path}: {fld}.{k}: unknown field (ignored)" for k in o if k not in _KNOWN["objects"]]
        oname = o.get("name")
        if not isinstance(oname, str) or not oname:
            raise SceneError(path, f"{fld}.name", f"expected a non-empty string, got {oname!r}")
        if any(x.name == oname for x in objects):
            raise SceneError(path, f"{fld}.name", f"duplicate object name {oname!r}")
        mesh = _path(o, "mesh", root, path, f"{fld}.mesh", check_files)
        scale = float(_number(o, "mesh_scale", path, f"{fld}.mesh_scale", default=1.0, positive=True))
        if "T_base_obj" not in o:
            raise SceneError(path, f"{fld}.T_base_obj", "missing")
        repair = o.get("repair_rotation", False)
        if not isinstance(repair, bool):
            raise SceneError(path, f"{fld}.repair_rotation", f"expected true or false, got {repair!r}")
        T, residual = _matrix(o["T_base_obj"], path, f"{fld}.T_base_obj", tolerance=ROTATION_TOLERANCE, repair=repair)
        if residual > 1e-6:
            warnings.append(f"{path}: {fld}.T_base_obj: rotation projected onto SO(3) (residual {residual:.3g})")
        class_id = _number(o, "class_id", path, f"{fld}.class_id", integer=True, default=0)
        symmetric = o.get("symmetric", False)
        if not isinstance(symmetric, bool):
            raise SceneError(path, f"{fld}.symmetric", f"expected true or false, got {symmetric!r}")
        objects.append(ObjectSpec(oname, mesh, T, scale, class_id, symmetric, repair, residual,
                                  np.asarray(o["T_base_obj"], dtype=np.float64)))

    return SceneManifest(path, name, camera, events_path, trajectory_path, frame, hand_eye,
                         offset_us, skew_ppm, objects, warnings, max_gap_us)


# ---------------------------------------------------------------------- scene
class Scene:
    """A manifest plus the user's corrections: the single source of labels.

    ``T_cam_obj(t) = inv(T_base_cam(t_pose)) @ T_base_obj`` with the corrected clock,
    hand-eye and object poses (see :mod:`core.corrections`). Events, trajectory and meshes load
    lazily and are cached.
    """

    def __init__(self, manifest: SceneManifest, corrections: Corrections | None = None):
        self.manifest = manifest
        self.corrections = corrections if corrections is not None else Corrections(scene_name=manifest.name)

    @classmethod
    def open(cls, path, *, corrections: Corrections | str | None = "auto") -> "Scene":
        """Open a scene folder or ``scene.toml``; ``corrections="auto"`` loads ``corrections.json``
        beside it when present."""
        manifest = load_manifest(path)
        if isinstance(corrections, str) and corrections == "auto":
            cpath = manifest.root / CORRECTIONS_FILENAME
            corrections = (Corrections.load(cpath, known_objects=[o.name for o in manifest.objects])
                           if cpath.exists() or cpath.is_symlink() else None)
        return cls(manifest, corrections)

    # ------------------------------------------------------------------ resources
    @property
    def name(self) -> str:
        return self.manifest.name

    @property
    def root(self) -> Path:
        return self.manifest.root

    @property
    def camera(self) -> CameraModel:
        return self.manifest.camera

    @property
    def corrections_path(self) -> Path:
        return self.root / CORRECTIONS_FILENAME

    @property
    def object_names(self) -> list[str]:
        return [o.name for o in self.manifest.objects]

    @cached_property
    def events(self):
        """The scene's :class:`~evpose.core.data.events.EventStore` (opened read-only on first use; events outside
        the camera's ``width`` x ``height`` are refused, see the store's validation)."""
        from evpose.core.data.events import EventStore

        cam = self.manifest.camera
        return EventStore(self.manifest.events_path, sensor_size=(cam.width, cam.height))

    @cached_property
    def trajectory(self) -> Trajectory:
        """The trajectory file, with holes where samples are more than ``max_gap_us`` apart
        (``[trajectory] max_gap_us``, default :func:`evpose.core.data.trajectory.default_max_gap_us`)."""
        mg = self.manifest.trajectory_max_gap_us
        try:
            return Trajectory.load_csv(self.manifest.trajectory_path, max_gap_us="auto" if mg is None else mg)
        except TrajectoryError as exc:
            raise SceneError(self.manifest.path, "trajectory.path", str(exc)) from None

    def unlabeled_reasons(self, t_event_us, clock: ClockModel | None = None) -> list[str | None]:
        """Why each event time gets no label (None where it gets one): before or after the
        trajectory, or inside a hole of it (the same test :meth:`T_base_cam` applies)."""
        return self.trajectory.reasons_at_event_time(np.atleast_1d(t_event_us), clock or self.clock)

    def trajectory_holes(self, clock: ClockModel | None = None, window_us: int = 10_000) -> list[dict]:
        """The trajectory's holes and what they cost.

        Returns one dict per hole: ``t0_pose_us``/``t1_pose_us`` (the samples around the hole, pose
        clock), ``t0_us``/``t1_us`` (the same on the event clock under ``clock``), ``gap_ms``, and
        ``n_windows``: how many windows of the recording's tiling with ``window_us`` windows
        (labels at the centre, :func:`evpose.core.label.annotate.time_windows`) have their label time in the
        hole, so get no label.
        """
        traj = self.trajectory
        clock = clock or self.clock
        ev = self.events
        out = []
        W = int(window_us)
        n_win = 0 if ev.t_first_us is None else -(-(ev.t_last_us + 1 - ev.t_first_us) // W)
        for k, (a, b) in zip(traj.hole_index, traj.holes):
            ea, eb = (int(v) for v in clock.event_time(np.array([a, b], np.int64)))
            n = 0
            if n_win:
                first = ev.t_first_us + W // 2            # label time of window 0
                j0 = min(max((ea - 2 - first) // W, 0), n_win)
                j1 = min(max((eb + 2 - first) // W + 1, 0), n_win)
                if j1 > j0:
                    labels = first + W * np.arange(j0, j1, dtype=np.int64)
                    code, seg = traj.locate_rel(clock.pose_time_rel(labels, traj.t_first_us))
                    n = int(np.count_nonzero((code == 3) & (seg == k)))
            out.append({"t0_pose_us": a, "t1_pose_us": b, "t0_us": ea, "t1_us": eb, "gap_ms": (b - a) / 1000.0,
                        "n_windows": n})
        return out

    @cached_property
    def _models(self) -> dict[str, ObjectModel]:
        return {}

    def model(self, name: str) -> ObjectModel:
        """The object's mesh in metres (loaded once)."""
        if name not in self._models:
            spec = self.manifest.object(name)
            try:
                self._models[name] = ObjectModel.from_file(spec.mesh, name=name, mesh_scale=spec.mesh_scale,
                                                           class_id=spec.class_id, symmetric=spec.symmetric)
            except ObjectModelError as exc:
                i = self.object_names.index(name)
                raise SceneError(self.manifest.path, f"objects[{i}].mesh", str(exc)) from None
        return self._models[name]

    def raster_model(self, name: str) -> ObjectModel:
        """The object's mesh for rasterising: the same surface with long edges split
        (:func:`evpose.core.data.objects.raster_friendly`; loaded once). Keypoints, boxes and masks are
        identical to :meth:`model`'s, rendering is faster for coarse CAD meshes."""
        key = ("raster", name)
        if key not in self._models:
            self._models[key] = raster_friendly(self.model(name))
        return self._models[key]

    @property
    def models(self) -> list[ObjectModel]:
        return [self.model(n) for n in self.object_names]

    def with_corrections(self, corrections: Corrections) -> "Scene":
        """A scene with other corrections that shares this one's loaded events, trajectory and
        meshes (for snapshots handed to worker threads and for previews)."""
        other = Scene(self.manifest, corrections)
        for key in ("events", "trajectory", "_models"):
            if key in self.__dict__:
                other.__dict__[key] = self.__dict__[key]
        return other

    def close(self) -> None:
        if "events" in self.__dict__:
            self.events.close()
            del self.__dict__["events"]

    # ------------------------------------------------------------------ time
    @property
    def t_ref_us(self) -> int:
        """Clock reference: the first event time (0 for a scene without events)."""
        t = self.events.t_first_us
        return 0 if t is None else int(t)

    @property
    def clock(self) -> ClockModel:
        """The clock model in effect: prior from the manifest plus the user's correction."""
        return ClockModel(self.manifest.clock_offset_us + self.corrections.offset_us,
                          self.manifest.clock_skew_ppm + self.corrections.skew_ppm, self.t_ref_us)

    def clock_with(self, offset_us: int | None = None, skew_ppm: float | None = None) -> ClockModel:
        """The clock model with an effective offset/skew substituted (for previews and fitting)."""
        c = self.clock
        return ClockModel(c.offset_us if offset_us is None else offset_us,
                          c.skew_ppm if skew_ppm is None else skew_ppm, c.t_ref_us)

    # ------------------------------------------------------------------ poses
    def T_base_cam(self, t_event_us, clock: ClockModel | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Camera poses at event times: ``(T_base_cam (N, 4, 4), valid (N,))``.

        Applies the clock model, the hand-eye calibration (for ``tcp`` trajectories) and the
        hand-eye correction. ``valid`` is False where the pose time falls outside the
        trajectory; those rows hold the identity.
        """
        T, valid = self.trajectory.at_event_time(t_event_us, clock or self.clock)
        if self.manifest.trajectory_frame == "tcp":
            T = T @ self.manifest.hand_eye
        dT = self.corrections.hand_eye_delta
        if not np.array_equal(dT, np.eye(4)):
            T = T @ dT
        T[~valid] = np.eye(4)
        return T, valid

    def T_base_obj(self, name: str) -> np.ndarray:
        """Corrected object pose in the base frame: ``dT_base @ T_base_obj``."""
        T = self.manifest.object(name).T_base_obj
        d = self.corrections.object_deltas.get(name)
        return T.copy() if d is None else d @ T

    def T_cam_obj(self, t_event_us, names=None, clock: ClockModel | None = None, *,
                  base_cam: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Object poses in the camera at event times (``base_cam``: the result of
        :meth:`T_base_cam` for the same times and clock, when the caller has it already).

        Returns
        -------
        T : (N, K, 4, 4) float64
            ``inv(T_base_cam(t)) @ T_base_obj`` for the K objects in ``names`` (default: all).
        valid : (N,) bool
            False where the pose time is outside the trajectory (those rows are identity).
        """
        names = self.object_names if names is None else list(names)
        T_bc, valid = base_cam if base_cam is not None else self.T_base_cam(np.atleast_1d(t_event_us), clock)
        T_cb = inv_T(T_bc)
        T_bo = np.stack([self.T_base_obj(n) for n in names]) if names else np.zeros((0, 4, 4))
        T = np.einsum("nij,kjl->nkil", T_cb, T_bo)
        T[~valid] = np.eye(4)
        return T, valid

    # ------------------------------------------------------------------ document
    def save_corrections(self, apply_merge=None, prefer: str | None = None) -> Path:
        """Save ``corrections.json`` beside the manifest: the one save path of the CLI and the app.

        Checks the revision on disk and merges another program's edits saved meanwhile, or refuses a
        real conflict naming the field and both values (:class:`evpose.core.document.corrections_merge.CorrectionsConflict`);
        atomic and durable; writes through a symlink. ``apply_merge(merged)`` applies merged edits to
        the document (default: directly); details in ``self.corrections.last_save``
        (see :mod:`evpose.core.document.corrections_file`)."""
        self.corrections.scene_name = self.name
        return self.corrections.save(self.corrections_path, apply_merge=apply_merge, prefer=prefer)
