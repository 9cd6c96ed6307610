"""Reading and validating a scene manifest (``scene.toml``) into a :class:`~evpose.core.data.manifest.SceneManifest`.

Every problem raises :class:`~evpose.core.data.manifest.SceneError` naming the file and the field; unknown
fields are ignored with a warning (``SceneManifest.warnings``). The tables are read in the order of the
file format (DESIGN section 4): camera, events, trajectory, clock, objects.

``[trajectory]`` is optional: a manifest without it (and without ``[[objects]]``, which need it) is an
event-only scene, opened for looking at the events; what needs poses refuses it then
(:class:`~evpose.core.data.manifest.NoPosesError`), not the reading.

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
from pathlib import Path

import numpy as np

from evpose.core.data.camera import CameraError, CameraModel
from evpose.core.data.clock import MAX_ABS_TIME_US
from evpose.core.data.geometry import ROTATION_TOLERANCE, GeometryError, validate_T
from evpose.core.data.input_files import MAX_MANIFEST_BYTES, InputFileError, check_regular, open_regular
from evpose.core.data.manifest import (
    KNOWN_FIELDS,
    MAX_SKEW_PPM,
    SCENE_FILENAME,
    SCENE_FORMAT,
    TRAJECTORY_FRAMES,
    ObjectSpec,
    SceneError,
    SceneManifest,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def load_manifest(path, *, check_files: bool = True, defaults: dict | None = None) -> SceneManifest:
    """Read and validate ``scene.toml`` (``path`` may be the file or its folder).

    Parameters
    ----------
    check_files : bool
        Check that the events, trajectory and mesh files exist.
    defaults : dict, optional
        Shared tables of a dataset (``dataset.toml``'s ``[defaults]``: ``camera``, ``trajectory``
        without ``path``, ``clock``) under the scene's own: a key the scene gives wins.
    """
    path = Path(path)
    if path.is_dir():
        path = path / SCENE_FILENAME
    if not path.exists():
        raise SceneError(path, "", "scene manifest not found (expected a scene folder or a scene.toml)")
    data = _read_toml(path)
    if defaults:
        own_trajectory = "trajectory" in data
        data = merge_defaults(defaults, data)
        if not own_trajectory:            # a dataset's shared frame / hand_eye never makes a trajectory of its own
            data.pop("trajectory", None)
    reader = _ManifestReader(path, data, check_files)
    name = reader.name()
    camera = reader.camera()
    events_path = reader.events_path()
    trajectory_path, frame, hand_eye, max_gap_us = reader.trajectory()
    offset_us, skew_ppm = reader.clock()
    objects = reader.objects()
    if trajectory_path is None and objects:
        raise SceneError(path, "[trajectory]", f"missing table: the scene has {len(objects)} object(s) "
                         f"({', '.join(o.name for o in objects)}), placed in the base frame, and they need a camera "
                         "trajectory (add [trajectory], or remove [[objects]] for an event-only scene)")
    return SceneManifest(path, name, camera, events_path, trajectory_path, frame, hand_eye,
                         offset_us, skew_ppm, objects, reader.warnings, max_gap_us)


def merge_defaults(defaults: dict, data: dict) -> dict:
    """``data`` with the tables of ``defaults`` filled in below it (one level deep: a table the scene
    gives keeps its own keys and takes the missing ones from the default)."""
    out = dict(data)
    for key, table in defaults.items():
        mine = out.get(key)
        if isinstance(table, dict) and isinstance(mine, dict):
            out[key] = {**table, **mine}
        elif key not in out:
            out[key] = table
    return out


def _read_toml(path: Path) -> dict:
    """The parsed TOML of a manifest (a regular file of bounded size, UTF-8)."""
    try:
        with open_regular(path, "rb", max_bytes=MAX_MANIFEST_BYTES) as f:
            raw = f.read()
        return tomllib.loads(raw.decode("utf-8"))
    except InputFileError as exc:
        raise SceneError(path, "", f"cannot read the scene manifest: {exc.reason}") from None
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise SceneError(path, "", f"line {line}: not UTF-8 text") from None
    except OSError as exc:
        raise SceneError(path, "", f"cannot read ({exc.strerror or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(path, "", f"not valid TOML ({exc})") from None


class _ManifestReader:
    """The sections of one parsed manifest, validated one at a time; collects the warnings."""

    def __init__(self, path: Path, data: dict, check_files: bool):
        self.path, self.root, self.data, self.check_files = path, path.parent, data, check_files
        self.warnings = _unknown_fields(data, path)

    def name(self) -> str:
        """The format tag (checked) and the scene name (default: the folder's name)."""
        path, data = self.path, self.data
        fmt = data.get("format")
        if fmt != SCENE_FORMAT:
            raise SceneError(path, "format", f"expected {SCENE_FORMAT!r}, got {fmt!r}")
        name = data.get("name", self.root.name)
        if not isinstance(name, str) or not name:
            raise SceneError(path, "name", f"expected a non-empty string, got {name!r}")
        return name

    def camera(self) -> CameraModel:
        path = self.path
        cam_t = _table(self.data, "camera", path)
        width = _number(cam_t, "width", path, "camera.width", integer=True, positive=True)
        height = _number(cam_t, "height", path, "camera.height", integer=True, positive=True)
        if "K" not in cam_t:
            raise SceneError(path, "camera.K", "missing")
        try:
            return CameraModel(cam_t["K"], cam_t.get("dist", []), width, height, source=f"{path}: camera")
        except CameraError as exc:
            raise SceneError(path, "", str(exc).replace(f"{path}: ", "", 1)) from None

    def events_path(self) -> Path:
        ev_t = _table(self.data, "events", self.path)
        return _path(ev_t, "path", self.root, self.path, "events.path", self.check_files)

    def trajectory(self) -> tuple[Path | None, str, np.ndarray | None, int | None]:
        """``(path, frame, hand_eye T_tcp_cam or None, max_gap_us or None)`` of ``[trajectory]``; a manifest
        without the table is an event-only scene: ``(None, "cam", None, None)``."""
        path = self.path
        if "trajectory" not in self.data:
            return None, "cam", None, None
        tr_t = _table(self.data, "trajectory", path)
        trajectory_path = _path(tr_t, "path", self.root, path, "trajectory.path", self.check_files)
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
        return trajectory_path, frame, hand_eye, max_gap_us

    def clock(self) -> tuple[int, float]:
        """``(offset_us, skew_ppm)`` of the optional ``[clock]`` prior."""
        path = self.path
        clk = self.data.get("clock", {})
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
        return offset_us, skew_ppm

    def objects(self) -> list[ObjectSpec]:
        raw_objs = self.data.get("objects", [])
        if not isinstance(raw_objs, list):
            raise SceneError(self.path, "objects", "expected an array of tables ([[objects]])")
        objects: list[ObjectSpec] = []
        for i, o in enumerate(raw_objs):
            objects.append(self._object(i, o, [x.name for x in objects]))
        return objects

    def _object(self, i: int, o, names_before: list[str]) -> ObjectSpec:
        """``objects[i]``; ``names_before``: the names of the entries before it (names are unique)."""
        path, fld = self.path, f"objects[{i}]"
        if not isinstance(o, dict):
            raise SceneError(path, fld, "expected a table")
        self.warnings += [f"{path}: {fld}.{k}: unknown field (ignored)" for k in o if k not in KNOWN_FIELDS["objects"]]
        oname = o.get("name")
        if not isinstance(oname, str) or not oname:
            raise SceneError(path, f"{fld}.name", f"expected a non-empty string, got {oname!r}")
        if oname in names_before:
            raise SceneError(path, f"{fld}.name", f"duplicate object name {oname!r}")
        mesh = _path(o, "mesh", self.root, path, f"{fld}.mesh", self.check_files)
        scale = float(_number(o, "mesh_scale", path, f"{fld}.mesh_scale", default=1.0, positive=True))
        if "T_base_obj" not in o:
            raise SceneError(path, f"{fld}.T_base_obj", "missing")
        repair = _flag(o, "repair_rotation", path, fld)
        T, residual = _matrix(o["T_base_obj"], path, f"{fld}.T_base_obj", tolerance=ROTATION_TOLERANCE, repair=repair)
        if residual > 1e-6:
            self.warnings.append(f"{path}: {fld}.T_base_obj: rotation projected onto SO(3) (residual {residual:.3g})")
        class_id = _number(o, "class_id", path, f"{fld}.class_id", integer=True, default=0)
        symmetric = _flag(o, "symmetric", path, fld)
        return ObjectSpec(oname, mesh, T, scale, class_id, symmetric, repair, residual,
                          np.asarray(o["T_base_obj"], dtype=np.float64))


# ---------------------------------------------------------------------- fields
def _table(data: dict, key: str, file) -> dict:
    value = data.get(key)
    if value is None:
        raise SceneError(file, f"[{key}]", "missing table")
    if not isinstance(value, dict):
        raise SceneError(file, key, f"expected a table, got {type(value).__name__}")
    return value


def _flag(table: dict, key: str, file, prefix: str) -> bool:
    """An optional boolean (default false)."""
    v = table.get(key, False)
    if not isinstance(v, bool):
        raise SceneError(file, f"{prefix}.{key}", f"expected true or false, got {v!r}")
    return v


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
    for table, known in KNOWN_FIELDS.items():
        if table == "objects":
            continue  # checked per entry
        content = data if table == "" else data.get(table)
        if isinstance(content, dict):
            prefix = "" if table == "" else f"{table}."
            out += [f"{path}: {prefix}{k}: unknown field (ignored)" for k in content if k not in known]
    return out
