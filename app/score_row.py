"""Keeps the timeline's score row in step with the document: stale at once, recomputed in the background.

Once "Score all windows" has put scores on the timeline, every change of the clock, the hand-eye or an
object pose (a document change, undo and redo included) makes them stale: the row is dimmed with
"stale — recomputing" in the same event-loop turn, any recompute still running is cancelled, and after a
short pause (a dragged slider or repeated nudges send many changes) the scores are recomputed with
:func:`evpose.core.align.score_table.score_windows` on a snapshot of the scene in a
:class:`~evpose.app.workers.Job` (the global thread pool: the GUI thread never waits). A result is shown
only when it is of the document as it is now; an older one is dropped. Review marks and view changes do
not touch the scores.
"""
from __future__ import annotations

import numpy as np
from PySide6 import QtCore

from evpose.app.workers import Job
from evpose.core.document.review import mark_state
from evpose.core.signals import Change

__all__ = ["RECOMPUTE_DELAY_MS", "ScoreRowUpdater", "document_key"]

#: Pause after the last change before recomputing, ms.
RECOMPUTE_DELAY_MS = 300
#: Document fields whose change makes scores stale (besides every ``object:<name>``).
SCORE_FIELDS = frozenset({"clock", "hand_eye"})


def document_key(scene):
    """What the scores (and an estimate's start) depend on in the document: the clock in effect and every object's
    pose inputs, hand-eye included; the review marks' :func:`~evpose.core.document.review.mark_state`."""
    return mark_state(scene)


def _scores_change(change: Change) -> bool:
    return change.kind == "document" and any(f in SCORE_FIELDS or f.startswith("object:") for f in change.fields)


class ScoreRowUpdater(QtCore.QObject):
    """The score row of a :class:`~evpose.app.main_window.MainWindow`'s timeline, kept fresh.

    Attributes
    ----------
    table : ScoreTable or None
        The scores shown (None before the first "Score all windows").
    job : Job or None
        The recompute running, if any; ``jobs_started`` / ``jobs_cancelled`` / ``results_dropped`` count them.
    compute : callable(scene, window_us, progress, cancel) -> ScoreTable
        The scoring function (replaceable in tests).
    """

    def __init__(self, window):
        super().__init__(window)
        self.window = window
        self.session = None
        self.table = None
        self.window_us: int | None = None
        self.key = None
        self.job: Job | None = None
        self._running: set[Job] = set()     # cancelled jobs still finishing in the pool are kept alive
        self.jobs_started = self.jobs_cancelled = self.results_dropped = 0
        self.compute = _score
        self._timer = QtCore.QTimer(self, singleShot=True, interval=RECOMPUTE_DELAY_MS)
        self._timer.timeout.connect(self.recompute)

    # ------------------------------------------------------------------ session
    def attach(self, session) -> None:
        """Follow ``session`` (after a scene was opened; the window passes its changes to :meth:`on_change`,
        so the session keeps one subscriber per view); nothing is shown until :meth:`show`."""
        self.detach()
        self.session = session

    def detach(self) -> None:
        """Forget the session: cancel any recompute, drop the scores."""
        self._timer.stop()
        self._cancel()
        self.session = self.table = self.key = self.window_us = None

    # ------------------------------------------------------------------ state
    @property
    def stale(self) -> bool:
        """True while the scores shown are not of the document as it is now."""
        return self.table is not None and self.key != document_key(self.session.scene)

    def show(self, table, window_us: int, key) -> None:
        """Put ``table`` (scored with ``window_us`` windows on the document state ``key``, see
        :func:`document_key`) on the timeline: fresh when ``key`` is the document's state now, else stale
        and recomputed."""
        tl = self.window.timeline
        if self.session is None or tl is None:
            return
        self._cancel()               # a recompute still running would replace this newer table when it ends
        self._timer.stop()
        self.table, self.window_us, self.key = table, int(window_us), key
        t_s = np.array([tl.x_of(t) for t in table.t_label_us], np.float64)
        tl.set_scores(t_s, {n: np.ma.filled(table.score[n].astype(np.float64), np.nan) for n in table.objects},
                      low_evidence={n: table.low_evidence[n] for n in table.objects if n in table.low_evidence})
        if self.stale:
            self.invalidate()

    def invalidate(self) -> None:
        """After a change: cancel a running recompute; mark the scores stale now and recompute after a pause,
        or, when the change led back to the state they were computed on (an undo), show them fresh."""
        if self.table is None:
            return
        self._cancel()
        stale = self.stale
        if self.window.timeline is not None:
            self.window.timeline.set_scores_stale(stale)
        if stale:
            self._timer.start()
        else:
            self._timer.stop()

    def on_change(self, change: Change) -> None:
        """A session change: one of the clock, the hand-eye or a pose makes the scores stale."""
        if _scores_change(change):
            self.invalidate()

    # ------------------------------------------------------------------ background recompute
    def recompute(self) -> Job | None:
        """Score the document as it is now in the thread pool (a no-op when the scores are fresh)."""
        session = self.session
        if session is None or self.table is None or not self.stale:
            return None
        self._cancel()
        snapshot = session.scene.with_corrections(session.scene.corrections.copy())
        key, window_us, compute = document_key(snapshot), self.window_us, self.compute
        job = Job(lambda progress, cancel: compute(snapshot, window_us, progress, cancel))
        job.signals.finished.connect(lambda table, job=job: self._finished(job, session, table, key, window_us))
        job.signals.failed.connect(lambda message, details, job=job: self._failed(job, message))
        self.job = job
        self._running.add(job)
        self.jobs_started += 1
        return job.start()

    def _cancel(self) -> None:
        if self.job is not None:
            self.job.cancel()
            self.jobs_cancelled += 1
            self.job = None

    def _finished(self, job: Job, session, table, key, window_us: int) -> None:
        self._running.discard(job)
        if job is not self.job or session is not self.session or job.cancelled:
            self.results_dropped += 1        # superseded by a newer change or table, or of a closed scene
            return
        self.job = None
        self.window.align.last_scores = table
        self.show(table, window_us, key)     # the window length the job scored with

    def _failed(self, job: Job, message: str) -> None:
        self._running.discard(job)
        if job is not self.job:
            return
        self.job = None
        if message != "cancelled":
            self.window.statusBar().showMessage(f"could not recompute the scores: {message}", 10_000)
            if self.window.timeline is not None:
                self.window.timeline.set_scores_stale(True, "stale — recompute failed")


def _score(scene, window_us: int, progress, cancel):
    from evpose.core.align.score_table import score_windows

    return score_windows(scene, window_us=window_us, progress=progress, cancel=cancel)
