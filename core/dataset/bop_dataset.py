"""One BOP dataset from the scenes' BOP exports (``OUT/bop``, see :mod:`evpose.core.dataset.export`).

Every scene's export ``OUT/<name>`` holds its scene as ``SPLIT/000000`` (scene id 0; ``SPLIT`` the
export's split folder, ``test`` unless chosen, the same for every scene). Scene ``k`` of the dataset
(dataset order, counting failed scenes too, so ids stay stable when one scene fails) becomes
``OUT/bop/SPLIT/{k:06d}``; its files are hard links to ``OUT/<name>/SPLIT/000000/...``, so the BOP dataset
costs no disk space and holds exactly the bytes of the per-scene exports, in the same conventions
(:mod:`evpose.core.export.bop`: BOP pixel origin in ``cam_K``, calc_gt_info's ``scene_gt_info``, models
with normals). ``models/`` holds each ``obj_id`` once: the same ``obj_id`` in two scenes must have
byte-identical models (the same class id names the same object). :func:`check_models` refuses scenes that
break this before any scene is exported (from the manifests; the assembly checks the bytes again).
``test_targets_bop19.json`` and ``test_targets_bop24.json`` are the scenes' targets with ``scene_id`` set
to ``k``. ``camera.json`` is the first scene's (BOP's per-image ``cam_K`` in ``scene_camera.json`` is what
counts). ``scene_names.json`` maps scene id to scene name and lists the missing scenes and the files.
Scenes exported with shards (``--bop-shards``) bring ``SPLIT_web/shard-*.tar``: linked as ``OUT/bop/SPLIT_web/``
numbered on scene after scene, with one merged ``key_to_shard.json`` (the keys carry the dataset's scene ids).

All or nothing
--------------
The dataset is assembled in a hidden staging folder ``OUT/.bop.assemble-<pid>-<tag>`` (locked while
written), every file logged in its ownership log (:mod:`evpose.core.data.owned_log`, role ``"bop"``), and
renamed into place only when complete; the previous ``OUT/bop`` is moved aside meanwhile
(``OUT/.bop.replaced-<pid>-<tag>``) and then removed. A refused merge leaves ``OUT/bop`` as it was (or
absent). The next run removes what a killed run left (the staging folder of a dead process; a moved-aside
dataset is put back when ``OUT/bop`` is missing). An earlier ``OUT/bop`` is replaced when all of it is
evpose's: logged files unchanged, or -- assemblies written before the log -- files its ``scene_names.json``
lists and hard links of the scene exports' own files (still the same file, or with the size and modification
time the export's log recorded); anything else refuses the run, naming it.

A scene that the previous complete ``OUT/bop`` holds and that fails now is not dropped: the merge is
refused with the reason and the previous dataset kept, whole. A scene that failed and was never merged is
left out, its id unused, and listed under ``missing``.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import secrets
import shutil
import stat
from pathlib import Path
from types import SimpleNamespace

from evpose.core.data import atomic
from evpose.core.data.atomic import write_atomic
from evpose.core.data.input_files import describe_kind
from evpose.core.data.owned_files import Inventory, inventory, remove_owned
from evpose.core.data.owned_log import STATE_DIR, read_logs, record_tree
from evpose.core.data.temp_files import is_stale
from evpose.core.errors import InputError
from evpose.core.export.bop import dump_list
from evpose.core.export.bop_conventions import TARGETS_BOP19, TARGETS_BOP24
from evpose.core.export.bop_shards import KEY_TO_SHARD, json_member, shard_name, web_dir_name
from evpose.core.export.out_folder import EXPORT_ROLE, lock_folder

__all__ = ["BopAssemblyError", "assemble_bop", "check_models", "read_names", "scene_split", "BOP_DIR", "BOP_ROLE",
           "NAMES_FILE"]

BOP_DIR = "bop"
NAMES_FILE = "scene_names.json"
SCENE_SUBDIR = "000000"          # where a single-scene BOP export puts its scene (scene_id 0)
#: Role of the merged dataset's ownership log (a scene's or an export's log proves nothing there).
BOP_ROLE = "bop"
#: Beside ``OUT/bop``: a staging folder, or an earlier dataset moved aside while the new one is renamed in.
_SIDE_RE = re.compile(rf"^\.{BOP_DIR}\.(?P<kind>assemble|replaced)-(?P<pid>\d+)-[0-9a-f]+$")


class BopAssemblyError(InputError):
    """The scenes' BOP exports cannot form one dataset (conflicting models, foreign files, a lost scene)."""


