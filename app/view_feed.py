"""One feed per view: session state -> a request on the view's worker thread -> the result in the widget.

Every view of the main window (the frame's events and overlays, the space-time view, the kymograph, the residual
view, the timeline's curves) is fed the same way, by a :class:`ViewFeed`:

* a request is a snapshot of the session (:meth:`evpose.core.session.model.Session.request`, serials growing across
  sessions) computed by a function of ``core/views/`` on a :class:`~evpose.app.workers.LatestWorker` (a newer
  request replaces a pending one; a superseded staged computation stops at its next checkpoint);
* requests can be coalesced (``coalesce_ms``: a burst of changes makes one request when it ends);
* a view out of sight computes nothing: the feed notes that its data is stale and requests when the view comes
  into sight (:meth:`ViewFeed.visibility_changed`);
* a result older than the one shown, or from a closed session (:meth:`ViewFeed.drop_pending`), is dropped;
  ``up_to_date()`` tells the tests and benches when the view shows the latest request.
"""
from __future__ import annotations

from typing import Any, Callable

from PySide6 import QtCore

from evpose.app.workers import LatestWorker

__all__ = ["ViewFeed", "in_sight"]


def in_sight(widget) -> bool:
    """True while some of ``widget`` (None: no such view) can be seen: not closed, not a tab behind another, not in
    a minimised window."""
    return widget is not None and not widget.isHidden() and not widget.visibleRegion().isEmpty()


class ViewFeed(QtCore.QObject):
    """The feed of one view.

    Parameters
    ----------
    name : str
        The worker thread's name.
    compute : callable
        ``compute(request)`` on the worker: a result, or a generator of checkpoints returning it (staged).
    deliver : callable
        ``deliver(result, serial)`` on the GUI thread, only for results newer than the last delivered.
    make_request : callable, optional
        ``make_request()`` -> a request with a ``serial`` (None: nothing to compute now), for :meth:`request`.
    in_sight : callable, optional
        ``in_sight()`` -> False while the view cannot be seen (a closed dock, a tab behind another): then
        :meth:`request` only marks the data stale.
    idle : callable, optional
        The worker's idle work (prefetching), see :class:`~evpose.app.workers.LatestWorker`.
    on_failed : callable, optional
        ``on_failed(message, serial)`` for a failure of the latest request.
    coalesce_ms : int
        When > 0, :meth:`request` waits this long for more changes before it submits one request.
    """

    def __init__(self, parent: QtCore.QObject | None, name: str, compute: Callable[[Any], Any],
                 deliver: Callable[[Any, int], None], *, make_request: Callable[[], Any] | None = None,
                 in_sight: Callable[[], bool] | None = None, idle: Callable | None = None,
                 on_failed: Callable[[str, int], None] | None = None, coalesce_ms: int = 0):
        super().__init__(parent)
        self.name = name
        self.worker = LatestWorker(compute, name, idle=idle)
        self.worker.done.connect(self._done)
        self.worker.failed.connect(self._failed)
        self._deliver = deliver
        self._make_request = make_request
        self._in_sight = in_sight
        self._on_failed = on_failed
        #: serial of the last request submitted / of the last result delivered
        self.submitted = 0
        self.shown = 0
        #: True while the view's data is out of date because it was out of sight when asked
        self.stale = False
        self.timer = QtCore.QTimer(self)
        self.timer.setSingleShot(True)
        self.timer.setInterval(int(coalesce_ms))
        self.timer.timeout.connect(self.request_now)
        self._coalesce = coalesce_ms > 0

    # ------------------------------------------------------------------ requests
    def request(self) -> None:
        """Ask for the view's data for the current state (coalesced when the feed coalesces)."""
        if self._coalesce:
            self.timer.start()
        else:
            self.request_now()

    def request_now(self) -> None:
        """Ask for the view's data now (no coalescing); only marks it stale while the view is out of sight."""
        if self._make_request is None:
            return
        if self._in_sight is not None and not self._in_sight():
            self.stale = True
            return
        req = self._make_request()
        if req is not None:
            self.submit(req)

    def submit(self, req) -> None:
        """Compute ``req`` now (whatever the view's visibility)."""
        self.stale = False
        self.submitted = req.serial
        self.worker.submit(req)

    def visibility_changed(self, visible: bool) -> None:
        """The view came into sight or left it: requests what it missed while hidden."""
        if visible and self.stale:
            QtCore.QTimer.singleShot(0, self.request_now)

    # ------------------------------------------------------------------ results
    def _done(self, result, serial: int) -> None:
        if serial <= self.shown:
            return                          # older than what is shown, or from a closed session
        self.shown = serial
        self._deliver(result, serial)

    def _failed(self, message: str, serial: int) -> None:
        if serial >= self.submitted and self._on_failed is not None:
            self._on_failed(message, serial)

    def up_to_date(self) -> bool:
        """True when the latest request's result has been delivered."""
        return self.submitted > 0 and self.shown >= self.submitted

    def drop_pending(self) -> None:
        """Drop every result of the requests made so far (the session they belong to is closing)."""
        self.timer.stop()
        self.stale = False
        self.shown = self.submitted = max(self.shown, self.submitted)

    def stop(self) -> None:
        """Stop the worker thread (the window is closing)."""
        self.drop_pending()
        self.worker.stop()
