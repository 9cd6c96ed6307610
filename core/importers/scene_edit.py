"""Editing a scene after its import: ``evpose scene set-trajectory`` and ``evpose scene add-objects`` (issue 26.4).

An event-only scene (``scene.toml`` without ``[trajectory]``, no objects) becomes a labelled one in two steps:
:func:`set_trajectory` reads a trajectory file with the importers' readers (our ``t_us,x,y,z,qx,qy,qz,qw`` CSV, TUM /
RPG text: :func:`~evpose.core.importers.pose_text.read_pose_text`; ``.npz``:
:func:`~evpose.core.importers.npz.read_npz_trajectory`), writes it as ``trajectory.csv`` into the scene folder (as an
import does: validated, ``T_base_cam``, metres, µs) and adds ``[trajectory]`` to ``scene.toml``; :func:`add_objects`
copies meshes into ``models/`` and adds ``[[objects]]`` entries (``--objects name=mesh:T_base_obj.json``, as for
``evpose import``). The same edits by hand are in the README ("Event-only scenes").

Safety (DESIGN section 9):

* the scene folder is locked (``flock``) during the edit; a second edit at the same time is refused;
* ``scene.toml`` is read once, must load, and is replaced atomically (temporary file, fsync, rename) only when its
  bytes are still those read: a file changed meanwhile (an editor, another program) is never overwritten, and the
  files this edit had added are removed again;
* the new ``scene.toml`` is loaded (paths, object sizes, the camera outside every object) before it replaces the old
  one; it keeps the fields and values of the old one (TOML comments are not kept);
* a new file never replaces one evpose did not write (``trajectory.csv`` or a mesh of that name the user put there):
  refused in one line naming it; every file written is logged in the scene's ownership log before it appears
  (:mod:`evpose.core.data.owned_log`), and ``scene.toml`` too when the version replaced was evpose's, so that
  ``evpose import --force`` can still replace the scene;
* the sources are only read (regular files; FIFOs and devices refused before they are opened).
"""
from __future__ import annotations

import contextlib
import os
import re
import sys
from pathlib import Path

from evpose.core.data.input_files import MAX_MANIFEST_BYTES, InputFileError, check_regular, open_regular
from evpose.core.data.manifest import SCENE_FILENAME, SceneError
from evpose.core.errors import InputError
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.options import ImportOptions
from evpose.core.importers.report import ImportContext

__all__ = ["TRAJECTORY_FORMATS", "TRAJECTORY_NAME", "SceneEdit", "set_trajectory", "add_objects"]

#: ``--format`` of ``set-trajectory``: auto (``.npz`` by its suffix, else text), csv / tum (text, unit from the
#: header or guessed), rpg (``groundtruth.txt``: seconds), npz.
TRAJECTORY_FORMATS = ("auto", "csv", "tum", "rpg", "npz")
#: The trajectory's name in the scene folder (as the importers write it).
TRAJECTORY_NAME = "trajectory.csv"
SCENE_ROLE = "scene"


