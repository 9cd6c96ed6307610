"""Benchmark of the space-time view: the update per step on the realistic scene against the code before
issue 14's space-time work, then core's ``SpaceTimeComputer.spacetime`` on a span holding ~2 M events and the
widget's ``set_data`` -> rendered frame, each against a naive baseline.

Usage::

    python bench/bench_spacetime.py [--steps 12] [--rounds 3] [--baseline 08008e8] [--json]
                                    [--events 2_000_000] [--repeats 5] [--size 900x650] [--skip-core] [--skip-ycb]

``--json``: the report goes to stderr and one JSON document of the headline figures to stdout.

Realistic scene (first table; ``bench/synth_scenes.py::ensure_ycb_scene``: 5 E-POSE objects with their real
YCB meshes, 5 s, DAVIS346), default span 100 ms, 12 silhouette slices, budget 300k: the *update per step* of
one window from the middle of the recording: the session steps, then core (``spacetime`` of the new request:
event read, decimation, silhouette slices) -> ``SpaceTimeView.set_data`` -> ``canvas.render()``. Ours runs as the
app does: between steps the space-time worker is idle and ``prefetch_spacetime`` computes the slices of the next
steps (not timed, as in the app). The baseline is commit ``--baseline`` (08008e8: the slice cache by pose, the
Markers-based point visual) checked out with ``git worktree`` and imported in a child process through a
``PYTHONPATH`` folder; ours and the baseline run in alternating child processes (``--rounds`` each), each under
Xvfb, and every figure carries the 1-minute load average of its run.

Needs an X display with GLX (vispy cannot draw with QT_QPA_PLATFORM=offscreen). Without ``DISPLAY`` the
script re-runs itself under ``xvfb-run -a -s "-screen 0 1600x1000x24 +extension GLX +render"``.
Under Xvfb, OpenGL is Mesa's llvmpipe (software, on the machine's cores), so draw times are CPU times
and larger than on a GPU; uploads are memcpys into the driver. The ratios are what carries over.

Data: a synthetic scene (``evpose.core.sim.synth.generate``: three objects, trajectory B at 1 m/s, full DAVIS346
resolution) cached in ``bench/.data/spacetime_scene`` (about two minutes to build, once). The span is
chosen around the middle of the recording so it holds ``--events`` events.

Rows (median of ``--repeats`` runs, wall clock and process CPU time -- the CPU time includes llvmpipe's
threads and stays steady when other jobs share the cores, so ratios use it; every repeat hands over fresh
arrays so nothing is skipped as unchanged):

core
  * ``window read``: ``EventStore.window`` of the span alone (lower bound of any approach);
  * ``silhouettes only``: ``spacetime`` with a budget of 1 event (the projected tubes dominate);
  * ``spacetime, budget 300k``: ours (events decimated in core, silhouettes at 12 slices);
  * ``spacetime, no budget``: the naive call that returns every event of the span.
widget, ``set_data`` -> ``canvas.render()`` (FBO + readback)
  * ``ours, handed 2 M``: the view thins to the session's budget by a stride, 16 B/point upload;
  * ``ours, budget 300k``: handed what core returns with the budget (the app's normal path);
  * ``ours, all 2 M drawn``: budget raised to the whole span;
  * ``Markers.set_data, all 2 M``: the same view with vispy's stock interleaved upload (56 B/point);
  * ``naive: new Markers, all 2 M``: the baseline, a new ``Markers`` visual (per-point colours) per update;
  * ``time-scale change``: ours (one 4x4 uniform) vs naive (rebuild z, new ``Markers``);
  * ``redraw only (orbit)``: one frame with no data change, 300k vs 2 M points drawn, and the coarse
    time-uniform prefix (~40k) the view draws while the mouse drags the camera.
end to end: core + widget, ours (budget) vs naive (no budget, new ``Markers``).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / ".data"
SCENE = DATA / "spacetime_scene"
XVFB = ["xvfb-run", "-a", "-s", "-screen 0 1600x1000x24 +extension GLX +render"]
BASELINE = "08008e8"
TARGET_UPDATE_MS = 100.0
LOG = sys.stdout


def say(*a) -> None:
    print(*a, file=LOG, flush=True)


def _reexec_under_xvfb() -> None:
    if os.environ.get("DISPLAY"):
        return
    if shutil.which("xvfb-run") is None:
        sys.exit("bench_spacetime: no DISPLAY and no xvfb-run; run it under an X server with GLX")
    os.environ.pop("QT_QPA_PLATFORM", None)
    sys.exit(subprocess.call(XVFB + [sys.executable, *sys.argv]))


@dataclass(frozen=True)
class Timing:
    """Median wall-clock and process-CPU milliseconds. The CPU time includes llvmpipe's render threads
    and is much steadier than wall time on a shared machine, so the ratios are taken on it."""

    wall: float
    cpu: float

    def __add__(self, other: "Timing") -> "Timing":
        return Timing(self.wall + other.wall, self.cpu + other.cpu)


def median_time(fn, repeats: int, setup=None) -> Timing:
    """Median wall and CPU time of ``fn()`` in ms (``setup()`` before each call, not timed)."""
    walls, cpus = [], []
    for _ in range(repeats):
        if setup is not None:
            setup()
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        walls.append((time.perf_counter() - t0) * 1e3)
        cpus.append((time.process_time() - c0) * 1e3)
    return Timing(statistics.median(walls), statistics.median(cpus))


# ------------------------------------------------------------------------------------------------ data
def ensure_scene(n_events: int):
    """The cached synthetic scene, (re)generated when missing or too short for ``n_events``."""
    sys.path.insert(0, str(ROOT))
    from evpose.core.data.scene import Scene
    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    if SCENE.exists():
        try:
            sc = Scene.open(SCENE)
            n = len(sc.events)
            sc.close()
            if n >= 1.05 * n_events:
                return
        except Exception:  # noqa: BLE001 - a broken cache is rebuilt
            pass
    duration = max(0.5, n_events / 1.2e6 + 0.2)      # ~1.3 M events/s at 1 m/s on a DAVIS346 (seed 11)
    say(f"generating {SCENE} ({duration:.1f} s of synthetic events, once) ...")
    t0 = time.perf_counter()
    DATA.mkdir(parents=True, exist_ok=True)
    generate(SCENE, SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=1.0,
                                duration_s=duration, seed=11), overwrite=True)
    say(f"  done in {time.perf_counter() - t0:.0f} s")


def span_for(session, n_events: int) -> tuple[int, int]:
    """(centre, span) in µs around the recording's middle holding about ``n_events`` events."""
    ev = session.scene.events
    t0, t1 = session.time_range
    tc = (t0 + t1) // 2
    lo, hi = 1_000, int(t1 - t0)
    while hi - lo > 100:
        mid = (lo + hi) // 2
        i0, i1 = ev.index_range(tc - mid // 2, tc - mid // 2 + mid)
        lo, hi = (mid, hi) if i1 - i0 < n_events else (lo, mid)
    return tc, hi


# ------------------------------------------------------------------------------------------------ realistic scene
def ycb_child(steps: int) -> dict:
    """Run in a child (whichever ``evpose`` PYTHONPATH gives): per-step update times on the realistic scene."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from PySide6 import QtWidgets
    from synth_scenes import ensure_ycb_scene

    import evpose
    try:
        from evpose.core.views.spacetime import SpaceTimeComputer
    except ImportError:          # a baseline from before the view layer (issue 25): the frame computer did it
        from evpose.core.session.frames import FrameComputer as SpaceTimeComputer
    from evpose.core.session.model import Session

    qapp = QtWidgets.QApplication.instance() or QtWidgets.QApplication([])
    try:
        from evpose.widgets.spacetime.view import SpaceTimeView
    except ImportError:          # a baseline from before the widget packages (issue 25)
        from evpose.widgets.spacetime_view import SpaceTimeView

    session = Session.open(ensure_ycb_scene())
    session.scene.trajectory            # the app's timeline loads it on the session's scene; requests share it
    t0, t1 = session.time_range
    session.set_time((t0 + t1) // 2)
    fc = SpaceTimeComputer()
    prefetch = getattr(fc, "prefetch_spacetime", None)
    view = SpaceTimeView(session)
    view.resize(900, 720)
    view.show()
    for _ in range(10):
        qapp.processEvents()
        time.sleep(0.01)
    view.set_data(fc.spacetime(session.request()))       # warm: kernels, shaders, first slices
    view.render_image()
    core, widget, total, cpu, full = [], [], [], [], []
    stepping = hasattr(view, "step_coarse_s")
    for _ in range(steps):
        if prefetch is not None:
            prefetch()                                   # the worker's idle time between requests (not timed)
        session.step_windows(1)
        if stepping:
            view.step_coarse_s = float("inf")            # back-to-back steps, as when the user holds a key
        c0, a = time.process_time(), time.perf_counter()
        data = fc.spacetime(session.request())
        b = time.perf_counter()
        view.set_data(data)
        view.render_image()
        e = time.perf_counter()
        core.append((b - a) * 1e3)
        widget.append((e - b) * 1e3)
        total.append((e - a) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
        if stepping:                                     # the full cloud once the user stops (not the step)
            f0 = time.perf_counter()
            view.set_interacting(False)
            view.render_image()
            full.append((time.perf_counter() - f0) * 1e3)
    view.close()
    return {"code": str(Path(evpose.__file__).resolve().parent), "core_ms": core, "widget_ms": widget,
            "total_ms": total, "cpu_ms": cpu, "full_ms": full, "points": len(data.points),
            "polylines": sum(len(p) for _, _, p in data.tubes), "span_us": int(session.view.spacetime_span_us),
            "load_avg_1m": os.getloadavg()[0]}


def run_child(steps: int, code_path: Path | None) -> dict:
    env = dict(os.environ)
    if code_path is not None:
        env["PYTHONPATH"] = str(code_path) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    p = subprocess.run([sys.executable, __file__, "--ycb-child", str(steps)], env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"child failed ({code_path or 'current'}):\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def add_baseline(work: Path, rev: str) -> tuple[Path, str]:
    """``rev`` checked out with ``git worktree`` under ``work``; the PYTHONPATH folder whose ``evpose`` links to
    it and the commit's one-line description."""
    tree = work / "baseline_tree"
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(tree), rev], check=True)
    path = work / "baseline_path"
    path.mkdir()
    (path / "evpose").symlink_to(tree)
    desc = subprocess.run(["git", "-C", str(ROOT), "log", "-1", "--format=%h %s", rev], capture_output=True,
                          text=True, check=True).stdout.strip()
    return path, desc[:100]


