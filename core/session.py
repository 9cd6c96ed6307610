"""The model the desktop app views: a scene, its corrections, the undo history and view state.

Pure Python (no Qt): views subscribe with :meth:`Session.subscribe` and get told *what*
changed (``"time"``, ``"view"``, ``"objects"``, ``"document"``, ``"history"``, ``"reviews"``).
Document edits (clock, poses, hand-eye, reviews) go through :class:`~evpose.core.document.history.History`;
view state (current time, window length, representation, overlays, visibility, selection) is
neither saved nor undoable (DESIGN section 2).

Frame computation is a pure function of a :class:`FrameRequest` snapshot, so the app can run it
in a worker thread while the user keeps editing; the snapshot carries a copy of the corrections.

The current window is a cell of the export grid (windows of ``window_us`` from the first event,
:func:`evpose.core.document.review.grid_window`), so what the user sees and marks is an export window.

Changes another program saves to ``corrections.json`` (an ``evpose ... --apply``, a second app)
come in through :meth:`Session.check_disk` and :meth:`Session.reload_from_disk` /
:meth:`Session.merge_from_disk`, or through :meth:`Session.save`, which merges them. Each such
change is **one undo step of its own, labelled** ("another program's change to corrections.json
(revision N)"), recorded on top of the user's steps: undoing it returns to the state before it
(which then differs from the file, so the window shows unsaved changes), and the steps below it
stay consistent because each step records the values it replaced.
"""
from __future__ import annotations

import itertools
import json
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from evpose.core.data.events import EventArray
from evpose.core.data.scene import Scene
from evpose.core.document.corrections import CORRECTIONS_FORMAT, Corrections, CorrectionsError, ReviewMark
from evpose.core.document.corrections_file import read as read_corrections
from evpose.core.document.corrections_file import signature, target_of
from evpose.core.document.corrections_merge import MergeResult, field_name, merge
from evpose.core.document.history import Group, History, SetValue
from evpose.core.document.pose_edit import hand_eye_step, nudge_step
from evpose.core.document.review import grid_window, insert_mark, mark_state, stale_reasons
from evpose.core.label import represent
from evpose.core.label.annotate import Annotator, Request, Window, WindowLabels, label_time
from evpose.core.label.overlay import (
    ObjectOverlay,
    axes_segments,
    box_segments,
    compose_masks_rgba,
    mask_contours,
    object_color,
)

OVERLAY_KINDS = ("mask", "contour", "box", "axes", "center")
REPRESENTATION_NAMES = ("polarity", "spike", "three_channel", "time_surface", "counts", "voxel")
JOURNAL_NAME = ".corrections.autosave.json"
_SERIALS = itertools.count(1)


@dataclass(frozen=True)
class ViewState:
    """What the user looks at (not part of the document)."""

    t_us: int
    window_us: int = 10_000
    representation: str = "polarity"
    overlays: tuple = ("mask", "contour", "box", "center")
    hidden: frozenset = frozenset()
    selected: str | None = None
    mask_alpha: float = 0.35
    spacetime_span_us: int = 100_000
    spacetime_budget: int = 300_000
    spacetime_slices: int = 12
    #: Start of the window grid (the first event): windows are ``[origin + k w, origin + (k+1) w)``.
    grid_origin_us: int = 0

    def window(self, index: int | None = None) -> Window:
        """The grid window holding ``t_us`` (the export's tiling for this window length); ``index``
        defaults to its position in the grid."""
        t0, t1 = grid_window(self.t_us, self.grid_origin_us, self.window_us)
        k = (t0 - int(self.grid_origin_us)) // int(self.window_us) if index is None else index
        return Window(k, t0, t1, label_time(t0, t1))


@dataclass
class FrameData:
    """Everything the frame view draws for one window."""

    window: Window
    n_events: int
    image_rgb: np.ndarray                # (H, W, 3) uint8
    counts: np.ndarray                   # (H, W) int64: events per pixel (hover readout)
    labels: WindowLabels
    mask_rgba: np.ndarray | None         # (H, W, 4) uint8 composite of visible masks
    overlays: list[ObjectOverlay] = field(default_factory=list)
    inside_fraction: float | None = None  # share of the window's events on the (dilated) masks
    scores: dict = field(default_factory=dict)  # name -> evpose.core.align.score alignment score (None: undefined)
    compute_ms: float = 0.0


