"""E-POSE assets (``--assets DIR --scene S --sequence Q``): objects, meshes, calibration and clock prior.

Objects and ``T_base_obj`` come from ``scenes.json``, meshes from ``models/``, the calibration from
``camera_davis346.json`` and the published clock prior from ``time_shifts.csv`` (seconds, added to event
time: ``offset_us = round(shift_s * 1e6)``). Scene names are matched robustly (aliases dishwasher->
bleach_cleanser, spam->potted_meat_can, domino->sugar_box, peg->nine_hole_peg; ``time_shifts.csv`` short names
such as ``bleach``, ``block``, ``potted meat``; sequence names case-insensitively) and the report says what
matched.
"""
from __future__ import annotations

import csv
import io
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evpose.core.data.camera import CameraModel
from evpose.core.data.geometry import ROTATION_TOLERANCE
from evpose.core.importers.calibration import load_camera
from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.pose_checks import check_T
from evpose.core.importers.report import ImportContext

#: Residual tolerance for rotations *published by E-POSE* (``scenes.json``, and the pose blocks of its exports made
#: from them): their rotation blocks are rounded to 3-5 digits, giving residuals up to 0.145 (five_obj_clut /
#: nine_hole_peg); the one typo (three_obj / potted_meat_can, 0.51) stays refused without ``--repair``. Values above
#: the core tolerance are projected, reported, and written with ``repair_rotation = true``. User-supplied
#: rotations (``--objects``) use the core tolerance (:data:`evpose.core.data.geometry.ROTATION_TOLERANCE`).
EPOSE_PUBLISHED_TOLERANCE = 0.2

#: Object names published in the E-POSE multi-object scenes -> the YCB names used for meshes and scenes.
OBJECT_ALIASES = {"dishwasher": "bleach_cleanser", "spam": "potted_meat_can", "domino": "sugar_box",
                  "peg": "nine_hole_peg"}


