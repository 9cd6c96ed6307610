"""App memory over a scripted session of the real main window, then at rest (tracker issue 25, item 4: <= 700 MB
resident after a 10-minute session with Auto, the kymograph, refine and scrubbing on the 5-object real-mesh scene,
back within 10 % of the start level when idle; issue 14, part 4 was the scrubbing-only session).

Usage::

    python bench/bench_memory.py [--minutes 10] [--idle-s 60] [--scene DIR] [--baseline 8c676cd | none] [--json]
                                 [--tracemalloc]

Needs an X display with GLX (the window embeds the vispy space-time view); without ``DISPLAY`` the script re-runs
itself under ``xvfb-run`` (``bench_spacetime._reexec_under_xvfb``).

Scene: ``bench/synth_scenes.py::ensure_ycb_scene`` (``bench/.data/ycb_5obj_5s``: 5 real YCB meshes, 5 s, about 5 M
events on the full DAVIS346 sensor), or ``--scene``.

Each variant runs in a child process of its own (the parent imports only the standard library, so the children's
figures are their own): a real ``MainWindow`` (private QSettings, non-modal dialogs, the raster kernels warmed in the
background as ``evpose gui`` does) opens the scene and runs a scripted session for ``--minutes``, cycling through

* scrub forth over the whole recording, one 10 ms window per step, each step waiting for the painted frame;
* play (timeline playback) for a few seconds;
* every event representation at a few times;
* the space-time view: spans of 50 to 400 ms, moved over the recording, each waiting for the drawn cloud;
* select each object, nudge its pose (camera / object axes), nudge the clock offset, undo all, redo all, undo all;
* "Score all windows" (the timeline's score row), once;
* the kymograph (issue 16): its dock opened and in front, a line drawn once across an object edge (the default
  line moved by a few pixels) and kept, the time moved over the recording (a different set each pass) and its span
  changed (the default, 1 s, back), each step waiting for the kymograph of the new state;
* the residual view (issue 25.2; ``window.residual_feed.show()``): in front, stepped through windows, each waiting
  for its table;
* Auto (Tools > Auto: the event-rate clock, then clock and poses jointly from edges; issue 15), accepted as soon
  as it proposes something usable (``auto_answer["auto"]``; rejected otherwise), waiting for the job's end;
* Refine from events: one object (a different one each pass) nudged 3 mm / 2 deg off, then "Refine selected object
  from edges", accepted (``auto_answer["refine"]``);
* scrub back over the whole recording (with the residual view in front: it follows the scrubbing).

The space-time dock is brought to the front again at the start of each cycle (the kymograph and residual docks are
tabs beside it). A phase that has started runs to its end, so the session may overrun ``--minutes`` by one Auto.
Then ``--idle-s`` seconds of nothing (the event loop runs, nobody touches the window: the app's idle release,
``app/memory.py``, acts once it is quiet for 2 s); the idle level is compared with the start (scene shown).

A sampler thread reads ``/proc/self/smaps_rollup`` every ``--sample-s`` seconds (RSS, PSS, USS = private clean +
private dirty). Printed: RSS at named points (imports, window shown, scene open + first frame, space-time drawn,
after each kind of activity the first time), per activity (runs, seconds, RSS after its first run, highest RSS
sampled during its runs, RSS after its last run), the start (scene shown), the peak, the end of the session and the
idle level after ``--idle-s`` (its ratio to the start; target: within 10 %), and what holds the memory at rest:
resident bytes per mapping (anonymous heap vs the libraries' code and data) at the end of the session and at rest,
glibc's malloc arena (in use vs free but kept), the numpy arrays reachable from Python objects, grouped by where
they hang (by holder type, and by the first attribute path from the window or an ``evpose`` module, start -> rest),
what a full ``gc.collect()`` then ``malloc_trim(0)`` would still give back, and what clearing the views' caches
(``clear_view_caches``: every ``*Cache`` of the workers' computers, the rasterisers' and the event cache) gives back
after that. ``--tracemalloc`` traces allocations from the start of the session on and prints, at rest, the sites of
those still live: what the session left behind (much slower: a 10-minute session may not reach Auto; changes the
figures). Diagnostics run only after the idle figure, so they do not flatter it.

Baseline: the same script against the code of commit ``--baseline`` (default 8c676cd, the code before the issue-14
memory work), extracted with ``git archive`` into ``bench/.data/mem_baseline_<commit>`` (once) and imported first
through ``PYTHONPATH``; its raster kernels are compiled into their disk cache before the timed run, as for ours.
Activities the baseline's window does not have (8c676cd: no kymograph dock, no residual view, no Auto / refine
proposal panel) are skipped there and listed as skipped: its session is the issue-14 one, so compare the two on the
common points (start, the scrubbing phases), not on the end level.

``--json`` prints one JSON document of the headline figures on stdout (progress goes to stderr).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH = Path(__file__).resolve().parent
DATA = BENCH / ".data"
OUT = BENCH / "out"
TARGET_MB = 700.0
IDLE_TOLERANCE = 0.10     # idle RSS within 10 % of the start level
DEFAULT_BASELINE = "8c676cd"
PACKAGE_PATHS = ("__init__.py", "__main__.py", "core", "app", "widgets", "resources")


def log(*a) -> None:
    print(*a, file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------------------------ /proc readers
def rollup_mb() -> dict:
    """RSS, PSS, USS (private clean + dirty) and anonymous MB of this process from ``/proc/self/smaps_rollup``."""
    kb = {}
    with open("/proc/self/smaps_rollup") as f:
        for line in f:
            parts = line.split()
            if len(parts) >= 2 and parts[0].endswith(":") and parts[1].isdigit():
                kb[parts[0][:-1]] = int(parts[1])
    return {"rss": kb.get("Rss", 0) / 1024, "pss": kb.get("Pss", 0) / 1024,
            "uss": (kb.get("Private_Clean", 0) + kb.get("Private_Dirty", 0)) / 1024,
            "anon": kb.get("Anonymous", 0) / 1024}


def mappings_mb(top: int = 12) -> list[tuple[str, float]]:
    """Resident MB per mapped file (libraries), anonymous memory and the heap, from ``/proc/self/smaps``:
    the ``top`` largest, then the rest summed."""
    by: dict[str, float] = {}
    name = "?"
    with open("/proc/self/smaps") as f:
        for line in f:
            head = line.split(maxsplit=5)
            if len(head) >= 5 and "-" in head[0] and ":" in head[3]:      # a mapping's first line
                path = head[5].strip() if len(head) > 5 else ""
                name = Path(path).name if path.startswith("/") else (path or "[anonymous]")
                if name.startswith("memfd:") or name.startswith("/dev/dri"):
                    name = "[gpu/shm buffers]"
            elif head and head[0] == "Rss:":
                by[name] = by.get(name, 0.0) + int(head[1]) / 1024
    rows = sorted(by.items(), key=lambda kv: -kv[1])
    rest = sum(v for _, v in rows[top:])
    return rows[:top] + [(f"({len(rows) - top} other mappings)", rest)]


def malloc_mb() -> dict | None:
    """glibc ``mallinfo2``: bytes handed out by malloc (``in_use``) and free but kept in its arenas
    (``free_kept``), MB; None off glibc."""
    import ctypes

    class MallInfo2(ctypes.Structure):
        _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                   "fsmblks", "uordblks", "fordblks", "keepcost")]

    try:
        libc = ctypes.CDLL("libc.so.6")
        fn = libc.mallinfo2
    except (OSError, AttributeError):
        return None
    fn.restype = MallInfo2
    m = fn()
    return {"in_use": (m.uordblks + m.hblkhd) / 2**20, "free_kept": m.fordblks / 2**20, "mmapped": m.hblkhd / 2**20}


def numpy_holders(top: int = 12) -> tuple[float, list[tuple[str, float, int]]]:
    """Numpy arrays owning their data, reachable from gc-tracked Python objects, grouped by the type (and
    attribute) of the object that refers to them: (total MB, [(holder, MB, count)])."""
    import gc

    import numpy as np

    gc.collect()
    seen: dict[int, str] = {}
    size: dict[int, int] = {}

    def referents(obj, depth=0):
        """gc referents, looking into containers the collector does not track (a tuple of arrays only)."""
        try:
            refs = gc.get_referents(obj)
        except Exception:  # noqa: BLE001 - exotic objects
            return
        for r in refs:
            if isinstance(r, (tuple, list)) and not gc.is_tracked(r) and depth < 3:
                yield from referents(r, depth + 1)
            else:
                yield r

    for obj in gc.get_objects():
        for r in referents(obj):
            if type(r) is not np.ndarray or id(r) in seen:
                continue
            base = r
            while isinstance(base.base, np.ndarray):
                base = base.base
            if base.base is not None or id(base) in size:        # memory owned elsewhere / counted
                continue
            seen[id(r)] = owner = _owner_name(obj, r)
            size[id(base)] = base.nbytes
            seen[id(base)] = owner
    total = sum(size.values()) / 2**20
    groups: dict[str, list] = {}
    for i, b in size.items():
        g = groups.setdefault(seen[i], [0.0, 0])
        g[0] += b / 2**20
        g[1] += 1
    rows = sorted(((k, v[0], v[1]) for k, v in groups.items()), key=lambda r: -r[1])
    return total, rows[:top]


def numpy_paths(window, top: int | None = 16) -> list[tuple[str, float, int]]:
    """Numpy arrays (their owning base) reachable from ``window`` and from the globals of the ``evpose`` modules
    through Python attributes, containers, bound methods and closures, grouped by the first path found to them
    (indices and non-text keys shown as ``[*]``, cut at 7 steps: :func:`_short_path`): [(path, MB, count)], largest
    first (all of them when ``top`` is None)."""
    import collections
    import functools
    import types

    import numpy as np

    seen: set[int] = set()
    owned: dict[int, tuple[str, int]] = {}
    queue: collections.deque = collections.deque()
    queue.append(("window", window, 0))
    for name, mod in list(sys.modules.items()):
        if name.startswith("evpose.") and mod is not None:
            queue.append((name.split(".", 1)[1], mod, 0))
    leaves = (type, types.BuiltinFunctionType, str, bytes, int, float, bool, complex, type(None))

    def children(obj):
        if isinstance(obj, types.ModuleType):
            return [(f".{k}", v) for k, v in vars(obj).items() if not isinstance(v, (types.ModuleType, type))]
        if isinstance(obj, dict):
            return [(f".{k}" if isinstance(k, str) else "[*]", v) for k, v in list(obj.items())]
        if isinstance(obj, (list, tuple, set, frozenset, collections.deque)):
            return [("[*]", v) for v in list(obj)]
        if isinstance(obj, types.MethodType):
            return [("", obj.__self__)]
        if isinstance(obj, types.FunctionType):
            return [(f"<{obj.__name__}>", c.cell_contents) for c in (obj.__closure__ or ())
                    if _cell_full(c)]
        out = []
        d = getattr(obj, "__dict__", None)
        if isinstance(d, dict):
            out += [(f".{k}", v) for k, v in list(d.items())]
        for k in getattr(type(obj), "__slots__", ()) or ():
            if isinstance(k, str) and hasattr(obj, k):
                out.append((f".{k}", getattr(obj, k)))
        if isinstance(obj, functools.partial):
            out += [("<partial>", obj.func), ("<partial>", obj.args), ("<partial>", obj.keywords)]
        return out

    n = 0
    while queue and n < 3_000_000:
        path, obj, depth = queue.popleft()
        n += 1
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        if isinstance(obj, np.ndarray):
            base = obj
            while isinstance(base.base, np.ndarray):
                base = base.base
            if base.base is None and id(base) not in owned:
                owned[id(base)] = (path, base.nbytes)
            continue
        if isinstance(obj, leaves) or isinstance(obj, types.ModuleType) and depth > 0:
            continue
        try:
            kids = children(obj)
        except Exception:  # noqa: BLE001 - exotic objects (deleted Qt wrappers, properties that raise)
            continue
        for step, v in kids:
            if id(v) not in seen and not isinstance(v, leaves):
                queue.append((path + step, v, depth + 1))
    groups: dict[str, list] = {}
    for path, nbytes in owned.values():
        g = groups.setdefault(_short_path(path), [0.0, 0])
        g[0] += nbytes / 2**20
        g[1] += 1
    rows = sorted(((k, v[0], v[1]) for k, v in groups.items()), key=lambda r: -r[1])
    return rows if top is None else rows[:top]


def clear_view_caches(window) -> list[str]:
    """Diagnosis at rest: empty the caches of the views' computers (every attribute of a worker's computer whose
    class name ends in ``Cache`` and that has ``clear()``, the annotators' rasteriser caches) and the shared event
    cache, so that RSS tells what the caches held and what stays without them. Returns what was cleared."""
    roots = []
    feeds = getattr(window, "feeds", None)
    if feeds is not None:                                    # the view layer (issue 25.1)
        roots += [(f.name, f.worker) for f in feeds.all]
    else:                                                    # the main window's own workers (older code)
        roots += [(k, v) for k, v in vars(window).items() if k.endswith("_worker")]
    rf = getattr(window, "residual_feed", None)
    if rf is not None:
        roots.append(("residual", getattr(getattr(rf, "feed", None), "worker", None) or getattr(rf, "worker", None)))
    cleared = []
    for name, worker in roots:
        computer = getattr(getattr(worker, "_fn", None), "__self__", None)
        if computer is None:
            continue
        for k, v in list(vars(computer).items()):
            cls = type(v).__name__
            if cls.endswith("Cache") and callable(getattr(v, "clear", None)) and v is not getattr(window, "event_cache",
                                                                                                  None):
                v.clear()
                cleared.append(f"{name}.{k}")
            elif cls.endswith("Cache") and isinstance(getattr(v, "_items", None), dict):
                v._items.clear()
                cleared.append(f"{name}.{k}._items")
            raster = getattr(v, "_raster", None) if cls == "Annotator" else None
            rc = getattr(raster, "_cache", None)
            if isinstance(rc, dict) or callable(getattr(rc, "clear", None)):   # one dict each, or the shared one
                rc.clear()
                cleared.append(f"{name}.{k}._raster._cache")
    cache = getattr(window, "event_cache", None)
    if cache is not None:
        cache.clear()
        cleared.append("event_cache")
    return cleared


def _traced_by_site(frames: int = 6) -> dict:
    """tracemalloc's live allocations grouped by their ``frames`` innermost frames, innermost first (tracemalloc
    lists them oldest first; paths shortened to the package / site-packages): {(frame, ...): (bytes, blocks)}. The
    snapshot is dropped before returning (it is large)."""
    import tracemalloc

    snap = tracemalloc.take_snapshot().filter_traces([tracemalloc.Filter(False, tracemalloc.__file__)])
    out: dict = {}
    for st in snap.statistics("traceback"):
        key = tuple(_short_file(f.filename) + f":{f.lineno}" for f in list(st.traceback)[::-1][:frames])
        size, count = out.get(key, (0, 0))
        out[key] = (size + st.size, count + st.count)
    del snap
    return out


def _short_file(name: str) -> str:
    for marker in ("/site-packages/", "/evpose/", "/main/", "/lib/python3"):
        if marker in name:
            return name.split(marker, 1)[1]
    return name


def _cell_full(cell) -> bool:
    try:
        cell.cell_contents
    except ValueError:
        return False
    return True


def _short_path(path: str, steps: int = 7) -> str:
    """``path`` cut after ``steps`` attribute / index steps (the rest summed under it)."""
    import re

    parts = re.findall(r"\.[^.\[<]+|\[\*\]|<[^>]*>|^[^.\[<]+", path)
    return "".join(parts[:steps]) + ("…" if len(parts) > steps else "")


def _owner_name(obj, arr) -> str:
    if isinstance(obj, dict):
        for k, v in obj.items():
            if v is arr:
                return f"dict[{str(k)[:40]}]"
        return "dict"
    t = type(obj)
    return f"{t.__module__.split('.')[-1]}.{t.__qualname__}"


def _reclaim_probe() -> dict:
    """What the end state could give back at once: the source text cached by ``linecache`` (PySide's import hook
    reads the source of every module importing after it) and glibc's free arena memory (``malloc_trim``)."""
    import ctypes
    import linecache

    src_mb = sum(sum(len(x) for x in e[2]) for e in linecache.cache.values() if len(e) > 2) / 2**20
    linecache.clearcache()
    t0 = time.perf_counter()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
    return {"linecache_mb": src_mb, "malloc_trim_ms": (time.perf_counter() - t0) * 1e3}


