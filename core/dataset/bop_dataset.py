"""One BOP dataset from the scenes' BOP exports (``OUT/bop``, see :mod:`evpose.core.dataset.export`).

Every scene's export ``OUT/<name>`` holds its scene as ``SPLIT/000000`` (scene id 0; ``SPLIT`` the
export's split folder, ``test`` unless chosen, the same for every scene). Scene ``k`` of the dataset
(dataset order, counting failed scenes too, so ids stay stable when one scene fails) becomes
``OUT/bop/SPLIT/{k:06d}``; its files are hard links to ``OUT/<name>/SPLIT/000000/...``, so the BOP dataset
costs no disk space and holds exactly the bytes of the per-scene exports, in the same conventions
(:mod:`evpose.core.export.bop`: BOP pixel origin in ``cam_K``, calc_gt_info's ``scene_gt_info``, models
with normals). ``models/`` holds each ``obj_id`` once: the same ``obj_id`` in two scenes must have
byte-identical models (the same class id names the same object), else the assembly fails naming both
scenes. ``test_targets_bop19.json`` and ``test_targets_bop24.json`` are the scenes' targets with
``scene_id`` set to ``k``. ``camera.json`` is the first scene's (BOP's per-image ``cam_K`` in
``scene_camera.json`` is what counts). ``scene_names.json`` maps scene id to scene name and lists the
files, which a rerun may remove before it assembles again; any other file in ``OUT/bop`` makes the rerun
refuse.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from evpose.core.data.atomic import write_atomic
from evpose.core.errors import InputError
from evpose.core.export.bop import dump_list
from evpose.core.export.bop_conventions import TARGETS_BOP19, TARGETS_BOP24

__all__ = ["BopAssemblyError", "assemble_bop", "scene_split", "BOP_DIR", "NAMES_FILE"]

BOP_DIR = "bop"
NAMES_FILE = "scene_names.json"
SCENE_SUBDIR = "000000"          # where a single-scene BOP export puts its scene (scene_id 0)


class BopAssemblyError(InputError):
    """The scenes' BOP exports cannot form one dataset (conflicting models, foreign files)."""


def _link(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:               # another filesystem or no hard links: copy
        shutil.copyfile(src, dst)


def _clear_previous(bop: Path) -> None:
    """Remove the files an earlier assembly listed; refuse when anything else is in ``bop``."""
    if not bop.exists():
        return
    names = bop / NAMES_FILE
    listed: set[str] = set()
    if names.is_file():
        try:
            listed = set(json.loads(names.read_text())["files"]) | {NAMES_FILE}
        except (ValueError, KeyError, TypeError):
            raise BopAssemblyError(f"{names}: files: not an evpose BOP assembly list; remove {bop} yourself") from None
    present = {str(p.relative_to(bop)) for p in bop.rglob("*") if not p.is_dir()}
    foreign = sorted(present - listed)
    if foreign:
        raise BopAssemblyError(f"{bop}: holds files evpose did not assemble ({', '.join(foreign[:3])}"
                               f"{', ...' if len(foreign) > 3 else ''}); move them or choose another --out")
    for rel in present:
        (bop / rel).unlink()
    for d in sorted((p for p in bop.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts)):
        d.rmdir()


def scene_split(export_dir: Path) -> str:
    """The split folder of a single-scene BOP export: the one folder holding ``000000/scene_gt.json``."""
    found = sorted(d.name for d in Path(export_dir).iterdir()
                   if d.is_dir() and (d / SCENE_SUBDIR / "scene_gt.json").is_file())
    if len(found) != 1:
        raise BopAssemblyError(f"{export_dir}: expected one SPLIT/{SCENE_SUBDIR}/scene_gt.json of a BOP export, "
                               f"found {len(found)}")
    return found[0]


def assemble_bop(out_dir, names: list[str], done: list[str]) -> Path:
    """Build ``out_dir/bop`` from the BOP exports ``out_dir/<name>`` of the scenes in ``done``
    (``names``: all scenes in dataset order, which fixes the scene ids). Returns the folder."""
    out_dir = Path(out_dir)
    bop = out_dir / BOP_DIR
    _clear_previous(bop)
    files: list[str] = []
    model_from: dict[str, str] = {}
    targets: dict[str, list] = {TARGETS_BOP19: [], TARGETS_BOP24: []}
    split = None
    for k, name in enumerate(names):
        if name not in done:
            continue
        src = out_dir / name
        sp = scene_split(src)
        if split is not None and sp != split:
            raise BopAssemblyError(f"{src}: split {sp!r} differs from the other scenes' {split!r}")
        split = sp
        _link_models(src, bop, name, model_from, files)
        for p in sorted((src / split / SCENE_SUBDIR).rglob("*")):
            if p.is_file():
                rel = f"{split}/{k:06d}/{p.relative_to(src / split / SCENE_SUBDIR)}"
                _link(p, bop / rel)
                files.append(rel)
        for fname, lst in targets.items():
            lst += [{**e, "scene_id": k} for e in _read_targets(src / fname)]
    _write_models_info(out_dir, bop, model_from)
    first = next((n for n in names if n in done), None)
    if first is not None:
        _link(out_dir / first / "camera.json", bop / "camera.json")
        files += ["camera.json", "models/models_info.json"]
        for fname, lst in targets.items():
            write_atomic(bop / fname, dump_list(lst).encode())
            files.append(fname)
    doc = {"scenes": {f"{k:06d}": n for k, n in enumerate(names) if n in done}, "split": split,
           "missing": [n for n in names if n not in done], "files": sorted(files)}
    bop.mkdir(parents=True, exist_ok=True)
    write_atomic(bop / NAMES_FILE, (json.dumps(doc, indent=1) + "\n").encode())
    return bop


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