# ------------------------------------------------------------------------------------------- assembly
def assemble_bop(out_dir, names: list[str], done: list[str]) -> Path:
    """Build ``out_dir/bop`` from the BOP exports ``out_dir/<name>`` of the scenes in ``done``
    (``names``: all scenes in dataset order, which fixes the scene ids). Returns the folder. All or
    nothing: on any error ``out_dir/bop`` is left as it was (see the module docstring)."""
    out_dir = Path(out_dir)
    bop = out_dir / BOP_DIR
    if not done:
        raise BopAssemblyError(f"{bop}: not assembled: no scene could be exported")
    lock = lock_folder(out_dir)          # one assembly at a time into OUT
    try:
        _clean_side_folders(out_dir, names)
        held = _previous_scenes(bop, out_dir, names)
        lost = [n for n in names if n in held and n not in done]
        if lost:
            which = ", ".join(map(repr, lost))
            raise BopAssemblyError(f"{bop}: kept as it was: it holds scene(s) {which}, which could not be exported "
                                   f"now, and a merge without them would lose them; fix them and rerun (or remove "
                                   f"{bop} to merge without them)")
        stage = out_dir / f".{BOP_DIR}.assemble-{os.getpid()}-{secrets.token_hex(4)}"
        stage.mkdir()
        fd = _lock_dir(stage)
        try:
            _build(stage, out_dir, names, done)
            record_tree(stage, BOP_ROLE, "dataset export bop")
            atomic.sync_filesystem(stage)    # every file on disk before the rename
            _swap(stage, bop, out_dir, names)
        except BaseException:
            shutil.rmtree(stage, ignore_errors=True)
            raise
        finally:
            os.close(fd)
    finally:
        os.close(lock)
    return bop


def _lock_dir(path: Path) -> int:
    """An open descriptor holding a ``flock`` on the folder (a live staging folder is never cleaned)."""
    import fcntl

    fd = os.open(path, os.O_RDONLY)
    with contextlib.suppress(OSError):
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return fd


def _build(stage: Path, out_dir: Path, names: list[str], done: list[str]) -> None:
    """The dataset's files into ``stage`` (links to the scene exports, the merged targets, the names)."""
    files: list[str] = []
    model_from: dict[str, str] = {}
    targets: dict[str, list] = {TARGETS_BOP19: [], TARGETS_BOP24: []}
    split = None
    shards = _Shards()
    for k, name in enumerate(names):
        if name not in done:
            continue
        src = out_dir / name
        sp = scene_split(src)
        if split is not None and sp != split:
            raise BopAssemblyError(f"{src}: split {sp!r} differs from the other scenes' {split!r}")
        split = sp
        _link_models(src, stage, name, model_from, files)
        for p in sorted((src / split / SCENE_SUBDIR).rglob("*")):
            if p.is_file():
                rel = f"{split}/{k:06d}/{p.relative_to(src / split / SCENE_SUBDIR)}"
                _link(p, stage / rel)
                files.append(rel)
        shards.add(src, split, k, stage, files)
        for fname, lst in targets.items():
            lst += [{**e, "scene_id": k} for e in _read_targets(src / fname)]
    shards.finish(stage, split, files)
    _write_models_info(out_dir, stage, model_from)
    _link(out_dir / next(n for n in names if n in done) / "camera.json", stage / "camera.json")
    files += ["camera.json", "models/models_info.json"]
    for fname, lst in targets.items():
        write_atomic(stage / fname, dump_list(lst).encode())
        files.append(fname)
    doc = {"scenes": {f"{k:06d}": n for k, n in enumerate(names) if n in done}, "split": split,
           "missing": [n for n in names if n not in done], "files": sorted(files)}
    write_atomic(stage / NAMES_FILE, (json.dumps(doc, indent=1) + "\n").encode())


def _swap(stage: Path, bop: Path, out_dir: Path, names: list[str]) -> None:
    """Rename the complete ``stage`` to ``bop``; an earlier ``bop`` is moved aside first (put back if
    anything goes wrong, or if something not evpose's appeared in it since it was checked) and removed after."""
    trash = inv = None
    if os.path.lexists(bop):
        trash = out_dir / f".{BOP_DIR}.replaced-{os.getpid()}-{secrets.token_hex(4)}"
        atomic.rename_durably(bop, trash)
        inv = _inventory(trash, out_dir, names)
        if not inv.clean:
            atomic.rename_durably(trash, bop)
            raise _foreign(bop, inv)
    try:
        atomic.rename_durably(stage, bop)
    except BaseException:
        if trash is not None:
            atomic.rename_durably(trash, bop)
        raise
    if inv is not None:
        remove_owned(inv, keep_root=False)


