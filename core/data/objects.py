"""Object models: triangle meshes in the object frame (metres), geometry only.

Meshes are read with trimesh from any format it supports. Materials and textures are skipped:
the published E-POSE OBJ files reference texture images that do not exist, which is not an error.
Pillow is a dependency because trimesh needs it to parse such OBJ files at all.

Scale sanity: a mesh written in millimetres and read as metres is 1000x too large (a 19 cm bottle
becomes 191 m; splitting its edges for the rasteriser once took 5 GB), one in metres read with
``mesh_scale = 0.001`` 1000x too small (it renders 0 pixels). :func:`size_problem` refuses an object whose
bounding box's largest side is outside [:data:`MIN_OBJECT_SIZE_M`, :data:`MAX_OBJECT_SIZE_M`] and
:func:`camera_inside_problem` one whose box holds the camera at every pose of the recording (a mesh in
centimetres), each naming the ``mesh_scale`` to try; :class:`~evpose.core.data.scene.Scene` runs them when
it opens a scene (boxes read by :func:`mesh_bounds`, cached by file content), imports warn.
"""
from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from evpose.core.errors import InputError

#: Smallest and largest plausible object, metres (the largest side of its bounding box after ``mesh_scale``):
#: objects of pose datasets are a few millimetres (a screw) to a metre or two (a chair); the E-POSE YCB meshes
#: are 1.5 to 32 cm. Below or above, the mesh's unit is almost certainly not what ``mesh_scale`` says.
MIN_OBJECT_SIZE_M = 0.001
MAX_OBJECT_SIZE_M = 5.0


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
    def symmetry(self) -> tuple[str | None, np.ndarray | None]:
        """The mesh's continuous symmetry, as trimesh finds it from the principal moments of inertia and a check of
        the surface: ``("radial", axis)`` (a solid of revolution: its spin about the unit ``axis``, object frame,
        through :attr:`symmetry_centre_m`, leaves every view unchanged), ``("spherical", None)`` (any rotation about
        its centre does), or ``(None, None)``. Discrete symmetries (a box's 180 degree turns) are not continuous and
        do not count: they do not make a pose unobservable, only ambiguous far from the start."""
        return self._symmetry_found[:2]

    @cached_property
    def symmetry_centre_m(self) -> np.ndarray | None:
        """A point of the symmetry axis (the centre of mass; object frame, metres), or None without a symmetry."""
        return self._symmetry_found[2]

    @cached_property
    def _symmetry_found(self) -> tuple[str | None, np.ndarray | None, np.ndarray | None]:
        import trimesh

        try:
            mesh = trimesh.Trimesh(self.vertices_m, self.faces, process=True)
            kind = mesh.symmetry
            axis = None if mesh.symmetry_axis is None else np.asarray(mesh.symmetry_axis, np.float64)
            centre = np.asarray(mesh.center_mass, np.float64)
        except Exception:                   # noqa: BLE001 -- a degenerate mesh has no measurable symmetry
            return None, None, None
        if kind == "radial" and axis is not None and np.linalg.norm(axis) > 0:
            return "radial", axis / np.linalg.norm(axis), centre
        if kind == "spherical":
            return "spherical", None, centre
        return None, None, None

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


# ---------------------------------------------------------------------------------------------- scale sanity
def _length(m: float) -> str:
    return f"{m * 1e3:.3g} mm" if m < 0.1 else f"{m:.3g} m"


def _scale_hint(mesh_scale: float, factors) -> str:
    opts = " or ".join(f"mesh_scale = {mesh_scale * f:g} ({unit})" for f, unit in factors)
    return f"set {opts} in its [[objects]] entry of scene.toml"


