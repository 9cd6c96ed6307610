"""Slow work off the GUI thread (DESIGN section 2): request -> response, stale responses dropped.

:class:`LatestWorker` runs a function on its own thread and only ever computes the most recent
request: while it is busy, newer requests replace older pending ones (scrubbing never queues
up). :class:`Job` runs a one-off core function in the global thread pool with progress and
cancel, for exports and estimations.
"""
from __future__ import annotations

import inspect
import sys
import threading
import traceback
from typing import Any, Callable

from PySide6 import QtCore, QtWidgets


#: GIL switch interval while worker threads run, s (Python's default is 5 ms). The GUI thread paints through many
#: short Python calls (pyqtgraph items); against a worker busy in Python each call may wait a whole interval for
#: the GIL, which delayed the paint of an event image until its overlays were done.
GIL_SWITCH_INTERVAL_S = 0.0005


class LatestWorker(QtCore.QObject):
    """Computes ``fn(request)`` for the latest submitted request on a dedicated thread.

    Signals ``done(result, serial)`` and ``failed(message, serial)`` arrive on the GUI thread;
    the receiver drops results whose serial is older than the one it last displayed.

    Staged work: when ``fn(request)`` returns a generator, the worker runs it step by step. Each value
    it yields that is not None is emitted as ``partial(value, serial)`` (e.g. the event image before
    the overlays), a yielded None is a checkpoint; the generator's return value is emitted with
    ``done``. Before every step the worker looks for a newer request: when one waits, the current
    request is abandoned there (the generator is closed, nothing more is emitted for it, ``abandoned``
    counts it). Requests replaced while pending are counted in ``replaced``.

    ``idle(should_stop)``, when given, runs on the worker thread after a request when no newer one
    waits (e.g. prefetching); it must return soon after ``should_stop()`` turns True, which it does as
    soon as a request is submitted.
    """

    done = QtCore.Signal(object, int)
    partial = QtCore.Signal(object, int)
    failed = QtCore.Signal(str, int)
    #: the return value of a function run by :meth:`call_soon` (None when it raised; the traceback goes to ``failed``)
    called = QtCore.Signal(object)
    _kick = QtCore.Signal()
    _call = QtCore.Signal(object)

    def __init__(self, fn: Callable[[Any], Any], name: str = "worker", idle: Callable | None = None):
        super().__init__()
        self._fn = fn
        self._idle = idle
        self._lock = threading.Lock()
        self._pending = None
        self._stopping = False
        #: requests replaced by a newer one before they started / abandoned at a checkpoint
        self.replaced = 0
        self.abandoned = 0
        if sys.getswitchinterval() > GIL_SWITCH_INTERVAL_S:
            sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
        self._thread = QtCore.QThread()
        self._thread.setObjectName(name)
        self.moveToThread(self._thread)
        self._kick.connect(self._run, QtCore.Qt.QueuedConnection)
        self._call.connect(self._run_call, QtCore.Qt.QueuedConnection)
        self._thread.start()

    def submit(self, request) -> None:
        """Queue ``request`` (must have a ``serial`` attribute), replacing any pending one."""
        with self._lock:
            if self._pending is not None:
                self.replaced += 1
            self._pending = request
        self._kick.emit()

    def call_soon(self, fn: Callable[[], Any]) -> None:
        """Run ``fn()`` on the worker's thread between requests (after the current request and its idle work,
        before any request submitted later): work on the computer's state that must not race with a computation,
        e.g. emptying its caches. ``called`` reports the return value on the receiver's thread."""
        self._call.emit(fn)

    @QtCore.Slot(object)
    def _run_call(self, fn) -> None:
        try:
            result = fn()
        except Exception:  # reported, never a silent crash of the thread
            self.failed.emit(traceback.format_exc(limit=6), 0)
            result = None
        self.called.emit(result)

    def superseded(self) -> bool:
        """True when a newer request waits (or the worker is stopping): the current one is stale."""
        return self._pending is not None or self._stopping

    @QtCore.Slot()
    def _run(self) -> None:
        with self._lock:
            req, self._pending = self._pending, None
        if req is None:
            return
        try:
            result = self._fn(req)
            if inspect.isgenerator(result):
                result = self._stages(result, req.serial)
                if result is _ABANDONED:
                    self.abandoned += 1
                    return
        except Exception:  # reported to the GUI, never a silent crash of the thread
            self.failed.emit(traceback.format_exc(limit=6), req.serial)
            return
        self.done.emit(result, req.serial)
        if self._idle is not None and not self.superseded():
            try:
                self._idle(self.superseded)
            except Exception:  # idle work is optional: report, never kill the thread
                self.failed.emit(traceback.format_exc(limit=6), req.serial)

    def _stages(self, gen, serial: int):
        """Run a staged computation; :data:`_ABANDONED` when a newer request arrived at a checkpoint."""
        try:
            while True:
                if self.superseded():
                    gen.close()
                    return _ABANDONED
                part = next(gen)
                if part is not None:
                    self.partial.emit(part, serial)
        except StopIteration as stop:
            return stop.value

    def stop(self) -> None:
        with self._lock:
            self._pending = None
            self._stopping = True
        self._thread.quit()
        self._thread.wait(5000)


#: What :meth:`LatestWorker._stages` returns for a request superseded at a checkpoint.
_ABANDONED = object()


class _JobEvents(QtCore.QObject):
    #: a :class:`Job` has ended (finished, failed or cancelled), emitted after its own signals
    ended = QtCore.Signal()


#: Every :class:`Job`'s end, for the app's idle memory release (a job's temporaries are freed when it ends).
JOB_EVENTS = _JobEvents()


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
            # a stage that cannot size its step reports None: -1 keeps the bar where it is (message only)
            result = self.fn(progress=lambda f, m="": self.signals.progress.emit(-1.0 if f is None else float(f),
                                                                                   str(m)),
                             cancel=self._cancel.is_set)
        except Cancelled:
            self.signals.failed.emit("cancelled", "")
        except Exception as exc:
            self.signals.failed.emit(str(exc), traceback.format_exc(limit=8))
        else:
            self.signals.finished.emit(result)
        finally:
            JOB_EVENTS.ended.emit()

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
    job.signals.progress.connect(lambda f, m: (f >= 0 and dlg.setValue(int(f * 1000)),
                                               dlg.setLabelText(m or dlg.labelText())))
    return dlg
