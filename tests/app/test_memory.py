"""app/memory.py: freed heap pages and cached module sources go back to the system once the user pauses."""
from __future__ import annotations

import linecache
import os
import subprocess
import sys

import pytest

from evpose.app import memory, startup


_TRIM_CHILD = r"""
import sys
from evpose.app import memory, startup

def rss_mb():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20

big, keep = [], []
for _ in range(2000):                       # ~125 MB, every page written
    big.append(bytearray(64 << 10))
    big[-1][:] = b"\x01" * (64 << 10)
    keep.append(bytearray(b"\x02" * 1000))
del big
before = rss_mb()
ok = memory.trim_heap()
after = rss_mb()
print(ok, before, after, len(keep))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux") or startup.libc() is None, reason="glibc only")
def test_trim_heap_gives_freed_heap_pages_back():
    """64 kB blocks (below glibc's mmap threshold: they live in the heap) interleaved with small ones that stay:
    freeing the large ones leaves holes malloc keeps (RSS unchanged) until trim_heap returns their pages.
    Run in a fresh interpreter: the test process's heap, shaped by earlier tests, would blur the figure."""
    out = subprocess.run([sys.executable, "-c", _TRIM_CHILD], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "QT_QPA_PLATFORM": "offscreen"})
    assert out.returncode == 0, out.stderr
    ok, before, after, kept = out.stdout.split()
    assert ok == "True" and int(kept) == 2000
    assert float(before) - float(after) > 60, f"RSS {before} -> {after} MB"


def test_release_memory_drops_the_cached_module_sources():
    linecache.getlines(memory.__file__)
    assert memory.__file__ in linecache.cache
    memory.release_memory()
    assert memory.__file__ not in linecache.cache
    assert linecache.getlines(memory.__file__)         # read again when a traceback needs it


def test_idle_releaser_waits_for_a_quiet_period(qtbot, monkeypatch):
    calls = []
    monkeypatch.setattr(memory, "release_memory", lambda: calls.append(1) or True)
    trims = []
    monkeypatch.setattr(memory, "trim_heap", lambda: trims.append(1) or True)
    r = memory.IdleReleaser(idle_ms=1000, late_trim_ms=600, busy_trim_s=60)
    for _ in range(6):                           # activity every 100 ms: never quiet for 1 s
        r.poke()
        qtbot.wait(100)
    assert calls == []
    qtbot.waitUntil(lambda: calls == [1], timeout=2000)
    qtbot.wait(300)
    assert calls == [1] and r.releases == 1 and trims == []     # once per quiet period, not periodically
    qtbot.waitUntil(lambda: trims == [1], timeout=2000)        # once more later, if nothing happened
    qtbot.wait(1500)
    assert trims == [1] and r.late_trims == 1 and calls == [1]
    r.poke()                                                    # activity before the late trim: none
    qtbot.waitUntil(lambda: calls == [1, 1], timeout=3000)
    qtbot.wait(100)
    r.poke()
    qtbot.wait(900)
    assert trims == [1]


def test_main_window_releases_memory_when_the_user_pauses(window, scene_copy, qtbot, monkeypatch):
    calls = []
    monkeypatch.setattr(memory, "release_memory", lambda: calls.append(1) or True)
    window.memory.timer.setInterval(1000)
    window.controller.open_scene(scene_copy)
    qtbot.waitUntil(lambda: window.frame_up_to_date() and len(calls) == 1, timeout=20_000)   # after the first frame
    t0, t1 = window.session.time_range
    for k in range(1, 4):                    # stepping: one release once it stops, none in between
        window.session.set_time(t0 + k * (t1 - t0) // 4)
        qtbot.wait(30)
    assert len(calls) == 1
    qtbot.waitUntil(lambda: len(calls) == 2, timeout=10_000)


_STARTUP_CHILD = r"""
import linecache, sys
from evpose.app import startup
assert "PySide6" not in sys.modules
assert startup.configure_malloc() is True
done = startup.preload_engine()
assert "PySide6" not in sys.modules, "startup imported Qt"
import PySide6.QtWidgets
import evpose.app.main_window
assert startup.preload_engine() == []                 # too late once PySide6 is in
text = sum(sum(len(x) for x in e[2]) for e in linecache.cache.values() if len(e) > 2)
print(len(done), text)
"""


def test_startup_imports_the_engine_before_qt_and_keeps_linecache_small():
    """PySide6's import hook reads the source of every module imported after it (linecache keeps it): with
    the engine imported first, the main window's import leaves under 8 MB of source text (13 MB without)."""
    out = subprocess.run([sys.executable, "-c", _STARTUP_CHILD], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "QT_QPA_PLATFORM": "offscreen"})
    assert out.returncode == 0, out.stderr[-2000:]
    n_done, text = map(int, out.stdout.split())
    assert n_done >= 5
    assert text < 8 << 20, f"{text / 2**20:.1f} MB of module source held by linecache"


