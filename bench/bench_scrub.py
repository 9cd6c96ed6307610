"""Scrub latency of the real main window, quiet and with a CPU-bound load process, and the space-time view update
(tracker issue 14, point 3).

Usage::

    python bench/bench_scrub.py [--positions 60] [--rate-steps 90] [--rate-hz 30] [--scenes ycb,synth] [--json]

``--json``: the human report goes to stderr and one JSON document of the headline figures to stdout (the full
samples also go to ``bench/out/bench_scrub.json``). Needs an X display with GLX (the window embeds the vispy
space-time view); without ``DISPLAY`` the script re-runs itself under ``xvfb-run`` (Mesa llvmpipe: painting is
CPU work on the same cores).

Scenes (one row each): ``ycb`` is the realistic scene of issue 14 (``bench/synth_scenes.py::ensure_ycb_scene``: 5
E-POSE objects with their real YCB meshes, 5 s, ~8 M events, DAVIS346); ``synth`` the earlier 3-object scene of
built-in shapes (``ensure_scene``, 2 s). Window 10 ms, overlays mask + contour + box + centre.

Code paths, same window, same positions, interleaved by block:

* ``ours``: the app as it is: a frame request goes to two coalescing workers, the event image (read through the
  byte-bounded :class:`~evpose.core.data.event_cache.EventChunkCache`, prefetched in the direction of motion) is
  painted at once, the overlays (rasterised labels, masks, contours, boxes, scores) when they are ready;
* ``baseline``: the code before issue 14.3: one coalescing worker computes the whole frame
  (``FrameComputer.frame`` without the event cache) and the view paints events and overlays together
  (``FrameView.set_frame``).

Measures, per scene and path:

1. *step* latency (``--positions`` times in order over the recording; each step waits until painted, like the
   Right key): request -> first paint showing the events (``events``), -> first paint showing its overlays
   (``overlays``); median and p95, quiet and with the load process;
2. *requests behind* while scrubbing at ``--rate-hz`` without waiting (a drag or playback: ``--rate-steps``
   steps of one window): at every paint of the frame view, how many frame requests newer than the displayed
   events (and overlays) had been issued; max, p95 and the distribution, quiet and loaded;
3. *space-time update* (ycb scene, default span 100 ms): request -> data set -> canvas repainted, for steps of one
   window (the app's path: slices on a fixed grid, contours cached by pose, events through the cache) against
   the baseline (no slice cache: all 12 silhouettes rasterised per update).

The load process is started by the bench (``python -c "while True: pass"``, one core busy) and stopped after the
loaded rows. Every row carries the 1-minute load average when it was measured: on this shared 2-core machine
other jobs change the figures by tens of per cent.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = Path(__file__).resolve().parent / "out"
TARGET_MEDIAN_MS, TARGET_P95_MS, TARGET_BEHIND, TARGET_SPACETIME_MS = 33.0, 100.0, 2, 100.0
OVERLAYS = ("mask", "contour", "box", "center")
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_spacetime import _reexec_under_xvfb  # noqa: E402  (shared helper)

LOG = sys.stdout


def say(*a) -> None:
    print(*a, file=LOG, flush=True)


def load_avg() -> float:
    return round(os.getloadavg()[0], 2)


def pct(xs, q: float) -> float:
    return float(np.percentile(np.asarray(xs, float), q)) if len(xs) else float("nan")


def summary(xs) -> dict:
    return {"median": round(statistics.median(xs), 2), "p95": round(pct(xs, 95), 2), "max": round(max(xs), 2),
            "n": len(xs)} if xs else {}


# ------------------------------------------------------------------------------------------------ Qt helpers
def run_until(cond, timeout_s: float = 30.0, poll_ms: int = 2) -> bool:
    from PySide6 import QtCore

    if cond():
        return True
    loop = QtCore.QEventLoop()
    poll = QtCore.QTimer(interval=poll_ms)
    poll.timeout.connect(lambda: cond() and loop.quit())
    QtCore.QTimer.singleShot(int(timeout_s * 1000), loop.quit)
    poll.start()
    loop.exec()
    poll.stop()
    return cond()


class PaintLog:
    """Event filter on the frame view's viewport: at every paint, the serials of the events and the overlays on
    screen (read from the window's bookkeeping) and the time."""

    def __init__(self, window):
        from PySide6 import QtCore

        log = self

        class Filter(QtCore.QObject):
            def eventFilter(self, obj, ev):  # noqa: N802 (Qt name)
                if ev.type() == QtCore.QEvent.Paint:
                    log.paints.append((time.perf_counter(), window.shown_events_serial(), window.shown_frame_serial()))
                return False

        self.paints: list[tuple[float, int, int]] = []
        self.filter = Filter()
        self.viewport = window.frame_view.glw.viewport()
        self.viewport.installEventFilter(self.filter)

    def first_paint(self, serial: int, which: int, after: float) -> float | None:
        for t, se, sf in self.paints:
            if t >= after and (se, sf)[which] >= serial:
                return t
        return None

    def close(self) -> None:
        self.viewport.removeEventFilter(self.filter)


def make_paths(window):
    """Switches the window between the app's frame path (ours) and the baseline (one worker, whole frame); a
    QObject on the GUI thread, so the baseline worker's results are delivered there."""
    from PySide6 import QtCore

    class Paths(QtCore.QObject, _Paths):
        pass

    p = Paths()
    p.setup(window)
    return p


class _Paths:
    def setup(self, window):
        from evpose.app.workers import LatestWorker
        from evpose.core.views.frame import FrameComputer

        self.w = window
        self.mode = "ours"
        self.base_shown = 0
        self.base_worker = LatestWorker(FrameComputer().frame, "baseline-frame-worker")
        self.base_worker.done.connect(self._base_ready)
        self.issued: list[int] = []
        ours = window.request_frame

        def request_frame():
            if self.mode == "ours":
                ours()
                self.issued.append(window._submitted_serial["frame"])
            elif window.session is not None:
                req = window.session.request()
                self.base_submitted = req.serial
                self.issued.append(req.serial)
                self.base_worker.submit(req)

        window.request_frame = request_frame
        window.shown_events_serial = lambda: (window._shown_serial["events"] if self.mode == "ours" else self.base_shown)
        window.shown_frame_serial = lambda: (window._shown_serial["frame"] if self.mode == "ours" else self.base_shown)

    def _base_ready(self, data, serial):
        if serial <= self.base_shown or self.w.frame_view is None:
            return
        self.base_shown = serial
        self.w.frame_view.set_frame(data)
        self.w.objects.set_scores(data.scores)

    def up_to_date(self) -> bool:
        last = self.issued[-1] if self.issued else 0
        return self.w.shown_events_serial() >= last and self.w.shown_frame_serial() >= last

    def stop(self) -> None:
        self.base_worker.stop()


# ------------------------------------------------------------------------------------------------ measures
def steps(window, paths, plog: PaintLog, positions) -> dict:
    """Step to each position and wait until its events and overlays are painted."""
    session = window.session
    ev_ms, ov_ms = [], []
    for t in positions:
        t0 = time.perf_counter()
        session.set_time(int(t))
        serial = paths.issued[-1]
        if not run_until(lambda: paths.up_to_date() and plog.first_paint(serial, 1, t0) is not None, 30):
            raise RuntimeError(f"no painted frame within 30 s at t = {t} (last error: {window.last_error}; "
                               f"{paths.mode}: issued {paths.issued[-3:]}, on screen {window.shown_events_serial()}, "
                               f"{window.shown_frame_serial()}, paints {plog.paints[-3:]})")
        ev_ms.append((plog.first_paint(serial, 0, t0) - t0) * 1e3)
        ov_ms.append((plog.first_paint(serial, 1, t0) - t0) * 1e3)
    return {"events_ms": ev_ms, "overlays_ms": ov_ms}


def scrub_at_rate(window, paths, plog: PaintLog, t_start: int, n_steps: int, rate_hz: float) -> dict:
    """Step one window every 1/rate s without waiting; at each paint, the frame requests issued after the one
    whose events (overlays) are on screen."""
    from PySide6 import QtCore

    session = window.session
    session.set_time(int(t_start))
    run_until(lambda: paths.up_to_date() and bool(plog.paints) and plog.paints[-1][2] >= paths.issued[-1], 30)
    issued_t: list[tuple[float, int]] = []
    n0 = len(plog.paints)
    t_begin = time.perf_counter()
    timer = QtCore.QTimer(interval=max(int(round(1000 / rate_hz)), 1))
    timer.setTimerType(QtCore.Qt.PreciseTimer)

    def step():
        session.step_windows(1)
        issued_t.append((time.perf_counter(), paths.issued[-1]))
        if len(issued_t) >= n_steps:
            timer.stop()

    timer.timeout.connect(step)
    timer.start()
    run_until(lambda: len(issued_t) >= n_steps, 120)
    t_end = time.perf_counter()
    run_until(lambda: paths.up_to_date(), 30)
    serials = np.array([s for _, s in issued_t])
    times = np.array([t for t, _ in issued_t])
    behind_ev, behind_ov, lag_ms = [], [], []
    for t, se, sf in plog.paints[n0:]:
        if t > t_end:
            break
        newer = serials[times <= t]
        behind_ev.append(int(np.sum(newer > se)))
        behind_ov.append(int(np.sum(newer > sf)))
        shown = np.flatnonzero(serials == se)
        if len(shown):
            lag_ms.append((t - times[shown[0]]) * 1e3)
    return {"behind_events": behind_ev, "behind_overlays": behind_ov, "lag_ms": lag_ms,
            "paints": len(behind_ev), "issued": len(issued_t), "achieved_hz": len(issued_t) / (t_end - t_begin)}


def distribution(xs) -> dict:
    vals, counts = np.unique(np.asarray(xs, int), return_counts=True)
    return {int(v): int(c) for v, c in zip(vals, counts)}


def spacetime_updates(window, n: int) -> dict:
    """Space-time update per step of one window: ours (the app's worker) and the baseline (no slice cache)."""
    from evpose.core.views.frame import FrameComputer

    session, view = window.session, window.spacetime
    window._spacetime_timer.stop()
    run_until(lambda: window.spacetime_drawn(), 60)
    ours, base, core_ours, core_base = [], [], [], []
    naive = FrameComputer()
    canvas = view.canvas.native
    for k in range(n):
        session.step_windows(1)
        window._spacetime_timer.stop()
        run_until(lambda: window.frame_up_to_date(), 30)
        t0 = time.perf_counter()
        window.request_spacetime()
        run_until(window.spacetime_drawn, 30, poll_ms=1)
        canvas.repaint()
        ours.append((time.perf_counter() - t0) * 1e3)
        req = session.request()
        t0 = time.perf_counter()
        naive.slice_cache.clear()                  # the baseline: every silhouette rasterised per update
        data = naive.spacetime(req)
        t1 = time.perf_counter()
        view.set_data(data)
        canvas.repaint()
        base.append((time.perf_counter() - t0) * 1e3)
        core_base.append((t1 - t0) * 1e3)
    window.request_spacetime()                      # the app's own data on screen again
    run_until(window.spacetime_drawn, 30)
    n_pts = view.shown_count
    return {"ours_ms": ours, "baseline_ms": base, "baseline_core_ms": core_base, "points_drawn": n_pts,
            "span_us": session.view.spacetime_span_us}


def start_load() -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


# ------------------------------------------------------------------------------------------------ one scene
def bench_scene(name: str, folder: Path, args) -> dict:
    from PySide6 import QtCore

    from evpose.app.main_window import MainWindow
    from evpose.app.settings import Settings

    tmp = tempfile.mkdtemp(prefix="bench_scrub_")
    qs = QtCore.QSettings(str(Path(tmp) / "settings.ini"), QtCore.QSettings.IniFormat)
    window = MainWindow(Settings(qs))
    window.modal_dialogs = False
    window.show()
    session = window.controller.open_scene(folder)
    session.set_window_us(10_000)
    for kind in ("mask", "contour", "box", "axes", "center"):
        session.set_overlay(kind, kind in OVERLAYS)
    if not run_until(lambda: window.frame_up_to_date() and window.spacetime_drawn(), 120):
        raise RuntimeError(f"the window never showed its first frame (last error: {window.last_error})")
    run_until(lambda: False, 0.3)
    paths = make_paths(window)
    plog = PaintLog(window)
    t0, t1 = session.time_range
    w = session.view.window_us
    positions = np.linspace(t0 + w, t1 - 2 * w, args.positions).round().astype(np.int64)
    cam = session.scene.camera
    fv = window.frame_view.glw.viewport().size()
    say(f"\n=== scene {name} ({folder.name}): {cam.width}x{cam.height}, {len(session.scene.events):,} events over "
        f"{(t1 - t0) / 1e6:.2f} s, {len(session.object_names)} objects; window 10 ms, overlays {'+'.join(OVERLAYS)}; "
        f"frame view {fv.width()}x{fv.height()} px; {os.cpu_count()} cores, load average {load_avg()}")
    res: dict = {"scene": str(folder), "n_events": len(session.scene.events), "objects": session.object_names}
    for paths.mode in ("ours", "baseline"):          # warm both paths (caches, pyqtgraph items)
        steps(window, paths, plog, positions[:4] + w // 2)
    blocks = 3
    for condition in ("quiet", "loaded"):
        load = start_load() if condition == "loaded" else None
        try:
            time.sleep(0.5 if load else 0)
            row = {"load_avg_start": load_avg()}
            for mode in ("ours", "baseline"):
                row[mode] = {"events_ms": [], "overlays_ms": []}
            for b in range(blocks):                    # interleaved blocks: drift hits both paths alike
                for mode in (("ours", "baseline") if b % 2 == 0 else ("baseline", "ours")):
                    paths.mode = mode
                    r = steps(window, paths, plog, positions[b::blocks])
                    row[mode]["events_ms"] += r["events_ms"]
                    row[mode]["overlays_ms"] += r["overlays_ms"]
            for mode in ("ours", "baseline"):
                paths.mode = mode
                start = positions[len(positions) // 4]
                row[mode]["rate"] = scrub_at_rate(window, paths, plog, start, args.rate_steps, args.rate_hz)
            row["load_avg_end"] = load_avg()
        finally:
            if load is not None:
                load.kill()
                load.wait()
        paths.mode = "ours"
        res[condition] = row
        report_condition(name, condition, row, args)
    if name == "ycb":
        paths.mode = "ours"
        st = spacetime_updates(window, args.spacetime_steps)
        st["load_avg"] = load_avg()
        res["spacetime"] = st
        o, b = summary(st["ours_ms"]), summary(st["baseline_ms"])
        say(f"[{name}] space-time update per step of one window (span {st['span_us'] / 1e3:g} ms, "
            f"{st['points_drawn']:,} points drawn), request -> data -> canvas repainted, quiet, load average "
            f"{st['load_avg']}:\n    ours median {o['median']:.1f} ms, p95 {o['p95']:.1f}; baseline (every silhouette "
            f"rasterised per update) median {b['median']:.1f} ms, p95 {b['p95']:.1f} ({b['median'] / o['median']:.1f}x); "
            f"target <= {TARGET_SPACETIME_MS:g} ms: {'met' if o['median'] <= TARGET_SPACETIME_MS else 'missed'}")
    c = window.event_cache
    res["event_cache"] = {"nbytes": c.nbytes, "max_bytes": c.max_bytes, **vars(c.stats)}
    say(f"[{name}] event-chunk cache: {c.nbytes / 2**20:.1f} MiB of {c.max_bytes / 2**20:.0f} MiB; {vars(c.stats)}")
    plog.close()
    paths.stop()
    window.auto_answer["Unsaved corrections"] = 0x00800000      # Discard (nothing is edited)
    window.close()
    return res


def report_condition(name: str, condition: str, row: dict, args) -> None:
    say(f"[{name}, {condition}] load average {row['load_avg_start']} -> {row['load_avg_end']}"
        + (" (one `while True: pass` process started by the bench)" if condition == "loaded" else ""))
    say(f"  {'path':<10} {'events med':>10} {'p95':>7} {'overlays med':>13} {'p95':>7}   "
        f"{'behind max':>10} {'p95':>5} {'lag med ms':>10}  behind distribution (events on screen)")
    for mode in ("ours", "baseline"):
        r = row[mode]
        e, o, rate = summary(r["events_ms"]), summary(r["overlays_ms"]), r["rate"]
        be = rate["behind_events"]
        say(f"  {mode:<10} {e['median']:10.1f} {e['p95']:7.1f} {o['median']:13.1f} {o['p95']:7.1f}   "
            f"{max(be) if be else -1:10d} {pct(be, 95):5.1f} {statistics.median(rate['lag_ms']) if rate['lag_ms'] else float('nan'):10.1f}"
            f"  {distribution(be)} ({rate['paints']} paints, {rate['issued']} requests at {rate['achieved_hz']:.1f}/s)")
    ours, base = row["ours"], row["baseline"]
    say(f"  ratio baseline/ours, median events-first latency: "
        f"{statistics.median(base['events_ms']) / statistics.median(ours['events_ms']):.2f}x; full overlays "
        f"{statistics.median(base['overlays_ms']) / statistics.median(ours['overlays_ms']):.2f}x")


def headline(results: dict, runtime_s: float) -> dict:
    out = {"bench": "scrub", "runtime_s": round(runtime_s, 1), "cores": os.cpu_count(),
           "targets": {"events_median_ms": TARGET_MEDIAN_MS, "events_p95_ms": TARGET_P95_MS,
                       "max_requests_behind_loaded": TARGET_BEHIND, "spacetime_ms": TARGET_SPACETIME_MS}}
    for name, res in results.items():
        sc = {"n_events": res["n_events"], "objects": len(res["objects"])}
        for cond in ("quiet", "loaded"):
            row = res[cond]
            c = {"load_avg": [row["load_avg_start"], row["load_avg_end"]]}
            for mode in ("ours", "baseline"):
                r = row[mode]
                be, bo = r["rate"]["behind_events"], r["rate"]["behind_overlays"]
                c[mode] = {"events_ms": summary(r["events_ms"]), "overlays_ms": summary(r["overlays_ms"]),
                           "behind_events": {"max": max(be) if be else None, "p95": pct(be, 95),
                                             "distribution": distribution(be)},
                           "behind_overlays": {"max": max(bo) if bo else None, "p95": pct(bo, 95)},
                           "rate_hz": round(r["rate"]["achieved_hz"], 1)}
            c["ratio_events_median"] = round(c["baseline"]["events_ms"]["median"] / c["ours"]["events_ms"]["median"], 2)
            c["ratio_overlays_median"] = round(c["baseline"]["overlays_ms"]["median"]
                                               / c["ours"]["overlays_ms"]["median"], 2)
            sc[cond] = c
        if "spacetime" in res:
            st = res["spacetime"]
            sc["spacetime"] = {"ours_ms": summary(st["ours_ms"]), "baseline_ms": summary(st["baseline_ms"]),
                               "load_avg": st["load_avg"], "span_us": st["span_us"]}
        sc["event_cache"] = res["event_cache"]
        out[name] = sc
    return out


def main(argv=None) -> int:
    global LOG
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--positions", type=int, default=60, help="step positions per condition and path")
    ap.add_argument("--rate-steps", type=int, default=90, help="steps of the fixed-rate scrub")
    ap.add_argument("--rate-hz", type=float, default=30.0, help="request rate of the fixed-rate scrub")
    ap.add_argument("--spacetime-steps", type=int, default=15)
    ap.add_argument("--scenes", default="ycb,synth", help="comma-separated: ycb (5 real meshes), synth (3 shapes)")
    ap.add_argument("--json", action="store_true", help="print one JSON document of the headline figures")
    args = ap.parse_args(argv)
    _reexec_under_xvfb()
    if args.json:
        LOG = sys.stderr
    t_run = time.perf_counter()
    from PySide6 import QtWidgets
    from synth_scenes import ensure_scene, ensure_ycb_scene

    QtWidgets.QApplication.instance() or QtWidgets.QApplication([])
    folders = {"ycb": ensure_ycb_scene, "synth": ensure_scene}
    results = {}
    for name in args.scenes.split(","):
        results[name] = bench_scene(name, folders[name](), args)
    head = headline(results, time.perf_counter() - t_run)
    say(f"\nbench runtime {head['runtime_s']:.0f} s, load average now {load_avg()}")
    for name in results:
        q, lo = head[name]["quiet"]["ours"], head[name]["loaded"]["ours"]
        say(f"[{name}] ours: events-first {q['events_ms']['median']:.1f} ms median / {q['events_ms']['p95']:.1f} p95 "
            f"quiet (target {TARGET_MEDIAN_MS:g} / {TARGET_P95_MS:g}), overlays {q['overlays_ms']['median']:.1f} / "
            f"{q['overlays_ms']['p95']:.1f}; loaded: events {lo['events_ms']['median']:.1f} / {lo['events_ms']['p95']:.1f}, "
            f"at most {lo['behind_events']['max']} requests behind (target {TARGET_BEHIND})")
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "bench_scrub.json").write_text(json.dumps({"headline": head, "samples": results}, default=str))
    if args.json:
        print(json.dumps(head, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
