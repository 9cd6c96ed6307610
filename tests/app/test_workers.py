"""The frame worker never computes a stale request (issue 14, point 3): a flood of requests while it is busy
is coalesced to the latest one, and results arrive on the GUI thread with their serial."""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from PySide6 import QtCore

from evpose.app.workers import LatestWorker


@dataclass
class Request:
    serial: int


class Receiver(QtCore.QObject):
    """Lives on the GUI thread, as the main window does: its slot runs there."""

    def __init__(self):
        super().__init__()
        self.results, self.threads = [], []

    @QtCore.Slot(object, int)
    def on_done(self, result, serial):
        self.results.append((result, serial))
        self.threads.append(QtCore.QThread.currentThread())


def test_a_flood_of_requests_computes_only_the_latest(qtbot):
    computed: list[int] = []
    gate = threading.Event()

    def fn(req):
        computed.append(req.serial)
        if req.serial == 0:
            gate.wait(10)              # busy with the first request while the flood arrives
        else:
            time.sleep(0.01)
        return req.serial * 10

    worker = LatestWorker(fn, name="test-worker")
    receiver = Receiver()
    results, threads = receiver.results, receiver.threads
    worker.done.connect(receiver.on_done)
    try:
        worker.submit(Request(0))
        qtbot.waitUntil(lambda: computed == [0], timeout=5000)
        for k in range(1, 201):       # 200 requests while request 0 is being computed
            worker.submit(Request(k))
        gate.set()
        qtbot.waitUntil(lambda: bool(results) and results[-1][1] == 200, timeout=10_000)
        qtbot.wait(100)
    finally:
        worker.stop()
    assert computed == [0, 200], "superseded requests were computed"
    assert results == [(0, 0), (2000, 200)]
    app_thread = QtCore.QCoreApplication.instance().thread()
    assert all(t == app_thread for t in threads), "results must arrive on the GUI thread"


def test_a_failure_is_reported_with_its_serial_and_the_worker_goes_on(qtbot):
    def fn(req):
        if req.serial == 1:
            raise ValueError("bad window")
        return req.serial

    worker = LatestWorker(fn, name="test-worker-2")
    failed, done = [], []
    worker.failed.connect(lambda msg, serial: failed.append((msg, serial)))
    worker.done.connect(lambda result, serial: done.append(serial))
    try:
        worker.submit(Request(1))
        qtbot.waitUntil(lambda: bool(failed), timeout=5000)
        worker.submit(Request(2))
        qtbot.waitUntil(lambda: done == [2], timeout=5000)
    finally:
        worker.stop()
    assert failed[0][1] == 1 and "ValueError: bad window" in failed[0][0]


def test_a_staged_request_superseded_at_a_checkpoint_is_abandoned(qtbot):
    """A generator function: yielded values are partial results, a newer request waiting at a checkpoint ends
    the current one there (no partial, no result), and only the latest of a flood runs to its end."""
    gate = threading.Event()
    steps: list[tuple[int, str]] = []

    def fn(req):
        steps.append((req.serial, "read"))
        if req.serial == 0:
            gate.wait(10)               # reading the events while the flood arrives
        yield None                      # checkpoint: superseded requests stop here
        steps.append((req.serial, "image"))
        yield f"events {req.serial}"
        steps.append((req.serial, "overlays"))
        return f"overlays {req.serial}"

    worker = LatestWorker(fn, name="test-worker-3")
    partial, done = [], []
    worker.partial.connect(lambda value, serial: partial.append((value, serial)))
    worker.done.connect(lambda value, serial: done.append((value, serial)))
    try:
        worker.submit(Request(0))
        qtbot.waitUntil(lambda: steps == [(0, "read")], timeout=5000)
        for k in range(1, 51):
            worker.submit(Request(k))
        gate.set()
        qtbot.waitUntil(lambda: done == [("overlays 50", 50)], timeout=10_000)
        qtbot.wait(50)
    finally:
        worker.stop()
    assert steps == [(0, "read"), (50, "read"), (50, "image"), (50, "overlays")]
    assert partial == [("events 50", 50)] and done == [("overlays 50", 50)]
    assert worker.abandoned == 1 and worker.replaced == 49


def test_a_request_superseded_after_its_partial_result_skips_the_rest(qtbot):
    """The events of a request are shown, a newer request arrives while they are painted: the expensive rest
    of the old one is never computed."""
    shown = threading.Event()
    go_on = threading.Event()
    steps = []

    def fn(req):
        yield f"events {req.serial}"
        if req.serial == 1:
            go_on.wait(10)              # the newer request arrives here
        steps.append(req.serial)
        yield None
        return f"overlays {req.serial}"

    worker = LatestWorker(fn, name="test-worker-4")
    done, partial = [], []
    worker.partial.connect(lambda v, s: (partial.append(s), shown.set()))
    worker.done.connect(lambda v, s: done.append(s))
    try:
        worker.submit(Request(1))
        qtbot.waitUntil(shown.is_set, timeout=5000)
        worker.submit(Request(2))
        go_on.set()
        qtbot.waitUntil(lambda: done == [2], timeout=5000)
    finally:
        worker.stop()
    assert partial == [1, 2] and done == [2] and worker.abandoned == 1


def test_idle_work_runs_when_nothing_waits_and_stops_at_the_next_request(qtbot):
    idle_runs, idle_stopped = [], threading.Event()
    computed = []

    def idle(should_stop):
        idle_runs.append(len(computed))
        t_end = time.monotonic() + 10
        while not should_stop() and time.monotonic() < t_end:
            time.sleep(0.002)
        if should_stop():
            idle_stopped.set()

    worker = LatestWorker(lambda req: computed.append(req.serial) or req.serial, name="test-worker-5", idle=idle)
    try:
        worker.submit(Request(1))
        qtbot.waitUntil(lambda: idle_runs == [1], timeout=5000)
        t0 = time.monotonic()
        worker.submit(Request(2))            # the idle work must give way at once
        qtbot.waitUntil(lambda: computed == [1, 2], timeout=5000)
        assert time.monotonic() - t0 < 2.0 and idle_stopped.is_set()
        qtbot.waitUntil(lambda: idle_runs == [1, 2], timeout=5000)
    finally:
        worker.stop()
