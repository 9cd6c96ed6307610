"""Slow work off the GUI thread (DESIGN section 2): request -> response, stale responses dropped.

:class:`LatestWorker` runs a function on its own thread and only ever computes the most recent
request: while it is busy, newer requests replace older pending ones (scrubbing never queues
up). :class:`Job` runs a one-off core function in the global thread pool with progress and
cancel, for exports and estimations.
"""
from __future__ import annotations

import threading
import traceback
from typing import Any, Callable

from PySide6 import QtCore, QtWidgets


class LatestWorker(QtCore.QObject):
    """Computes ``fn(request)`` for the latest submitted request on a dedicated thread.

    Signals ``done(result, serial)`` and ``failed(message, serial)`` arrive on the GUI thread;
    the receiver drops results whose serial is older than the one it last displayed.
    """

    done = QtCore.Signal(object, int)
    failed = QtCore.Signal(str, int)
    _kick = QtCore.Signal()

    def __init__(self, fn: Callable[[Any], Any], name: str = "worker"):
        super().__init__()
        self._fn = fn
        self._lock = threading.Lock()
        self._pending = None
        self._thread = QtCore.QThread()
        self._thread.setObjectName(name)
        self.moveToThread(self._thread)
        self._kick.connect(self._run, QtCore.Qt.QueuedConnection)
        self._thread.start()

    def submit(self, request) -> None:
        """Queue ``request`` (must have a ``serial`` attribute), replacing any pending one."""
        with self._lock:
            self._pending = request
        self._kick.emit()

    @QtCore.Slot()
    def _run(self) -> None:
        with self._lock:
            req, self._pending = self._pending, None
        if req is None:
            return
        try:
            result = self._fn(req)
        except Exception:  # reported to the GUI, never a silent crash of the thread
            self.failed.emit(traceback.format_exc(limit=6), req.serial)
            return
        self.done.emit(result, req.serial)

    def stop(self) -> None:
        with self._lock:
            self._pending = None
        self._thread.quit()
        self._thread.wait(5000)


class _JobSignals(QtCore.QObject):
    progress = QtCore.Signal(float, str)
    finished = QtCore.Signal(object)
    failed = QtCore.Signal(str, str)  # short message, details


class Job(QtCore.QRunnable):
    """Run ``fn(progress=..., cancel=...)`` in the thread pool; ``cancel()`` asks it to stop.

    ``fn`` is a core function taking ``progress(fraction, message)`` and ``cancel() -> bool``
    callbacks; cancellation surfaces as ``evpose.core.data.events.Cancelled`` and is reported as failure
    with the message "cancelled".
    """

    def __init__(self, fn: Callable[..., Any]):
        super().__init__()
        self.fn = fn
        self.signals = _JobSignals()
        self._cancel = threading.Event()
        self.setAutoDelete(False)

    def cancel(self) -> None:
        self._cancel.set()

    @property
    def cancelled(self) -> bool:
        return self._cancel.is_set()

    def run(self) -> None:
        from evpose.core.data.events import Cancelled

        try:
            result = self.fn(progress=lambda f, m="": self.signals.progress.emit(float(f), str(m)),
                             cancel=self._cancel.is_set)
        except Cancelled:
            self.signals.failed.emit("cancelled", "")
        except Exception as exc:
            self.signals.failed.emit(str(exc), traceback.format_exc(limit=8))
        else:
            self.signals.finished.emit(result)

    def start(self) -> "Job":
        QtCore.QThreadPool.globalInstance().start(self)
        return self


def progress_dialog(parent, title: str, label: str, job: Job, min_duration_ms: int = 300) -> QtWidgets.QProgressDialog:
    """A progress dialog driven by ``job``'s progress signal whose Cancel cancels the job (shown
    only when the job runs longer than ``min_duration_ms``); the caller closes it when done."""
    dlg = QtWidgets.QProgressDialog(label, "Cancel", 0, 1000, parent)
    dlg.setWindowTitle(title)
    dlg.setMinimumDuration(min_duration_ms)
    dlg.setAutoClose(False)
    dlg.setAutoReset(False)
    dlg.canceled.connect(job.cancel)
    job.signals.progress.connect(lambda f, m: (dlg.setValue(int(f * 1000)), dlg.setLabelText(m or dlg.labelText())))
    return dlg