class Sampler(threading.Thread):
    """Reads :func:`rollup_mb` every ``period_s`` seconds (and on :meth:`mark`)."""

    def __init__(self, period_s: float):
        super().__init__(name="bench-memory-sampler", daemon=True)
        self.period_s, self.t0 = period_s, time.perf_counter()
        self.samples: list[dict] = []
        self.marks: list[dict] = []
        self._halt = threading.Event()

    def sample(self) -> dict:
        s = {"t_s": round(time.perf_counter() - self.t0, 2), **rollup_mb()}
        self.samples.append(s)
        return s

    def mark(self, name: str) -> dict:
        s = {"name": name, **self.sample()}
        m = malloc_mb()
        if m is not None:
            s["malloc_in_use"], s["malloc_free_kept"] = m["in_use"], m["free_kept"]
        import tracemalloc

        if tracemalloc.is_tracing():
            s["traced"] = tracemalloc.get_traced_memory()[0] / 2**20
        self.marks.append(s)
        log(f"  [{s['t_s']:6.1f} s] {name:<44} RSS {s['rss']:7.1f} MB  USS {s['uss']:7.1f}  PSS {s['pss']:7.1f}"
            + (f"  malloc in use {m['in_use']:6.1f} free {m['free_kept']:6.1f}" if m else "")
            + (f"  traced {s['traced']:6.1f}" if "traced" in s else ""))
        return s

    def run(self) -> None:
        while not self._halt.wait(self.period_s):
            self.sample()

    def stop(self) -> None:
        self._halt.set()
        self.join()


