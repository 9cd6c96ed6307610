"""Automatic estimates in the app: clock and poses (Auto, from edges, refine an object) and sequence-wide scores.

Clock and poses: Auto (the event rate, then clock and poses jointly from edges), "clock and poses from edges"
and "refine object" run :mod:`evpose.app.auto_sync` on a snapshot of the scene in a
:class:`~evpose.app.workers.Job`, with progress and Cancel in a side panel beside the frame view; the proposal is
shown there and on the frame (before / after preview) and Accept stores it as **one** undo step
(:class:`~evpose.app.auto_controller.ProposalController`). Scores run :mod:`evpose.core.align.score_table` the
same way with a progress dialog. Nothing is applied without the user's accept.
"""
from __future__ import annotations

from PySide6 import QtCore

from evpose.app.auto_controller import ProposalController
from evpose.app.workers import Job, progress_dialog


class AlignController(QtCore.QObject):
    """Runs the estimation and score jobs for a :class:`~evpose.app.main_window.MainWindow`.

    Clock and poses go through :attr:`proposals` (a :class:`~evpose.app.auto_controller.ProposalController`: the
    side panel, the preview, Accept / Reject). In tests and screenshot runs (``window.modal_dialogs`` False)
    ``window.auto_answer["auto"]`` / ``["edge_sync"]`` / ``["refine"]`` True accepts a proposal as soon as it
    arrives, False rejects it (no key: the panel waits, drive it through ``proposals``). The last results are kept
    in ``last_proposal`` (any of the three), ``last_sync`` (Auto's rate stage), ``last_clock_refine`` (the joint
    fit of Auto or of "from edges"), ``last_refine`` (an object's) and ``last_scores``.
    """

    def __init__(self, window):
        super().__init__(window)
        self.window = window
        self.jobs: list[Job] = []
        self.proposals = ProposalController(window)
        self.last_proposal = None
        self.last_sync = None
        self.last_clock_refine = None
        self.last_refine = None
        self.last_scores = None
        #: event windows of the edge fits (the CLI's ``--windows``; default 24)
        self.edge_windows = 24

    # ------------------------------------------------------------------ plumbing
    def _run(self, title: str, fn, on_done, on_cancel=None) -> Job | None:
        session = self.window.session
        if session is None:
            return None
        snapshot = session.scene.with_corrections(session.scene.corrections.copy())
        job = Job(lambda progress, cancel: fn(snapshot, progress, cancel))
        dlg = progress_dialog(self.window, title, title + "…", job)

        def finished(result):
            dlg.close()
            self.jobs.remove(job)
            if self.window.session is session:   # the scene may have been closed meanwhile
                on_done(session, result)

        def failed(message, details):
            dlg.close()
            self.jobs.remove(job)
            if message == "cancelled":
                self.window.statusBar().showMessage(f"{title.lower()} cancelled", 5000)
                if on_cancel is not None and self.window.session is session:
                    on_cancel(session)
            else:
                self.window.controller.error(title, message, details)

        job.signals.finished.connect(finished)
        job.signals.failed.connect(failed)
        self.jobs.append(job)
        self.window.statusBar().showMessage(f"{title.lower()}…")
        return job.start()

    def cancel_all(self) -> None:
        for job in list(self.jobs):
            job.cancel()
        self.proposals.teardown()

    # ------------------------------------------------------------------ clock and poses: proposals beside the frame
    def auto_sync(self) -> Job | None:
        """Auto: the event-rate clock, then the clock and every object's pose jointly from edges, in one job
        (:func:`evpose.app.auto_sync.run_auto`); it stops after the rate stage when that is not reliable."""
        from evpose.app.auto_sync import run_auto

        n = self.edge_windows
        return self.proposals.start("Automatic estimate", "auto",
                                    lambda scene, progress, cancel: run_auto(scene, n, progress=progress,
                                                                             cancel=cancel),
                                    self._auto_done)

    def _auto_done(self, proposal) -> None:
        self.last_proposal, self.last_sync, self.last_clock_refine = proposal, proposal.rate, proposal.joint

    def refine_clock(self) -> Job | None:
        """The clock and every object's pose jointly from edges, started at the clock in effect
        (:func:`evpose.app.auto_sync.run_edges`: a local fit; Auto first when the clock may be far off)."""
        from evpose.app.auto_sync import run_edges
        from evpose.core.align.joint_result import JointParams

        session = self.window.session
        if session is None:
            return None
        if not session.object_names:
            self.window.statusBar().showMessage("clock from edges: the scene has no objects", 5000)
            return None
        params, title = JointParams(n_windows=self.edge_windows), "Clock and poses from edges"
        return self.proposals.start(title, "edge_sync",
                                    lambda scene, progress, cancel: run_edges(
                                        scene, params, "edges", title, "clock and poses from edges",
                                        progress=progress, cancel=cancel),
                                    self._clock_done)

    def _clock_done(self, proposal) -> None:
        self.last_proposal, self.last_clock_refine = proposal, proposal.joint

    def refine(self, name: str) -> Job | None:
        """Object ``name``'s pose from edges, the clock and the other objects held (the joint fit with only that
        object free: :func:`evpose.app.auto_sync.run_edges`)."""
        from evpose.app.auto_sync import run_edges
        from evpose.core.align.joint_result import JointParams

        session = self.window.session
        if session is None or name not in session.object_names:
            self.window.statusBar().showMessage("select an object to refine", 5000)
            return None
        params, title = JointParams(clock=False, objects=(name,), n_windows=self.edge_windows), f"Refine {name}"
        return self.proposals.start(title, "refine",
                                    lambda scene, progress, cancel: run_edges(scene, params, "refine", title,
                                                                              f"refine {name}", progress=progress,
                                                                              cancel=cancel),
                                    self._refine_done)

    def _refine_done(self, proposal) -> None:
        self.last_proposal, self.last_refine = proposal, proposal.joint

    # ------------------------------------------------------------------ scores over the sequence
    def score_all(self) -> Job | None:
        """Score every window; the timeline's score row then follows the document
        (:class:`~evpose.app.score_row.ScoreRowUpdater`: stale at once after a change, recomputed in the background)."""
        from evpose.app.score_row import document_key
        from evpose.core.align.score_table import score_windows

        session = self.window.session
        if session is None:
            return None
        window_us, key = int(session.view.window_us), document_key(session.scene)
        return self._run("Score all windows",
                         lambda scene, progress, cancel: score_windows(scene, window_us=window_us, progress=progress,
                                                                       cancel=cancel),
                         lambda s, table: self._scores_done(s, table, window_us, key), self._scores_cancelled)

    def _scores_cancelled(self, session) -> None:
        """Score all cancelled: scores still shown that are not of the document and window length now say so."""
        row = self.window.score_row
        if self.window.timeline is None or row.table is None:
            return
        if row.stale or row.window_us != int(session.view.window_us):
            self.window.timeline.set_scores_stale(True, f"not current — Score all cancelled (shown: {row.window_us / 1000:g} "
                                                        "ms windows)")

    def _scores_done(self, session, table, window_us: int, key) -> None:
        self.last_scores = table
        if self.window.timeline is None:
            return
        self.window.score_row.show(table, window_us, key)
        self.window.ensure_timeline_height(300)   # room for the score row
        means = ", ".join(f"{n} {m:+.2f}" for n in table.objects if (m := table.mean_score(n)) is not None)
        self.window.statusBar().showMessage(f"scored {len(table)} windows in {table.runtime_s:.1f} s: {means}", 10_000)