def _norm(s: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", str(s).lower()).strip("_")


def _tokens_match(short: str, long: str) -> bool:
    """Every token of ``short`` is a prefix of a token of ``long``, in order (``bleach`` ~ ``bleach_cleanser``,
    ``block`` ~ ``wood_block``, ``rubik`` ~ ``rubiks_cube``)."""
    ts, tl = short.split("_"), long.split("_")
    j = 0
    for t in ts:
        while j < len(tl) and not tl[j].startswith(t):
            j += 1
        if j == len(tl):
            return False
        j += 1
    return True


def match_name(name: str, candidates, *, file, record: str, fld: str) -> tuple[str, str]:
    """Find ``name`` among ``candidates``: exact (normalised), alias, then token-prefix match either way.

    Returns (candidate, how). Raises :class:`ImportFailure` when nothing or more than one candidate matches.
    """
    cands = list(candidates)
    n = _norm(name)
    norm = {c: _norm(c) for c in cands}
    exact = [c for c in cands if norm[c] == n]
    if exact:
        return exact[0], "exact" if exact[0] == name else f"{name!r} matched {exact[0]!r} (case/spacing)"
    if n in OBJECT_ALIASES:
        a = _norm(OBJECT_ALIASES[n])
        hit = [c for c in cands if norm[c] == a]
        if hit:
            return hit[0], f"alias {name!r} -> {hit[0]!r}"
    fuzzy = [c for c in cands if _tokens_match(n, norm[c]) or _tokens_match(norm[c], n)]
    if len(fuzzy) == 1:
        return fuzzy[0], f"{name!r} matched {fuzzy[0]!r} (name prefix)"
    if len(fuzzy) > 1:
        raise ImportFailure(file, record, fld, f"{name!r} is ambiguous: matches {', '.join(map(repr, fuzzy))}")
    raise ImportFailure(file, record, fld, f"no entry for {name!r} (have: {', '.join(map(str, cands))})")


@dataclass
class EposeAssets:
    """What an E-POSE assets folder gives an import: the camera, the scene's objects and its clock prior (µs)."""

    camera: CameraModel
    scene: str
    objects: list[tuple[str, Path, np.ndarray, int]]     # (name, mesh, T_base_obj raw, class_id)
    offset_us: int | None


def find_mesh(models: Path, name: str) -> Path | None:
    for suf in (".obj", ".stl", ".ply", ".off", ".glb"):
        p = models / f"{name}{suf}"
        if p.is_file():
            return p
    return None


def load_epose_assets(ctx: ImportContext, assets, scene: str | None, sequence: str | None,
                      need_scene: bool = True) -> EposeAssets:
    """Camera, objects (meshes, ``T_base_obj``) and the published clock prior from an E-POSE assets folder."""
    assets = Path(assets)
    rep = ctx.report
    cam_file = assets / "camera_davis346.json"
    if not cam_file.is_file():
        raise ImportFailure(cam_file, "(file)", "-", "not found (expected an assets folder like shared/assets/epose)")
    camera = load_camera(cam_file, ctx)
    scenes_file = assets / "scenes.json"
    scenes = read_scenes(scenes_file)
    if scene is None:
        if need_scene:
            raise ImportFailure(scenes_file, "(options)", "--scene", f"give --scene (one of {', '.join(scenes)})")
        return EposeAssets(camera, "", [], None)
    key, how = match_name(scene, scenes, file=scenes_file, record="scenes", fld="--scene")
    if how != "exact":
        rep.assume(f"scene: {how}")
    rep.details["epose_scene"] = key
    # class ids: order of the single-object scenes in scenes.json (1-based)
    singles = [k for k, v in scenes.items() if _n_objects(v) == 1]
    objs = scenes[key].get("objects")
    if not isinstance(objs, dict) or not objs:
        raise ImportFailure(scenes_file, key, "objects", "no objects")
    models = assets / "models"
    out = []
    for oname, T in objs.items():
        canon = OBJECT_ALIASES.get(_norm(oname), oname)
        if canon != oname:
            rep.assume(f"object {oname!r} of scene {key!r} is {canon!r} (published alias)")
        if not isinstance(T, list):
            raise ImportFailure(scenes_file, f"{key}/{oname}", "T_base_obj", "expected a 4x4 list")
        try:
            T_raw = np.asarray(T, dtype=np.float64)
        except (TypeError, ValueError):
            raise ImportFailure(scenes_file, f"{key}/{oname}", "T_base_obj", "not a numeric 4x4 matrix") from None
        _, res = check_T(T_raw, ctx, scenes_file, f"{key}/{oname}", "T_base_obj", tolerance=EPOSE_PUBLISHED_TOLERANCE)
        if ROTATION_TOLERANCE < res <= EPOSE_PUBLISHED_TOLERANCE:
            rep.repair(f"{scenes_file.name}: {key}/{oname}: T_base_obj: published rotation rounded (residual {res:.3g} > "
                       f"{ROTATION_TOLERANCE:g}): projected onto SO(3), repair_rotation = true in scene.toml")
        mesh = find_mesh(models, canon)
        if mesh is None:
            raise ImportFailure(models, f"{key}/{oname}", "mesh", f"no mesh {canon}.obj/.stl/.ply in {models}")
        cid = singles.index(canon) + 1 if canon in singles else 0
        out.append((canon, mesh, T_raw, cid))
    rep.assume("class ids follow the order of the single-object scenes in scenes.json (1-based)")
    offset = None
    if sequence is not None:
        offset = _time_shift(ctx, assets / "time_shifts.csv", key, sequence)
    else:
        rep.warn("no --sequence: clock prior offset 0 (the published time shifts are per sequence)")
    return EposeAssets(camera, key, out, offset)


def read_scenes(scenes_file: Path) -> dict:
    """The ``scenes`` mapping of ``scenes.json`` (scene name -> ``{"objects": {name: T_base_obj}}``)."""
    with wrap_errors(scenes_file, "(file)", "scenes", "cannot read"):
        data = json.loads(scenes_file.read_text())
        scenes = data["scenes"]
        if not isinstance(scenes, dict):
            raise TypeError("'scenes' is not a mapping")
    for k, v in scenes.items():
        if not isinstance(v, dict):
            raise ImportFailure(scenes_file, f"scenes/{k}", "-", f"expected a mapping, got {type(v).__name__}")
    return scenes


def _n_objects(scene: dict) -> int:
    objs = scene.get("objects", {})
    return len(objs) if isinstance(objs, (dict, list)) else 0


def read_time_shifts(path: Path) -> dict[str, dict[str, tuple[str, str, int]]]:
    """``time_shifts.csv`` as ``{scene: {sequence: (sequence, shift_s text, line number)}}``, names as published."""
    with wrap_errors(path, "(file)", "-", "cannot read"):
        text = path.read_text(encoding="utf-8-sig")
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or [h.strip().lower() for h in rows[0][:3]] != ["scene", "sequence", "shift_s"]:
        raise ImportFailure(path, "line 1", "header", "expected 'scene,sequence,shift_s'")
    table: dict[str, dict[str, tuple[str, str, int]]] = {}
    for ln, row in enumerate(rows[1:], start=2):
        if not row or not "".join(row).strip():
            continue
        if len(row) < 3:
            raise ImportFailure(path, f"line {ln}", "shift_s", f"expected 3 columns, got {len(row)}")
        table.setdefault(row[0].strip(), {})[row[1].strip()] = (row[1].strip(), row[2].strip(), ln)
    return table


def lookup_time_shift(table: dict, path: Path, scene_key: str, sequence: str) -> tuple[str, str, str, int, str]:
    """The row of ``scene_key`` / ``sequence`` in a :func:`read_time_shifts` table: ``(scene as published,
    sequence as published, shift_s text, line, how the scene matched)``; the sequence matches case-insensitively.
    Raises :class:`ImportFailure` naming ``path`` when there is no such row."""
    sname, how = match_name(scene_key, table, file=path, record="scene", fld="scene")
    seqs = table[sname]
    hits = [s for s in seqs if s.lower() == sequence.strip().lower()]
    if not hits:
        raise ImportFailure(path, f"scene {sname!r}", "sequence", f"no sequence {sequence!r} (have: {', '.join(seqs)})")
    seq, val, ln = seqs[hits[0]]
    return sname, seq, val, ln, how


def _time_shift(ctx: ImportContext, path: Path, scene_key: str, sequence: str) -> int:
    sname, seq, val, ln, how = lookup_time_shift(read_time_shifts(path), path, scene_key, sequence)
    try:
        shift_s = float(val)
    except ValueError:
        raise ImportFailure(path, f"line {ln}", "shift_s", f"not a number ({val!r})") from None
    if not math.isfinite(shift_s):
        raise ImportFailure(path, f"line {ln}", "shift_s", f"not finite ({val!r})")
    off = int(round(shift_s * 1e6))
    ctx.report.assume(f"clock prior from {path.name} line {ln}: scene {sname!r} (for {scene_key!r}, {how}), sequence "
                      f"{seq!r} (for {sequence!r}): shift {val} s -> offset_us = {off}")
    ctx.report.details["time_shift"] = {"file": str(path), "line": ln, "scene": sname, "sequence": seq,
                                        "shift_s": shift_s, "offset_us": off}
    if shift_s == 0:
        ctx.report.warn(f"{path.name}: the published shift for {sname}/{seq} is 0 (apparently not estimated)")
    return off