# ------------------------------------------------------------------------------------------------ the child
def child(args) -> dict:
    """One scripted session in this process (the child); returns its figures. The window's settings go to a private
    folder this run creates and removes (also when the session fails)."""
    import shutil

    settings_dir = tempfile.mkdtemp(prefix="bench_memory_")
    try:
        return _session(args, settings_dir)
    finally:
        shutil.rmtree(settings_dir, ignore_errors=True)


def _session(args, settings_dir: str) -> dict:
    sampler = Sampler(args.sample_s)
    sampler.start()
    sampler.mark("python + bench imports")
    import numpy as np  # noqa: F401  (the first mark above is the interpreter alone)
    try:                                  # as `evpose gui` starts: malloc settings, the engine before Qt
        from evpose.app.startup import prepare_process
    except ImportError:                   # a baseline older than app/startup.py
        prepare_process = None
    if prepare_process is not None:
        prepare_process()
    from PySide6 import QtCore, QtWidgets

    import evpose
    from evpose.app.main import _warm_up_in_background
    from evpose.app.main_window import MainWindow
    from evpose.app.settings import Settings
    from evpose.core.session.model import Session

    sys.path.insert(0, str(BENCH))
    from bench_scrub import run_until     # shared Qt helper: the event loop until a condition holds

    def settle() -> None:
        """The event loop until the app's own frame and (debounced) space-time work is done."""
        run_until(lambda: (not window._spacetime_timer.isActive() and window.spacetime_drawn()
                           and window.frame_up_to_date()), timeout_s=60)

    code = str(Path(evpose.__file__).resolve().parent)
    sampler.mark("imports (Qt, app, core)")
    qapp = QtWidgets.QApplication.instance() or QtWidgets.QApplication([])
    _warm_up_in_background()
    window = MainWindow(Settings(QtCore.QSettings(str(Path(settings_dir) / "settings.ini"), QtCore.QSettings.IniFormat)))
    window.modal_dialogs = False
    window.auto_answer["Unsaved corrections"] = 0x00800000      # Discard at the end
    window.show()
    run_until(lambda: False, timeout_s=0.5)
    sampler.mark("window shown (no scene)")
    run_until(lambda: not any(t.name == "evpose-raster-warm-up" for t in threading.enumerate()),
              timeout_s=300)
    sampler.mark("raster kernels loaded (numba)")
    session = Session.open(args.scene)
    sampler.mark("scene opened (manifest, events, trajectory)")
    for name in session.object_names:            # what the first frame would load (same objects, cached)
        session.scene.raster_model(name)
    sampler.mark("meshes loaded")
    window.set_session(session)
    if not run_until(window.frame_up_to_date, timeout_s=180):
        raise RuntimeError(f"no first frame (last error: {window.last_error})")
    sampler.mark("first frame shown")
    settle()
    start = sampler.mark("space-time drawn (start of the session)")
    # what holds the memory at the start, to compare with the idle level (after the start mark: not in its figure)
    mappings_start, malloc_start = mappings_mb(), malloc_mb()
    paths_start = numpy_paths(window, top=None)
    if args.tracemalloc:          # from here on: what is still traced at rest was allocated during the session
        import tracemalloc

        tracemalloc.start(8)
    if args.spacetime_budget:                     # diagnosis: another point budget of the space-time view
        session.set_view_option(spacetime_budget=args.spacetime_budget)
        settle()
    if args.hide_spacetime:                       # diagnosis: the session without the space-time view
        window._docks[2].setVisible(False)
        run_until(lambda: False, timeout_s=0.5)

    t_first, t_last = session.time_range
    w = session.view.window_us
    names = session.object_names
    t_session0 = time.perf_counter()
    deadline = t_session0 + 60 * args.minutes
    done_once: set[str] = set()
    runs: list[dict] = []                 # one per phase run: name, t0_s, t1_s (sampler clock), RSS after
    notes: dict[str, list] = {}           # per activity: what it did (results, states, runtimes)
    spacetime_dock = window._docks[2]
    kymo_dock = window.findChild(QtWidgets.QDockWidget, "dock_kymograph")
    feed = getattr(window, "residual_feed", None)
    proposals = getattr(window.align, "proposals", None)
    skipped = {}                          # activity -> why (the baseline's window lacks it)
    if kymo_dock is None or not hasattr(window, "kymograph"):
        skipped["kymograph"] = "no kymograph dock in this code"
    if feed is None:
        skipped["residual view"] = "no residual view in this code"
    if proposals is None:
        skipped["Auto (accept)"] = skipped["refine object"] = "no Auto / refine proposal panel in this code"
    for k, why in skipped.items():
        log(f"  skipping {k}: {why}")
    window.auto_answer.update({"auto": True, "refine": True})

    def left() -> bool:
        return time.perf_counter() < deadline

    def wait_frame() -> None:
        if not run_until(window.frame_up_to_date, timeout_s=30):
            raise RuntimeError(f"no frame within 30 s (last error: {window.last_error})")

    def scrub(direction: int) -> None:
        """Over the whole recording, one window at a time when it has at most ``--scrub-steps`` windows, else
        ``--scrub-steps`` windows spread over it (a different set each pass)."""
        grid = np.arange(t_first + w // 2, t_last, w)
        k = max(1, -(-len(grid) // args.scrub_steps))
        ts = grid[(len(done_once) + direction) % k::k][::direction]
        for t in ts:
            if not left():
                return
            session.set_time(int(t))
            wait_frame()

    def play() -> None:
        session.set_time(t_first)
        window.timeline.play()
        run_until(lambda: not left(), timeout_s=min(args.play_s, max(deadline - time.perf_counter(), 0)))
        window.timeline.pause()
        wait_frame()

    def representations() -> None:
        for name in ("polarity", "spike", "three_channel", "time_surface", "counts", "voxel", "polarity"):
            for t in np.linspace(t_first + w, t_last - w, 4):
                if not left():
                    return
                session.set_representation(name)
                session.set_time(int(t))
                wait_frame()

    def spacetime() -> None:
        for span_ms in (50, 100, 200, 400, 100):
            session.set_view_option(spacetime_span_us=span_ms * 1000)
            for t in np.linspace(t_first + span_ms * 500, t_last - span_ms * 500, 6):
                if not left():
                    return
                session.set_time(int(t))
                settle()

    def edits() -> None:
        session.set_time((t_first + t_last) // 2)
        n = 0
        for name in names:
            session.select(name)
            for frame, kw in (("camera", {"trans_mm": (1, 0, 0)}), ("object", {"rot_deg": (0, 0, 2)}),
                              ("camera", {"trans_mm": (0, -2, 1)})):
                session.nudge_object(name, frame, mergeable=False, **kw)
                wait_frame()
                n += 1
        for d in (500, -200, 1000):
            session.set_offset_correction_us(session.scene.corrections.offset_us + d, mergeable=False)
            wait_frame()
            n += 1
        for op in (session.history.undo, session.history.redo, session.history.undo):
            for _ in range(n):
                op()
                run_until(window.frame_up_to_date, timeout_s=30)
        session.select(None)
        wait_frame()

    def score_row() -> None:
        if "score row" in done_once:
            return
        job = window.align.score_all()
        run_until(lambda: job not in window.controller.jobs and getattr(window.align, "last_scores", None)
                  is not None or not left(), timeout_s=max(deadline - time.perf_counter(), 0))

    def front(dock) -> None:
        """``dock`` shown and in front of its tab group, laid out."""
        if dock.isHidden():
            dock.show()
        dock.raise_()
        run_until(lambda: not dock.visibleRegion().isEmpty(), timeout_s=5)

    def error_since(before):
        return window.last_error if window.last_error is not before else None

    def wait_for(what: str, cond, timeout_s: float = 120) -> None:
        """The event loop until ``cond()``; fails on a timeout or a worker error shown meanwhile."""
        err0 = window.last_error
        ok = run_until(lambda: cond() or error_since(err0) is not None, timeout_s=timeout_s)
        if error_since(err0) is not None:
            raise RuntimeError(f"{what}: the app showed an error: {window.last_error}")
        if not ok:
            raise RuntimeError(f"{what}: nothing within {timeout_s:g} s")

    kymo = {"line": None, "results": 0}

    def kymograph() -> None:
        """The kymograph dock in front; a line drawn once (the default line moved 3 px) and kept; the time moved
        over the recording, the span changed; each step waits for the kymograph of the new state."""
        view = window.kymograph
        feeds = getattr(window, "feeds", None)       # the view layer (issue 25.1): the kymograph's own coalescing
        timer = feeds.kymograph.timer if feeds is not None else window._spacetime_timer
        if kymo["line"] is None:
            window.spacetime.controls.kymograph_button.click()          # as the user opens it
            wait_for("first kymograph", lambda: view.data is not None and view.data.image_rgb.size > 0, 180)
            u0, v0, u1, v1 = view.data.line.as_tuple()
            kymo["line"] = (u0 + 3.0, v0 + 3.0, u1 + 3.0, v1 + 3.0)
            shown = view.data
            view.set_line(kymo["line"])                                 # drawn (lineChanged: computed at once)
            wait_for("kymograph of the drawn line", lambda: view.data is not shown, 120)
            kymo["results"] += 2
        front(kymo_dock)
        span0 = session.view.kymograph_span_us
        n = len(done_once)
        for span_us in (span0, 1_000_000, span0):
            session.set_view_option(kymograph_span_us=span_us)
            for t in np.linspace(t_first + span_us // 2, t_last - span_us // 2, 8)[n % 2::2]:
                if not left():
                    break
                shown = view.data
                session.set_time(int(t))
                wait_for("kymograph after a time step", lambda: not timer.isActive()
                         and view.data is not shown and window.frame_up_to_date(), 120)
                kymo["results"] += 1
        notes["kymograph"] = [f"{kymo['results']} kymographs drawn; line {tuple(round(c, 1) for c in kymo['line'])} "
                              f"kept; last lag {view.shift_ms}"]

    resid = {"results": 0}

    def residuals() -> None:
        """The residual view in front (as the pose panel's Residuals button does), stepped through windows."""
        view = feed.view
        if view.data is None:
            feed.show()
            wait_for("first residual view", lambda: view.data is not None, 180)
            resid["results"] += 1
        else:
            front(feed.dock)
        n = len(runs)
        for t in np.linspace(t_first + w, t_last - w, 12)[n % 3::3].tolist() + [None] * 3:
            if not left():
                break
            shown = view.data
            if t is None:                  # the next window, towards the middle (never clamped at an end)
                session.step_windows(1 if session.view.t_us < (t_first + t_last) // 2 else -1)
            else:
                session.set_time(int(t))
            wait_for("residual view after a time step", lambda: view.data is not shown and window.frame_up_to_date())
            resid["results"] += 1
        notes["residual view"] = [f"{resid['results']} residual tables drawn"]

    def proposal_job(key: str, start) -> None:
        """Start an estimation job (``start()``), wait for its end (hang guard 15 min), accept (auto_answer) or
        reject; records its state and runtime."""
        pc = proposals
        t0 = time.perf_counter()
        start()
        if pc.state != "running":
            raise RuntimeError(f"{key}: the job did not start (state {pc.state})")
        wait_for(key, lambda: pc.state != "running", 900)
        p = pc.proposal if pc.state == "proposal" else window.align.last_proposal
        state = pc.state
        if pc.state == "proposal":                # nothing usable: the panel waits; reject as a user would
            pc.reject()
        wait_frame()
        notes.setdefault(key, []).append(
            f"{state} after {time.perf_counter() - t0:.1f} s"
            + (f" ({p.reason})" if p is not None and p.reason else ""))

    def auto() -> None:
        if feed is not None:
            front(feed.dock)               # the residual view follows the accepted proposal
        proposal_job("Auto (accept)", window.actions_by_name["auto_sync"].trigger)

    def refine() -> None:
        name = names[len([r for r in runs if r["name"] == "refine object"]) % len(names)]
        session.select(name)
        session.nudge_object(name, "camera", rot_deg=(0, 0, 2), trans_mm=(3, 0, 0), mergeable=False)
        wait_frame()
        proposal_job("refine object", window.actions_by_name["refine_selected"].trigger)
        notes["refine object"][-1] = f"{name}: " + notes["refine object"][-1]
        session.select(None)
        wait_frame()

    def cycle_start() -> None:
        front(spacetime_dock)
        settle()

    def scrub_back() -> None:
        if feed is not None:
            front(feed.dock)               # the residual view follows the scrubbing
        scrub(-1)

    phases = [("(cycle start: space-time in front)", cycle_start), ("scrub forth", lambda: scrub(1)),
              ("play", play), ("representations", representations), ("space-time spans", spacetime),
              ("select + nudge + undo/redo", edits), ("score row", score_row), ("kymograph", kymograph),
              ("residual view", residuals), ("Auto (accept)", auto), ("refine object", refine),
              ("scrub back", scrub_back)]
    phases = [(n, fn) for n, fn in phases if n not in skipped]
    cycles = 0
    while left():
        for name, fn in phases:
            if not left():
                break
            t0 = round(time.perf_counter() - sampler.t0, 2)
            fn()
            runs.append({"name": name, "t0_s": t0, "t1_s": round(time.perf_counter() - sampler.t0, 2),
                         "rss_after": sampler.sample()["rss"]})
            if name not in done_once:
                done_once.add(name)
                sampler.mark(f"after {name} (first time)")
        cycles += 1
    run_until(lambda: False, timeout_s=1.0)
    end = sampler.mark("end of the session")
    session_s = time.perf_counter() - t_session0
    mappings_end, malloc_end = mappings_mb(), malloc_mb()
    releases0 = getattr(getattr(window, "memory", None), "releases", None)
    log(f"  idle for {args.idle_s:g} s (nothing touched; the app's idle release may act) ...")
    t_idle0 = time.perf_counter()
    run_until(lambda: False, timeout_s=args.idle_s)
    idle = sampler.mark(f"idle {args.idle_s:g} s after the session")
    idle_s = time.perf_counter() - t_idle0
    releases = None if releases0 is None else window.memory.releases - releases0
    sampler.stop()
    idle_samples = [s for s in sampler.samples if s["t_s"] >= end["t_s"]]
    mappings_idle, malloc_idle = mappings_mb(), malloc_mb()
    import gc

    gc_found = gc.collect()
    after_gc = sampler.mark("diagnosis: after gc.collect()")
    reclaim = _reclaim_probe()
    after_reclaim = sampler.mark("diagnosis: after gc + malloc_trim(0) + linecache.clearcache()")
    # what holds the memory at rest (before the caches are cleared below)
    numpy_idle = numpy_holders(top=16)
    paths_idle = numpy_paths(window, top=None)
    traced = None
    if args.tracemalloc:
        import tracemalloc

        traced = tracemalloc.get_traced_memory()[0] / 2**20, _traced_by_site()
        tracemalloc.stop()
    try:
        cleared = clear_view_caches(window)
    except Exception as e:  # noqa: BLE001 - a diagnosis of another code's internals: say so, go on
        cleared = [f"failed: {e!r}"]
    run_until(lambda: False, timeout_s=3.0)
    gc.collect()
    _reclaim_probe()
    after_caches = sampler.mark("diagnosis: ... + the views' caches cleared")
    shot = OUT / f"bench_memory_{args.label}.png"
    window.save_screenshot(shot)
    peak = max(sampler.samples, key=lambda s: s["rss"])
    per_phase = []
    for name in dict.fromkeys(r["name"] for r in runs):
        rr = [r for r in runs if r["name"] == name]
        inside = [s["rss"] for s in sampler.samples for r in rr if r["t0_s"] <= s["t_s"] <= r["t1_s"]]
        per_phase.append({"name": name, "runs": len(rr), "seconds": round(sum(r["t1_s"] - r["t0_s"] for r in rr), 1),
                          "rss_after_first": round(rr[0]["rss_after"], 1),
                          "rss_max_during": round(max(inside + [r["rss_after"] for r in rr]), 1),
                          "rss_after_last": round(rr[-1]["rss_after"], 1), "notes": notes.get(name, [])})
    res = {"label": args.label, "code": code, "scene": str(args.scene), "minutes": args.minutes, "cycles": cycles,
           "session_s": round(session_s, 1), "idle_s": round(idle_s, 1), "idle_releases": releases,
           "idle_min_rss": min(s["rss"] for s in idle_samples), "skipped": skipped, "per_phase": per_phase,
           "phases_done": sorted(done_once), "start": start, "peak": peak, "end": end, "idle": idle,
           "marks": sampler.marks, "samples": sampler.samples, "screenshot": str(shot),
           "last_error": window.last_error, "mappings_end": mappings_end, "malloc_end": malloc_end,
           "mappings_idle": mappings_idle, "malloc_idle": malloc_idle, "gc_collected": gc_found,
           "after_gc": after_gc, "reclaim": reclaim, "after_reclaim": after_reclaim}
    res["numpy_idle"] = {"total_mb": numpy_idle[0], "holders": numpy_idle[1]}
    res["numpy_paths"] = paths_idle[:16]
    res["caches_cleared"], res["after_caches"] = cleared, after_caches
    res["mappings_start"], res["malloc_start"] = mappings_start, malloc_start
    before = {p: (mb, n) for p, mb, n in paths_start}
    after = {p: (mb, n) for p, mb, n in paths_idle}
    growth = [(p, before.get(p, (0.0, 0))[0], after.get(p, (0.0, 0))[0]) for p in set(before) | set(after)]
    res["numpy_paths_growth"] = sorted(growth, key=lambda g: -abs(g[2] - g[1]))[:16]
    res["numpy_paths_total"] = (sum(mb for _, mb, _ in paths_start), sum(mb for _, mb, _ in paths_idle))
    if traced is not None:
        res["tracemalloc_traced_mb"], idle_sites = traced
        res["tracemalloc_top"] = [(size / 2**20, count, where) for where, (size, count) in
                                  sorted(idle_sites.items(), key=lambda kv: -kv[1][0])[:20]]
    window.close()
    window.settings.qs.sync()     # written now (closing saves the layout): nothing left to write into the removed folder
    return res


# ------------------------------------------------------------------------------------------------ the parent
def baseline_tree(commit: str) -> Path:
    """``bench/.data/mem_baseline_<commit>/evpose``: the package files of ``commit`` (extracted once, atomically),
    with its raster kernels compiled into their disk cache."""
    full = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--verify", f"{commit}^{{commit}}"], check=True,
                          capture_output=True, text=True).stdout.strip()
    home = DATA / f"mem_baseline_{full[:12]}"
    if not (home / "evpose" / "__init__.py").is_file():
        DATA.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{home.name}-", dir=DATA))
        (tmp / "evpose").mkdir()
        arch = subprocess.run(["git", "-C", str(ROOT), "archive", full, *PACKAGE_PATHS], check=True,
                              capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tmp / "evpose")], input=arch, check=True)
        tmp.rename(home)
        log(f"baseline {commit}: extracted into {home}")
    subprocess.run([sys.executable, "-c", "from evpose.core.label.raster import warm_up; warm_up()"],
                   env={**os.environ, "PYTHONPATH": str(home)}, check=True)
    return home


def run_child(label: str, args, pythonpath: Path | None) -> dict:
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as f:
        out = Path(f.name)
    cmd = [sys.executable, __file__, "--child", "--label", label, "--scene", str(args.scene), "--minutes",
           str(args.minutes), "--idle-s", str(args.idle_s), "--sample-s", str(args.sample_s), "--play-s",
           str(args.play_s),
           "--scrub-steps", str(args.scrub_steps), "--child-out", str(out)]
    cmd += [f"--{k.replace('_', '-')}" for k in ("tracemalloc", "hide_spacetime") if getattr(args, k)]
    if args.spacetime_budget:
        cmd += ["--spacetime-budget", str(args.spacetime_budget)]
    log(f"\n== {label} ({'PYTHONPATH=' + str(pythonpath) if pythonpath else 'this tree'}), {args.minutes:g} min")
    try:
        subprocess.run(cmd, env=env, check=True, stdout=sys.stderr)
        res = json.loads(out.read_text())
    finally:
        out.unlink(missing_ok=True)
    if pythonpath is not None and not res["code"].startswith(str(pythonpath)):
        raise RuntimeError(f"the {label} run imported evpose from {res['code']}, not from {pythonpath}")
    return res


def idle_ratio(res: dict) -> float:
    return res["idle"]["rss"] / res["start"]["rss"]


def verdicts(res: dict) -> dict:
    """The issue-25.4 targets: RSS <= TARGET_MB at the end of the session (and at its peak), and back within
    IDLE_TOLERANCE of the start once idle."""
    return {"end_within_target": res["end"]["rss"] <= TARGET_MB, "peak_within_target": res["peak"]["rss"] <= TARGET_MB,
            "idle_within_10pct_of_start": idle_ratio(res) <= 1.0 + IDLE_TOLERANCE}


def headline(res: dict) -> dict:
    return {"rss_start_mb": round(res["start"]["rss"], 1), "rss_peak_mb": round(res["peak"]["rss"], 1),
            "rss_end_mb": round(res["end"]["rss"], 1), "rss_idle_mb": round(res["idle"]["rss"], 1),
            "idle_over_start": round(idle_ratio(res), 3), "uss_end_mb": round(res["end"]["uss"], 1),
            "pss_end_mb": round(res["end"]["pss"], 1), "uss_idle_mb": round(res["idle"]["uss"], 1),
            "session_s": res["session_s"], "idle_s": res["idle_s"], "cycles": res["cycles"],
            "idle_releases": res["idle_releases"], "skipped": res["skipped"], **verdicts(res),
            "per_phase": [{k: v for k, v in ph.items() if k != "notes"} for ph in res["per_phase"]],
            "marks_rss_mb": {m["name"]: round(m["rss"], 1) for m in res["marks"]}}


def report(ours: dict, base: dict | None) -> None:
    print(f"scene {ours['scene']}; scripted session of {ours['minutes']:g} min (ran {ours['session_s']:.0f} s, "
          f"{ours['cycles']} cycles of: {', '.join(ph['name'] for ph in ours['per_phase'])}), then "
          f"{ours['idle_s']:.0f} s idle; RSS sampled every few seconds from /proc/self/smaps_rollup")
    if base and base.get("skipped"):
        print(f"baseline: skipped {', '.join(f'{k} ({v})' for k, v in base['skipped'].items())}")
    print(f"\n{'point':<58} {'ours RSS MB':>12} {'USS':>7}" + (f" {'baseline RSS':>13}" if base else ""))
    print("-" * (79 + (14 if base else 0)))
    bm = {m["name"]: m for m in base["marks"]} if base else {}
    for m in ours["marks"]:
        b = bm.get(m["name"])
        print(f"{m['name'][:58]:<58} {m['rss']:12.1f} {m['uss']:7.1f}" + (f" {b['rss']:13.1f}" if b else ""))
    print("\nper activity (ours)")
    print(f"{'activity':<36} {'runs':>4} {'s':>6} {'RSS after 1st':>13} {'max during':>10} {'after last':>10}")
    for ph in ours["per_phase"]:
        print(f"{ph['name'][:36]:<36} {ph['runs']:4d} {ph['seconds']:6.0f} {ph['rss_after_first']:13.1f} "
              f"{ph['rss_max_during']:10.1f} {ph['rss_after_last']:10.1f}")
        for note in ph["notes"]:
            print(f"    {note[:150]}")
    print("-" * (79 + (14 if base else 0)))
    for k, label in (("start", "START (scene shown)"), ("peak", "PEAK"), ("end", "END of the session"),
                     ("idle", f"IDLE ({ours['idle_s']:.0f} s after the session)")):
        line = f"{label:<58} {ours[k]['rss']:12.1f} {ours[k]['uss']:7.1f}"
        if base and k in base:
            line += f" {base[k]['rss']:13.1f}   baseline/ours {base[k]['rss'] / ours[k]['rss']:.2f}x"
        print(line)
    v = verdicts(ours)
    print(f"target <= {TARGET_MB:g} MB resident after the session: {'PASS' if v['end_within_target'] else 'FAIL'} "
          f"(end {ours['end']['rss']:.0f} MB; peak {ours['peak']['rss']:.0f} MB at {ours['peak']['t_s']:.0f} s: "
          f"{'within' if v['peak_within_target'] else 'over'})")
    print(f"idle / start = {idle_ratio(ours):.3f} (target <= {1 + IDLE_TOLERANCE:.2f}): "
          f"{'PASS' if v['idle_within_10pct_of_start'] else 'FAIL'}; lowest RSS while idle "
          f"{ours['idle_min_rss']:.1f} MB; idle releases (app/memory.py) during the idle phase: "
          f"{ours['idle_releases']}")
    print(f"diagnosis at rest: gc.collect() found {ours['gc_collected']} objects, RSS {ours['idle']['rss']:.1f} -> "
          f"{ours['after_gc']['rss']:.1f} MB; then malloc_trim + linecache -> {ours['after_reclaim']['rss']:.1f} MB "
          f"({ours['reclaim']['linecache_mb']:.1f} MB of source text); then the views' caches cleared -> "
          f"{ours['after_caches']['rss']:.1f} MB ({len(ours['caches_cleared'])} caches: "
          f"{', '.join(ours['caches_cleared'])})")
    print("\nresident MB per mapping: start -> end of the session -> idle")
    def by_name(rows):       # the "(N other mappings)" row under one key
        return {("(other mappings)" if n.startswith("(") else n): mb for n, mb in rows}

    idle_map, start_map = by_name(ours["mappings_idle"]), by_name(ours["mappings_start"])
    for name, mb in by_name(ours["mappings_end"]).items():
        print(f"  {name[:60]:<60} {start_map.get(name, float('nan')):8.1f} -> {mb:8.1f} -> "
              f"{idle_map.get(name, float('nan')):8.1f}")
    for key, when in (("malloc_start", "start"), ("malloc_end", "end"), ("malloc_idle", "idle")):
        mi = ours.get(key)
        if mi:
            print(f"glibc malloc ({when}): {mi['in_use']:.1f} MB in use ({mi['mmapped']:.1f} MB of it in mmapped "
                  f"blocks), {mi['free_kept']:.1f} MB free in the arenas (after a malloc_trim the whole pages of "
                  "it are back with the kernel: not resident, still counted here)")
    nh = ours["numpy_idle"]
    print(f"numpy arrays reachable from Python objects (idle): {nh['total_mb']:.1f} MB; by holder:")
    for holder, mb, n in nh["holders"]:
        print(f"  {holder[:70]:<70} {mb:8.1f} MB in {n} arrays")
    print("numpy arrays by the first path from the window / the evpose modules' globals (idle):")
    for path, mb, n in ours["numpy_paths"]:
        print(f"  {path[:90]:<90} {mb:8.1f} MB in {n} arrays")
    t0, t1 = ours["numpy_paths_total"]
    print(f"the same, start -> idle (total {t0:.1f} -> {t1:.1f} MB), the largest changes:")
    for path, mb0, mb1 in ours["numpy_paths_growth"]:
        print(f"  {path[:90]:<90} {mb0:8.1f} -> {mb1:8.1f} MB ({mb1 - mb0:+.1f})")
    if "tracemalloc_traced_mb" in ours:
        print(f"tracemalloc (traced from the start of the session on): {ours['tracemalloc_traced_mb']:.1f} MB "
              "allocated during the session still live at rest (Python objects and numpy buffers; the C libraries' own "
              "allocations are not traced), by site (innermost frame first):")
    for size, count, where in ours.get("tracemalloc_top", []):
        print(f"  {size:7.1f} MB in {count:7d} blocks: {' <- '.join(where)}")
    print(f"screenshot at rest: {ours['screenshot']}")
    if ours.get("last_error"):
        print(f"last error shown by the app: {ours['last_error'].strip().splitlines()[-1]}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="length of the scripted session (default 10)")
    ap.add_argument("--idle-s", type=float, default=60.0,
                    help="seconds of nothing after the session, then the idle level (default 60)")
    ap.add_argument("--scene", type=Path, help="scene folder (default: bench/.data/ycb_5obj_5s)")
    ap.add_argument("--baseline", default=DEFAULT_BASELINE, help="commit of the baseline code, or 'none'")
    ap.add_argument("--sample-s", type=float, default=2.0, help="RSS sampling period")
    ap.add_argument("--play-s", type=float, default=8.0, help="playback seconds per cycle")
    ap.add_argument("--scrub-steps", type=int, default=120, help="scrub steps per pass over the recording")
    ap.add_argument("--tracemalloc", action="store_true",
                    help="trace allocations from the start of the session; at rest, the sites of those still live "
                         "(slower)")
    ap.add_argument("--spacetime-budget", type=int, help="diagnosis: the space-time view's point budget")
    ap.add_argument("--hide-spacetime", action="store_true",
                    help="diagnosis: close the space-time dock once the session has started")
    ap.add_argument("--json", action="store_true", help="print one JSON document of the headline figures")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--child-out", help=argparse.SUPPRESS)
    ap.add_argument("--label", default="ours", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        os.environ.setdefault("QT_QPA_PLATFORM", "xcb")
        Path(args.child_out).write_text(json.dumps(child(args), default=str))
        return 0
    sys.path.insert(0, str(BENCH))
    from bench_spacetime import _reexec_under_xvfb

    _reexec_under_xvfb()
    if args.scene is None:
        if not (DATA / "ycb_5obj_5s" / "scene.toml").is_file():
            log("generating the realistic scene bench/.data/ycb_5obj_5s (once, several minutes) ...")
        from synth_scenes import ensure_ycb_scene

        args.scene = ensure_ycb_scene()
    OUT.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    ours = run_child("ours", args, None)
    base = None
    if args.baseline != "none":
        base = run_child("baseline", args, baseline_tree(args.baseline))
    doc = {"benchmark": "memory", "scene": str(args.scene), "minutes": args.minutes, "idle_s": args.idle_s,
           "target_mb": TARGET_MB, "idle_tolerance": IDLE_TOLERANCE, "load_average": os.getloadavg(),
           "ours": headline(ours), "baseline_commit": None if base is None else args.baseline,
           "baseline": None if base is None else headline(base),
           "ratio_baseline_over_ours": None if base is None else {
               k: round(base[k]["rss"] / ours[k]["rss"], 2) for k in ("start", "peak", "end", "idle")},
           "holders_idle_mb": {"mappings": [(n, round(v, 1)) for n, v in ours["mappings_idle"]],
                               "malloc": ours["malloc_idle"], "numpy_total": round(ours["numpy_idle"]["total_mb"], 1),
                               "numpy_paths": [(n, round(v, 1), c) for n, v, c in ours["numpy_paths"][:8]]},
           "runtime_s": round(time.perf_counter() - t0, 1)}
    (OUT / "bench_memory.json").write_text(json.dumps({"headline": doc, "ours": ours, "baseline": base}, default=str))
    if args.json:
        print(json.dumps(doc))
    else:
        report(ours, base)
    return 0


if __name__ == "__main__":
    sys.exit(main())