class _Shards:
    """The scenes' BOP-webdataset shards (``--bop-shards``) as one set: scene ``k``'s shards are linked as
    ``SPLIT_web/shard-GGGGGG.tar`` numbered on from the earlier scenes' (no gaps), ``key_to_shard.json`` merged. The
    image keys already carry the dataset's scene id (the dataset export gives each scene's writer its id)."""

    def __init__(self):
        self.keys: dict[str, int] = {}
        self.next = 0
        self.sharded: bool | None = None         # whether the scenes have shards (None: no scene seen yet)

    def add(self, src: Path, split: str, k: int, stage: Path, files: list) -> None:
        web = web_dir_name(split)
        path = src / web / KEY_TO_SHARD
        has = path.is_file()
        if self.sharded is not None and has != self.sharded:
            raise BopAssemblyError(f"{src}: {'has' if has else 'has no'} {web}/{KEY_TO_SHARD}, unlike "
                                   "the other scenes' exports (export them all with the same --bop-shards)")
        self.sharded = has
        if not has:
            return
        try:
            keys = json.loads(path.read_text())
            if not isinstance(keys, dict) or not all(isinstance(v, int) for v in keys.values()):
                raise ValueError("expected an object of image key -> shard number")
        except (OSError, ValueError) as exc:
            raise BopAssemblyError(f"{path}: not a key_to_shard.json evpose wrote: {exc}") from None
        prefix = f"{k:06d}_"
        wrong = next((key for key in keys if not key.startswith(prefix)), None)
        if wrong is not None:
            raise BopAssemblyError(f"{path}: image key {wrong!r} does not carry the dataset's scene id {k} (exported "
                                   f"alone, or before the dataset's scenes were reordered): export it again with "
                                   f"evpose dataset export --force")
        renumber = {}
        for n in sorted(set(keys.values())):
            renumber[n] = self.next
            rel = f"{web}/{shard_name(self.next)}"
            _link(src / web / shard_name(n), stage / rel)
            files.append(rel)
            self.next += 1
        self.keys.update({key: renumber[n] for key, n in keys.items()})

    def finish(self, stage: Path, split: str, files: list) -> None:
        if self.sharded:
            rel = f"{web_dir_name(split)}/{KEY_TO_SHARD}"
            write_atomic(stage / rel, json_member(dict(sorted(self.keys.items()))))
            files.append(rel)


# ------------------------------------------------------------------------------------------- what was there
def _clean_side_folders(out_dir: Path, names: list[str]) -> None:
    """What killed assemblies left beside ``OUT/bop``: a staging folder is removed; a dataset moved aside
    is put back when ``OUT/bop`` is missing (the swap was cut), else its evpose files are removed.
    Folders of live processes are left alone."""
    try:
        entries = list(os.scandir(out_dir))
    except OSError:
        return
    for e in entries:
        m = _SIDE_RE.match(e.name)
        if m is None or not e.is_dir(follow_symlinks=False) or not is_stale(e.path, int(m["pid"])):
            continue
        p = Path(e.path)
        if m["kind"] == "assemble":
            shutil.rmtree(p, ignore_errors=True)
        elif not os.path.lexists(out_dir / BOP_DIR):
            atomic.rename_durably(p, out_dir / BOP_DIR)
        else:
            remove_owned(_inventory(p, out_dir, names), keep_root=False)


def _previous_scenes(bop: Path, out_dir: Path, names: list[str]) -> set[str]:
    """The scenes an earlier complete assembly in ``bop`` holds (empty: none, or an unfinished one);
    refuses a ``bop`` that is not a folder or holds anything evpose did not assemble."""
    try:
        mode = os.lstat(bop).st_mode
    except FileNotFoundError:
        return set()
    if not stat.S_ISDIR(mode):
        kind = "a symbolic link" if stat.S_ISLNK(mode) else describe_kind(mode)
        raise BopAssemblyError(f"{bop}: exists and is {kind}, not a BOP dataset evpose assembled; evpose never "
                               "replaces it: move it away or choose another --out")
    inv = _inventory(bop, out_dir, names)
    if not inv.clean:
        raise _foreign(bop, inv)
    doc = read_names(bop)
    return set(doc["scenes"].values()) if doc is not None else set()


