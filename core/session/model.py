"""The model the desktop app views: a scene, its corrections, the undo history and view state.

Pure Python (no Qt). Views subscribe to :attr:`Session.changed` (an
:class:`evpose.core.signals.Signal`) and get one :class:`~evpose.core.signals.Change` per action:

==========================================  =============================================
action                                      ``Session.changed`` emits (once)
==========================================  =============================================
:meth:`~Session.set_time`, step             ``Change("time", {"t_us"})``
window length, representation, overlays,    ``Change("view", {the ViewState fields set})``
display options
visibility, selection                       ``Change("objects", {"hidden"} / {"selected"})``
:meth:`~Session.set_preview` (on or off)    ``Change("view", {"preview"})``
any document edit, undo, redo, restore,     ``Change("document", {"clock", "hand_eye",
reload or merge of another program's save   "reviews", "object:<name>" it set})``
each move of a drag on the frame            ``Change("document", {"object:<name>"})``; the
(:meth:`~Session.drag_object`)              whole drag is one undo step
save, no-op edit, unchanged view            nothing
==========================================  =============================================

Document edits (clock, poses, hand-eye, reviews) go through
:class:`~evpose.core.document.history.History` (whose own :attr:`~History.changed` also tells
the undo state, e.g. after a save); view state (:class:`~evpose.core.session.view_state.ViewState`)
is neither saved nor undoable (DESIGN section 2).

Changes another program saves to ``corrections.json`` come in through :meth:`Session.check_disk`
and :meth:`Session.reload_from_disk` / :meth:`Session.merge_from_disk`, or through
:meth:`Session.save`, which merges them. Each is **one undo step of its own, labelled**, recorded
on top of the user's steps: undoing it returns to the state before it (which then differs from the
file, so the window shows unsaved changes).
"""
from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np

from evpose.core.data.scene import Scene
from evpose.core.document import disk_change, journal
from evpose.core.document.corrections import Corrections, ReviewMark
from evpose.core.document.corrections_merge import MergeResult, merge
from evpose.core.document.estimates import apply_clock_estimate, apply_pose_estimate
from evpose.core.document.commands import Group, SetValue
from evpose.core.document.history import History
from evpose.core.document.pose_edit import drag_step, hand_eye_step, nudge_step
from evpose.core.document.review import insert_mark, mark_state, stale_reasons
from evpose.core.label import represent
from evpose.core.label.overlay import object_color
from evpose.core.views.request import FrameRequest
from evpose.core.session.view_state import OVERLAY_KINDS, CountGrid, ViewState
from evpose.core.signals import Change, Signal

_SERIALS = itertools.count(1)