LOD_NOTE = "(the budget)"


def summary(xs) -> dict:
    a = np.asarray(xs, float)
    return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "min": float(a.min()), "n": len(a)}


def ycb_rows(args) -> dict:
    """Ours and the baseline in alternating child processes; the first table and its JSON part."""
    import tempfile

    work = Path(tempfile.mkdtemp(prefix="bench_spacetime_"))
    base_path, desc = add_baseline(work, args.baseline)
    runs = {"ours": [], "baseline": []}
    try:
        for r in range(args.rounds):
            for name, path in (("ours", None), ("baseline", base_path)):
                res = run_child(args.steps, path)
                runs[name].append(res)
                say(f"  round {r + 1} {name:<8}: update median {statistics.median(res['total_ms']):6.1f} ms "
                    f"(core {statistics.median(res['core_ms']):5.1f}, view {statistics.median(res['widget_ms']):6.1f}),"
                    f" load {res['load_avg_1m']:.2f}")
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(work / "baseline_tree")],
                       check=False)
        shutil.rmtree(work, ignore_errors=True)
    out = {"scene": "ycb_5obj_5s", "baseline": desc, "span_us": runs["ours"][0]["span_us"],
           "points": runs["ours"][0]["points"], "polylines": runs["ours"][0]["polylines"]}
    for name, rs in runs.items():
        out[name] = {k: summary([x for r in rs for x in r[k]]) for k in ("total_ms", "core_ms", "widget_ms", "cpu_ms")}
        out[name]["load_avg_1m"] = [r["load_avg_1m"] for r in rs]
    full = [x for r in runs["ours"] for x in r.get("full_ms", [])]
    if full:
        out["ours"]["full_redraw_ms"] = summary(full)
    o, b = out["ours"], out["baseline"]
    out["ratio_median"] = b["total_ms"]["median"] / o["total_ms"]["median"]
    out["ratio_min"] = b["total_ms"]["min"] / o["total_ms"]["min"]
    out["ratio_cpu_median"] = b["cpu_ms"]["median"] / o["cpu_ms"]["median"]
    say(f"\nrealistic scene ycb_5obj_5s, span {out['span_us'] / 1e3:g} ms, {out['points']:,} points, "
        f"{out['polylines']} silhouette polylines; update per step of one window (core -> set_data -> render)")
    say(f"{'code':<10} {'update median':>14} {'p95':>7} {'min':>7} {'core med':>9} {'view med':>9} {'cpu med':>8}  load")
    for name in ("ours", "baseline"):
        x = out[name]
        say(f"{name:<10} {x['total_ms']['median']:14.1f} {x['total_ms']['p95']:7.1f} {x['total_ms']['min']:7.1f} "
            f"{x['core_ms']['median']:9.1f} {x['widget_ms']['median']:9.1f} {x['cpu_ms']['median']:8.1f}  "
            f"{', '.join(f'{v:.1f}' for v in x['load_avg_1m'])}")
    if "full_redraw_ms" in o:
        say(f"ours: a step draws the coarse subset while steps follow each other; all "
            f"{out['points']:,} points {LOD_NOTE} once stepping stops: median {o['full_redraw_ms']['median']:.1f} ms")
    say(f"baseline = {desc}\nours / baseline: {out['ratio_median']:.2f}x faster (median), {out['ratio_min']:.2f}x (min), "
        f"{out['ratio_cpu_median']:.2f}x less CPU; target <= {TARGET_UPDATE_MS:g} ms on a quiet machine: "
        f"{'met' if o['total_ms']['median'] <= TARGET_UPDATE_MS else 'missed'} here")
    return out