def _foreign(bop: Path, inv: Inventory) -> BopAssemblyError:
    return BopAssemblyError(f"{bop}: holds files evpose did not assemble: {inv.describe_foreign()}; move them "
                            "away or choose another --out")


def read_names(folder: Path) -> dict | None:
    """``scene_names.json`` of an assembly (None when absent or not one of evpose's)."""
    try:
        doc = json.loads((folder / NAMES_FILE).read_text())
    except (OSError, ValueError):
        return None
    if not (isinstance(doc, dict) and isinstance(doc.get("scenes"), dict) and isinstance(doc.get("files"), list)):
        return None
    return doc


def _inventory(folder: Path, out_dir: Path, names: list[str]) -> Inventory:
    """``folder`` (an earlier ``OUT/bop``) sorted into evpose's and foreign: logged files, and for
    assemblies written before the ownership log, the files its ``scene_names.json`` lists and hard links
    of the scene exports' own files (a merge refused half-way left only those)."""
    inv = inventory(folder, BOP_ROLE, temps="all")
    if inv.clean or (folder / STATE_DIR).is_dir():      # logged: the log alone is the proof
        return inv
    doc = read_names(folder)
    listed = set(doc["files"]) | {NAMES_FILE} if doc is not None else set()
    foreign, proofs = [], {}
    for p, why in inv.foreign:
        rel = p.relative_to(folder).as_posix()
        if p.is_dir() and not p.is_symlink():
            if why != "folder not made by evpose":
                foreign.append((p, why))
        elif rel in listed or _linked_from_export(p, rel, out_dir, names, proofs):
            inv.files.append(p)
        else:
            foreign.append((p, why))
    inv.foreign = foreign
    if inv.clean:                  # every file is ours: so are the folders holding them
        inv.dirs = sorted((Path(d) for d, _, _ in os.walk(folder) if Path(d) != folder),
                          key=lambda q: len(q.parts), reverse=True)
    return inv


def _linked_from_export(p: Path, rel: str, out_dir: Path, names: list[str], proofs: dict) -> bool:
    """Whether ``p`` (``rel`` in an assembly) is the scene export file it was hard-linked from: the same file
    still, or one with the size and modification time the export logged for it (the export rewrote it since).
    ``proofs`` caches each scene export's ownership logs."""
    parts = rel.split("/")
    if parts[0] == "models" or rel == "camera.json":
        sources = [(n, rel) for n in names]
    elif len(parts) >= 3 and parts[1].isdigit() and int(parts[1]) < len(names):
        sources = [(names[int(parts[1])], "/".join([parts[0], SCENE_SUBDIR, *parts[2:]]))]
    else:
        return False
    try:
        st = os.lstat(p)
    except OSError:
        return False
    if not stat.S_ISREG(st.st_mode):
        return False
    for name, src in sources:
        with contextlib.suppress(OSError):
            o = os.lstat(out_dir / name / src)
            if (o.st_dev, o.st_ino) == (st.st_dev, st.st_ino):
                return True
        if name not in proofs:
            proofs[name] = read_logs(out_dir / name, EXPORT_ROLE)
        if (st.st_size, st.st_mtime_ns) in proofs[name].files.get(src, ()):
            return True
    return False