def size_problem(size_m, mesh_scale: float = 1.0) -> str | None:
    """Why an object whose bounding box has the sides ``size_m`` (metres, ``mesh_scale`` applied) is
    implausible, with the ``mesh_scale`` to try; None when its largest side is within
    [:data:`MIN_OBJECT_SIZE_M`, :data:`MAX_OBJECT_SIZE_M`]."""
    size = np.asarray(size_m, dtype=np.float64)
    big = float(size.max())
    unit, f = ("mm", 1e3) if big < 0.1 else ("m", 1.0)
    dims = " x ".join(f"{x * f:.3g}" for x in size) + f" {unit}"
    if big > MAX_OBJECT_SIZE_M:
        k = max(1, int(np.ceil(np.log10(big / MAX_OBJECT_SIZE_M) / 3)))       # powers of 1000 to come into range
        return (f"the object is {_length(big)} across ({dims} with mesh_scale = {mesh_scale:g}), more than "
                f"{MAX_OBJECT_SIZE_M:g} m: a mesh in millimetres read as metres? "
                + _scale_hint(mesh_scale, [(1000.0 ** -k, "millimetres" if k == 1 else "its unit")]))
    if big < MIN_OBJECT_SIZE_M:
        k = max(1, int(np.ceil(np.log10(MIN_OBJECT_SIZE_M / max(big, 1e-300)) / 3)))
        return (f"the object is {_length(big)} across ({dims} with mesh_scale = {mesh_scale:g}), less than "
                f"{MIN_OBJECT_SIZE_M * 1e3:g} mm: a mesh in metres given a millimetre scale? "
                + _scale_hint(mesh_scale, [(1000.0 ** k, "metres" if k == 1 else "its unit")]))
    return None


def camera_inside_problem(lo_m, hi_m, T_base_obj, cam_positions_base, mesh_scale: float = 1.0) -> str | None:
    """Why an object whose box ``[lo_m, hi_m]`` (object frame, metres) holds every camera position
    ``cam_positions_base`` (N, 3) of the recording is implausible (the camera inside the object all along:
    a mesh in centimetres or millimetres read as metres); None when some position is outside the box."""
    P = np.asarray(cam_positions_base, dtype=np.float64).reshape(-1, 3)
    if not len(P):
        return None
    T = np.asarray(T_base_obj, dtype=np.float64)
    p_obj = (P - T[:3, 3]) @ T[:3, :3]                      # R^T (p - t), row-wise
    lo, hi = np.asarray(lo_m, dtype=np.float64), np.asarray(hi_m, dtype=np.float64)
    if not np.all((p_obj >= lo) & (p_obj <= hi)):
        return None
    dims = " x ".join(f"{x:.3g}" for x in hi - lo)
    return (f"the camera is inside the object's {dims} m bounding box at every one of the {len(P)} poses of the "
            f"trajectory (mesh_scale = {mesh_scale:g}): a mesh in centimetres or millimetres read as metres? "
            + _scale_hint(mesh_scale, [(0.01, "centimetres"), (0.001, "millimetres")]))


def size_warnings(specs) -> list[str]:
    """One line per object of ``specs`` (``ObjectSpec``: ``name``, ``mesh``, ``mesh_scale``) whose mesh cannot
    be read or whose size is implausible (:func:`size_problem`): what an import reports about the scene it
    writes, which evpose then refuses to open until ``scene.toml`` is fixed."""
    out = []
    for i, spec in enumerate(specs):
        try:
            lo, hi = mesh_bounds(spec.mesh)
        except ObjectModelError as exc:
            out.append(f"objects[{i}] {spec.name!r}: {exc}")
            continue
        problem = size_problem((hi - lo) * spec.mesh_scale, spec.mesh_scale)
        if problem is not None:
            out.append(f"objects[{i}] {spec.name!r} ({Path(spec.mesh).name}): {problem}; evpose refuses the scene "
                       "until then")
    return out


_BOUNDS: dict[str, tuple[np.ndarray, np.ndarray]] = {}
_BOUNDS_LOCK = threading.Lock()


