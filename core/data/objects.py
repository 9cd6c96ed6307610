"""Object models: triangle meshes in the object frame (metres), geometry only.

Meshes are read with trimesh from any format it supports. Materials and textures are skipped:
the published E-POSE OBJ files reference texture images that do not exist, which is not an error.
Pillow is a dependency because trimesh needs it to parse such OBJ files at all.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from evpose.core.errors import InputError


class ObjectModelError(InputError):
    """A mesh that cannot be used; the message names the file."""


#: Order of :meth:`ObjectModel.bbox_corners`: corner ``i`` takes the max along axis ``a`` when
#: bit ``a`` of ``i`` is set (x is bit 0, y bit 1, z bit 2).
BBOX_CORNER_BITS = tuple((i & 1, (i >> 1) & 1, (i >> 2) & 1) for i in range(8))
#: The 12 edges of the box as pairs of corner indices (for wireframes).
BBOX_EDGES = tuple((i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1)


@dataclass(eq=False)
class ObjectModel:
    """A rigid object: triangle mesh in its own frame, in metres.

    Parameters
    ----------
    name : str
    vertices_m : (V, 3) float64
        Vertex positions in the object frame, metres.
    faces : (F, 3) int32
        Triangle vertex indices.
    class_id : int
        Dataset class index (E-POSE ``cls_index``, BOP ``obj_id``).
    symmetric : bool
        Whether the object has a symmetry (scores/refinement may treat it differently).
    source : str
        File the mesh came from (for messages).
    """

    name: str
    vertices_m: np.ndarray
    faces: np.ndarray
    class_id: int = 0
    symmetric: bool = False
    source: str = "<memory>"
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        v = np.ascontiguousarray(self.vertices_m, dtype=np.float64)
        f = np.ascontiguousarray(self.faces)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise ObjectModelError(f"{self.source}: vertices: expected (V, 3) with V > 0, got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise ObjectModelError(f"{self.source}: faces: expected a triangle mesh (F, 3) with F > 0, got {f.shape}")
        if not np.all(np.isfinite(v)):
            raise ObjectModelError(f"{self.source}: vertices: contain NaN or inf")
        if f.min() < 0 or f.max() >= len(v):
            raise ObjectModelError(f"{self.source}: faces: vertex index out of range [0, {len(v)})")
        self.vertices_m = v
        self.faces = f.astype(np.int32, copy=False)
        self.vertices_m.setflags(write=False)
        self.faces.setflags(write=False)

    # ------------------------------------------------------------------ loading
    @classmethod
    def from_file(cls, path, *, name: str | None = None, mesh_scale: float = 1.0, class_id: int = 0,
                  symmetric: bool = False) -> "ObjectModel":
        """Load a mesh with trimesh (geometry only) and scale it to metres.

        ``mesh_scale`` multiplies the file's coordinates (0.001 for millimetre meshes). Scenes
        with several geometries are merged into one mesh.
        """
        import trimesh  # local: keeps `import core` light

        from evpose.core.data.input_files import (
            MAX_MESH_BYTES,
            InputFileError,
            check_regular,
        )

        path = Path(path)
        if not path.exists():
            raise ObjectModelError(f"{path}: mesh file not found")
        try:   # a folder, a FIFO or /dev/zero would make trimesh fail late, block or read forever
            check_regular(path, max_bytes=MAX_MESH_BYTES)
        except InputFileError as exc:
            raise ObjectModelError(f"{path}: cannot read the mesh: {exc.reason}") from None
        if not (np.isfinite(mesh_scale) and mesh_scale > 0):
            raise ObjectModelError(f"{path}: mesh_scale: must be a positive number, got {mesh_scale}")
        try:
            loaded = trimesh.load(path, force="mesh", skip_materials=True, process=True)
        except Exception as exc:  # trimesh raises many types for bad files
            raise ObjectModelError(f"{path}: trimesh could not read the mesh ({type(exc).__name__}: {exc})") from None
        faces = getattr(loaded, "faces", None)
        if faces is None or len(faces) == 0:
            raise ObjectModelError(f"{path}: the file holds no triangles")
        model = cls(name or path.stem, np.asarray(loaded.vertices) * float(mesh_scale), np.asarray(faces),
                    class_id=class_id, symmetric=symmetric, source=str(path))
        if not loaded.is_watertight:
            model.notes.append("mesh is not watertight (masks are still exact: both faces are rasterised)")
        return model

    @classmethod
    def from_trimesh(cls, mesh, name: str, **kwargs) -> "ObjectModel":
        return cls(name, np.asarray(mesh.vertices), np.asarray(mesh.faces), **kwargs)

    # ------------------------------------------------------------------ geometry
    @cached_property
    def bbox_min_max(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box in the object frame, metres."""
        return self.vertices_m.min(axis=0), self.vertices_m.max(axis=0)

    def bbox_corners(self, margin_m: float = 0.0) -> np.ndarray:
        """The 8 corners ``(8, 3)`` of the axis-aligned box in the object frame.

        ``margin_m`` enlarges the box by that distance on every side (each corner moves outward
        along all three axes), unlike the E-POSE scripts, which shifted the box by +1 mm.
        Corner order: :data:`BBOX_CORNER_BITS`.
        """
        lo, hi = self.bbox_min_max
        lo = lo - margin_m
        hi = hi + margin_m
        bits = np.asarray(BBOX_CORNER_BITS, dtype=bool)
        return np.where(bits, hi, lo)

    @cached_property
    def bbox_center_m(self) -> np.ndarray:
        """Centre of the axis-aligned bounding box in the object frame."""
        lo, hi = self.bbox_min_max
        return (lo + hi) / 2.0

    @cached_property
    def diameter_m(self) -> float:
        """Largest distance between two vertices (computed on the convex hull)."""
        from scipy.spatial import ConvexHull, QhullError

        v = self.vertices_m
        try:
            pts = v[ConvexHull(v).vertices]
        except (QhullError, ValueError):  # degenerate (planar) meshes
            pts = v
        from scipy.spatial.distance import cdist

        # scipy's C distance loops: 20-40x the numpy broadcast (nine_hole_peg's 2003 hull points: 13 vs 479 ms),
        # in blocks of 2048 rows so that a large hull never needs a quadratic buffer
        best = 0.0
        for i in range(0, len(pts), 2048):
            best = max(best, float(cdist(pts[i:i + 2048], pts).max()))
        return best


