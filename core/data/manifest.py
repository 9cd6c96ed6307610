"""The scene manifest (``scene.toml``, DESIGN section 4) as data: :class:`SceneManifest` and its
:class:`ObjectSpec` entries, written back with :meth:`SceneManifest.save`.

:func:`evpose.core.data.manifest_reader.load_manifest` reads and validates a manifest; every problem is a
:class:`SceneError` whose message names the file and the field, e.g. ``scene.toml: objects[1].T_base_obj:
rotation is not orthonormal (...)``.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evpose.core.data.atomic import atomic_write_text
from evpose.core.data.camera import CameraModel
from evpose.core.errors import InputError

SCENE_FORMAT = "evpose-scene/1"
#: Largest accepted clock skew prior: crystal clocks differ by tens of ppm; 10**5 ppm (10 %) is not a
#: clock drift but a wrong time unit, and much larger values overflow the clock model's µs arithmetic.
MAX_SKEW_PPM = 1e5
SCENE_FILENAME = "scene.toml"
TRAJECTORY_FRAMES = ("cam", "tcp")
#: The fields of each table ("": the top level); others are reported as unknown and ignored.
KNOWN_FIELDS = {
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


#: What ``info`` and the refusals say of a scene without ``[trajectory]`` (and so without objects).
EVENTS_ONLY = "events only: no trajectory, no objects"
#: How a trajectory is added to such a scene (README, "Event-only scenes").
ADD_TRAJECTORY_HINT = "add a trajectory with: evpose scene set-trajectory SCENE TRAJECTORY"


class NoPosesError(SceneError):
    """Poses were asked of an event-only scene (one without a ``[trajectory]`` table): raised by everything
    that needs the trajectory (labels, alignment, scores), never when the scene opens. ``str(exc)`` is one
    line naming the manifest and the missing table."""

    def __init__(self, file, what: str = "poses"):
        super().__init__(file, "[trajectory]", f"missing table: a camera trajectory is needed for {what}; this "
                         f"scene holds {EVENTS_ONLY} ({ADD_TRAJECTORY_HINT})")


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
    trajectory_path: Path | None  # None: an event-only scene (no [trajectory] table, no objects)
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

    @property
    def has_trajectory(self) -> bool:
        """The manifest has a ``[trajectory]`` table (False: an event-only scene, see :data:`EVENTS_ONLY`)."""
        return self.trajectory_path is not None

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

        traj = None
        if self.trajectory_path is not None:
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
        doc = {
            "format": SCENE_FORMAT,
            "name": self.name,
            "camera": {"width": self.camera.width, "height": self.camera.height,
                       "K": self.camera.K.tolist(), "dist": self.camera.dist.tolist()},
            "events": {"path": rel(self.events_path)},
            "trajectory": traj,
            "clock": {"offset_us": int(self.clock_offset_us), "skew_ppm": float(self.clock_skew_ppm)},
            "objects": objs,
        }
        if traj is None:              # an event-only scene: no [trajectory] table
            del doc["trajectory"]
        if not objs:                  # no `objects = []` line: [[objects]] tables can be appended by hand
            del doc["objects"]
        return doc

    def save(self, path=None) -> Path:
        """Write the manifest atomically (default: its own path)."""
        import tomli_w

        path = Path(path) if path is not None else self.path
        return atomic_write_text(path, tomli_w.dumps(self.to_toml_dict()))
