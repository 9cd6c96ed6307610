"""A dataset: many scenes checked, corrected and exported together.

A dataset is a folder. Either its immediate subfolders that hold a ``scene.toml`` are its scenes, in
name order (hidden folders, such as the staging folder of an import in progress, are not scenes), or a ``dataset.toml`` in it lists the scenes and may give shared defaults::

    format = "evpose-dataset/1"
    name = "E-POSE"                       # optional (default: the folder's name)
    scenes = ["seq_001", "more/seq_002"]  # scene folders, relative to this file (or absolute)

    [defaults.camera]                     # tables every scene inherits where its scene.toml is silent
    width = 346
    height = 260
    K = [[...], [...], [...]]
    dist = [...]
    [defaults.trajectory]                 # frame, hand_eye, max_gap_us (never a path)
    hand_eye = [[...], ...]

Each scene keeps its own ``corrections.json``: there is no second copy of the truth. Scenes are named
by their folder's name (unique within a dataset).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

from evpose.core.data.input_files import MAX_MANIFEST_BYTES, InputFileError, open_regular
from evpose.core.data.manifest import SCENE_FILENAME
from evpose.core.errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["DATASET_FILENAME", "DATASET_FORMAT", "DatasetError", "SceneRef", "Dataset"]

DATASET_FILENAME = "dataset.toml"
DATASET_FORMAT = "evpose-dataset/1"
#: Tables and keys ``[defaults]`` may give (paths stay per scene: they travel with the scene's folder).
DEFAULT_KEYS = {"camera": {"width", "height", "K", "dist"}, "trajectory": {"frame", "hand_eye", "max_gap_us"},
                "clock": {"offset_us", "skew_ppm"}}


class DatasetError(InputError):
    """Invalid dataset input; the message names the file (or folder) and the field."""


@dataclass(frozen=True)
class SceneRef:
    """One scene of a dataset: its name (the folder's name) and its folder."""

    name: str
    path: Path


@dataclass
class Dataset:
    """The scenes of a dataset, in dataset order, and the defaults they share."""

    root: Path
    name: str
    scenes: list[SceneRef]
    defaults: dict = field(default_factory=dict)
    source: str = "folder"        # "folder" (subfolders with a scene.toml) or "dataset.toml"

    @classmethod
    def open(cls, path) -> "Dataset":
        """Read the dataset at ``path`` (its folder, or its ``dataset.toml``)."""
        path = Path(path).expanduser()
        if path.name == DATASET_FILENAME and path.is_file():
            return _from_file(path)
        if not path.is_dir():
            raise DatasetError(f"{path}: not a dataset folder (no such folder)")
        if (path / DATASET_FILENAME).is_file():
            return _from_file(path / DATASET_FILENAME)
        scenes = [SceneRef(p.name, p) for p in sorted(path.iterdir(), key=lambda p: p.name)
                  if p.is_dir() and not p.name.startswith(".") and (p / SCENE_FILENAME).is_file()]
        if not scenes:
            raise DatasetError(f"{path}: not a dataset: no {DATASET_FILENAME} and no subfolder holds a {SCENE_FILENAME}")
        return cls(path.resolve(), path.resolve().name, scenes)

    def scene(self, name: str) -> SceneRef:
        for ref in self.scenes:
            if ref.name == name:
                return ref
        raise DatasetError(f"{self.root}: no scene named {name!r}")

    def open_scene(self, ref: SceneRef, **kwargs):
        """The :class:`~evpose.core.data.scene.Scene` of ``ref`` with the dataset's defaults."""
        from evpose.core.data.scene import Scene

        return Scene.open(ref.path, defaults=self.defaults or None, **kwargs)

    def __len__(self) -> int:
        return len(self.scenes)


def _from_file(path: Path) -> Dataset:
    try:
        with open_regular(path, "rb", max_bytes=MAX_MANIFEST_BYTES) as f:
            data = tomllib.loads(f.read().decode("utf-8"))
    except InputFileError as exc:
        raise DatasetError(f"{path}: cannot read: {exc.reason}") from None
    except UnicodeDecodeError:
        raise DatasetError(f"{path}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise DatasetError(f"{path}: not valid TOML ({exc})") from None
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if data.get("format") != DATASET_FORMAT:
        raise DatasetError(f"{path}: format: expected {DATASET_FORMAT!r}, got {data.get('format')!r}")
    root = path.parent.resolve()
    name = data.get("name", root.name)
    if not isinstance(name, str) or not name:
        raise DatasetError(f"{path}: name: expected a non-empty string, got {name!r}")
    return Dataset(root, name, _scene_list(path, root, data.get("scenes")), _defaults(path, data.get("defaults", {})),
                   "dataset.toml")


def _scene_list(path: Path, root: Path, entries) -> list[SceneRef]:
    if not isinstance(entries, list) or not entries or not all(isinstance(e, str) and e for e in entries):
        raise DatasetError(f"{path}: scenes: expected a non-empty list of scene folders, got {entries!r}")
    scenes, seen = [], {}
    for k, entry in enumerate(entries):
        folder = Path(entry).expanduser()
        folder = folder if folder.is_absolute() else root / folder
        if not (folder / SCENE_FILENAME).is_file():
            raise DatasetError(f"{path}: scenes[{k}]: {folder} holds no {SCENE_FILENAME}")
        name = folder.resolve().name
        if name in seen:
            raise DatasetError(f"{path}: scenes[{k}]: a second scene named {name!r} (also scenes[{seen[name]}]); "
                               "scene folders must have distinct names")
        seen[name] = k
        scenes.append(SceneRef(name, folder.resolve()))
    return scenes


def _defaults(path: Path, table) -> dict:
    if not isinstance(table, dict):
        raise DatasetError(f"{path}: defaults: expected a table, got {table!r}")
    for key, sub in table.items():
        allowed = DEFAULT_KEYS.get(key)
        if allowed is None:
            raise DatasetError(f"{path}: defaults.{key}: not a shared table (allowed: {', '.join(DEFAULT_KEYS)})")
        if not isinstance(sub, dict):
            raise DatasetError(f"{path}: defaults.{key}: expected a table")
        for k in sub:
            if k not in allowed:
                raise DatasetError(f"{path}: defaults.{key}.{k}: not a shared field (allowed: {', '.join(sorted(allowed))})")
    return table
