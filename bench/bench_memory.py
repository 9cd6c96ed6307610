"""App memory after a scripted session of the real main window (tracker issue 14, part 4: <= 400 MB resident).

Usage::

    python bench/bench_memory.py [--minutes 5] [--scene DIR] [--baseline 8c676cd | none] [--json]
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
* scrub back over the whole recording.

A sampler thread reads ``/proc/self/smaps_rollup`` every ``--sample-s`` seconds (RSS, PSS, USS = private clean +
private dirty). Printed: RSS at named points (imports, window shown, scene open + first frame, space-time drawn,
after each kind of activity the first time), the start (scene shown), the peak and the end of the session, and what
holds the memory at the end: resident bytes per mapping (anonymous heap vs the libraries' code and data), glibc's
malloc arena (in use vs free but kept), and the numpy arrays reachable from Python objects, grouped by where they
hang. ``--tracemalloc`` adds the top allocation sites (slower; changes the figures a little).

Baseline: the same script against the code of commit ``--baseline`` (default 8c676cd, the code before the issue-14
memory work), extracted with ``git archive`` into ``bench/.data/mem_baseline_<commit>`` (once) and imported first
through ``PYTHONPATH``; its raster kernels are compiled into their disk cache before the timed run, as for ours.

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
TARGET_MB = 400.0
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
    if args.tracemalloc:
        import tracemalloc

        tracemalloc.start(8)
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
    if args.spacetime_budget:                     # diagnosis: another point budget of the space-time view
        session.set_view_option(spacetime_budget=args.spacetime_budget)
        settle()
    if args.hide_spacetime:                       # diagnosis: the session without the space-time view
        window._docks[2].setVisible(False)
        run_until(lambda: False, timeout_s=0.5)

    t_first, t_last = session.time_range
    w = session.view.window_us
    names = session.object_names
    deadline = time.perf_counter() + 60 * args.minutes
    done_once: set[str] = set()

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

    phases = [("scrub forth", lambda: scrub(1)), ("play", play), ("representations", representations),
              ("space-time spans", spacetime), ("select + nudge + undo/redo", edits), ("score row", score_row),
              ("scrub back", lambda: scrub(-1))]
    cycles = 0
    while left():
        for name, fn in phases:
            if not left():
                break
            fn()
            if name not in done_once:
                done_once.add(name)
                sampler.mark(f"after {name} (first time)")
        cycles += 1
    run_until(lambda: False, timeout_s=1.0)
    end = sampler.mark("end of the session")
    sampler.stop()
    malloc_before = malloc_mb()
    reclaim = _reclaim_probe()
    after_reclaim = sampler.mark("diagnosis: after malloc_trim(0) + linecache.clearcache()")
    shot = OUT / f"bench_memory_{args.label}.png"
    window.save_screenshot(shot)
    peak = max(sampler.samples, key=lambda s: s["rss"])
    res = {"label": args.label, "code": code, "scene": str(args.scene), "minutes": args.minutes, "cycles": cycles,
           "phases_done": sorted(done_once), "start": start, "peak": peak, "end": end, "marks": sampler.marks,
           "samples": sampler.samples, "screenshot": str(shot), "last_error": window.last_error,
           "mappings_end": mappings_mb(), "malloc_end": malloc_before, "reclaim": reclaim,
           "after_reclaim": after_reclaim}
    total, rows = numpy_holders()
    res["numpy_end"] = {"total_mb": total, "holders": rows}
    if args.tracemalloc:
        import tracemalloc

        res["tracemalloc_traced_mb"] = tracemalloc.get_traced_memory()[0] / 2**20
        snap = tracemalloc.take_snapshot()
        stats = snap.statistics("traceback")[:10]
        res["tracemalloc_top"] = [(s.size / 2**20, s.count, [f"{f.filename.replace(code, '')}:{f.lineno}"
                                                            for f in s.traceback[:4]]) for s in stats]
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
           str(args.minutes), "--sample-s", str(args.sample_s), "--play-s", str(args.play_s), "--scrub-steps", str(args.scrub_steps), "--child-out", str(out)]
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


def headline(res: dict) -> dict:
    return {"rss_start_mb": round(res["start"]["rss"], 1), "rss_peak_mb": round(res["peak"]["rss"], 1),
            "rss_end_mb": round(res["end"]["rss"], 1), "uss_end_mb": round(res["end"]["uss"], 1),
            "pss_end_mb": round(res["end"]["pss"], 1),
            "marks_rss_mb": {m["name"]: round(m["rss"], 1) for m in res["marks"]}}


def report(ours: dict, base: dict | None) -> None:
    print(f"scene {ours['scene']}; scripted session of {ours['minutes']:g} min ({ours['cycles']} cycles of: "
          f"{', '.join(ours['phases_done'])}); RSS sampled every few seconds from /proc/self/smaps_rollup")
    print(f"\n{'point':<46} {'ours RSS MB':>12} {'USS':>7}" + (f" {'baseline RSS':>13}" if base else ""))
    print("-" * (67 + (14 if base else 0)))
    bm = {m["name"]: m for m in base["marks"]} if base else {}
    for m in ours["marks"]:
        b = bm.get(m["name"])
        print(f"{m['name']:<46} {m['rss']:12.1f} {m['uss']:7.1f}" + (f" {b['rss']:13.1f}" if b else ""))
    print("-" * (67 + (14 if base else 0)))
    for k in ("start", "peak", "end"):
        line = f"{k.upper() + (' (scene shown)' if k == 'start' else ''):<46} {ours[k]['rss']:12.1f} {ours[k]['uss']:7.1f}"
        if base:
            line += f" {base[k]['rss']:13.1f}   baseline/ours {base[k]['rss'] / ours[k]['rss']:.2f}x"
        print(line)
    verdict = "PASS" if ours["peak"]["rss"] <= TARGET_MB and ours["end"]["rss"] <= TARGET_MB else "FAIL"
    print(f"target <= {TARGET_MB:g} MB resident after the session (and at its peak): {verdict}")
    print("\nwhat holds the memory at the end (ours): resident MB per mapping")
    for name, mb in ours["mappings_end"]:
        print(f"  {name[:60]:<60} {mb:8.1f}")
    mi = ours.get("malloc_end")
    if mi:
        print(f"glibc malloc: {mi['in_use']:.1f} MB in use ({mi['mmapped']:.1f} MB of it in mmapped blocks), "
              f"{mi['free_kept']:.1f} MB free but kept in the arenas")
    nh = ours["numpy_end"]
    print(f"numpy arrays reachable from Python objects: {nh['total_mb']:.1f} MB; by holder:")
    for holder, mb, n in nh["holders"]:
        print(f"  {holder[:60]:<60} {mb:8.1f} MB in {n} arrays")
    if "tracemalloc_traced_mb" in ours:
        print(f"tracemalloc: {ours['tracemalloc_traced_mb']:.1f} MB traced (Python objects and numpy buffers)")
    for size, count, where in ours.get("tracemalloc_top", []):
        print(f"  tracemalloc {size:7.1f} MB in {count} blocks: {' <- '.join(where)}")
    print(f"screenshot of the end of the session: {ours['screenshot']}")
    if ours.get("last_error"):
        print(f"last error shown by the app: {ours['last_error'].strip().splitlines()[-1]}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=5.0, help="length of the scripted session (default 5)")
    ap.add_argument("--scene", type=Path, help="scene folder (default: bench/.data/ycb_5obj_5s)")
    ap.add_argument("--baseline", default=DEFAULT_BASELINE, help="commit of the baseline code, or 'none'")
    ap.add_argument("--sample-s", type=float, default=2.0, help="RSS sampling period")
    ap.add_argument("--play-s", type=float, default=8.0, help="playback seconds per cycle")
    ap.add_argument("--scrub-steps", type=int, default=120, help="scrub steps per pass over the recording")
    ap.add_argument("--tracemalloc", action="store_true", help="also the top allocation sites (slower)")
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
    doc = {"benchmark": "memory", "scene": str(args.scene), "minutes": args.minutes, "target_mb": TARGET_MB,
           "ours": headline(ours), "baseline_commit": None if base is None else args.baseline,
           "baseline": None if base is None else headline(base),
           "ratio_baseline_over_ours": None if base is None else {
               k: round(base[k]["rss"] / ours[k]["rss"], 2) for k in ("start", "peak", "end")},
           "holders_end_mb": {"mappings": [(n, round(v, 1)) for n, v in ours["mappings_end"]],
                              "malloc": ours["malloc_end"], "numpy_total": round(ours["numpy_end"]["total_mb"], 1)},
           "runtime_s": round(time.perf_counter() - t0, 1)}
    (OUT / "bench_memory.json").write_text(json.dumps({"headline": doc, "ours": ours, "baseline": base}, default=str))
    if args.json:
        print(json.dumps(doc))
    else:
        report(ours, base)
    return 0


if __name__ == "__main__":
    sys.exit(main())
