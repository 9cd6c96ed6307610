"""One estimation job at a time, with its proposal beside the frame: the app's Auto, clock-and-poses-from-edges
and refine-object actions (:mod:`evpose.app.auto_sync`).

The job runs on a snapshot of the scene in the thread pool; its progress and Cancel live in a
:class:`~evpose.app.auto_panel.ProposalPanel` in a tab over the corrections (beside the frame view, never over
it). When the job ends, the panel shows the proposal and the frame and space-time views show it too
(:meth:`Session.set_preview`: "after"), until the user flips the preview to "before", accepts (one undo step,
:func:`~evpose.app.auto_sync.apply_proposal`) or rejects (or closes the panel). Nothing reaches the document
before Accept.

Unattended (``window.modal_dialogs`` False, tests and screenshot runs): ``window.auto_answer[key]`` True
accepts a usable proposal as soon as it arrives, False rejects it; without the key the panel waits.
"""
from __future__ import annotations

from PySide6 import QtCore, QtWidgets

from evpose.app.auto_panel import ProposalDock, ProposalPanel
from evpose.app.auto_sync import apply_proposal, preview_corrections
from evpose.app.score_row import document_key
from evpose.app.workers import Job
from evpose.core.signals import DOCUMENT

__all__ = ["ProposalController"]


