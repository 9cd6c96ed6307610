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

    [[groups]]                            # what scenes share (evpose dataset refine --joint --shared ...)
    name = "day1"                         # unique among the groups
    shared = ["hand-eye"]                 # "hand-eye" (one camera mounting), "placement" (one T_base_obj each)
    scenes = ["seq_001", "seq_002"]       # scene names (their folders' names)

A scene may be in one group per kind of shared term (a recording day's hand-eye and its scene's placement);
each scene keeps its own clock.

Each scene keeps its own ``corrections.json``: there is no second copy of the truth. Scenes are named
by their folder's name (unique within a dataset).

A scene that cannot be read -- a subfolder (or a listed folder) that is a symbolic link loop or whose link
leads nowhere, a ``scene.toml`` that is a loop, a FIFO, a device or a folder -- is never skipped: it stays
in :attr:`Dataset.scenes` with its :attr:`SceneRef.error`, and every dataset command reports it as failed
(:meth:`Dataset.open_scene` raises it, :meth:`Dataset.unreadable_failed` overrides what a worker said). A
``dataset.toml`` that is not a regular file is refused, never passed over for the subfolders.
"""
from __future__ import annotations

import os
import stat
import sys
from dataclasses import dataclass, field
from pathlib import Path

from evpose.core.data.input_files import MAX_MANIFEST_BYTES, InputFileError, describe_kind, open_regular
from evpose.core.data.manifest import SCENE_FILENAME
from evpose.core.errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["DATASET_FILENAME", "DATASET_FORMAT", "SHARED_KINDS", "DatasetError", "Group", "SceneRef", "Dataset"]

DATASET_FILENAME = "dataset.toml"
DATASET_FORMAT = "evpose-dataset/1"
#: Tables and keys ``[defaults]`` may give (paths stay per scene: they travel with the scene's folder).
DEFAULT_KEYS = {"camera": {"width", "height", "K", "dist"}, "trajectory": {"frame", "hand_eye", "max_gap_us"},
                "clock": {"offset_us", "skew_ppm"}}
#: What ``[[groups]]`` of scenes may share: the camera mounting (hand-eye) and the objects' placement (T_base_obj).
SHARED_KINDS = ("hand-eye", "placement")


class DatasetError(InputError):
    """Invalid dataset input; the message names the file (or folder) and the field."""


@dataclass(frozen=True)
class SceneRef:
    """One scene of a dataset: its name (the folder's name) and its folder; ``error``: why it cannot be
    read (None for a readable scene)."""

    name: str
    path: Path
    error: str | None = None


@dataclass(frozen=True)
class Group:
    """Scenes that share terms of the campaign fit: ``shared`` kinds of :data:`SHARED_KINDS`, ``scenes`` by name."""

    name: str
    shared: tuple
    scenes: tuple


@dataclass
class Dataset:
    """The scenes of a dataset, in dataset order, and the defaults they share."""

    root: Path
    name: str
    scenes: list[SceneRef]
    defaults: dict = field(default_factory=dict)
    source: str = "folder"        # "folder" (subfolders with a scene.toml) or "dataset.toml"
    groups: list = field(default_factory=list)     # :class:`Group` of dataset.toml's [[groups]]

    def group_of(self, name: str, kind: str) -> Group | None:
        """The group sharing ``kind`` that scene ``name`` is in (None: the scene has its own)."""
        return next((g for g in self.groups if kind in g.shared and name in g.scenes), None)

    @classmethod
    def open(cls, path) -> "Dataset":
        """Read the dataset at ``path`` (its folder, or its ``dataset.toml``)."""
        path = Path(path).expanduser()
        if path.name == DATASET_FILENAME and os.path.lexists(path) and not path.is_dir():
            return _from_file(path)
        if not path.is_dir():
            raise DatasetError(f"{path}: not a dataset folder (no such folder)")
        if os.path.lexists(path / DATASET_FILENAME):        # a FIFO or a link loop is refused, never passed over
            return _from_file(path / DATASET_FILENAME)
        scenes = []
        for p in sorted(path.iterdir(), key=lambda p: p.name):
            is_scene, error = (False, None) if p.name.startswith(".") else _probe(p)
            if is_scene:
                scenes.append(SceneRef(p.name, p, error))
        if not scenes:
            raise DatasetError(f"{path}: not a dataset: no {DATASET_FILENAME} and no subfolder holds a {SCENE_FILENAME}")
        return cls(path.resolve(), path.resolve().name, scenes)

    def only(self, names) -> "Dataset":
        """The same dataset with only the scenes named (in dataset order); an unknown name is refused."""
        names = list(names)
        known = {ref.name for ref in self.scenes}
        for n in names:
            if n not in known:
                raise DatasetError(f"{self.root}: no scene named {n!r}")
        return Dataset(self.root, self.name, [ref for ref in self.scenes if ref.name in set(names)], self.defaults,
                       self.source, self.groups)

    def scene(self, name: str) -> SceneRef:
        for ref in self.scenes:
            if ref.name == name:
                return ref
        raise DatasetError(f"{self.root}: no scene named {name!r}")

    def open_scene(self, ref: SceneRef, **kwargs):
        """The :class:`~evpose.core.data.scene.Scene` of ``ref`` with the dataset's defaults (an unreadable
        scene raises its :attr:`SceneRef.error`)."""
        from evpose.core.data.scene import Scene

        if ref.error is not None:
            raise DatasetError(ref.error)
        return Scene.open(ref.path, defaults=self.defaults or None, **kwargs)

    def input_folders(self, out=None) -> list[tuple[Path, str]]:
        """``(folder, what)`` of every folder a dataset command reads: the scenes' and the dataset's, and any
        other scene folder ``out`` is inside of (no output may land inside one:
        :func:`evpose.core.data.owned_files.check_out_path`)."""
        from evpose.core.data.owned_files import scene_folders_around

        return ([(ref.path, "the scene folder") for ref in self.scenes] + [(self.root, "the dataset folder")]
                + (scene_folders_around(out) if out is not None else []))

    def unreadable_failed(self, result):
        """``result`` (a :class:`~evpose.core.dataset.batch.BatchResult` of every scene) with each unreadable
        scene failed for its own reason (a worker that tried to open it can only say less)."""
        for ref in self.scenes:
            if ref.error is not None:
                result.scenes.pop(ref.name, None)
                result.failed[ref.name] = ref.error
        return result.ordered([ref.name for ref in self.scenes])

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
    scenes = _scene_list(path, root, data.get("scenes"))
    return Dataset(root, name, scenes, _defaults(path, data.get("defaults", {})), "dataset.toml",
                   _groups(path, data.get("groups", []), [ref.name for ref in scenes]))


def _groups(path: Path, entries, names: list) -> list:
    """``[[groups]]`` checked: each a table with a unique ``name``, ``shared`` kinds of :data:`SHARED_KINDS`
    and ``scenes`` of this dataset, no scene in two groups that share the same kind."""
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise DatasetError(f"{path}: groups: expected an array of tables ([[groups]]), got {entries!r}")
    known, out, member = set(names), [], {}
    for k, e in enumerate(entries):
        where = f"{path}: groups[{k}]"
        for key in e:
            if key not in ("name", "shared", "scenes"):
                raise DatasetError(f"{where}.{key}: not a group field (allowed: name, scenes, shared)")
        name = e.get("name")
        if not isinstance(name, str) or not name.strip():
            raise DatasetError(f"{where}.name: expected a non-empty string, got {name!r}")
        if any(g.name == name for g in out):
            raise DatasetError(f"{where}.name: a second group named {name!r}")
        shared = e.get("shared")
        if (not isinstance(shared, list) or not shared or not all(isinstance(x, str) for x in shared)
                or len(set(shared)) != len(shared)):
            raise DatasetError(f"{where}.shared: expected a list of distinct kinds from {list(SHARED_KINDS)}, "
                               f"got {shared!r}")
        for kind in shared:
            if kind not in SHARED_KINDS:
                raise DatasetError(f"{where}.shared: unknown kind {kind!r} (allowed: {', '.join(SHARED_KINDS)})")
        scenes = e.get("scenes")
        if not isinstance(scenes, list) or not scenes or not all(isinstance(x, str) for x in scenes):
            raise DatasetError(f"{where}.scenes: expected a non-empty list of scene names, got {scenes!r}")
        for x in scenes:
            if x not in known:
                raise DatasetError(f"{where}.scenes: {x!r} is not a scene of this dataset (scenes are named by "
                                   "their folders' names)")
            for kind in shared:
                if (x, kind) in member:
                    raise DatasetError(f"{where}.scenes: {x!r} is also in group {member[(x, kind)]!r}, which "
                                       f"shares {kind} too (a scene has one {kind})")
                member[(x, kind)] = name
        out.append(Group(name, tuple(shared), tuple(dict.fromkeys(scenes))))
    return out


def _scene_list(path: Path, root: Path, entries) -> list[SceneRef]:
    if not isinstance(entries, list) or not entries or not all(isinstance(e, str) and e for e in entries):
        raise DatasetError(f"{path}: scenes: expected a non-empty list of scene folders, got {entries!r}")
    scenes, seen = [], {}
    for k, entry in enumerate(entries):
        folder = Path(entry).expanduser()
        folder = folder if folder.is_absolute() else root / folder
        is_scene, error = _probe(folder)
        if not is_scene:
            raise DatasetError(f"{path}: scenes[{k}]: {folder} holds no {SCENE_FILENAME}")
        try:
            folder = folder.resolve()
        except (OSError, RuntimeError):      # a symbolic link loop: reported as the scene's error
            folder = Path(os.path.abspath(folder))
        name = folder.name
        if name in seen:
            raise DatasetError(f"{path}: scenes[{k}]: a second scene named {name!r} (also scenes[{seen[name]}]); "
                               "scene folders must have distinct names")
        seen[name] = k
        scenes.append(SceneRef(name, folder, error))
    return scenes


def _probe(folder: Path) -> tuple[bool, str | None]:
    """``(is a scene, why it cannot be read)`` of a candidate scene folder: a folder holding a
    ``scene.toml`` is a scene (error None when that is a regular file); a symbolic link that cannot be
    followed is an unreadable scene (it may have been one); anything else is not a scene."""
    def unreadable(p, exc: OSError) -> tuple[bool, str]:
        return True, f"{p}: cannot be read ({exc.strerror})"

    try:
        st = os.stat(folder)
    except FileNotFoundError:
        if not os.path.islink(folder):
            return False, None
        return True, f"{folder}: a symbolic link to {os.readlink(folder)}, which does not exist"
    except OSError as exc:
        return unreadable(folder, exc)
    if not stat.S_ISDIR(st.st_mode):
        return False, None
    manifest = folder / SCENE_FILENAME
    try:
        os.lstat(manifest)
    except FileNotFoundError:
        return False, None
    except OSError as exc:
        return unreadable(manifest, exc)
    try:
        st = os.stat(manifest)
    except OSError as exc:
        return unreadable(manifest, exc)
    if not stat.S_ISREG(st.st_mode):
        return True, f"{manifest}: is {describe_kind(st.st_mode)}, expected a regular file"
    return True, None


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
