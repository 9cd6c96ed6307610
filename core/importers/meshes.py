"""Object meshes into the scene's ``models/`` folder: copied verbatim (with an OBJ's material files) or
written as PLY from generated vertices and faces."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.report import ImportReport

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf")


def place_mesh(mesh, models_dir: Path, safe: str, name: str, report: ImportReport, inputs: list) -> Path:
    """Put the mesh of object ``name`` into ``models_dir`` as ``{safe}{suffix}`` and return its path.

    ``mesh`` is a mesh file (copied verbatim, plus the ``.mtl`` files an OBJ names; the source is appended to
    ``inputs``) or a ``(vertices_m, faces)`` pair (written as PLY, metres).
    """
    if isinstance(mesh, tuple):
        import trimesh

        dst = models_dir / f"{safe}.ply"
        trimesh.Trimesh(np.asarray(mesh[0]), np.asarray(mesh[1]), process=False).export(dst)
        return dst
    src = Path(mesh)
    if not src.is_file():
        raise ImportFailure(src, name, "mesh", "mesh file not found")
    inputs.append(src)
    if src.suffix.lower() not in MESH_SUFFIXES:
        report.warn(f"{src}: mesh suffix {src.suffix!r} is not one of {MESH_SUFFIXES}; copied anyway")
    dst = models_dir / f"{safe}{src.suffix.lower()}"
    shutil.copyfile(src, dst)
    if src.suffix.lower() == ".obj":
        for mtl in _obj_material_files(src):
            if mtl.is_file() and not (dst.parent / mtl.name).exists():
                shutil.copyfile(mtl, dst.parent / mtl.name)
    return dst


def _obj_material_files(obj: Path) -> list[Path]:
    """``mtllib`` files referenced in the first KB of lines of an OBJ (plus ``<stem>.mtl``)."""
    out = [obj.with_suffix(".mtl")]
    try:
        with open(obj, "rb") as f:
            for _ in range(200):
                line = f.readline()
                if not line:
                    break
                if line.startswith(b"mtllib"):
                    for nm in line.split()[1:]:
                        out.append(obj.parent / nm.decode("utf-8", "replace"))
    except OSError:
        pass
    return out