#: Procedural meshes are split until no edge is longer than this: same surface, but triangles
#: small on screen, which the rasteriser handles fastest (a 12-triangle box seen from 0.3 m has
#: triangles of ~10^4 pixels whose distortion bound inflates their candidate boxes; ~40 % faster
#: scene synthesis at full DAVIS346 resolution).
PROCEDURAL_MAX_EDGE_M = 0.02


def _subdivided(mesh, max_edge_m: float | None):
    import trimesh

    if not max_edge_m:
        return mesh
    v, f = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, float(max_edge_m))
    return trimesh.Trimesh(v, f, process=True)


def raster_friendly(model: ObjectModel, max_edge_m: float = PROCEDURAL_MAX_EDGE_M) -> ObjectModel:
    """``model`` with its edges longer than ``max_edge_m`` split at their midpoints
    (``trimesh.remesh.subdivide_to_size``); the model itself when no edge is that long.

    The surface is the same (planar triangles split into planar pieces; the original vertices
    are kept, so the bounding box, the keypoints and every mask are unchanged), but the
    rasteriser of the distorted camera bounds the bend of an edge by a margin quadratic in the
    triangle's size, so a few huge triangles (CAD primitives, a 12-triangle box) cost far more
    than many small ones: 72 -> 12 ms per export window, 154 -> 73 ms per app frame.
    Real scanned meshes (E-POSE: sub-centimetre triangles) are returned as they are.
    """
    import trimesh

    v, f = model.vertices_m, model.faces
    if len(f) == 0:
        return model
    e = v[f[:, [1, 2, 0]]] - v[f]
    if float(np.einsum("fij,fij->fi", e, e).max()) <= max_edge_m ** 2:
        return model
    v2, f2 = trimesh.remesh.subdivide_to_size(v, f, max_edge=max_edge_m)
    return ObjectModel(model.name, v2, f2, class_id=model.class_id, symmetric=model.symmetric,
                       source=f"{model.source} (edges split to <= {max_edge_m * 1e3:g} mm for rasterising)")


def box_model(name: str, size_m=(0.1, 0.06, 0.16), max_edge_m: float | None = PROCEDURAL_MAX_EDGE_M,
              **kwargs) -> ObjectModel:
    """A procedural box centred at the origin (sizes along x, y, z in metres)."""
    import trimesh

    mesh = _subdivided(trimesh.creation.box(extents=size_m), max_edge_m)
    return ObjectModel.from_trimesh(mesh, name, source=f"box{tuple(size_m)}", **kwargs)


def cylinder_model(name: str, radius_m: float = 0.04, height_m: float = 0.12, sections: int = 48,
                   max_edge_m: float | None = PROCEDURAL_MAX_EDGE_M, **kwargs) -> ObjectModel:
    """A procedural closed cylinder along z, centred at the origin."""
    import trimesh

    mesh = _subdivided(trimesh.creation.cylinder(radius=radius_m, height=height_m, sections=sections), max_edge_m)
    return ObjectModel.from_trimesh(mesh, name, source=f"cylinder(r={radius_m}, h={height_m})", **kwargs)