class SceneEdit:
    """One locked, checked edit of a scene folder: new files, then ``scene.toml`` (see the module docstring).

    Use as a context manager: ``doc`` is the parsed ``scene.toml`` (to change), ``manifest`` the validated one;
    :meth:`write_file` adds a file, :meth:`commit` writes the new ``doc``. Leaving with an exception removes the
    files this edit created.
    """

    def __init__(self, scene, command: str):
        path = Path(scene).expanduser()
        self.path = path / SCENE_FILENAME if path.is_dir() else path
        self.root = self.path.parent
        self.command = command
        self._fd: int | None = None
        self._log = None
        self._created: list[Path] = []
        self.raw = b""
        self.doc: dict = {}
        self.manifest = None

    # ------------------------------------------------------------------ open / close
    def __enter__(self) -> "SceneEdit":
        from evpose.core.data.manifest_reader import load_manifest

        if self.path.is_symlink():
            raise SceneError(self.path, "", "is a symbolic link; edit the scene it points to")
        self.manifest = load_manifest(self.path)          # a scene that does not load is refused as it is
        self._lock()
        try:
            self.raw = self._read()
            self.doc = _toml(self.raw, self.path)
        except BaseException:
            self._unlock()
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:               # undo: only files this edit created and nobody replaced since
            for p in reversed(self._created):
                if self._ours(p):
                    with contextlib.suppress(OSError):
                        p.unlink()
        if self._log is not None:
            self._log.close()
        self._unlock()

    def _lock(self) -> None:
        from evpose.core.data.temp_files import try_lock_folder

        self._fd = try_lock_folder(self.root)
        if self._fd is None:
            raise SceneError(self.path, "", "another evpose command is changing this scene folder; try again when "
                             "it is done")

    def _unlock(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None

    def _read(self) -> bytes:
        try:
            with open_regular(self.path, "rb", max_bytes=MAX_MANIFEST_BYTES) as f:
                return f.read()
        except InputFileError as exc:
            raise SceneError(self.path, "", f"cannot read the scene manifest: {exc.reason}") from None

    @property
    def log(self):
        from evpose.core.data.owned_log import OwnedLog

        if self._log is None:
            self._log = OwnedLog(self.root, SCENE_ROLE, self.command)
        return self._log

    def _ours(self, path: Path) -> bool:
        """``path`` is a file evpose wrote into this scene and nobody changed since (its ownership log says so)."""
        from evpose.core.data.owned_log import read_logs

        try:
            st = os.lstat(path)
        except OSError:
            return False
        rel = path.relative_to(self.root).as_posix()
        return (st.st_size, st.st_mtime_ns) in read_logs(self.root, SCENE_ROLE).files.get(rel, set())

    # ------------------------------------------------------------------ writing
    def write_file(self, rel: str, data: bytes, field: str) -> Path:
        """Write ``data`` to ``root/rel`` atomically, logged before it appears; refuse a file there that evpose did
        not write (``field``: the manifest field the file is for, named in the refusal)."""
        from evpose.core.data.atomic import atomic_path

        dst = self.root / rel
        existed = dst.exists() or dst.is_symlink()
        if existed and not self._ours(dst):
            raise SceneError(self.path, field, f"{dst} exists and evpose did not write it (or it changed since): "
                             "move it away first; evpose never replaces a file it did not write")
        if not dst.parent.is_dir():
            self.log.dirs([dst.parent])                   # (logged before it exists, as every entry)
            dst.parent.mkdir()
        with atomic_path(dst) as tmp:
            tmp.write_bytes(data)
            st = os.stat(tmp)
            self.log.files([(dst, st.st_size, st.st_mtime_ns)])
            self.log.sync()
        if not existed:
            self._created.append(dst)
        return dst

    def commit(self, doc: dict, check=None) -> Path:
        """Replace ``scene.toml`` by ``doc`` when its bytes are still those read; the new manifest must load
        (``check(manifest)``: further checks, e.g. :func:`check_scene`). Returns the manifest's path."""
        import tomli_w

        from evpose.core.data.atomic import atomic_path
        from evpose.core.data.manifest_reader import load_manifest

        ours = self._ours(self.path)
        with atomic_path(self.path) as tmp:
            tmp.write_text(tomli_w.dumps(doc), encoding="utf-8")
            try:
                m = load_manifest(tmp)
                m.path = self.path
                if check is not None:
                    check(m)
            except InputError as exc:
                raise InputError(str(exc).replace(str(tmp), str(self.path))) from None
            if self._read() != self.raw:
                raise SceneError(self.path, "", "changed since this command read it (another program wrote it); "
                                 "nothing was changed: run the command again")
            if ours:
                st = os.stat(tmp)
                self.log.files([(self.path, st.st_size, st.st_mtime_ns)])
                self.log.sync()
        return self.path


def _toml(raw: bytes, path: Path) -> dict:
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    try:
        return tomllib.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:       # load_manifest read it a moment ago
        raise SceneError(path, "", f"not valid TOML any more ({exc})") from None


def check_scene(manifest) -> None:
    """Open the edited manifest as a scene the way every command does: object sizes, the trajectory, the camera
    outside every object at every pose (:class:`~evpose.core.data.scene.Scene`)."""
    from evpose.core.data.scene import Scene

    scene = Scene(manifest)
    scene.check_object_sizes()
    if scene.has_poses:
        scene.trajectory


def _with_table(doc: dict, key: str, table, after: str) -> dict:
    """``doc`` with ``key`` set to ``table``, placed right after ``after`` (the order of DESIGN section 4)."""
    out = {}
    for k, v in doc.items():
        if k != key:
            out[k] = v
        if k == after:
            out[key] = table
    out.setdefault(key, table)
    return out


# ---------------------------------------------------------------------- set-trajectory
def read_trajectory(path, ctx: ImportContext, fmt: str = "auto"):
    """A validated ``T_base_cam`` :class:`~evpose.core.data.trajectory.Trajectory` from ``path`` in format ``fmt``
    (:data:`TRAJECTORY_FORMATS`), by the readers of the importers."""
    from evpose.core.importers.pose_text import read_pose_text

    path = Path(path)
    if fmt not in TRAJECTORY_FORMATS:
        raise ImportFailure("(arguments)", "--format", "format", f"expected one of {', '.join(TRAJECTORY_FORMATS)}, "
                            f"got {fmt!r}")
    try:
        check_regular(path)
    except InputFileError as exc:
        raise ImportFailure(path, "(file)", "TRAJECTORY", exc.reason) from None
    if fmt == "npz" or (fmt == "auto" and path.suffix.lower() == ".npz"):
        from evpose.core.importers.npz import read_npz_trajectory

        return read_npz_trajectory(path, ctx)
    if fmt == "rpg":
        return read_pose_text(path, ctx, declared_unit="s", what="groundtruth")
    return read_pose_text(path, ctx)


def set_trajectory(scene, trajectory, options: ImportOptions | None = None, *, fmt: str = "auto",
                   log=None) -> dict:
    """Give the event-only scene ``scene`` (folder or ``scene.toml``) the trajectory in the file ``trajectory``
    (``T_base_cam``, metres; ``fmt``: :data:`TRAJECTORY_FORMATS`); ``options``: ``time_unit``, ``repair``,
    ``offset_us`` (the clock prior, pose minus event time) of :class:`~evpose.core.importers.options.ImportOptions`.
    ``log(line)`` gets the assumptions, repairs and warnings.

    Returns the summary: ``scene``, ``trajectory`` (its path in the scene), ``n_poses``, ``t0_us``, ``t1_us`` (pose
    clock), ``time_overlap_us``, ``clock`` and the report's ``assumptions``, ``repairs``, ``warnings``.
    """
    from evpose.core.data.trajectory_csv import pose_csv_text
    from evpose.core.importers.scene_builder import warn_if_no_time_overlap

    ctx = ImportContext("scene set-trajectory", [trajectory], options, log=log)
    with SceneEdit(scene, "scene set-trajectory") as edit:
        m = edit.manifest
        if m.has_trajectory or "trajectory" in edit.doc:
            raise SceneError(edit.path, "trajectory", f"the scene has a trajectory already ({m.trajectory_path}); "
                             "set-trajectory gives one to an event-only scene (edit scene.toml to change it)")
        traj = read_trajectory(trajectory, ctx, fmt)
        rep = ctx.report
        rep.assume(f"{Path(trajectory).name}: poses are T_base_cam (camera in the base frame, metres)")
        doc = _with_table(edit.doc, "trajectory", {"path": TRAJECTORY_NAME, "frame": "cam"}, after="events")
        clock = dict(doc.get("clock") or {})
        if ctx.options.offset_us is not None:
            clock["offset_us"] = int(ctx.options.offset_us)
            doc = _with_table(doc, "clock", clock, after="trajectory")
            rep.assume(f"clock prior offset {int(ctx.options.offset_us)} µs (--offset-us)")
        offset, skew = int(clock.get("offset_us", m.clock_offset_us)), float(clock.get("skew_ppm", m.clock_skew_ppm))
        _overlap_details(rep, m, traj)
        warn_if_no_time_overlap(rep, offset, skew)
        edit.write_file(TRAJECTORY_NAME, pose_csv_text(traj.t_us, traj.positions_m, traj.quats_xyzw).encode(),
                        "trajectory.path")
        edit.commit(doc, check_scene)
    return {"scene": str(edit.root), "trajectory": str(edit.root / TRAJECTORY_NAME), "n_poses": len(traj),
            "t0_us": int(traj.t_first_us), "t1_us": int(traj.t_last_us),
            "time_overlap_us": rep.details.get("time_overlap_us"), "clock": {"offset_us": offset, "skew_ppm": skew},
            "assumptions": rep.assumptions, "repairs": rep.repairs, "warnings": rep.warnings}


def _overlap_details(rep, manifest, traj) -> None:
    """The events' and the trajectory's time ranges into the report (for the overlap warning)."""
    from evpose.core.data.event_store import EventStore

    cam = manifest.camera
    with EventStore(manifest.events_path, sensor_size=(cam.width, cam.height)) as ev:
        rep.details["events"] = {"t_first_us": ev.t_first_us, "t_last_us": ev.t_last_us}
    rep.details["trajectory"] = {"n": len(traj), "t_first_us": int(traj.t_first_us), "t_last_us": int(traj.t_last_us)}


# ---------------------------------------------------------------------- add-objects
def add_objects(scene, options: ImportOptions, *, log=None) -> dict:
    """Add the objects of ``options.objects`` (``name=mesh:T_base_obj.json,...``, as ``evpose import --objects``;
    ``options.mesh_scale``: mesh units to metres, default 1) to a scene that has a trajectory: each mesh is copied
    into ``models/`` (checked to load as a triangle mesh), each entry appended to ``[[objects]]`` with the next
    class ids. Returns ``scene``, ``objects`` (the names added) and the report's lines."""
    from evpose.core.data.geometry import ROTATION_TOLERANCE, orthonormalize
    from evpose.core.importers.meshes import check_mesh
    from evpose.core.importers.object_args import collect_objects

    ctx = ImportContext("scene add-objects", [], options, log=log)
    with SceneEdit(scene, "scene add-objects") as edit:
        m = edit.manifest
        if not m.has_trajectory:
            raise SceneError(edit.path, "[trajectory]", "missing table: objects are placed in the base frame and "
                             "need a camera trajectory first (evpose scene set-trajectory SCENE TRAJECTORY)")
        objs = collect_objects(ctx, None)
        if not objs:
            raise ImportFailure("(arguments)", "--objects", "objects", "give --objects name=mesh:T_base_obj.json,...")
        have = {o.name for o in m.objects}
        used = {Path(o.mesh).resolve() for o in m.objects}
        next_id = max((o.class_id for o in m.objects), default=0) + 1
        entries = list(edit.doc.get("objects") or [])
        scale = float(options.mesh_scale) if options.mesh_scale is not None else 1.0
        for k, (name, (mesh, T, _cid, _src)) in enumerate(objs.items()):
            if name in have:
                raise ImportFailure("--objects", name, "name", f"the scene has an object named {name!r} already")
            check_mesh(Path(mesh), name)
            rel = f"models/{re.sub(r'[^A-Za-z0-9_.-]+', '_', name) or 'object'}{Path(mesh).suffix.lower()}"
            if (edit.root / rel).resolve() in used:
                raise ImportFailure("--objects", name, "mesh", f"{rel} is the mesh of another object of the scene")
            with open_regular(mesh, "rb") as f:
                edit.write_file(rel, f.read(), f"objects[{len(entries)}].mesh")
            entry = {"name": name, "mesh": rel, "mesh_scale": scale, "T_base_obj": T.tolist(),
                     "class_id": next_id + k, "symmetric": False}
            if orthonormalize(T[:3, :3])[1] > ROTATION_TOLERANCE:      # accepted by --repair: projected on load
                entry["repair_rotation"] = True
            entries.append(entry)
        doc = {k: v for k, v in edit.doc.items() if k != "objects"}
        doc["objects"] = entries                          # last, as in DESIGN section 4
        edit.commit(doc, check_scene)
    rep = ctx.report
    return {"scene": str(edit.root), "objects": list(objs), "assumptions": rep.assumptions, "repairs": rep.repairs,
            "warnings": rep.warnings}
