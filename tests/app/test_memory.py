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
    r = memory.IdleReleaser(idle_ms=1000)
    for _ in range(6):                           # activity every 100 ms: never quiet for 1 s
        r.poke()
        qtbot.wait(100)
    assert calls == []
    qtbot.waitUntil(lambda: calls == [1], timeout=2000)
    qtbot.wait(300)
    assert calls == [1] and r.releases == 1      # once per quiet period, not periodically


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