class ProposalController(QtCore.QObject):
    """Runs estimation jobs for a :class:`~evpose.app.main_window.MainWindow` and shows their proposals.

    ``state`` tells where it is: ``"idle"``, ``"running"``, ``"proposal"``, ``"cancelled"``, ``"failed"``,
    ``"accepted"`` or ``"rejected"``; ``proposal`` is the proposal on show (None otherwise).
    """

    def __init__(self, window):
        super().__init__(window)
        self.window = window
        self.job: Job | None = None
        self.proposal = None
        self.state = "idle"
        self.panel: ProposalPanel | None = None
        self.dock: ProposalDock | None = None
        self._session = None
        self._title, self._key = "", ""
        self._running: set[Job] = set()        # started jobs whose end has not arrived (kept alive until then)
        self._connection = None
        self._doc_key = None             # document_key of the snapshot the running / shown estimate started from

    # ------------------------------------------------------------------ the panel
    def _ensure_panel(self) -> ProposalPanel:
        if self.dock is None:
            self.panel = ProposalPanel()
            self.dock = ProposalDock("Automatic estimate", self.window)
            self.dock.setObjectName("dock_proposal")
            self.dock.set_panel(self.panel)
            self.panel.cancelRequested.connect(self.cancel)
            self.panel.acceptRequested.connect(self.accept)
            self.panel.rejectRequested.connect(self.reject)
            self.panel.previewChanged.connect(self.set_preview)
            self.dock.closed.connect(self._dock_closed)
            self._place_dock()
        return self.panel

    def _place_dock(self) -> None:
        """In a tab over the corrections (the right column's whole height): beside the frame view, never over it."""
        w = self.window
        w.addDockWidget(QtCore.Qt.RightDockWidgetArea, self.dock)
        corrections = w.findChild(QtWidgets.QDockWidget, "dock_corrections")
        if corrections is not None and corrections is not self.dock:
            w.tabifyDockWidget(corrections, self.dock)

    def _status(self, text: str, ms: int = 8000) -> None:
        self.window.statusBar().showMessage(text, ms)

    # ------------------------------------------------------------------ jobs
    def start(self, title: str, key: str, fn, on_done=None) -> Job | None:
        """Run ``fn(snapshot, progress, cancel) -> Proposal`` in the thread pool (a running job is cancelled,
        a proposal on show dropped); ``on_done(proposal)`` is called when it arrives, before it is shown."""
        session = self.window.session
        if session is None:
            return None
        self._drop(cancel_job=True)
        snapshot = session.scene.with_corrections(session.scene.corrections.copy())
        self._doc_key = document_key(snapshot)          # what the estimate starts from (clock, hand-eye, poses)
        job = Job(lambda progress, cancel: fn(snapshot, progress, cancel))
        panel = self._ensure_panel()
        panel.show_running(title)
        self.dock.setWindowTitle(title)
        self.dock.show()
        self.dock.raise_()
        self._title, self._key, self._session, self.state = title, key, session, "running"
        job.signals.progress.connect(lambda f, m, job=job: job is self.job and panel.set_progress(f, m))
        job.signals.finished.connect(lambda p, job=job: self._finished(job, session, p, on_done))
        job.signals.failed.connect(lambda message, details, job=job: self._failed(job, message, details))
        self.job = job
        self._running.add(job)
        self._status(f"{title.lower()}: running (progress and Cancel in the side panel)", 0)
        return job.start()

    def cancel(self) -> None:
        """Ask the running job to stop (it ends as "cancelled")."""
        if self.job is not None:
            self.job.cancel()

    def _finished(self, job: Job, session, proposal, on_done) -> None:
        self._running.discard(job)
        if job is not self.job or self.window.session is not session:
            return                                  # superseded, or the scene was closed meanwhile
        self.job = None
        if on_done is not None:
            on_done(proposal)
        self.proposal, self.state = proposal, "proposal"
        self.panel.show_proposal(proposal, preview_after=proposal.usable)
        self._connection = session.changed.connect(self._on_session, {DOCUMENT})
        if self._document_moved():
            return
        self.set_preview(proposal.usable)
        self._status(f"{self._title.lower()}: " + ("proposal shown on the frame; Accept or Reject in the side panel"
                                                   if proposal.usable else f"nothing to apply ({proposal.reason})"), 0)
        answer = None if getattr(self.window, "modal_dialogs", True) else self.window.auto_answer.get(self._key)
        if answer is True and proposal.usable:
            self.accept()
        elif answer is False:
            self.reject()

    def _failed(self, job: Job, message: str, details: str) -> None:
        self._running.discard(job)
        if job is not self.job:
            return
        self.job = None
        if message == "cancelled":
            self.state = "cancelled"
            self.panel.show_stopped(self._title, "cancelled; nothing applied")
            self._status(f"{self._title.lower()} cancelled")
        else:
            self.state = "failed"
            self.panel.show_stopped(self._title, f"failed: {message}")
            self.window.controller.error(self._title, message, details)

    # ------------------------------------------------------------------ preview, accept, reject
    def set_preview(self, after: bool) -> None:
        """Show the proposal ("after") or the document ("before") on the frame and space-time views."""
        session, p = self._session, self.proposal
        if session is None or self.window.session is not session:
            return
        session.set_preview(preview_corrections(session, p) if after and p is not None and p.usable else None)

    def _on_session(self, change) -> None:
        """An edit while the proposal is on show: a change of the clock, hand-eye or a pose makes it stale (it holds
        totals computed from the document it started from: accepting it would silently undo the edit); other
        edits (review marks) leave it, and the preview follows."""
        if change.kind != "document" or self.proposal is None or self._document_moved():
            return
        if self.panel.preview_after():
            self.set_preview(True)

    def _document_moved(self) -> bool:
        """When the clock, hand-eye or a pose differs from the job's start: the proposal becomes stale."""
        if self._session is None or document_key(self._session.scene) == self._doc_key:
            return False
        self._session.set_preview(None)
        self.state = "stale"
        self.panel.mark_stale("The clock or a pose changed since this estimate started: accepting it would undo "
                              "that change. Run it again.")
        self._status(f"{self._title.lower()}: stale (the document changed); run it again", 0)
        return True

    def accept(self) -> bool:
        """Store the proposal as one undo step; returns whether anything was stored."""
        p, session = self.proposal, self._session
        if p is None or not p.usable or session is None or self.window.session is not session:
            return False
        if self.state == "stale" or self._document_moved():
            return False
        self._drop()
        applied = apply_proposal(session, p)
        self.state = "accepted"
        self._status(f"{p.undo_text}: applied as one undo step; Ctrl+Z undoes")
        return applied

    def reject(self) -> None:
        """Drop the proposal (or stop the job); the views show the document again."""
        if self.proposal is None and self.job is None:
            return
        self._drop(cancel_job=True)
        self.state = "rejected"
        self._status(f"{self._title.lower()}: rejected; nothing applied")

    def _dock_closed(self) -> None:
        if self.job is not None or self.proposal is not None:
            self.reject()

    def _drop(self, cancel_job: bool = False) -> None:
        """Forget the proposal, the preview and (``cancel_job``) the running job; hide the panel."""
        if cancel_job and self.job is not None:
            self.job.cancel()
            self.job = None
        if self._connection is not None:
            self._connection.disconnect()
            self._connection = None
        session, self.proposal = self._session, None
        if session is not None and self.window.session is session:
            session.set_preview(None)
        if self.dock is not None:
            self.dock.hide()

    def teardown(self) -> None:
        """The session is closing: stop the job, forget the proposal, remove the panel's dock."""
        if self.job is not None:
            self.job.cancel()
        self.job, self.proposal, self._session, self.state = None, None, None, "idle"
        if self._connection is not None:
            self._connection.disconnect()
            self._connection = None
        if self.dock is not None:
            self.window.removeDockWidget(self.dock)
            self.dock.deleteLater()
        self.panel = self.dock = None
