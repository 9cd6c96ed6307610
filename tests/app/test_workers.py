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
