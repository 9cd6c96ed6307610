"""The :class:`Scene`: a scene manifest combined with the user's corrections into labels ``T_cam_obj(t)``.

The manifest (:mod:`evpose.core.data.manifest`, read by :func:`evpose.core.data.manifest_reader.load_manifest`)
says where the events, the trajectory and the meshes are; they are opened lazily, when first needed, and
cached. Problems with them raise :class:`~evpose.core.data.manifest.SceneError` naming the manifest field.

An *event-only* scene has no ``[trajectory]`` (and no objects): :attr:`Scene.has_poses` is False, the events and
the clock work as usual, and everything that needs poses (:attr:`Scene.trajectory`, :meth:`Scene.T_base_cam`,
:meth:`Scene.T_cam_obj`, :meth:`Scene.unlabeled_reasons`, :meth:`Scene.trajectory_holes`) raises
:class:`~evpose.core.data.manifest.NoPosesError` -- one line naming the manifest and the missing table -- when it
is asked, never when the scene opens.
"""
from __future__ import annotations

from functools import cached_property
from pathlib import Path

import numpy as np

from evpose.core.data.camera import CameraModel
from evpose.core.data.clock import ClockModel
from evpose.core.data.geometry import inv_T
from evpose.core.data.manifest import NoPosesError, SceneError, SceneManifest
from evpose.core.data.manifest_reader import load_manifest
from evpose.core.data.mesh_closure import cached_cull_sign
from evpose.core.data.model_cache import file_identity, shared_model
from evpose.core.data.objects import (
    ObjectModel,
    ObjectModelError,
    camera_inside_problem,
    mesh_bounds,
    raster_friendly,
    size_problem,
)
from evpose.core.data.trajectory import Trajectory, TrajectoryError
from evpose.core.document.corrections import CORRECTIONS_FILENAME, Corrections
from evpose.core.label.windows import DEFAULT_WINDOW_US