@dataclass
class SpaceTimeData:
    """Events around the current time as an (x, y, t) cloud, and the objects' silhouette tubes."""

    t_center_us: int
    points: np.ndarray        # (N, 3) float32: x px, y px, t ms relative to t_center
    polarity: np.ndarray      # (N,) uint8
    n_total: int              # events in the span before decimation
    tubes: list[tuple[str, tuple[int, int, int], list[np.ndarray]]]  # (name, colour, polylines (M, 3))
    span_us: int = 0


@dataclass
class ExternalChange:
    """``corrections.json`` as another program saved it (see :meth:`Session.check_disk`)."""

    revision: int
    disk: Corrections
    signature: tuple | None
    #: Fields that differ from the state we last loaded or saved.
    fields: list


@dataclass(frozen=True)
class FrameRequest:
    scene: Scene       # a snapshot: shares data, owns a copy of the corrections
    view: ViewState
    serial: int = 0


class Session:
    """Scene + history + view state, with change notification."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self.history = History(scene.corrections)
        t0, t1 = self.time_range
        self.view = ViewState(t_us=min(t0 + ViewState.window_us // 2, t1), grid_origin_us=t0)
        #: Why the autosave journal was ignored (damaged), or None.
        self.journal_problem: str | None = None
        self._listeners: list[Callable[[str], None]] = []
        scene.corrections.subscribe(self._doc_changed)
        self.history.subscribe(lambda h: self._emit("history"))

    @classmethod
    def open(cls, path) -> "Session":
        return cls(Scene.open(path))

    def close(self) -> None:
        self.scene.close()

    # ------------------------------------------------------------------ observation
    def subscribe(self, callback: Callable[[str], None]) -> Callable[[], None]:
        self._listeners.append(callback)
        return lambda: self._listeners.remove(callback) if callback in self._listeners else None

    def _emit(self, what: str) -> None:
        for cb in list(self._listeners):
            cb(what)

    def _doc_changed(self, what: str) -> None:
        self._emit("reviews" if what == "reviews" else "document")

    # ------------------------------------------------------------------ scene facts
    @property
    def time_range(self) -> tuple[int, int]:
        """``[t_first_us, t_last_us]`` of the events (event clock)."""
        ev = self.scene.events
        if ev.t_first_us is None:
            return 0, 0
        return int(ev.t_first_us), int(ev.t_last_us)

    @property
    def object_names(self) -> list[str]:
        return self.scene.object_names

    def color(self, name: str) -> tuple[int, int, int]:
        return object_color(self.object_names.index(name))

    @property
    def dirty(self) -> bool:
        return not self.history.is_clean

    # ------------------------------------------------------------------ view state
    def _set_view(self, what: str = "view", **changes) -> None:
        new = replace(self.view, **changes)
        if new != self.view:
            self.view = new
            self._emit(what)

    def set_time(self, t_us: int) -> None:
        t0, t1 = self.time_range
        self._set_view("time", t_us=int(min(max(int(t_us), t0), t1)))

    def busiest_time(self) -> int:
        """Centre of the window with the most events (from the ms index: no event read)."""
        t_bins, counts = self.scene.events.rate(1000)
        if len(counts) == 0:
            return self.time_range[0]
        w_ms = max(self.view.window_us // 1000, 1)
        per_window = np.convolve(counts, np.ones(w_ms, np.int64), mode="valid")
        k = int(np.argmax(per_window))
        return int(t_bins[k] + self.view.window_us // 2)

    def step_windows(self, n: int) -> None:
        self.set_time(self.view.t_us + n * self.view.window_us)

    def set_window_us(self, window_us: int) -> None:
        if window_us <= 0:
            raise ValueError("window length must be positive")
        self._set_view(window_us=int(window_us))

    def set_representation(self, name: str) -> None:
        if name not in represent.REPRESENTATIONS:
            raise ValueError(f"unknown representation {name!r}; choose from {sorted(represent.REPRESENTATIONS)}")
        self._set_view(representation=name)

    def set_overlay(self, kind: str, on: bool) -> None:
        if kind not in OVERLAY_KINDS:
            raise ValueError(f"unknown overlay {kind!r}")
        cur = [k for k in self.view.overlays if k != kind]
        self._set_view(overlays=tuple(k for k in OVERLAY_KINDS if k in cur or (k == kind and on)))

    def set_object_visible(self, name: str, visible: bool) -> None:
        hidden = set(self.view.hidden)
        hidden.discard(name) if visible else hidden.add(name)
        self._set_view("objects", hidden=frozenset(hidden))

    def select(self, name: str | None) -> None:
        if name is not None and name not in self.object_names:
            raise KeyError(name)
        self._set_view("objects", selected=name)

    def set_view_option(self, **changes) -> None:
        self._set_view(**changes)

    # ------------------------------------------------------------------ document edits
    def set_offset_correction_us(self, offset_us: int, mergeable: bool = True) -> None:
        """Clock offset correction on top of the scene's prior (microseconds)."""
        self.history.set(("offset_us",), int(offset_us), text="change time offset", mergeable=mergeable)

    def set_skew_correction_ppm(self, skew_ppm: float, mergeable: bool = True) -> None:
        self.history.set(("skew_ppm",), float(skew_ppm), text="change clock skew", mergeable=mergeable)

    def current_T_base_cam(self) -> np.ndarray:
        T, valid = self.scene.T_base_cam(np.array([self.view.t_us]))
        return T[0]

    def nudge_object(self, name: str, frame: str, rot_deg=(0, 0, 0), trans_mm=(0, 0, 0), mergeable: bool = True) -> None:
        """Rotate (degrees) / translate (mm) an object in ``frame`` axes about its box centre."""
        model = self.scene.model(name)
        step = nudge_step(frame, rot_deg, trans_mm, self.scene.T_base_obj(name), self.current_T_base_cam(),
                          pivot_obj_m=model.bbox_center_m)
        new = step @ self.scene.corrections.object_delta(name)
        self.history.set(("object", name), new, text=f"move {name}", mergeable=mergeable)

    def nudge_hand_eye(self, rot_deg=(0, 0, 0), trans_mm=(0, 0, 0), mergeable: bool = True) -> None:
        new = self.scene.corrections.hand_eye_delta @ hand_eye_step(rot_deg, trans_mm)
        self.history.set(("hand_eye",), new, text="change hand-eye", mergeable=mergeable)

    def reset(self, field_name: str) -> None:
        """Reset one field: ``"offset_us"``, ``"skew_ppm"``, ``"hand_eye"`` or an object name."""
        if field_name == "offset_us":
            self.history.set(("offset_us",), 0, text="reset time offset")
        elif field_name == "skew_ppm":
            self.history.set(("skew_ppm",), 0.0, text="reset clock skew")
        elif field_name == "hand_eye":
            self.history.set(("hand_eye",), np.eye(4), text="reset hand-eye")
        elif field_name in self.object_names:
            self.history.set(("object", field_name), np.eye(4), text=f"reset {field_name}")
        else:
            raise KeyError(field_name)

    def add_review(self, status: str, t0_us: int | None = None, t1_us: int | None = None, note: str = "",
                   obj: str | None = None) -> ReviewMark:
        """Mark ``[t0, t1)`` (default: the current grid window) verified / rejected / flagged.

        The mark replaces older marks of its scope on the overlap (:func:`evpose.core.document.review.insert_mark`:
        no window is both verified and rejected, no duplicates) and records the clock and the
        covered objects' pose digests (:func:`evpose.core.document.review.mark_state`) to detect staleness later."""
        w = self.view.window()
        if obj is not None and obj not in self.object_names:
            raise KeyError(obj)
        mark = ReviewMark(w.t0_us if t0_us is None else t0_us, w.t1_us if t1_us is None else t1_us, status, note,
                          obj, mark_state(self.scene, obj))
        self.history.set(("reviews",), insert_mark(self.scene.corrections.reviews, mark), text=f"mark {status}")
        return mark

    def remove_review(self, mark: ReviewMark) -> None:
        self.history.set(("reviews",), [m for m in self.scene.corrections.reviews if m != mark], text="remove mark")

    def stale_reasons(self, mark: ReviewMark, now=None) -> list[str]:
        """Why ``mark`` no longer verifies the current labels (empty: it does); see :mod:`core.review`.
        ``now``: :meth:`mark_state` when checking many marks."""
        return stale_reasons(self.scene, mark, now=now)

    def mark_state(self):
        """The clock and pose digests now (:func:`evpose.core.document.review.mark_state`, all objects)."""
        return mark_state(self.scene)

    def next_window_where(self, predicate: Callable[[str | None], bool], direction: int = 1) -> int | None:
        """Centre time of the next window (from the current one) whose review status satisfies
        ``predicate`` (e.g. unreviewed: ``lambda s: s is None``); None if there is none."""
        t0, t1 = self.time_range
        w = self.view.window_us
        t = self.view.t_us + direction * w
        while t0 <= t <= t1:
            if predicate(self.scene.corrections.review_status(t)):
                return t
            t += direction * w
        return None

    # ------------------------------------------------------------------ saving, other writers, journal
    def save(self, prefer: str | None = None) -> Path:
        """Save through :meth:`evpose.core.data.scene.Scene.save_corrections` (revision check). Another program's
        edits saved meanwhile are merged in as one labelled undo step; a real conflict raises
        :class:`evpose.core.document.corrections_merge.CorrectionsConflict` (nothing saved) unless ``prefer``
        ("local" / "disk") resolves it."""
        def take_merge(merged: Corrections) -> None:
            rev = self.scene.corrections.revision
            self._push_external(merged, f"merge another program's change to corrections.json (after revision {rev})",
                                clean=True)

        path = self.scene.save_corrections(apply_merge=take_merge, prefer=prefer)
        self.history.set_clean()
        self.discard_journal()
        return path

    def _push_external(self, target: Corrections, text: str, clean: bool) -> list[tuple]:
        doc = self.scene.corrections
        keys = doc.differing_keys(target)
        cmd = Group(text, [SetValue(k, doc.get(k), target.get(k)) for k in keys])
        self.history.push_external(cmd, clean)
        return keys

    def check_disk(self) -> "ExternalChange | None":
        """Has another program saved ``corrections.json`` since we loaded or saved it?

        Cheap when nothing happened (one ``stat``). Returns the change, or None (also when the file
        was saved with the content we know, e.g. by ourselves). Raises :class:`CorrectionsError`
        when the file on disk cannot be read."""
        doc = self.scene.corrections
        path = self.scene.corrections_path
        sig = signature(target_of(path))
        if sig == doc.disk_signature:
            return None
        disk, sig = read_corrections(path)
        if disk is None:
            doc.disk_signature = None        # removed: nothing to take over; the next save recreates it
            return None
        base = self._base_doc()
        if disk.canonical() == base.canonical():
            doc.disk_signature = sig
            doc.revision = disk.revision
            return None
        return ExternalChange(disk.revision, disk, sig, [field_name(k) for k in base.differing_keys(disk)])

    def _base_doc(self) -> Corrections:
        base = self.scene.corrections.base
        if base is None:
            return Corrections()
        return Corrections.from_json({"format": CORRECTIONS_FORMAT, "revision": 0, **base})

    def _take_disk_state(self, change: "ExternalChange") -> None:
        doc = self.scene.corrections
        doc.base = change.disk.canonical()
        doc.revision = change.revision
        doc.disk_signature = change.signature

    def reload_from_disk(self, change: "ExternalChange") -> list[tuple]:
        """Take the file's content, discarding unsaved local edits (one labelled undo step; the
        document is then clean). Returns the keys that changed."""
        keys = self._push_external(change.disk, f"reload corrections.json (revision {change.revision}, "
                                                 "changed by another program)", clean=True)
        self._take_disk_state(change)
        self.history.set_clean()
        return keys

    def merge_from_disk(self, change: "ExternalChange", prefer: str | None = None) -> MergeResult:
        """Apply another program's saved edits under the unsaved local ones (three-way merge against
        the state last loaded or saved; one labelled undo step). A real conflict raises
        :class:`evpose.core.document.corrections_merge.CorrectionsConflict` and changes nothing, unless ``prefer``."""
        res = merge(self._base_doc(), self.scene.corrections, change.disk, prefer=prefer,
                    source=str(self.scene.corrections_path))
        clean = res.doc.canonical() == change.disk.canonical()
        self._push_external(res.doc, f"merge another program's change to corrections.json "
                                     f"(revision {change.revision})", clean=clean)
        self._take_disk_state(change)
        if clean:
            self.history.set_clean()
        return res

    @property
    def journal_path(self) -> Path:
        return self.scene.root / JOURNAL_NAME

    def write_journal(self) -> Path | None:
        """Autosave unsaved corrections beside the scene (atomic); nothing when clean.

        The journal also holds the state the edits started from (``base``, ``base_revision``), so a
        restore can merge with what was saved since."""
        if not self.dirty:
            return None
        doc = self.scene.corrections
        data = doc.to_json()
        data["autosaved_at"] = time.time()
        data["base"] = doc.base
        data["base_revision"] = doc.revision
        from evpose.core.data.atomic import atomic_write_text

        try:
            return atomic_write_text(self.journal_path, json.dumps(data, indent=1))
        except OSError:
            return None  # read-only scene folder: nothing to do, Save will tell the user

    def pending_journal(self) -> Corrections | None:
        """Corrections autosaved by a session that did not save (e.g. after a crash).

        A journal that cannot be read back whole (cut short, not UTF-8, invalid) is ignored and
        reported in :attr:`journal_problem` (it stays on disk until the next save or discard)."""
        self.journal_problem = None
        p = self.journal_path
        try:
            raw = p.read_bytes()
        except FileNotFoundError:
            return None
        except OSError as exc:
            self.journal_problem = f"{p}: cannot read the autosave journal ({exc.strerror}); ignored"
            return None
        try:
            data = json.loads(raw.decode("utf-8"))
            if not isinstance(data, dict):
                raise CorrectionsError(f"{p}: expected a JSON object at the top level")
            data.pop("autosaved_at", None)
            has_base = "base" in data                  # journals of earlier versions have none
            base, base_rev = data.pop("base", None), data.pop("base_revision", None)
            journal = Corrections.from_json(data, source=str(p))
            if has_base:
                if base is None:                       # there was no corrections.json: the identity
                    base = Corrections().canonical()
                if not isinstance(base, dict):
                    raise CorrectionsError(f"{p}: base: expected an object")
                journal.base = Corrections.from_json({"format": CORRECTIONS_FORMAT, "revision": 0, **base},
                                                     source=f"{p}: base").canonical()
            journal.revision = base_rev if isinstance(base_rev, int) and not isinstance(base_rev, bool) else 0
        except UnicodeDecodeError as exc:
            self.journal_problem = f"{p}: autosave journal is not UTF-8 text (byte {exc.start}); ignored"
            return None
        except json.JSONDecodeError as exc:
            self.journal_problem = (f"{p}: autosave journal is damaged or cut short (line {exc.lineno}, column "
                                    f"{exc.colno}: {exc.msg}); ignored")
            return None
        except (CorrectionsError, RecursionError, TypeError, ValueError) as exc:
            self.journal_problem = f"{p}: autosave journal is not usable ({exc}); ignored"
            return None
        if journal.canonical() == self.scene.corrections.canonical():
            return None
        return journal

    def restore_journal(self, journal: Corrections) -> list:
        """Apply autosaved corrections as one undoable step.

        When the journal records the state its edits started from, it is merged with the current
        document (which may hold changes another program saved since): the autosaved edits win
        where both changed a field. Returns those conflicts (:class:`evpose.core.document.corrections_merge.Conflict`)."""
        conflicts = []
        target = journal
        if journal.base is not None:
            base = Corrections.from_json({"format": CORRECTIONS_FORMAT, "revision": 0, **journal.base})
            res = merge(base, journal, self.scene.corrections, prefer="local", source=str(self.journal_path))
            target, conflicts = res.doc, res.conflicts
        doc = self.scene.corrections
        with self.history.group("restore autosaved corrections"):
            for key in doc.differing_keys(target):
                self.history.set(key, target.get(key))
        return conflicts

    def discard_journal(self) -> None:
        try:
            os.unlink(self.journal_path)
        except OSError:
            pass

    # ------------------------------------------------------------------ snapshots for workers
    def request(self) -> FrameRequest:
        # serials grow across sessions, so a late result of a closed scene is always stale
        return FrameRequest(self.scene.with_corrections(self.scene.corrections.copy()), self.view, next(_SERIALS))