def test_idle_release_runs_its_tasks_on_the_workers_then_gives_memory_back(qtbot, monkeypatch):
    """Each task runs on its worker's thread (never racing a computation there); the heap is trimmed once all have
    run; a background job's end restarts the quiet period."""
    from PySide6 import QtCore

    from evpose.app.workers import JOB_EVENTS, LatestWorker

    calls, threads = [], []
    monkeypatch.setattr(memory, "release_memory", lambda: calls.append(len(threads)) or True)
    workers = [LatestWorker(lambda req: None, f"w{k}") for k in range(2)]
    try:
        tasks = [(w, lambda: threads.append(QtCore.QThread.currentThread().objectName()) or 1000) for w in workers]
        tasks.append((None, lambda: threads.append("now") or 5))
        r = memory.IdleReleaser(idle_ms=200, tasks=lambda: tasks)
        r.poke()
        qtbot.waitUntil(lambda: r.releases == 1, timeout=5000)
        assert calls == [3] and sorted(threads) == ["now", "w0", "w1"]   # trimmed after all three
        assert sorted(r.last_released) == [5, 1000, 1000]
        JOB_EVENTS.ended.emit()                       # a job ended: its temporaries are freed, release again
        qtbot.waitUntil(lambda: r.releases == 2, timeout=5000)
        assert len(threads) == 6
    finally:
        for w in workers:
            w.stop()


def _caches(window):
    c = window.feeds._computers
    return {"overlays ahead": len(c["frame"].overlays_ahead), "slices": len(c["spacetime"].slice_cache),
            "fields": len(c["spacetime"].field_cache), "label maps": len(c["kymograph"].maps),
            "kymograph annotator": c["kymograph"]._ann is not None,
            "space-time annotator": c["spacetime"]._slice_annotator is not None,
            "residual annotator": window.residual_feed._compute._ann is not None}


def _quiet(feed) -> bool:
    return not feed.timer.isActive() and feed.shown >= feed.submitted       # (stale: out of sight, computes nothing)


def test_idle_release_empties_the_prefetch_and_the_caches_of_views_out_of_sight(window, scene_copy, qtbot):
    """Issue 25.4: once the user pauses, the work done ahead (the next window's overlays, all but 1 MB of the
    decoded event blocks) and the caches of the views that cannot be seen (the kymograph and the space-time view
    behind the residual view's tab) are dropped; the space-time view in sight keeps its slices."""
    from evpose.app.feeds import IDLE_EVENT_BYTES

    window.memory.timer.setInterval(60_000)           # released by hand below
    s = window.controller.open_scene(scene_copy)
    feeds = window.feeds
    s.set_time(s.time_range[0] + 300_000)
    window.spacetime.controls.kymograph_button.click()       # the kymograph in front of the space-time view
    qtbot.waitUntil(lambda: window.kymograph.data is not None, timeout=30_000)
    feeds.spacetime_dock.raise_()
    for _ in range(3):                                # steps: the next window's overlays are computed ahead
        s.step_windows(1)
        qtbot.waitUntil(lambda: window.frame_up_to_date() and feeds.spacetime.up_to_date(), timeout=30_000)
    qtbot.waitUntil(lambda: len(feeds._computers["frame"].overlays_ahead) > 0, timeout=10_000)
    window.panel.residuals_button.click()             # the residual view in front: both others out of sight
    qtbot.waitUntil(lambda: window.residual_feed.view.data is not None, timeout=60_000)
    # nothing still on its way to a view (a coalesced space-time request would be computed after the release and
    # refill what it emptied: the app does that on purpose, a view in a tab behind another counts as in sight)
    qtbot.waitUntil(lambda: all(_quiet(f) for f in (feeds.spacetime, feeds.kymograph, feeds.frame)), timeout=30_000)
    before = _caches(window)
    assert all(before.values()), before
    assert feeds.event_cache.nbytes > 0
    n = window.memory.releases
    window.memory.timer.timeout.emit()
    qtbot.waitUntil(lambda: window.memory.releases == n + 1, timeout=10_000)
    after = _caches(window)
    assert after == {**{k: 0 for k in ("overlays ahead", "slices", "fields", "label maps")},
                     "kymograph annotator": False, "space-time annotator": False, "residual annotator": True}, after
    assert feeds.event_cache.nbytes <= IDLE_EVENT_BYTES
    feeds.spacetime_dock.raise_()                     # the space-time view in sight: its slices are kept
    s.step_windows(1)
    qtbot.waitUntil(lambda: feeds.spacetime.up_to_date() and len(feeds._computers["spacetime"].slice_cache) > 0,
                    timeout=30_000)
    qtbot.wait(300)
    window.memory.timer.timeout.emit()
    qtbot.waitUntil(lambda: window.memory.releases == n + 2, timeout=10_000)
    kept = _caches(window)
    assert kept["slices"] > 0 and kept["space-time annotator"] and not kept["residual annotator"], kept
    assert window.last_error is None


def test_a_busy_user_gets_the_heap_trimmed_between_quiet_periods(qtbot, monkeypatch):
    """Scrubbing without a pause: no quiet period, but the free heap pages are given back every busy_trim_s."""
    trims, releases = [], []
    monkeypatch.setattr(memory, "trim_heap", lambda: trims.append(1) or True)
    monkeypatch.setattr(memory, "release_memory", lambda: releases.append(1) or True)
    r = memory.IdleReleaser(idle_ms=1000, busy_trim_s=0.3)
    for _ in range(15):                         # activity every 100 ms for 1.5 s: never quiet
        r.poke()
        qtbot.wait(100)
    qtbot.waitUntil(lambda: r.busy_trims == len(trims) >= 3, timeout=2000)
    assert len(trims) <= 6 and releases == []
    qtbot.waitUntil(lambda: releases == [1], timeout=3000)