class Scene:
    """A manifest plus the user's corrections: the single source of labels.

    ``T_cam_obj(t) = inv(T_base_cam(t_pose)) @ T_base_obj`` with the corrected clock,
    hand-eye and object poses (see :mod:`evpose.core.document.corrections`). Events, trajectory and meshes load
    lazily and are cached.
    """

    def __init__(self, manifest: SceneManifest, corrections: Corrections | None = None):
        self.manifest = manifest
        self.corrections = corrections if corrections is not None else Corrections(scene_name=manifest.name)

    @classmethod
    def open(cls, path, *, corrections: Corrections | str | None = "auto", defaults: dict | None = None) -> "Scene":
        """Open a scene folder or ``scene.toml``; ``corrections="auto"`` loads ``corrections.json``
        beside it when present; ``defaults``: a dataset's shared tables
        (:func:`evpose.core.data.manifest_reader.load_manifest`). Objects of implausible size are refused
        here (:meth:`check_object_sizes`), so every command that opens a scene says so."""
        manifest = load_manifest(path, defaults=defaults)
        if isinstance(corrections, str) and corrections == "auto":
            cpath = manifest.root / CORRECTIONS_FILENAME
            corrections = (Corrections.load(cpath, known_objects=[o.name for o in manifest.objects])
                           if cpath.exists() or cpath.is_symlink() else None)
        scene = cls(manifest, corrections)
        scene.check_object_sizes()
        return scene

    # ------------------------------------------------------------------ resources
    @property
    def name(self) -> str:
        return self.manifest.name

    @property
    def root(self) -> Path:
        return self.manifest.root

    @property
    def camera(self) -> CameraModel:
        return self.manifest.camera

    @property
    def corrections_path(self) -> Path:
        return self.root / CORRECTIONS_FILENAME

    @property
    def object_names(self) -> list[str]:
        return [o.name for o in self.manifest.objects]

    @property
    def has_poses(self) -> bool:
        """The scene has a trajectory, so camera poses and (with objects) labels. False for an event-only scene:
        events, event frames and the clock work; whatever needs poses raises
        :class:`~evpose.core.data.manifest.NoPosesError`."""
        return self.manifest.has_trajectory

    def require_poses(self, what: str = "poses") -> None:
        """Refuse an event-only scene for ``what`` (e.g. ``"alignment scores"``): one
        :class:`~evpose.core.data.manifest.NoPosesError` line naming the manifest and the missing table."""
        if not self.has_poses:
            raise NoPosesError(self.manifest.path, what)

    @cached_property
    def events(self):
        """The scene's :class:`~evpose.core.data.event_store.EventStore` (opened read-only on first use; events outside
        the camera's ``width`` x ``height`` are refused, see the store's validation)."""
        from evpose.core.data.event_store import EventStore

        cam = self.manifest.camera
        return EventStore(self.manifest.events_path, sensor_size=(cam.width, cam.height))

    @cached_property
    def trajectory(self) -> Trajectory:
        """The trajectory file, with holes where samples are more than ``max_gap_us`` apart
        (``[trajectory] max_gap_us``, default :func:`evpose.core.data.trajectory_holes.default_max_gap_us`).
        An event-only scene raises :class:`~evpose.core.data.manifest.NoPosesError`."""
        if not self.has_poses:
            raise NoPosesError(self.manifest.path)
        mg = self.manifest.trajectory_max_gap_us
        try:
            traj = Trajectory.load_csv(self.manifest.trajectory_path, max_gap_us="auto" if mg is None else mg)
        except TrajectoryError as exc:
            raise SceneError(self.manifest.path, "trajectory.path", str(exc)) from None
        self._check_camera_outside_objects(traj)
        return traj

    def unlabeled_reasons(self, t_event_us, clock: ClockModel | None = None) -> list[str | None]:
        """Why each event time gets no label (None where it gets one): before or after the
        trajectory, or inside a hole of it (the same test :meth:`T_base_cam` applies)."""
        return self.trajectory.reasons_at_event_time(np.atleast_1d(t_event_us), clock or self.clock)

    def trajectory_holes(self, clock: ClockModel | None = None, window_us: int = DEFAULT_WINDOW_US) -> list[dict]:
        """The trajectory's holes and what they cost.

        Returns one dict per hole: ``t0_pose_us``/``t1_pose_us`` (the samples around the hole, pose
        clock), ``t0_us``/``t1_us`` (the same on the event clock under ``clock``), ``gap_ms``, and
        ``n_windows``: how many windows of the recording's tiling with ``window_us`` windows
        (labels at the centre, :func:`evpose.core.label.windows.time_windows`) have their label time in the
        hole, so get no label.
        """
        traj = self.trajectory
        clock = clock or self.clock
        ev = self.events
        out = []
        W = int(window_us)
        n_win = 0 if ev.t_first_us is None else -(-(ev.t_last_us + 1 - ev.t_first_us) // W)
        for k, (a, b) in zip(traj.hole_index, traj.holes):
            ea, eb = (int(v) for v in clock.event_time(np.array([a, b], np.int64)))
            n = 0
            if n_win:
                first = ev.t_first_us + W // 2            # label time of window 0
                j0 = min(max((ea - 2 - first) // W, 0), n_win)
                j1 = min(max((eb + 2 - first) // W + 1, 0), n_win)
                if j1 > j0:
                    labels = first + W * np.arange(j0, j1, dtype=np.int64)
                    code, seg = traj.locate_rel(clock.pose_time_rel(labels, traj.t_first_us))
                    n = int(np.count_nonzero((code == 3) & (seg == k)))
            out.append({"t0_pose_us": a, "t1_pose_us": b, "t0_us": ea, "t1_us": eb, "gap_ms": (b - a) / 1000.0,
                        "n_windows": n})
        return out

    @cached_property
    def _models(self) -> dict[str, ObjectModel]:
        return {}

    def model(self, name: str) -> ObjectModel:
        """The object's mesh in metres (loaded once; refused when its size is implausible)."""
        if name not in self._models:
            spec = self.manifest.object(name)
            i = self.object_names.index(name)
            try:        # shared with the other scenes of this process that load the same file alike
                model = shared_model(self._model_key(name), lambda: ObjectModel.from_file(
                    spec.mesh, name=name, mesh_scale=spec.mesh_scale, class_id=spec.class_id,
                    symmetric=spec.symmetric))
            except ObjectModelError as exc:
                raise SceneError(self.manifest.path, f"objects[{i}].mesh", str(exc)) from None
            lo, hi = model.bbox_min_max
            self._refuse_size(i, size_problem(hi - lo, spec.mesh_scale))
            self._models[name] = model
        return self._models[name]

    # ------------------------------------------------------------------ scale sanity
    def object_box(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box ``(lo, hi)`` of object ``name`` in its frame, metres (no mesh loaded: cached bounds)."""
        return self._object_box(self.object_names.index(name))

    def _object_box(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box ``(lo, hi)`` of object ``i`` in its frame, metres, from the mesh file's cached bounds."""
        spec = self.manifest.objects[i]
        try:
            lo, hi = mesh_bounds(spec.mesh)
        except ObjectModelError as exc:
            raise SceneError(self.manifest.path, f"objects[{i}].mesh", str(exc)) from None
        return lo * spec.mesh_scale, hi * spec.mesh_scale

    def _refuse_size(self, i: int, problem: str | None) -> None:
        if problem is not None:
            spec = self.manifest.objects[i]
            raise SceneError(self.manifest.path, f"objects[{i}].mesh_scale", f"{spec.mesh} ({spec.name}): {problem}")

    def check_object_sizes(self) -> None:
        """Refuse an object whose size is implausible (:func:`evpose.core.data.objects.size_problem`: a mesh
        in millimetres read as metres, or the reverse), naming ``objects[i].mesh_scale`` and the value to try.
        Reads each mesh's bounding box (:func:`~evpose.core.data.objects.mesh_bounds`, cached by content)."""
        for i, spec in enumerate(self.manifest.objects):
            lo, hi = self._object_box(i)
            self._refuse_size(i, size_problem(hi - lo, spec.mesh_scale))

    def _check_camera_outside_objects(self, traj: Trajectory) -> None:
        """Refuse an object whose bounding box holds the camera at every pose of ``traj``
        (:func:`evpose.core.data.objects.camera_inside_problem`); run when the trajectory loads."""
        if not self.manifest.objects or not len(traj):
            return
        T = traj.T()
        if self.manifest.trajectory_frame == "tcp":
            T = T @ self.manifest.hand_eye
        positions = (T @ self.corrections.hand_eye_delta)[:, :3, 3]
        for i, spec in enumerate(self.manifest.objects):
            lo, hi = self._object_box(i)
            self._refuse_size(i, camera_inside_problem(lo, hi, self.T_base_obj(spec.name), positions,
                                                       spec.mesh_scale))

    def raster_model(self, name: str) -> ObjectModel:
        """The object's mesh for rasterising: the same surface with long edges split
        (:func:`evpose.core.data.objects.raster_friendly`; loaded once). Keypoints, boxes and masks are
        identical to :meth:`model`'s, rendering is faster for coarse CAD meshes."""
        key = ("raster", name)
        if key not in self._models:
            base = self.model(name)
            file_key = self._model_key(name)

            def load():
                model = raster_friendly(base)
                cached_cull_sign(model.vertices_m, model.faces)      # paid here, not by the first frame
                return model

            self._models[key] = shared_model(None if file_key is None else ("raster",) + file_key, load)
        return self._models[key]

    def _model_key(self, name: str) -> tuple | None:
        """The key of ``name``'s model in the process's shared models (:mod:`evpose.core.data.model_cache`):
        the mesh file's identity and the load arguments; None when the file cannot be stat-ed."""
        spec = self.manifest.object(name)
        ident = file_identity(spec.mesh)
        if ident is None:
            return None
        return ident + (str(spec.mesh), name, float(spec.mesh_scale), int(spec.class_id), bool(spec.symmetric))

    @property
    def models(self) -> list[ObjectModel]:
        return [self.model(n) for n in self.object_names]

    def with_corrections(self, corrections: Corrections) -> "Scene":
        """A scene with other corrections that shares this one's loaded events, trajectory and
        meshes (for snapshots handed to worker threads and for previews)."""
        other = Scene(self.manifest, corrections)
        for key in ("events", "trajectory", "_models"):
            if key in self.__dict__:
                other.__dict__[key] = self.__dict__[key]
        return other

    def close(self) -> None:
        if "events" in self.__dict__:
            self.events.close()
            del self.__dict__["events"]

    def __enter__(self) -> "Scene":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ time
    @property
    def t_ref_us(self) -> int:
        """Clock reference: the first event time (0 for a scene without events)."""
        t = self.events.t_first_us
        return 0 if t is None else int(t)

    @property
    def clock(self) -> ClockModel:
        """The clock model in effect: prior from the manifest plus the user's correction."""
        return ClockModel(self.manifest.clock_offset_us + self.corrections.offset_us,
                          self.manifest.clock_skew_ppm + self.corrections.skew_ppm, self.t_ref_us)

    def clock_with(self, offset_us: int | None = None, skew_ppm: float | None = None) -> ClockModel:
        """The clock model with an effective offset/skew substituted (for previews and fitting)."""
        c = self.clock
        return ClockModel(c.offset_us if offset_us is None else offset_us,
                          c.skew_ppm if skew_ppm is None else skew_ppm, c.t_ref_us)

    # ------------------------------------------------------------------ poses
    def T_base_cam(self, t_event_us, clock: ClockModel | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Camera poses at event times: ``(T_base_cam (N, 4, 4), valid (N,))``.

        Applies the clock model, the hand-eye calibration (for ``tcp`` trajectories) and the
        hand-eye correction. ``valid`` is False where the pose time falls outside the
        trajectory; those rows hold the identity.
        """
        T, valid = self.trajectory.at_event_time(t_event_us, clock or self.clock)
        T = self.camera_from_trajectory(T)
        T[~valid] = np.eye(4)
        return T, valid

    def camera_from_trajectory(self, T_base_frame: np.ndarray) -> np.ndarray:
        """The camera poses ``T_base_cam`` of trajectory poses ``T_base_frame (..., 4, 4)``: the hand-eye calibration
        for a ``tcp`` trajectory, then the hand-eye correction."""
        T = T_base_frame
        if self.manifest.trajectory_frame == "tcp":
            T = T @ self.manifest.hand_eye
        dT = self.corrections.hand_eye_delta
        if not np.array_equal(dT, np.eye(4)):
            T = T @ dT
        return T

    def T_base_obj(self, name: str) -> np.ndarray:
        """Corrected object pose in the base frame: ``dT_base @ T_base_obj``."""
        T = self.manifest.object(name).T_base_obj
        d = self.corrections.object_deltas.get(name)
        return T.copy() if d is None else d @ T

    def T_cam_obj(self, t_event_us, names=None, clock: ClockModel | None = None, *,
                  base_cam: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Object poses in the camera at event times (``base_cam``: the result of
        :meth:`T_base_cam` for the same times and clock, when the caller has it already).

        Returns
        -------
        T : (N, K, 4, 4) float64
            ``inv(T_base_cam(t)) @ T_base_obj`` for the K objects in ``names`` (default: all).
        valid : (N,) bool
            False where the pose time is outside the trajectory (those rows are identity).
        """
        names = self.object_names if names is None else list(names)
        T_bc, valid = base_cam if base_cam is not None else self.T_base_cam(np.atleast_1d(t_event_us), clock)
        T_cb = inv_T(T_bc)
        T_bo = np.stack([self.T_base_obj(n) for n in names]) if names else np.zeros((0, 4, 4))
        T = np.einsum("nij,kjl->nkil", T_cb, T_bo)
        T[~valid] = np.eye(4)
        return T, valid

    # ------------------------------------------------------------------ document
    def save_corrections(self, apply_merge=None, prefer: str | None = None) -> Path:
        """Save ``corrections.json`` beside the manifest: the one save path of the CLI and the app.

        Checks the revision on disk and merges another program's edits saved meanwhile, or refuses a
        real conflict naming the field and both values (:class:`evpose.core.document.corrections_merge.CorrectionsConflict`);
        atomic and durable; writes through a symlink. ``apply_merge(merged)`` applies merged edits to
        the document (default: directly); details in ``self.corrections.last_save``
        (see :mod:`evpose.core.document.corrections_file`)."""
        self.corrections.scene_name = self.name
        return self.corrections.save(self.corrections_path, apply_merge=apply_merge, prefer=prefer)
