"""The main window: frame view in the centre, space-time view, timeline and correction tools in
docks; menus and shortcuts from :mod:`app.actions`; frames computed off the GUI thread."""
from __future__ import annotations

from pathlib import Path

from PySide6 import QtCore, QtGui, QtWidgets

from evpose.app import actions as A
from evpose.app import frame_actions
from evpose.app import events_only
from evpose.app import layout as L
from evpose.app.residual_feed import ResidualFeed
from evpose.app.wheel_guard import install_wheel_guard
from evpose.app.align import AlignController
from evpose.app.controller import Controller
from evpose.app.dialog_place import DialogPlacer
from evpose.app.disk_watch import CorrectionsWatcher
from evpose.app.memory import IdleReleaser
from evpose.app.review_menu import fill_review_menu, review_actions
from evpose.app.score_row import ScoreRowUpdater
from evpose.app.settings import Settings
from evpose.app.shortcut_guard import ShortcutGuard
from evpose.app.undo_bridge import UndoBridge
from evpose.app.feeds import ViewFeeds
from evpose.core.views.frame import FrameData
from evpose.core.session.model import Session
from evpose.core.session.view_state import REPRESENTATION_NAMES
from evpose.core.signals import Change
from evpose.widgets.correction_panel import CorrectionPanel
from evpose.widgets.frame.view import DISPLAY_ONLY_FIELDS, FrameView
from evpose.widgets.help_overlay import HelpOverlay
from evpose.widgets.object_list import ObjectList
from evpose.widgets.review_panel import ReviewPanel

AUTOSAVE_MS = 20_000
OVERLAY_ACTIONS = {"toggle_mask": "mask", "toggle_contour": "contour", "toggle_box": "box", "toggle_axes": "axes"}
REPRESENTATION_LABELS = {"polarity": "Polarity (ON red / OFF blue)", "spike": "Spike (any event)",
                         "three_channel": "E-POSE 3-channel", "time_surface": "Time surface",
                         "counts": "Event counts", "voxel": "Voxel grid (signed sum)"}


