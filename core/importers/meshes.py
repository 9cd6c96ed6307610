"""Object meshes into the scene's ``models/`` folder: copied verbatim (with an OBJ's material files) or
written as PLY from generated vertices and faces.

A mesh file is loaded once on import, as the scene will load it (:meth:`~evpose.core.data.objects.ObjectModel.
from_file`: a regular file of sane size that trimesh reads as triangles with finite vertices), so that a file
that is not a mesh (random bytes, text, a point cloud) is refused with one line naming it, instead of making a
scene that fails later."""
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
    if not src.exists():
        raise ImportFailure(src, name, "mesh", "mesh file not found")
    check_mesh(src, name)
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


def check_mesh(src: Path, name: str) -> None:
    """Refuse ``src`` unless it loads as a triangle mesh (the check the scene makes when it opens)."""
    from evpose.core.data.objects import ObjectModel, ObjectModelError

    try:
        ObjectModel.from_file(src, name=name)
    except ObjectModelError as exc:
        reason = str(exc)
        reason = reason[len(f"{src}: "):] if reason.startswith(f"{src}: ") else reason
        raise ImportFailure(src, name, "mesh", reason) from None


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