# ---------------------------------------------------------------------- computation (thread-safe)
class FrameComputer:
    """Computes :class:`FrameData` and :class:`SpaceTimeData` from requests; caches the
    rasteriser and per-object geometry between calls (use one instance per worker thread)."""

    def __init__(self):
        self._annotator: Annotator | None = None
        self._key = None
        self._score_params = None

    def _annotator_for(self, scene: Scene) -> Annotator:
        key = (id(scene.manifest),)
        if self._annotator is None or self._key != key:
            self._annotator = Annotator(scene, Request(keypoints=True, masks_visible=True, label_map=True, depth=True,
                                                               amodal=False))   # views show visible masks only
            self._key = key
        self._annotator.scene = scene
        return self._annotator

    def frame(self, req: FrameRequest) -> FrameData:
        t_start = time.perf_counter()
        scene, view = req.scene, req.view
        cam = scene.camera
        w = view.window()
        ev = scene.events.window(w.t0_us, w.t1_us)
        image = represent.to_rgb(view.representation, ev, cam.width, cam.height, w.t0_us, w.t1_us)
        pos, neg = represent.polarity_counts(ev, cam.width, cam.height)
        counts = pos + neg
        ann = self._annotator_for(scene)
        labels = ann.annotate(w)
        overlays, mask_rgba, inside = [], None, None
        names = scene.object_names
        if labels.valid:
            shown = [n not in view.hidden for n in names]
            if "mask" in view.overlays:
                mask_rgba = compose_masks_rgba(labels.label_map, [object_color(k) for k in range(len(names))],
                                               view.mask_alpha, shown)
            for k, o in enumerate(labels.objects):
                if not shown[k]:
                    continue
                ov = ObjectOverlay(o.name, object_color(k))
                if o.in_view:
                    if "contour" in view.overlays:
                        ov.contours = mask_contours(o.mask_visible)
                    if "box" in view.overlays and o.corners_cam is not None:
                        ov.box_segments = box_segments(cam, o.corners_cam)
                    if "axes" in view.overlays:
                        model = scene.model(o.name)
                        ov.axes = axes_segments(cam, o.T_cam_obj, 0.5 * model.diameter_m, model.bbox_center_m)
                    if "center" in view.overlays and o.center_uv is not None and np.all(np.isfinite(o.center_uv)):
                        ov.center_uv = o.center_uv
                overlays.append(ov)
            inside = inside_fraction(ev, labels.label_map)
        scores = self._scores(scene, ev, labels)
        return FrameData(w, len(ev), image, counts, labels, mask_rgba, overlays, inside, scores,
                         (time.perf_counter() - t_start) * 1e3)

    def _scores(self, scene: Scene, ev: EventArray, labels: WindowLabels) -> dict:
        """The window's alignment score per object (:mod:`core.score`, higher is better), from the
        label and depth images the frame already has: no second rasterisation."""
        from evpose.core.align.score import ScoreParams, score_window

        names = scene.object_names
        if not labels.valid or labels.label_map is None or labels.depth_m is None:
            return {n: None for n in names}
        if self._score_params is None or self._score_params[0] is not scene.camera:
            self._score_params = (scene.camera, ScoreParams().resolved(scene.camera))
        p = self._score_params[1]
        if len(ev) > p.max_events:
            ev = ev[::int(np.ceil(len(ev) / p.max_events))]
        res = score_window(ev, labels.label_map, labels.depth_m, len(names), p)
        return {n: (float(r.score) if r.valid else None) for n, r in zip(names, res)}

    def spacetime(self, req: FrameRequest) -> SpaceTimeData:
        scene, view = req.scene, req.view
        span = int(view.spacetime_span_us)
        t0 = int(view.t_us - span // 2)
        ev = scene.events.window(t0, t0 + span)
        n = len(ev)
        if n > view.spacetime_budget:
            idx = np.linspace(0, n - 1, view.spacetime_budget).astype(np.int64)
            ev = ev[idx]
        pts = np.empty((len(ev), 3), np.float32)
        pts[:, 0] = ev.x
        pts[:, 1] = ev.y
        pts[:, 2] = (ev.t - view.t_us).astype(np.float32) * 1e-3
        tubes = []
        n_slices = max(int(view.spacetime_slices), 2)
        times = t0 + (np.arange(n_slices) + 0.5) * (span / n_slices)
        times = np.rint(times).astype(np.int64)
        ann = self._annotator_for(scene)
        T_co, T_bc, valid = ann.poses(times)
        per_obj: dict[str, list[np.ndarray]] = {name: [] for name in scene.object_names}
        for i, t in enumerate(times):
            if not valid[i]:
                continue
            lab = ann.annotate(Window(-1, int(t), int(t) + 1, int(t)), pose=(T_co[i], T_bc[i], True))
            for o in lab.objects:
                if o.name in view.hidden or not o.in_view:
                    continue
                for c in mask_contours(o.mask_visible):
                    poly = np.empty((len(c), 3), np.float32)
                    poly[:, :2] = c
                    poly[:, 2] = (t - view.t_us) * 1e-3
                    per_obj[o.name].append(poly)
        for k, name in enumerate(scene.object_names):
            if per_obj[name]:
                tubes.append((name, object_color(k), per_obj[name]))
        return SpaceTimeData(int(view.t_us), pts, ev.p.copy(), n, tubes, span)


def inside_fraction(ev: EventArray, label_map: np.ndarray, dilate_px: int = 2) -> float | None:
    """Share of the events that fall on any object's mask dilated by ``dilate_px`` pixels
    (None for an empty window)."""
    if len(ev) == 0 or label_map is None:
        return None
    import cv2

    mask = (label_map >= 0).astype(np.uint8)
    if dilate_px > 0:
        mask = cv2.dilate(mask, np.ones((2 * dilate_px + 1, 2 * dilate_px + 1), np.uint8))
    return float(mask[ev.y, ev.x].mean())


@dataclass
class TimelineData:
    """Whole-sequence curves on the event clock (seconds since the first event)."""

    t_ref_us: int
    t_s: np.ndarray          # bin centres, s
    rate_hz: np.ndarray      # events per second
    speed_mps: np.ndarray    # camera linear speed at the pose time of each bin (current clock)
    angular_dps: np.ndarray  # camera angular speed, degrees per second
    speed_valid: np.ndarray  # False where the pose time is outside the trajectory or in a hole
    #: (H, 2) trajectory holes on the event clock, s since ``t_ref_us`` (current clock): no labels there
    holes_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def timeline_data(scene: Scene, bin_us: int = 1000) -> TimelineData:
    """Event rate and robot speed, the latter mapped through the clock in effect so a wrong
    offset shows as a shift between the two curves."""
    t_bins, counts = scene.events.rate(bin_us)
    t_ref = scene.t_ref_us
    centres = t_bins + bin_us // 2
    t_pose = scene.clock.pose_time(centres) if len(centres) else centres
    v, w, valid = scene.trajectory.speed(t_pose) if len(centres) else (np.zeros(0),) * 3
    holes = [((h["t0_us"] - t_ref) * 1e-6, (h["t1_us"] - t_ref) * 1e-6)
             for h in scene.trajectory_holes(window_us=bin_us)] if scene.trajectory.holes else []
    return TimelineData(t_ref, (centres - t_ref) * 1e-6, counts * (1e6 / bin_us), np.asarray(v),
                        np.degrees(np.asarray(w)), np.asarray(valid, bool), np.array(holes, np.float64).reshape(-1, 2))