class MainWindow(QtWidgets.QMainWindow):
    """One window per session. ``set_session`` (via the controller's ``open_scene``) builds the views."""

    #: False in tests and screenshot runs: dialogs do not block (answers from ``auto_answer``).
    modal_dialogs = True

    def __init__(self, settings: Settings | None = None):
        super().__init__()
        install_wheel_guard(QtWidgets.QApplication.instance())     # the wheel scrolls panels, not their values
        self.settings = settings or Settings()
        self.session: Session | None = None
        self.controller = Controller(self)
        self.align = AlignController(self)
        self.score_row = ScoreRowUpdater(self)   # the timeline's scores: stale at once, recomputed in the background
        self.auto_answer: dict = {}
        self.last_error: str | None = None
        self.last_export = None
        self.dataset_window = None      # evpose.app.dataset_window.DatasetWindow, once a dataset is opened
        self.frame: FrameData | None = None
        self._docks: list[QtWidgets.QDockWidget] = []
        self._session_connection = None
        self.undo_bridge: UndoBridge | None = None
        self.disk_watcher: CorrectionsWatcher | None = None
        self.setWindowTitle("evpose[*]")
        L.fit_to_screen(self, "first")     # most of the screen, never larger (app/layout.py)
        self.setAcceptDrops(True)
        self.setDockNestingEnabled(True)

        # every view's request -> worker -> widget pipeline (app/feeds.py); the residual view has its own, with its dock
        self.feeds = ViewFeeds(self)
        self.residual_feed = ResidualFeed(self)
        #: gives freed heap pages and cached module sources back once the user pauses (app/memory.py)
        self.memory = IdleReleaser(self, tasks=lambda: (self.feeds.idle_release_tasks()
                                                        + self.residual_feed.idle_release_tasks()))
        self._autosave = QtCore.QTimer(self, interval=AUTOSAVE_MS)
        self._autosave.timeout.connect(lambda: self.session and self.session.write_journal())
        self._autosave.start()

        self.welcome = QtWidgets.QLabel("<h2>evpose</h2><p>Open a scene folder (Ctrl+O), pick a recent scene "
                                        "from the File menu, or drop a scene folder or scene.toml here.</p>")
        self.welcome.setAlignment(QtCore.Qt.AlignCenter)
        self.setCentralWidget(self.welcome)
        self._build_actions()
        self._build_menus()
        self.help = HelpOverlay(self)
        self.help.set_shortcuts(A.help_sections())
        self.dialog_placer = DialogPlacer(self)    # progress and result boxes beside the frame view, not over it
        # typed keys on a focused button / box / slider never reach the single-key shortcuts (issue 16)
        self.shortcut_guard = ShortcutGuard(self, lambda: frame_actions.focus_frame(self),
                                            lambda t: self.statusBar().showMessage(t, 6000))
        self.statusBar().showMessage("ready")
        if self.settings.restore_geometry(self):
            L.fit_to_screen(self)

    # ------------------------------------------------------------------ actions and menus
    def _build_actions(self) -> None:
        self.actions_by_name: dict[str, QtGui.QAction] = {}
        for sc in A.SHORTCUTS:
            act = QtGui.QAction(A.sentence_case(sc.text), self)
            act.setShortcuts([QtGui.QKeySequence(k) for k in sc.keys])
            act.setShortcutContext(QtCore.Qt.WindowShortcut)
            act.setToolTip(f"{sc.text} ({' / '.join(sc.keys)})")
            self.addAction(act)
            self.actions_by_name[sc.name] = act
        a = self.actions_by_name
        a["undo"].setText("&Undo")
        a["redo"].setText("&Redo")
        a["open"].setText("&Open scene…")
        a["save"].setText("&Save corrections")
        a["export"].setText("&Export dataset…")
        a["screenshot"].setText("Save s&creenshot…")
        a["quit"].setText("&Quit")
        a["help"].setText("&Keyboard shortcuts")
        a["open"].triggered.connect(self.controller.open_dialog)
        a["save"].triggered.connect(self.controller.save)
        a["export"].triggered.connect(self.controller.export_dialog)
        a["screenshot"].triggered.connect(self._screenshot_dialog)
        a["quit"].triggered.connect(self.close)
        a["help"].triggered.connect(lambda: self.help.toggle())
        for name, n in (("step_back", -1), ("step_forward", 1), ("step_back_10", -10), ("step_forward_10", 10)):
            a[name].triggered.connect(lambda _=False, n=n: self.session and self.session.step_windows(n))
        a["go_start"].triggered.connect(lambda: self.session and self.session.set_time(self.session.time_range[0]))
        a["go_end"].triggered.connect(lambda: self.session and self.session.set_time(self.session.time_range[1]))
        a["play"].triggered.connect(lambda: self.timeline is not None and self.timeline.toggle_play())
        for name, sign, big in (("offset_minus", -1, False), ("offset_plus", 1, False),
                                ("offset_minus_10", -1, True), ("offset_plus_10", 1, True)):
            a[name].triggered.connect(lambda _=False, s=sign, b=big: self.panel and self.panel.nudge_offset(s, b))
        for name, (kind, axis, sign) in A.NUDGES.items():
            act = a[name]
            act.setShortcuts(act.shortcuts() + [QtGui.QKeySequence(f"Shift+{act.shortcut().toString()}")])
            act.triggered.connect(lambda _=False, k=kind, ax=axis, sg=sign, act=act: self._nudge(k, ax, sg))
        a["next_object"].triggered.connect(self._next_object)
        for name in ("verified", "rejected", "flagged"):
            a[f"mark_{name}"].triggered.connect(lambda _=False, s=name: self.reviews and self.reviews.mark(s))
        a["next_unreviewed"].triggered.connect(lambda: self.reviews and self.reviews.goto_next(lambda s: s is None))
        a["next_flagged"].triggered.connect(lambda: self.reviews and self.reviews.goto_next(lambda s: s == "flagged"))
        for name, kind in OVERLAY_ACTIONS.items():
            a[name].setCheckable(True)
            a[name].toggled.connect(lambda on, k=kind: self.session and self.session.set_overlay(k, on))
        a["reset_zoom"].triggered.connect(lambda: self.frame_view and self.frame_view.reset_zoom())
        frame_actions.connect(self)      # window length, selected object only, outlines only
        for name, text, slot in (("auto_sync", "&Auto: clock and poses (event rate, then edges)…", self._auto_sync),
                                 ("edge_sync", "Clock and poses from &edges…", lambda: self.align.refine_clock()),
                                 ("refine_selected", "&Refine selected object from edges…", lambda: self._refine("")),
                                 ("score_all", "S&core all windows (timeline)", self.align.score_all)):
            act = QtGui.QAction(text, self)
            act.triggered.connect(slot)
            self.actions_by_name[name] = act
        self.open_dataset_action = QtGui.QAction("Open &dataset…", self)
        self.open_dataset_action.triggered.connect(lambda: _dataset_ui().open_dataset_dialog(self))
        self.back_to_dataset_action = QtGui.QAction("&Back to dataset", self)
        self.back_to_dataset_action.triggered.connect(lambda: _dataset_ui().show_dataset(self))
        self.actions_by_name.update(review_actions(self))    # range start, remove mark (app/review_menu.py)
        self.representation_group = QtGui.QActionGroup(self)
        self.representation_actions = {}
        for name in REPRESENTATION_NAMES:
            act = self.actions_by_name[A.REPRESENTATION_SHORTCUTS[name]]      # keys 1-6
            act.setText(REPRESENTATION_LABELS[name])
            act.setCheckable(True)
            act.triggered.connect(lambda _=False, n=name: self.session and self.session.set_representation(n))
            self.representation_group.addAction(act)
            self.representation_actions[name] = act
        self._set_document_actions_enabled(False)

    def _build_menus(self) -> None:
        a = self.actions_by_name
        m = self.menuBar().addMenu("&File")
        m.addAction(a["open"])
        self.recent_menu = m.addMenu("Open &recent")
        self.refresh_recent_menu()
        m.addAction(self.open_dataset_action)
        m.addAction(self.back_to_dataset_action)
        m.aboutToShow.connect(lambda: self.back_to_dataset_action.setEnabled(self.dataset_window is not None))
        m.addAction(a["save"])
        m.addSeparator()
        m.addAction(a["export"])
        m.addAction(a["screenshot"])
        m.addSeparator()
        m.addAction(a["quit"])
        m = self.menuBar().addMenu("&Edit")
        m.addAction(a["undo"])
        m.addAction(a["redo"])
        m = self.menuBar().addMenu("&View")
        rep = m.addMenu("Event &representation")
        for act in self.representation_actions.values():
            rep.addAction(act)
        for name in OVERLAY_ACTIONS:
            m.addAction(a[name])
        for name in frame_actions.MENU:
            m.addAction(a[name])
        m.addAction(a["reset_zoom"])
        self.docks_menu = m.addMenu("&Panels")
        m = self.menuBar().addMenu("&Navigate")
        for name in ("step_back", "step_forward", "step_back_10", "step_forward_10", "go_start", "go_end", "play",
                     "next_unreviewed", "next_flagged"):
            m.addAction(a[name])
        fill_review_menu(self.menuBar().addMenu("&Review"), a)
        m = self.menuBar().addMenu("&Tools")
        for name in ("auto_sync", "edge_sync", "refine_selected", "score_all"):
            m.addAction(a[name])
        m = self.menuBar().addMenu("&Help")
        m.addAction(a["help"])

    def refresh_recent_menu(self) -> None:
        self.recent_menu.clear()
        recent = self.settings.recent_scenes()
        for p in recent:
            act = self.recent_menu.addAction(p)
            act.triggered.connect(lambda _=False, p=p: self.controller.open_scene(p))
        self.recent_menu.setEnabled(bool(recent))

    def _set_document_actions_enabled(self, on: bool) -> None:
        for name, act in self.actions_by_name.items():
            if name not in ("open", "quit", "help"):
                act.setEnabled(on)
        for act in self.representation_actions.values():
            act.setEnabled(on)

    # ------------------------------------------------------------------ session
    frame_view: FrameView | None = None
    panel: CorrectionPanel | None = None
    reviews: ReviewPanel | None = None
    timeline = None
    spacetime = None
    kymograph = None
    objects: ObjectList | None = None

    def set_session(self, session: Session) -> None:
        """Show ``session`` (replacing any open one)."""
        self._teardown_session()
        self.session = session
        from evpose.widgets.spacetime.view import SpaceTimeView
        from evpose.widgets.timeline.view import Timeline

        self.frame_view = FrameView(session)
        frame_actions.attach(self, self.frame_view)      # key hints; hover text in the status bar
        self.setCentralWidget(self.frame_view)
        self.panel = CorrectionPanel(session, compact=L.compact(self))      # tabs on a laptop screen
        self.objects = ObjectList(session)
        self.reviews = ReviewPanel(session)
        self.timeline = Timeline(session)
        self.spacetime = SpaceTimeView(session)
        self.panel.autoSyncRequested.connect(self._auto_sync)
        self.panel.edgeSyncRequested.connect(lambda: self.align.refine_clock())
        self.panel.refineRequested.connect(self._refine)
        right = QtWidgets.QWidget()
        rl = QtWidgets.QVBoxLayout(right)
        rl.setContentsMargins(0, 0, 0, 0)
        self.objects.fit_rows(6)
        rl.addWidget(self.objects, 0)
        rl.addWidget(self.panel, 1)
        # side panels scroll inside their docks: the window fits a small screen and never grows for a text
        self._add_dock("Objects and corrections", L.scrolled(right), QtCore.Qt.RightDockWidgetArea, "dock_corrections")
        self._add_dock("Review", L.scrolled(self.reviews), QtCore.Qt.LeftDockWidgetArea, "dock_review")
        self._add_dock("Space-time (x, y, t)", L.scrolled(self.spacetime), QtCore.Qt.LeftDockWidgetArea,
                       "dock_spacetime")
        # review marks under the space-time view (a tab beside it on a laptop screen, L.compact): the right column
        # keeps its height for corrections
        self._arrange_left_column(L.compact(self))
        self._add_dock("Timeline", self.timeline, QtCore.Qt.BottomDockWidgetArea, "dock_timeline")
        L.bare_title(self._docks[3])    # no close button beside "Fit" (View ▸ Panels shows and hides it)
        self.feeds.spacetime_dock = self._docks[2]
        self._docks[2].visibilityChanged.connect(self.feeds.spacetime.visibility_changed)
        self.timeline.data_feed = self.feeds.timeline.request    # the curves on a worker after a clock change

        self._add_kymograph_dock(session)
        self.residual_feed.attach(session, self._add_dock, self._docks[2])
        self.panel.residualsRequested.connect(self.residual_feed.show)
        # the timeline spans the full width under the side docks
        self.setCorner(QtCore.Qt.BottomLeftCorner, QtCore.Qt.BottomDockWidgetArea)
        self.setCorner(QtCore.Qt.BottomRightCorner, QtCore.Qt.BottomDockWidgetArea)
        if not self.settings.restore_state(self, L.LAYOUT_VERSION, fits=lambda w, h: L.layout_fits(self, w, h)):
            self._default_dock_sizes()
            QtCore.QTimer.singleShot(0, self._default_dock_sizes)   # again once laid out
        self.undo_bridge = UndoBridge(session.history, self.actions_by_name["undo"], self.actions_by_name["redo"], self)
        self._session_connection = session.changed.connect(self._on_session)
        self.score_row.attach(session)
        # another program saving corrections.json (CLI --apply, a second app) is noticed and offered
        self.disk_watcher = CorrectionsWatcher(session.scene.corrections_path, self)
        self.disk_watcher.changed.connect(self.controller.on_disk_change)
        self._set_document_actions_enabled(True)
        if not session.scene.has_poses:
            events_only.apply(self)          # pose tools off, with the reason where they were
        self._sync_view_actions()
        self.setWindowTitle(f"evpose — {session.scene.name}[*]")
        self.undo_bridge.sync()
        self.request_frame()
        self.request_spacetime()
        self.request_kymograph()

    def _arrange_left_column(self, compact: bool) -> None:
        """Review marks as a tab beside the space-time view (``compact``: a laptop screen) or under it."""
        self._compact_column = compact
        if compact:
            self.tabifyDockWidget(self._docks[2], self._docks[1])
        else:
            self.splitDockWidget(self._docks[2], self._docks[1], QtCore.Qt.Vertical)

    def resizeEvent(self, event: QtGui.QResizeEvent) -> None:
        """A window resized across :data:`~evpose.app.layout.COMPACT_BELOW_H` rearranges its left column (the review
        marks stacked under the space-time view of a tall window left the canvas 33-86 px high once the window was
        made laptop-sized) and shares the window out again."""
        super().resizeEvent(event)
        d = self._docks
        if len(d) < 4 or getattr(self, "_compact_column", None) in (None, L.compact(self)):
            return
        if any(x.isFloating() or x.isHidden() for x in (d[1], d[2])):
            self._compact_column = L.compact(self)      # the user arranged them: left as they are
            return
        self._arrange_left_column(L.compact(self))
        QtCore.QTimer.singleShot(0, self._default_dock_sizes)

    def _default_dock_sizes(self) -> None:
        if len(self._docks) < 4:
            return
        d = self._docks
        if d[2] in self.tabifiedDockWidgets(d[1]) and not d[1].visibleRegion().isEmpty():
            d[2].raise_()                    # the space-time view in front of the review tab (not of one asked for)
        L.default_dock_sizes(self, spacetime=d[2], review=d[1], corrections=d[0], timeline=d[3])

    def ensure_timeline_height(self, px: int) -> None:
        """Give the timeline ``px`` of height (e.g. room for the score row), at most a third of the window's."""
        dock = self._docks[3] if len(self._docks) > 3 else None
        px = min(px, max(self.height() // 3, dock.minimumSizeHint().height() if dock is not None else 0))
        if dock is not None and not dock.isFloating() and dock.height() < px:
            self.resizeDocks([dock], [px], QtCore.Qt.Vertical)

    def _add_dock(self, title: str, widget: QtWidgets.QWidget, area, name: str) -> QtWidgets.QDockWidget:
        dock = QtWidgets.QDockWidget(title, self)
        dock.setObjectName(name)
        dock.setWidget(widget)
        self.addDockWidget(area, dock)
        self.docks_menu.addAction(dock.toggleViewAction())
        self._docks.append(dock)
        return dock

    def _teardown_session(self) -> None:
        if self.session is None:
            return
        self.settings.save_window(self, L.LAYOUT_VERSION)
        self.align.cancel_all()
        self.score_row.detach()
        if self._session_connection is not None:
            self._session_connection.disconnect()
            self._session_connection = None
        if self.undo_bridge:
            self.undo_bridge.detach()
            self.undo_bridge = None
        if self.disk_watcher is not None:
            self.disk_watcher.stop()
            self.disk_watcher.deleteLater()
            self.disk_watcher = None
        if self.timeline is not None:
            self.timeline.stop()
        if self.spacetime is not None:
            self.spacetime.shutdown()
        if self.kymograph is not None:
            self.kymograph.shutdown()
            self.kymograph = None
        self.residual_feed.detach()
        # everything submitted so far belongs to the old session: dropped when it arrives; late results find no views
        self.feeds.drop_pending()
        self.frame_view = self.panel = self.reviews = self.timeline = self.spacetime = self.objects = None
        self.frame = None
        for dock in self._docks:
            self.docks_menu.removeAction(dock.toggleViewAction())
            self.removeDockWidget(dock)
            dock.setObjectName("")      # until deleted, restoreState of the next scene would bring it back
            dock.deleteLater()
        self._docks.clear()
        self.session.close()
        self.session = None
        self.setCentralWidget(QtWidgets.QLabel())

    def _sync_view_actions(self) -> None:
        v = self.session.view
        for name, kind in OVERLAY_ACTIONS.items():
            act = self.actions_by_name[name]
            act.blockSignals(True)
            act.setChecked(kind in v.overlays)
            act.blockSignals(False)
        self.representation_actions[v.representation].setChecked(True)
        frame_actions.sync(self, v)

    def _on_session(self, change: Change) -> None:
        self.score_row.on_change(change)     # a clock or pose change: scores stale at once, then recomputed
        if not (change.kind == "view" and change.fields and change.fields <= DISPLAY_ONLY_FIELDS):
            # every other kind of session change shows in the views; display options (contrast, opacities,
            # selected-only, outlines-only) are redrawn by the frame view from what it has, and neither the
            # space-time view nor the kymograph uses them: nothing to compute
            self.request_frame()
            self.feeds.spacetime.request()           # coalesced: follows once scrubbing pauses
            self.feeds.kymograph.request()
        self.memory.poke()
        if change.kind == "view":
            self._sync_view_actions()

    # ------------------------------------------------------------------ views (app/feeds.py)
    def request_frame(self) -> None:
        self.feeds.request_frame()

    def request_spacetime(self) -> None:
        """Recompute the space-time view now, or mark it stale while its dock is closed (it is computed when the
        dock is shown again: a hidden view costs nothing)."""
        self.feeds.spacetime.timer.stop()
        self.feeds.spacetime.request_now()

    def request_kymograph(self) -> None:
        """Recompute the kymograph for its line and the session's state, unless it is out of sight (a tab behind
        another, a closed dock): it is computed when shown."""
        self.feeds.kymograph.request_now()

    def _add_kymograph_dock(self, session: Session) -> None:
        """The kymograph (x-t slice along a line drawn across an object edge): a tab beside the space-time view,
        closed until asked for (the space-time view's "Kymograph" button, View > Panels); computed while in sight."""
        from evpose.widgets.kymograph.view import KymographView

        self.kymograph = KymographView(session)
        self.kymograph.lineChanged.connect(self.request_kymograph)
        self._add_dock("Kymograph (x–t slice)", L.scrolled(self.kymograph), QtCore.Qt.LeftDockWidgetArea,
                       "dock_kymograph")
        dock = self._docks[-1]
        self.tabifyDockWidget(self._docks[2], dock)
        dock.hide()
        dock.visibilityChanged.connect(lambda on: on and QtCore.QTimer.singleShot(0, self.request_kymograph))
        self.spacetime.kymographRequested.connect(lambda: (dock.show(), dock.raise_()))

    def frame_up_to_date(self) -> bool:
        """True when the frame view shows the most recently requested state (events and overlays)."""
        return self.feeds.up_to_date()

    def events_up_to_date(self) -> bool:
        """True when the frame view shows the events of the most recent request (overlays may follow)."""
        return self.feeds.events_up_to_date()

    def spacetime_drawn(self) -> bool:
        """True once the space-time view shows data for the current view (or is hidden)."""
        return self.feeds.spacetime_drawn()

    # the names the benches (bench_scrub, bench_memory) and their baselines from before app/feeds.py use
    @property
    def _spacetime_timer(self) -> QtCore.QTimer:
        return self.feeds.spacetime.timer

    @property
    def event_cache(self):
        return self.feeds.event_cache

    @property
    def _submitted_serial(self) -> dict:
        f = self.feeds
        return {"frame": f.frame.submitted, "events": f.events.submitted, "spacetime": f.spacetime.submitted}

    @property
    def _shown_serial(self) -> dict:
        f = self.feeds
        return {"frame": f.frame.shown, "events": f.events.shown, "spacetime": f.spacetime.shown}

    def _worker_failed(self, message: str, serial: int) -> None:
        self.statusBar().showMessage("could not compute the view: " + message.strip().splitlines()[-1], 10_000)
        self.last_error = message

    # ------------------------------------------------------------------ editing helpers
    def _nudge(self, kind: str, axis: int, sign: int) -> None:
        if self.panel is None:
            return
        mods = QtWidgets.QApplication.keyboardModifiers()
        self.panel.nudge_object(kind, axis, sign, big=bool(mods & QtCore.Qt.ShiftModifier))

    def _next_object(self) -> None:
        s = self.session
        if s is None or not s.object_names:
            return
        names = s.object_names
        i = names.index(s.view.selected) + 1 if s.view.selected in names else 0
        s.select(names[i % len(names)])

    def _auto_sync(self) -> None:
        self.align.auto_sync()

    def _refine(self, name: str) -> None:
        if not name and self.session is not None:
            name = self.session.view.selected or (self.session.object_names[0] if self.session.object_names else "")
        self.align.refine(name)

    # ------------------------------------------------------------------ screenshots
    def save_screenshot(self, path) -> Path:
        """Render the whole window (GL views included) to a PNG."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        QtWidgets.QApplication.processEvents()
        img = self.grab().toImage()
        if not img.save(str(path)):
            raise OSError(f"{path}: could not write the screenshot")
        return path

    def _screenshot_dialog(self) -> None:
        name = f"evpose_{self.session.scene.name if self.session else 'window'}.png"
        path, _ = QtWidgets.QFileDialog.getSaveFileName(self, "Save screenshot", name, "PNG images (*.png)")
        if path:
            self.statusBar().showMessage(f"saved {self.save_screenshot(path)}", 5000)

    # ------------------------------------------------------------------ drag and drop, close
    @staticmethod
    def _scene_path_from_mime(mime: QtCore.QMimeData) -> str | None:
        for url in mime.urls():
            p = Path(url.toLocalFile())
            if p.name == "scene.toml" or (p / "scene.toml").is_file():
                return str(p)
        return None

    def dragEnterEvent(self, event: QtGui.QDragEnterEvent) -> None:
        if self._scene_path_from_mime(event.mimeData()):
            event.acceptProposedAction()

    def dropEvent(self, event: QtGui.QDropEvent) -> None:
        path = self._scene_path_from_mime(event.mimeData())
        if path:
            event.acceptProposedAction()
            self.controller.open_scene(path)

    def closeEvent(self, event: QtGui.QCloseEvent) -> None:
        if not self.controller.maybe_save():
            event.ignore()
            return
        for job in list(self.controller.jobs):
            job.cancel()
        self._teardown_session()
        self.settings.save_window(self, L.LAYOUT_VERSION)
        self.feeds.stop()
        self.residual_feed.stop()
        if self.dataset_window is not None:
            self.dataset_window.close()
        event.accept()


def _dataset_ui():
    """The dataset view's module (imported when first used)."""
    from evpose.app import dataset_window

    return dataset_window
