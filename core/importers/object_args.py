"""``--objects name=mesh[:T_base_obj.json],...``: the objects a user adds to an import.

Parsed once per import; the ``T_base_obj`` files are read and their rotations checked (metres, base frame).
Formats with published objects (E-POSE assets) merge them with these: ``--objects`` wins by name.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.pose_checks import check_T
from evpose.core.importers.report import ImportContext

if TYPE_CHECKING:
    from evpose.core.importers.epose_assets import EposeAssets


@dataclass
class ObjectArg:
    """One ``name=mesh[:T.json]`` entry of ``--objects``."""

    name: str
    mesh: Path | None
    T_raw: np.ndarray | None
    T_file: Path | None = None


def parse_objects_arg(spec, ctx: ImportContext) -> list[ObjectArg]:
    """``"name=mesh.obj:T.json,name2=mesh2.ply"`` (the T file: a 4x4 JSON list or ``{"T_base_obj": ...}``,
    or a 16-number text file). ``spec`` may also be a list of such strings."""
    if not spec:
        return []
    items = spec if isinstance(spec, (list, tuple)) else [s for s in str(spec).split(",")]
    out = []
    for item in (s.strip() for s in items):
        if not item:
            continue
        if "=" not in item:
            raise ImportFailure("--objects", item, "name", "expected name=mesh[:T_base_obj.json]")
        name, rest = item.split("=", 1)
        mesh_s, T_s = rest, None
        if ":" in rest:
            mesh_s, T_s = rest.rsplit(":", 1)
        mesh = Path(mesh_s).expanduser() if mesh_s else None
        T_raw = None
        T_file = None
        if T_s:
            T_file = Path(T_s).expanduser()
            with wrap_errors(T_file, "(file)", "T_base_obj", "cannot read"):
                text = T_file.read_text()
            try:
                d = json.loads(text)
                if isinstance(d, dict):
                    d = d.get("T_base_obj", d.get("T"))
            except RecursionError:
                raise ImportFailure(T_file, "(file)", "T_base_obj", "JSON nested too deeply") from None
            except json.JSONDecodeError:
                try:
                    d = [float(v) for v in text.replace(",", " ").split()]
                except ValueError:
                    raise ImportFailure(T_file, "(file)", "T_base_obj", "expected a 4x4 JSON list or 16 numbers") from None
            try:
                T_raw = np.asarray(d, dtype=np.float64)
            except (TypeError, ValueError):
                raise ImportFailure(T_file, "(file)", "T_base_obj", "not a numeric 4x4 matrix") from None
            if T_raw.size == 16:
                T_raw = T_raw.reshape(4, 4)
            check_T(T_raw, ctx, T_file, "(file)", "T_base_obj")
        out.append(ObjectArg(name.strip(), mesh, T_raw, T_file))
    return out


def collect_objects(ctx: ImportContext, assets: EposeAssets | None, *, require_T: bool = True) -> dict:
    """Objects from ``--assets/--scene`` and ``--objects`` (which replaces asset objects of the same name).

    Returns ``{name: (mesh path, T_base_obj raw or None, class_id, source)}`` in order.
    """
    objs: dict[str, tuple] = {}
    if assets is not None:
        for name, mesh, T, cid in assets.objects:
            objs[name] = (mesh, T, cid, f"{assets.scene} (assets)")
    for a in parse_objects_arg(ctx.options.objects, ctx):
        if a.T_raw is None and require_T:
            raise ImportFailure("--objects", a.name, "T_base_obj", "give name=mesh:T_base_obj.json")
        if a.mesh is None or not str(a.mesh):
            raise ImportFailure("--objects", a.name, "mesh", "give name=mesh[:T_base_obj.json]")
        if not Path(a.mesh).is_file():
            raise ImportFailure(a.mesh, a.name, "mesh", "mesh file not found (--objects)")
        prev = objs.get(a.name)
        objs[a.name] = (a.mesh, a.T_raw, prev[2] if prev else len(objs) + 1, "--objects")
    return objs