class Session:
    """Scene + history + view state, with one change signal (:attr:`changed`)."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self.history = History(scene.corrections)
        t0, t1 = self.time_range
        self.view = ViewState(t_us=min(t0 + ViewState.window_us // 2, t1), grid_origin_us=t0)
        #: Why the autosave journal was ignored (damaged), or None.
        self.journal_problem: str | None = None
        #: Corrections the views show instead of the document's (a proposal before Accept), or None: view state.
        self.preview: Corrections | None = None
        #: One :class:`~evpose.core.signals.Change` per action (see the module docstring).
        self.changed: Signal[Change] = Signal(Change)
        #: The object being dragged in the frame view (:meth:`begin_drag`): (name, its correction and pose
        #: at the start, the camera pose of the frame, the history's merge timeout), or None.
        self._drag: tuple | None = None
        self.history.changed.connect(self._history_changed)

    @classmethod
    def open(cls, path, defaults: dict | None = None) -> "Session":
        """A session on the scene at ``path``; ``defaults``: a dataset's shared tables (see ``Scene.open``)."""
        return cls(Scene.open(path, defaults=defaults))

    def close(self) -> None:
        """Close the scene; the autosave journal goes with it unless the document holds unsaved work (a session
        closed with unsaved edits it was told to keep, as after a crash)."""
        if not self.unsaved:
            self.discard_journal()
        self.scene.close()

    def _history_changed(self, change: Change) -> None:
        if self.journal_path.exists() and not self.unsaved:   # undo, redo or edits that cancel out came back to
            self.discard_journal()      # the saved content: the journal holds no work (it would offer a past state)
        if change.kind == "document":
            self.changed.emit(change)

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
        """Unsaved work: edits since the last save (the history's clean mark) that changed the content (edits that
        cancel out, a nudge and its opposite, leave nothing to save)."""
        return not self.history.is_clean and self.unsaved

    @property
    def unsaved(self) -> bool:
        """Does the document's content differ from the saved file's (:func:`evpose.core.document.journal.unsaved`)?
        Unlike :attr:`dirty` (the history's clean mark), False after edits that cancel out."""
        return journal.unsaved(self.scene.corrections)

    # ------------------------------------------------------------------ view state
    def _set_view(self, kind: str = "view", **changes) -> None:
        new = replace(self.view, **changes)
        fields = frozenset(k for k in changes if getattr(new, k) != getattr(self.view, k))
        if fields:
            self.view = new
            self.changed.emit(Change(kind, fields))

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
        grid = self.view.count_grid
        if grid is not None:                 # windows of N events: to the centre of the n-th next one
            self.set_time(grid.step(self.view.t_us, n))
            return
        self.set_time(self.view.t_us + n * self.view.window_us)

    def set_window_us(self, window_us: int) -> None:
        """Time windows of ``window_us`` (leaves windows of a number of events)."""
        if window_us <= 0:
            raise ValueError("window length must be positive")
        self._set_view(window_us=int(window_us), count_grid=None)

    def set_window_events(self, n_events: int) -> None:
        """Windows of ``n_events`` events each (the export's ``--window-events`` tiling, from the first
        event); ``window_us`` becomes their average length. 0 returns to time windows of that length."""
        n = int(n_events)
        if n < 0:
            raise ValueError("events per window must be positive")
        if n == 0:
            self._set_view(count_grid=None)
            return
        grid = CountGrid(self.scene.events, n)
        self._set_view(count_grid=grid, window_us=grid.mean_window_us())

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

    def set_preview(self, corrections: Corrections | None) -> None:
        """Show ``corrections`` (e.g. an estimate's proposal before Accept) in the frame and space-time views
        instead of the document's; None shows the document again. View state: the document, its history and
        its saves are untouched."""
        if corrections is None and self.preview is None:
            return
        self.preview = None if corrections is None else corrections.copy()
        self.changed.emit(Change("view", frozenset({"preview"})))

    # ------------------------------------------------------------------ document edits
    def set_offset_correction_us(self, offset_us: int, mergeable: bool = True) -> None:
        """Clock offset correction on top of the scene's prior (microseconds)."""
        self.end_drag()
        self.history.set(("offset_us",), int(offset_us), text="change time offset", mergeable=mergeable)

    def set_skew_correction_ppm(self, skew_ppm: float, mergeable: bool = True) -> None:
        self.end_drag()
        self.history.set(("skew_ppm",), float(skew_ppm), text="change clock skew", mergeable=mergeable)

    def label_sigma(self, name: str) -> dict | None:
        """The label sigma of object ``name`` at the current window (``t_mm``, ``deg``, ``px``: NaN where the window
        has no label) from the sigmas the applied estimates stored, with ``missing``: the inputs without one
        (:func:`evpose.core.label.uncertainty.stored_input_sigmas`); None when the document stores no sigma."""
        from evpose.core.label.uncertainty import label_sigmas, stored_input_sigmas

        c = self.scene.corrections
        if not c.sigmas or not self.scene.has_poses:
            return None
        inputs, missing = stored_input_sigmas(c, name)
        s = label_sigmas(self.scene, np.array([self.view.window().t_label_us], np.int64), [name], inputs)
        return {"t_mm": float(s.sigma_t_mm[0, 0]), "deg": float(s.sigma_R_deg[0, 0]), "px": float(s.sigma_px[0, 0]),
                "missing": missing}

    def current_T_base_cam(self) -> np.ndarray | None:
        """The camera pose at the view time, or None when the trajectory has none there (before or after it, or in
        a hole): then there are no camera axes to nudge along or read in."""
        T, valid = self.scene.T_base_cam(np.array([self.view.t_us]))
        return T[0] if valid[0] else None

    def nudge_object(self, name: str, frame: str, rot_deg=(0, 0, 0), trans_mm=(0, 0, 0), mergeable: bool = True) -> None:
        """Rotate (degrees) / translate (mm) an object in ``frame`` axes about its box centre. In camera axes only
        where the trajectory has a camera pose at the view time (``ValueError`` otherwise: the camera's axes there
        are unknown, and base axes would be applied under the camera's name)."""
        self.end_drag()
        model = self.scene.model(name)
        T_bc = self.current_T_base_cam()
        if T_bc is None:
            if frame == "camera":
                raise ValueError("no camera pose at this time (outside the trajectory): camera axes are unknown "
                                 "here; use object or base axes, or go to a time with a pose")
            T_bc = np.eye(4)                        # not used by the object and base axes
        step = nudge_step(frame, rot_deg, trans_mm, self.scene.T_base_obj(name), T_bc,
                          pivot_obj_m=model.bbox_center_m)
        new = step @ self.scene.corrections.object_delta(name)
        self.history.set(("object", name), new, text=f"move {name}", mergeable=mergeable)

    def set_object_pose(self, name: str, T_base_obj, text: str | None = None) -> None:
        """Set object ``name``'s pose in the base frame to ``T_base_obj`` (4x4; e.g. typed by the user): its
        correction becomes ``T_base_obj @ inv(T_base_obj of scene.toml)``, one undo step."""
        from evpose.core.data.geometry import inv_T, validate_T

        self.end_drag()
        T, _ = validate_T(np.asarray(T_base_obj, dtype=np.float64), f"{name}: T_base_obj")
        new = T @ inv_T(self.scene.manifest.object(name).T_base_obj)
        self.history.set(("object", name), new, text=text or f"set the pose of {name}")

    # ------------------------------------------------------------------ direct manipulation (frame view)
    def begin_drag(self, name: str) -> bool:
        """Start dragging object ``name`` on the frame (selecting it). Each :meth:`drag_object` until
        :meth:`end_drag` sets its pose from the pose at this moment, and all of them are one undo step
        (they merge, however long the drag pauses). False when the frame has no camera pose, or while a proposal
        is previewed (the object on screen is the proposal's, the drag would edit the document's)."""
        if name not in self.object_names:
            raise KeyError(name)
        self.end_drag()
        if self.preview is not None:
            return False
        T_bc, valid = self.scene.T_base_cam(np.array([self.view.window().t_label_us]))
        if not valid[0]:
            return False
        self.select(name)
        self._drag = (name, self.scene.corrections.object_delta(name), self.scene.T_base_obj(name), T_bc[0],
                      self.history.merge_timeout_s)
        self.history.merge_timeout_s = float("inf")
        self.history.break_merge()
        return True

    def drag_object(self, uv_from, uv_to, mode: str = "move") -> None:
        """Set the dragged object's pose for a drag from pixel ``uv_from`` to ``uv_to`` (raw image pixels,
        from the start of the drag): ``mode`` "move" (parallel to the image at the object's depth), "spin"
        (about the camera's z axis through its centre) or "tilt"; see
        :func:`evpose.core.document.pose_edit.drag_step`."""
        if self._drag is None:
            return
        name, delta0, T_bo0, T_bc, _ = self._drag
        step = drag_step(mode, uv_from, uv_to, self.scene.camera, T_bo0, T_bc, self.scene.model(name).bbox_center_m)
        self.history.set(("object", name), step @ delta0, text=f"drag {name}", mergeable=True)

    def end_drag(self) -> None:
        """End the drag: the next edit is a new undo step. Every other edit ends a drag first, so a drag whose mouse
        release never came (a dialog took the mouse) cannot absorb later edits into its undo step."""
        if self._drag is not None:
            self.history.merge_timeout_s = self._drag[4]
            self._drag = None
            self.history.break_merge()

    @property
    def dragging(self) -> str | None:
        """The object being dragged, or None."""
        return None if self._drag is None else self._drag[0]

    def nudge_hand_eye(self, rot_deg=(0, 0, 0), trans_mm=(0, 0, 0), mergeable: bool = True) -> None:
        self.end_drag()
        new = self.scene.corrections.hand_eye_delta @ hand_eye_step(rot_deg, trans_mm)
        self.history.set(("hand_eye",), new, text="change hand-eye", mergeable=mergeable)

    def reset(self, field_name: str) -> None:
        """Reset one field: ``"offset_us"``, ``"skew_ppm"``, ``"hand_eye"`` or an object name."""
        self.end_drag()
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

    def apply_clock_estimate(self, offset_us: int, skew_ppm: float | None = None,
                             text: str = "clock estimate", offset_std_us: float | None = None,
                             skew_std_ppm: float | None = None) -> None:
        """Make an accepted clock estimate the clock in effect (offset in us, skew in ppm, both
        totals; None keeps the skew) with its standard errors, one undo step
        (:func:`evpose.core.document.estimates.apply_clock_estimate`)."""
        apply_clock_estimate(self.history, self.scene, offset_us, skew_ppm, text, offset_std_us, skew_std_ppm)

    def apply_pose_estimate(self, name: str, dT_base, text: str | None = None, std_mm: float | None = None,
                            std_deg: float | None = None) -> None:
        """Make an accepted pose estimate ``dT_base`` (4x4, base frame) the correction of object
        ``name`` with its standard errors (mm of its centre, degrees), one undo step."""
        if name not in self.object_names:
            raise KeyError(name)
        apply_pose_estimate(self.history, name, dT_base, text, std_mm, std_deg)

    def apply_joint_estimate(self, result, text: str = "clock and poses from edges", *, clock: bool = True,
                             poses: bool = True) -> bool:
        """Make an accepted joint refinement (:class:`~evpose.core.align.joint_result.JointResult`: clock, object
        poses, hand-eye) the corrections in effect, one undo step
        (:func:`evpose.core.align.apply.apply_joint_result`). Returns whether anything changed."""
        from evpose.core.align.apply import apply_joint_result

        return apply_joint_result(self.history, self.scene, result, text, clock=clock, poses=poses)

    # ------------------------------------------------------------------ review marks
    def add_review(self, status: str, t0_us: int | None = None, t1_us: int | None = None, note: str = "",
                   obj: str | None = None) -> ReviewMark:
        """Mark ``[t0, t1)`` (default: the current grid window) verified / rejected / flagged.

        The mark replaces older marks of its scope on the overlap (:func:`evpose.core.document.review.insert_mark`:
        no window is both verified and rejected, no duplicates) and records the clock and the
        covered objects' pose digests (:func:`evpose.core.document.review.mark_state`) to detect staleness later.
        Refused (``ValueError``) while a proposal is previewed (:meth:`set_preview`): the mark would record the
        document's state, not the one on screen."""
        if self.preview is not None:     # the frame shows the proposal, the mark would record the document
            raise ValueError("a proposal is previewed on the frame: accept or reject it before marking windows")
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

    # ------------------------------------------------------------------ saving, other writers
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

    def check_disk(self) -> disk_change.ExternalChange | None:
        """Has another program saved ``corrections.json`` since we loaded or saved it? (See
        :func:`evpose.core.document.disk_change.check_disk`.)"""
        return disk_change.check_disk(self.scene.corrections, self.scene.corrections_path)

    def reload_from_disk(self, change: disk_change.ExternalChange) -> list[tuple]:
        """Take the file's content, discarding unsaved local edits (one labelled undo step; the
        document is then clean). Returns the keys that changed."""
        keys = self._push_external(change.disk, f"reload corrections.json (revision {change.revision}, "
                                                 "changed by another program)", clean=True)
        disk_change.take_disk_state(self.scene.corrections, change)
        self.history.set_clean()
        return keys

    def merge_from_disk(self, change: disk_change.ExternalChange, prefer: str | None = None) -> MergeResult:
        """Apply another program's saved edits under the unsaved local ones (three-way merge against
        the state last loaded or saved; one labelled undo step). A real conflict raises
        :class:`evpose.core.document.corrections_merge.CorrectionsConflict` and changes nothing, unless ``prefer``."""
        res = merge(disk_change.base_document(self.scene.corrections), self.scene.corrections, change.disk,
                    prefer=prefer, source=str(self.scene.corrections_path))
        clean = res.doc.canonical() == change.disk.canonical()
        self._push_external(res.doc, f"merge another program's change to corrections.json "
                                     f"(revision {change.revision})", clean=clean)
        disk_change.take_disk_state(self.scene.corrections, change)
        if clean:
            self.history.set_clean()
        return res

    # ------------------------------------------------------------------ autosave journal
    @property
    def journal_path(self) -> Path:
        return self.scene.root / journal.JOURNAL_NAME

    def write_journal(self) -> Path | None:
        """Autosave unsaved corrections beside the scene (atomic). With no unsaved work (clean, or edits that
        cancel out) nothing is written and a journal left from earlier in this session is removed."""
        if self.dirty and self.unsaved:
            return journal.write_journal(self.journal_path, self.scene.corrections)
        self.discard_journal()
        return None

    def pending_journal(self) -> journal.JournalOffer | None:
        """What a journal left by a session that did not save (e.g. a crash) holds that the document does not
        (:func:`evpose.core.document.journal.journal_offer`), or None. A journal that cannot be read back whole
        is ignored and reported in :attr:`journal_problem` (it stays on disk until the next save, discard or clean close)."""
        found, self.journal_problem = journal.read_journal(self.journal_path)
        if found is None:
            return None
        return journal.journal_offer(found, self.scene.corrections, journal_mtime=_mtime(self.journal_path),
                                     file_mtime=_mtime(self.scene.corrections_path), source=str(self.journal_path))

    def restore_journal(self, offer: journal.JournalOffer, take_autosaved: bool = False) -> list:
        """Apply a journal's edits as one undoable step, merged into what the file holds
        (:meth:`evpose.core.document.journal.JournalOffer.target`: the saved value is kept where both changed a
        field unless ``take_autosaved``); returns those conflicts."""
        target = offer.target(take_autosaved)
        doc = self.scene.corrections
        # the journal's values and sigmas as they are (History.set would drop a sigma whose value it changes)
        self.history.push(Group("restore autosaved corrections",
                                [SetValue(k, doc.get(k), target.get(k)) for k in doc.differing_keys(target)]))
        return offer.conflicts

    def discard_journal(self) -> None:
        journal.discard_journal(self.journal_path)

    # ------------------------------------------------------------------ snapshots for workers
    def request(self) -> FrameRequest:
        """A snapshot for the frame workers (:class:`~evpose.core.views.frame.FrameComputer`): the document's
        corrections, or the preview's while one is set (:meth:`set_preview`)."""
        corrections = self.scene.corrections if self.preview is None else self.preview
        # serials grow across sessions, so a late result of a closed scene is always stale
        return FrameRequest(self.scene.with_corrections(corrections.copy()), self.view, next(_SERIALS))


def _mtime(path: Path) -> float | None:
    """Modification time of ``path`` (s since the epoch), or None when it cannot be read."""
    try:
        return path.stat().st_mtime
    except OSError:
        return None