def mesh_bounds(path) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)``: the bounding box of a mesh file's vertices in the file's own units.

    Remembered by the file's content (SHA-1) in this process and in ``$XDG_CACHE_HOME/evpose/mesh_bounds``
    (never beside the mesh), so opening a scene reads a mesh with trimesh once per distinct file, not on
    every ``info``: hashing a 2 MB YCB mesh takes ~3 ms, loading it 50-250 ms. Raises
    :class:`ObjectModelError` like :meth:`ObjectModel.from_file`.
    """
    from evpose.core.data.event_index import default_cache_dir, write_npz_atomic
    from evpose.core.data.input_files import MAX_MESH_BYTES, InputFileError, open_regular

    path = Path(path)
    digest = hashlib.sha1()
    try:
        with open_regular(path, "rb", max_bytes=MAX_MESH_BYTES) as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
    except InputFileError as exc:
        raise ObjectModelError(f"{path}: cannot read the mesh: {exc.reason}") from None
    except OSError as exc:
        raise ObjectModelError(f"{path}: cannot read the mesh ({exc.strerror or exc})") from None
    key = digest.hexdigest()
    with _BOUNDS_LOCK:
        hit = _BOUNDS.get(key)
    if hit is not None:
        return hit
    cache = default_cache_dir().parent / "mesh_bounds" / f"{key}.npz"
    try:
        with np.load(cache) as z:
            hit = (z["lo"].astype(np.float64), z["hi"].astype(np.float64))
        if hit[0].shape != (3,) or hit[1].shape != (3,):
            hit = None
    except Exception:                       # noqa: BLE001 -- a missing or unreadable cache entry: recompute
        hit = None
    if hit is None:
        hit = ObjectModel.from_file(path).bbox_min_max
        try:
            write_npz_atomic(cache, lo=hit[0], hi=hit[1])
        except OSError:                     # a read-only or full cache folder costs time, not correctness
            pass
    with _BOUNDS_LOCK:
        _BOUNDS[key] = hit
    return hit


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


#: :func:`raster_friendly` adds at most this many triangles, whatever the mesh's metric size: the split
#: only speeds up rasterising, so a mesh that would need more (a 12-triangle CAD box in millimetres read as
#: metres: ~10^8 triangles of 2 cm, 4.4 GB) is split with longer edges, or not at all.
MAX_RASTER_ADDED_FACES = 65_536


def raster_friendly(model: ObjectModel, max_edge_m: float = PROCEDURAL_MAX_EDGE_M,
                    max_added_faces: int = MAX_RASTER_ADDED_FACES) -> ObjectModel:
    """``model`` with its edges longer than ``max_edge_m`` split at their midpoints
    (``trimesh.remesh.subdivide_to_size``); the model itself when no edge is that long.

    The surface is the same (planar triangles split into planar pieces; the original vertices
    are kept, so the bounding box, the keypoints and every mask are unchanged), but the
    rasteriser of the distorted camera bounds the bend of an edge by a margin quadratic in the
    triangle's size, so a few huge triangles (CAD primitives, a 12-triangle box) cost far more
    than many small ones: 72 -> 12 ms per export window, 154 -> 73 ms per app frame.
    Real scanned meshes (E-POSE: sub-centimetre triangles) are returned as they are.

    At most ``max_added_faces`` triangles are added, whatever the mesh's metric size: a round of
    splitting turns a triangle with a long edge into at most four and leaves the others alone, so ``K``
    rounds over ``n`` long triangles add at most ``n (4**K - 1)``; when the split to ``max_edge_m`` needs more
    rounds than that allows, the edge length is doubled (the mesh is returned unsplit if none fits).
    """
    import trimesh

    v, f = model.vertices_m, model.faces
    if len(f) == 0:
        return model
    e = v[f[:, [1, 2, 0]]] - v[f]
    longest = np.sqrt(np.einsum("fij,fij->fi", e, e).max(axis=1))
    edge = float(max_edge_m)
    while float(longest.max()) > edge:
        n_long = int(np.count_nonzero(longest > edge))
        rounds = int(np.log(1.0 + max_added_faces / n_long) / np.log(4.0))    # n_long (4**K - 1) <= max_added_faces
        needed = int(np.ceil(np.log2(float(longest.max()) / edge)))           # when every round halves every edge
        if needed <= rounds:
            try:
                v2, f2 = trimesh.remesh.subdivide_to_size(v, f, max_edge=edge, max_iter=rounds)
            except ValueError:              # "max_iter exceeded": thin triangles need extra rounds
                pass
            else:
                return ObjectModel(model.name, v2, f2, class_id=model.class_id, symmetric=model.symmetric,
                                   source=f"{model.source} (edges split to <= {edge * 1e3:g} mm for rasterising)")
        edge *= 2.0
    return model


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