# ------------------------------------------------------------------------------------------------ main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--events", type=int, default=2_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--size", default="900x650", help="canvas size WxH in pixels")
    ap.add_argument("--skip-core", action="store_true", help="synthesise the widget's data instead of the scene")
    ap.add_argument("--steps", type=int, default=12, help="steps per child run on the realistic scene")
    ap.add_argument("--rounds", type=int, default=3, help="child runs of ours and of the baseline, alternating")
    ap.add_argument("--baseline", default=BASELINE, help="git revision of the baseline code")
    ap.add_argument("--skip-ycb", action="store_true", help="skip the realistic-scene table")
    ap.add_argument("--skip-2m", action="store_true", help="skip the 2 M-event tables")
    ap.add_argument("--json", action="store_true", help="report on stderr, one JSON document on stdout")
    ap.add_argument("--ycb-child", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    _reexec_under_xvfb()
    if args.ycb_child:
        print(json.dumps(ycb_child(args.ycb_child)))
        return 0
    global LOG
    if args.json:
        LOG = sys.stderr
    headline = {"benchmark": "spacetime", "target_update_ms": TARGET_UPDATE_MS}
    if not args.skip_ycb:
        say(f"realistic scene: {args.rounds} rounds of {args.steps} steps, ours and baseline {args.baseline} "
            "alternating ...")
        headline["ycb"] = ycb_rows(args)
    if args.skip_2m:
        if args.json:
            print(json.dumps(headline))
        return 0
    sys.path.insert(0, str(ROOT))
    import numpy as np
    from PySide6 import QtWidgets

    from evpose.core.views.spacetime import SpaceTimeComputer, SpaceTimeData
    from evpose.core.session.model import Session

    qapp = QtWidgets.QApplication.instance() or QtWidgets.QApplication([])
    from vispy import scene as vscene

    try:
        from evpose.widgets.spacetime.view import SpaceTimeView
    except ImportError:          # a baseline from before the widget packages (issue 25)
        from evpose.widgets.spacetime_view import SpaceTimeView

    W, H = (int(v) for v in args.size.lower().split("x"))
    R = args.repeats
    rows: list[tuple] = []   # (section, name, Timing, baseline Timing | None[, python-side prep ms])
    prep_log: list[float] = []

    def prep_median() -> float:
        """Median of the python-side share (set_data / visual creation before the draw) since last call."""
        v = statistics.median(prep_log) if prep_log else float("nan")
        prep_log.clear()
        return v

    # ------------------------------------------------------------------ core
    if args.skip_core:
        session = None
    else:
        ensure_scene(args.events)
        session = Session.open(SCENE)
        tc, span = span_for(session, args.events)
        session.set_time(tc)
        session.set_view_option(spacetime_span_us=span)
        fc = SpaceTimeComputer()
        fc.spacetime(session.request())                         # warm: annotator, mesh BVHs, page cache
        ev = session.scene.events
        v = session.view
        t_read = median_time(lambda: ev.window(tc - span // 2, tc - span // 2 + span), R)
        budget0 = v.spacetime_budget
        data_budget = fc.spacetime(session.request())
        n_total = data_budget.n_total
        session.set_view_option(spacetime_budget=max(n_total, 1))
        data_full = fc.spacetime(session.request())
        # the three variants interleaved, repeat by repeat, so warm-up and load drift hit them alike
        variants = {"sil": 1, "ours": budget0, "naive": max(n_total, 1)}
        samples = {k: [] for k in variants}
        for _ in range(R):
            for k, b in variants.items():
                session.set_view_option(spacetime_budget=b)
                samples[k].append(median_time(lambda: fc.spacetime(session.request()), 1))
        session.set_view_option(spacetime_budget=budget0)
        t_sil, t_ours, t_naive = (Timing(statistics.median(x.wall for x in samples[k]),
                                         statistics.median(x.cpu for x in samples[k])) for k in variants)
        say(f"scene {SCENE.name}: span {span / 1e3:.1f} ms around t = {tc} µs holds {n_total:,} events; "
              f"{sum(len(p) for _, _, p in data_budget.tubes)} silhouette polylines")
        rows += [("core", "window read (lower bound)", t_read, None),
                 ("core", f"silhouettes only ({v.spacetime_slices} slices, 1 event)", t_sil, None),
                 ("core", f"spacetime, budget {v.spacetime_budget // 1000}k", t_ours, t_naive),
                 ("core", "spacetime, no budget (naive)", t_naive, t_naive)]

    if session is None:  # widget part on synthesised data of the right size
        import tempfile

        from evpose.core.sim.synth import generate
        from evpose.core.sim.synth_config import SynthConfig
        sys.path.insert(0, str(ROOT / "tests"))
        from evpose_testing import TINY_SCENE, half_davis_camera

        tmp = Path(tempfile.mkdtemp()) / "tiny"
        generate(tmp, SynthConfig(**TINY_SCENE, camera=half_davis_camera()))
        session = Session.open(tmp)
        session.set_time(session.time_range[0] + 300_000)
        rng = np.random.default_rng(0)
        n = args.events
        pts = np.column_stack([rng.uniform(0, 172, n), rng.uniform(0, 129, n), rng.uniform(-50, 50, n)])
        data_full = SpaceTimeData(session.view.t_us, pts.astype(np.float32),
                                  (rng.random(n) < 0.5).astype(np.uint8), n, [], 100_000)
        k = -(-n // session.view.spacetime_budget)
        data_budget = SpaceTimeData(data_full.t_center_us, data_full.points[::k].copy(),
                                    data_full.polarity[::k].copy(), n, [], 100_000)

    def fresh(d):
        """The same data in new arrays (defeats the view's unchanged-buffer check, like a new request)."""
        return SpaceTimeData(d.t_center_us, d.points.copy(), d.polarity.copy(), d.n_total, d.tubes, d.span_us)

    # ------------------------------------------------------------------ widget
    def make_view(lean=True):
        SpaceTimeView.lean_upload = lean
        w = SpaceTimeView(session)
        SpaceTimeView.lean_upload = True
        w.resize(W, H + 70)
        w.show()
        for _ in range(10):
            qapp.processEvents()
            time.sleep(0.01)
        return w

    def set_and_render(w, d_holder):
        t0 = time.perf_counter()
        w.set_data(d_holder[0])
        prep_log.append((time.perf_counter() - t0) * 1e3)
        w.render_image()

    budget0 = session.view.spacetime_budget
    view = make_view()
    say(f"canvas {view.canvas.size}, lean upload: {view.markers.lean}, GL: {_gl_renderer(view)}")
    holder = [None]
    set_and_render(view, [fresh(data_full)])                      # warm: shaders compiled, buffers allocated
    prep_median()

    def prep(d):
        return lambda: holder.__setitem__(0, fresh(d))

    t_w_handed = median_time(lambda: set_and_render(view, holder), R, prep(data_full))
    p_w_handed = prep_median()
    shown_handed = view.shown_count
    t_w_budget = median_time(lambda: set_and_render(view, holder), R, prep(data_budget))
    p_w_budget = prep_median()
    t_redraw_budget = median_time(lambda: view.render_image(), R)
    view.set_interacting(True)
    t_redraw_lod = median_time(lambda: view.render_image(), R)
    n_lod = view.point_layer.lod_count
    view.set_interacting(False)
    cam = view.view.camera
    cam_state = dict(fov=cam.fov, center=cam.center, azimuth=cam.azimuth, elevation=cam.elevation,
                     scale_factor=cam.scale_factor)
    matrix = view._transform.matrix.copy()
    s0 = view.time_scale
    flip = [False]

    def rescale():
        flip[0] = not flip[0]
        view.set_time_scale(s0 * (1.5 if flip[0] else 1.0))
        view.render_image()

    t_scale_ours = median_time(rescale, R)
    session.set_view_option(spacetime_budget=max(len(data_full.points), 1))
    t_w_all = median_time(lambda: set_and_render(view, holder), R, prep(data_full))
    p_w_all = prep_median()
    t_redraw_all = median_time(lambda: view.render_image(), R)
    session.set_view_option(spacetime_budget=budget0)
    view.close()

    stock = make_view(lean=False)
    session.set_view_option(spacetime_budget=max(len(data_full.points), 1))
    set_and_render(stock, [fresh(data_full)])
    prep_median()
    t_w_stock = median_time(lambda: set_and_render(stock, holder), R, prep(data_full))
    p_w_stock = prep_median()
    session.set_view_option(spacetime_budget=budget0)
    stock.close()

    # naive baseline: a bare canvas, a new Markers visual with per-point colours on every update
    canvas = vscene.SceneCanvas(keys=None, show=True, size=(W, H), bgcolor="white")
    vb = canvas.central_widget.add_view()
    vb.camera = vscene.TurntableCamera(**cam_state)            # the same framing and transform as ours
    from vispy.visuals.transforms import MatrixTransform

    node = vscene.Node(parent=vb.scene)
    node.transform = MatrixTransform(matrix)
    for _ in range(10):
        qapp.processEvents()
        time.sleep(0.01)
    naive_vis = [None]
    on, off = np.array([1, 0, 0, 0.55], np.float32), np.array([0, 0, 1, 0.55], np.float32)

    def naive_update(d, scale=1.0):
        t0 = time.perf_counter()
        if naive_vis[0] is not None:
            naive_vis[0].parent = None
        pos = d.points.astype(np.float32, copy=True)
        pos[:, 2] *= scale
        colors = np.where(d.polarity[:, None] > 0, on, off)
        m = vscene.visuals.Markers(antialias=0.0, parent=node)  # same look as ours (2 px, no AA, blended)
        m.set_gl_state("translucent", depth_test=False)
        m.set_data(pos, face_color=colors, size=2, edge_width=0)
        naive_vis[0] = m
        prep_log.append((time.perf_counter() - t0) * 1e3)
        canvas.render()

    naive_update(fresh(data_full))
    prep_median()
    t_w_naive = median_time(lambda: naive_update(holder[0]), R, prep(data_full))
    p_w_naive = prep_median()
    t_scale_naive = median_time(lambda: naive_update(data_full, 1.5), R)
    p_scale_naive = prep_median()
    canvas.close()

    nb = len(data_budget.points)
    rows += [("widget", f"ours, handed {len(data_full.points) / 1e6:.1f} M (draws {shown_handed / 1e3:.0f}k)",
              t_w_handed, t_w_naive, p_w_handed),
             ("widget", f"ours, budget {nb / 1e3:.0f}k from core", t_w_budget, t_w_naive, p_w_budget),
             ("widget", f"ours, all {len(data_full.points) / 1e6:.1f} M drawn (16 B/pt)", t_w_all, t_w_naive,
              p_w_all),
             ("widget", "Markers.set_data, all drawn (56 B/pt)", t_w_stock, t_w_naive, p_w_stock),
             ("widget", "naive: new Markers per update (baseline)", t_w_naive, t_w_naive, p_w_naive),
             ("widget", "time-scale change, ours (uniform only)", t_scale_ours, t_scale_naive),
             ("widget", "time-scale change, naive (rebuild)", t_scale_naive, t_scale_naive, p_scale_naive),
             ("widget", f"redraw only (orbit), {nb / 1e3:.0f}k drawn", t_redraw_budget, t_redraw_all),
             ("widget", f"redraw while dragging (coarse {n_lod / 1e3:.0f}k)", t_redraw_lod, t_redraw_budget),
             ("widget", f"redraw only (orbit), {len(data_full.points) / 1e6:.1f} M drawn", t_redraw_all,
              t_redraw_all)]
    if not args.skip_core:
        rows += [("end-to-end", "core budget + ours", t_ours + t_w_budget, t_naive + t_w_naive),
                 ("end-to-end", "core no budget + naive Markers", t_naive + t_w_naive, t_naive + t_w_naive)]

    say()
    say(f"{'section':<11} {'what':<48} {'prep ms':>8} {'wall ms':>9} {'cpu ms':>9} {'vs baseline':>12}")
    say("-" * 102)
    for sec, name, t, base, *pr in rows:
        ratio = f"{base.cpu / t.cpu:10.1f}x" if base else f"{'':>11}"
        prep_s = f"{pr[0]:8.1f}" if pr else f"{'':>8}"
        say(f"{sec:<11} {name:<48} {prep_s} {t.wall:9.1f} {t.cpu:9.1f} {ratio:>12}")
    say("\nwall / cpu = set_data (or the naive rebuild) through canvas.render(), i.e. upload + draw + readback, "
          "as wall-clock and as process CPU time (llvmpipe's threads included); prep = the python-side wall "
          "share before the draw.\n'vs baseline' = baseline cpu / this cpu (higher is faster): core rows vs "
          "'no budget', widget upload rows vs 'new Markers per update', time scale vs its naive rebuild, 300k "
          "redraw vs 2 M redraw, dragging vs the 300k redraw.")
    session.close()
    if not args.skip_core:
        headline["events_2m"] = {"scene": SCENE.name, "end_to_end_ms": (t_ours + t_w_budget).wall,
                                 "end_to_end_cpu_ms": (t_ours + t_w_budget).cpu,
                                 "naive_ms": (t_naive + t_w_naive).wall, "load_avg_1m": os.getloadavg()[0]}
    if args.json:
        print(json.dumps(headline))
    return 0


def _gl_renderer(view) -> str:
    try:
        from vispy.gloo import gl

        view.canvas.context.set_current()
        return gl.glGetParameter(gl.GL_RENDERER)
    except Exception:  # noqa: BLE001 - informational only
        return "?"


if __name__ == "__main__":
    sys.exit(main())