# ------------------------------------------------------------------------------------------- pieces
def _link(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:               # another filesystem or no hard links: copy
        shutil.copyfile(src, dst)


def scene_split(export_dir: Path) -> str:
    """The split folder of a single-scene BOP export: the one folder holding ``000000/scene_gt.json``."""
    found = sorted(d.name for d in Path(export_dir).iterdir()
                   if d.is_dir() and (d / SCENE_SUBDIR / "scene_gt.json").is_file())
    if len(found) != 1:
        raise BopAssemblyError(f"{export_dir}: expected one SPLIT/{SCENE_SUBDIR}/scene_gt.json of a BOP export, "
                               f"found {len(found)}")
    return found[0]


def _link_models(src: Path, bop: Path, name: str, model_from: dict, files: list) -> None:
    """Each model of the scene export ``src`` once into ``bop/models`` (byte-identical per obj_id)."""
    for p in sorted((src / "models").iterdir()):
        rel = f"models/{p.name}"
        if p.name == "models_info.json":
            continue
        if rel in model_from:
            if (bop / rel).read_bytes() != p.read_bytes():
                raise BopAssemblyError(f"{src / rel}: differs from {rel} of scene {model_from[rel]!r}: one obj_id "
                                       "must name one model (give the objects distinct class ids)")
            continue
        _link(p, bop / rel)
        model_from[rel] = name
        files.append(rel)


def _read_targets(path: Path) -> list[dict]:
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise BopAssemblyError(f"{path}: cannot read the scene's test targets ({exc})") from None
    if not isinstance(doc, list) or not all(isinstance(e, dict) for e in doc):
        raise BopAssemblyError(f"{path}: expected a list of test targets")
    return doc


def _write_models_info(out_dir: Path, bop: Path, model_from: dict) -> None:
    """``models/models_info.json``: each obj_id's entry from the scene its model came from."""
    info = {}
    for rel, name in model_from.items():
        obj_id = str(int(Path(rel).stem.split("_")[1]))
        info[obj_id] = json.loads((out_dir / name / "models" / "models_info.json").read_text())[obj_id]
    if model_from:
        text = json.dumps({k: info[k] for k in sorted(info, key=int)}, indent=1) + "\n"
        write_atomic(bop / "models" / "models_info.json", text.encode())


# ------------------------------------------------------------------------------------------- before the export
def check_models(dataset, objects=None) -> None:
    """Refuse, before any scene is exported, a dataset whose scenes give one ``obj_id`` to different models
    (the merge would be refused after hours of export). From the manifests: the same object name with the
    same mesh file content and scale is the same model; otherwise the meshes are loaded and compared.
    Scenes that cannot be read are left to their export, which reports them."""
    from evpose.core.data.manifest_reader import load_manifest
    from evpose.core.export.bop import bop_obj_ids
    from evpose.core.export.options import export_objects

    if isinstance(objects, str):
        objects = [s.strip() for s in objects.split(",") if s.strip()]
    first: dict[int, tuple] = {}          # obj_id -> (scene, ObjectSpec) that gave it first
    for ref in dataset.scenes:
        if ref.error is not None:
            continue
        try:
            m = load_manifest(ref.path, defaults=dataset.defaults or None)
            view = SimpleNamespace(manifest=m, object_names=[o.name for o in m.objects])
            ids = bop_obj_ids(view, export_objects(view, objects)[0])
        except (InputError, OSError):
            continue
        for name, oid in ids.items():
            spec = m.object(name)
            scene, other = first.setdefault(oid, (ref.name, spec))
            if other is not spec and not _same_model(other, spec):
                raise BopAssemblyError(
                    f"{m.path}: objects[{view.object_names.index(name)}]: {name!r} ({spec.mesh}) would be obj_id "
                    f"{oid} of the BOP dataset, which scene {scene!r} gives to another model ({other.name!r}, "
                    f"{other.mesh}): one obj_id must name one model; give the objects distinct class ids")


def _same_model(a, b) -> bool:
    """Whether two objects (:class:`~evpose.core.data.manifest.ObjectSpec`) give byte-identical BOP models
    (the model file names the object, so the names must match too)."""
    if a.name != b.name:
        return False
    try:
        if float(a.mesh_scale) == float(b.mesh_scale) and _digest(a.mesh) == _digest(b.mesh):
            return True
        return _model_bytes(a) == _model_bytes(b)
    except (InputError, OSError):
        return True                  # unreadable: the scene's export reports it


def _model_bytes(spec) -> bytes:
    """The PLY the BOP export writes for the object (:mod:`evpose.core.export.bop_models`), without its
    header comment (the object's name)."""
    from evpose.core.data.objects import ObjectModel
    from evpose.core.export.bop_models import ply_bytes, vertex_normals

    m = ObjectModel.from_file(spec.mesh, name=spec.name, mesh_scale=spec.mesh_scale)
    V = m.vertices_m * 1000.0
    return ply_bytes(V, m.faces, vertex_normals(V, m.faces))


#: sha256 of mesh files by (device, inode, size, modification time): the command checks before it starts
#: its cluster and the export again, hashing each file once.
_DIGESTS: dict = {}


def _digest(path) -> str:
    """sha256 of a file (once per file version)."""
    st = os.stat(path)
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    digests = _DIGESTS
    if key not in digests:
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        digests[key] = h.hexdigest()
    return digests[key]
