"""Accuracy against run time of clock synchronisation, alignment score and pose refinement.

Run ``python bench/accuracy.py`` (``--quick`` for one seed and fewer window counts; ``--sections joint`` or
``--sections classic`` for one part; ``--json`` prints one JSON document of the joint section's figures on
stdout, the tables then go to stderr). The full run also writes ``docs/accuracy.png`` and ``docs/accuracy.txt``
(``--no-docs`` to skip); the plot always goes to ``bench/out/accuracy.png``, the tables to stdout.

Run time on 2 cores: full ~13 min with the scenes cached, ~22 min the first time. The rendered scenes
are made once with :mod:`core.synth` and cached in ``bench/.data/accuracy/`` (two at a time;
generating all 21 takes ~9 min wall on 2 cores).

The scenes render a frame at least every :data:`MAX_FRAME_INTERVAL_US` while the camera moves
(``SynthConfig.max_frame_interval_us``), so the simulated event timing is finer than the 0.2 ms
the sync must resolve.

Sections
--------
1. **Sync** on rendered 8 s scenes (87x65 DAVIS346 optics, ~25-75 k events/s) at 0.1 / 0.5 /
   1.0 m/s, 3 seeds (1 in quick), offsets from the published E-POSE table (``time_shifts.csv``):
   our method (Poisson maximum likelihood refinement, the default; NCC refinement; parabolic
   peak only; speed proxy; 1-10 ms bins) against the E-POSE minima-matching
   baseline. Then at 0.1 m/s on 24 s and 40 s scenes (accuracy against sequence length) and on
   8 s scenes at the full 346x260 resolution; and how well the reported standard error
   (``SyncResult.offset_std_us``) describes the actual errors. Then the second stage on all of
   these scenes: the offset and skew from event/edge alignment
   (:func:`evpose.core.align.sync_edges.refine_offset_from_sync`, the clock-only edge stage that ``evpose sync
   --edges`` ran before issue 15; now the joint fit of section 6) with 12 and 24 windows.
2. **Skew** on 20 s sequences: rate-level scenes (events drawn with a rate proportional to the
   camera's image speed, ~330 k ev/s) with skews up to ±1000 ppm at 4 / 8 / 16 segments, and
   rendered 20 s scenes with -150 / +200 ppm.
3. **No reliable estimate**: static and periodic motion.
4. **Score**: share of 10 ms windows where the true pose scores higher than a 5 mm / 3 degree
   error, for the kernel score, the truncated edge distance and the inside fraction; cost per
   window.
6. **Joint** (issue 15, ``bench/accuracy_joint.py``): clock, poses and hand-eye fitted together on full-resolution
   scenes with a clock error and 5 mm / 3 degree pose errors on every object, three simulator settings (contrast
   threshold, background noise, texture), against the rate alone and the separate stages; a hand-eye table; the
   run time on the 5-object scene.
5. **Refinement** of 5 mm / 3 degree pose errors on half-resolution scenes (173x130, built-in
   boxes and, when ``../shared/assets/epose/models`` exists, the sugar / cracker box meshes),
   against the number of windows and per iteration, with run times; and the clock offset from
   edges (:func:`evpose.core.align.clock_refine.refine_offset`).
"""
from __future__ import annotations

import argparse
import csv
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))       # the bench's own modules

from evpose.core.data.camera import CameraModel  # noqa: E402
from evpose.core.data.geometry import inv_T, pose_error  # noqa: E402
from evpose.core.data.scene import Scene  # noqa: E402
from evpose.core.data.clock import ClockModel  # noqa: E402
from evpose.core.data.trajectory import Trajectory  # noqa: E402
from evpose.core.document.corrections import Corrections  # noqa: E402
from evpose.core.sim.synth import generate, load_ground_truth  # noqa: E402
from evpose.core.sim.synth_config import SynthConfig  # noqa: E402

DATA = REPO / "bench" / ".data" / "accuracy"
OUT = REPO / "bench" / "out"
DOCS = REPO / "docs"
ASSETS = Path(os.environ.get("EVPOSE_ASSETS", REPO.parent / "shared" / "assets" / "epose"))
MODELS = ASSETS / "models"


# ---------------------------------------------------------------------------- scenes
def scaled_camera(width: int, height: int) -> dict:
    cam = CameraModel.davis346()
    s = width / cam.width
    K = cam.K.copy()
    K[:2] *= s
    K[0, 2] = (cam.K[0, 2] + 0.5) * s - 0.5
    K[1, 2] = (cam.K[1, 2] + 0.5) * s - 0.5
    return {"width": width, "height": height, "K": K.tolist(), "dist": cam.dist.tolist()}


def published_offsets() -> list[int]:
    """Non-zero E-POSE clock offsets (µs), sorted; a fixed spread if the table is absent."""
    path = ASSETS / "time_shifts.csv"
    if path.is_file():
        with open(path) as f:
            vals = sorted({int(round(float(r["shift_s"]) * 1e6)) for r in csv.DictReader(f) if float(r["shift_s"])})
        if vals:
            return vals
    return [-116_500, -70_000, -34_000, 34_000, 55_000]


#: Longest time between two rendered frames while the camera moves: the ESIM-style linear
#: interpolation between frames delays the first event of a pixel after a brightness reversal by
#: a fraction of the frame interval (the contrast-threshold dead band), ~0.1 ms at 1 ms frames.
MAX_FRAME_INTERVAL_US = 1000
RENDER = dict(max_px_per_frame=0.5, max_frame_interval_us=MAX_FRAME_INTERVAL_US)


def _generate(job):
    name, cfg = job
    out = DATA / name
    t = time.perf_counter()
    generate(out, cfg, overwrite=True)
    return name, time.perf_counter() - t


def ensure_scenes(jobs: dict) -> dict:
    """Generate the missing scenes (two processes); returns name -> folder."""
    DATA.mkdir(parents=True, exist_ok=True)
    todo = [(n, c) for n, c in jobs.items() if not ((DATA / n / "scene.toml").is_file()
                                                    and (DATA / n / "ground_truth.json").is_file())]
    if todo:
        print(f"generating {len(todo)} scene(s) into {DATA} ...", file=sys.stderr, flush=True)
        with ProcessPoolExecutor(max_workers=2) as ex:
            for name, dt in ex.map(_generate, todo):
                print(f"  {name}: {dt:.1f} s", file=sys.stderr, flush=True)
    return {n: DATA / n for n in jobs}


def open_with_truth(folder, clock=True, poses=False, offset_shift_us=0) -> tuple[Scene, dict]:
    gt = load_ground_truth(folder)
    scene = Scene.open(folder, corrections=None)
    doc = Corrections()
    if clock:
        doc.offset_us = gt["clock"]["offset_us"] - scene.manifest.clock_offset_us + offset_shift_us
        doc.skew_ppm = gt["clock"]["skew_ppm"] - scene.manifest.clock_skew_ppm
    if poses:
        for n in scene.object_names:
            doc.object_deltas[n] = np.asarray(gt["objects"][n]["T_base_obj"]) @ inv_T(scene.manifest.object(n).T_base_obj)
    return scene.with_corrections(doc), gt


# ---------------------------------------------------------------------------- rate-level scenes (skew)
def rate_level_scene(folder: Path, duration_s, offset_us, skew_ppm, seed, *, periodic=False, static=False):
    """Events with a rate proportional to the camera's image speed (no rendering)."""
    from scipy.spatial.transform import Rotation

    from evpose.core.data.event_writer import write_events_h5
    from evpose.core.data.events import EventArray
    from evpose.core.data.manifest import SceneManifest

    if (folder / "scene.toml").is_file():
        return folder
    rng = np.random.default_rng(seed)
    T0, FX, margin = 1_700_000_000_000_000, 60.0, 1.0
    total = duration_s + 2 * margin
    grid = np.arange(0, total, 0.004)
    if static or periodic:
        P = np.zeros((len(grid), 3))
        if periodic:
            P[:, 0] = 0.05 * np.sin(2 * np.pi * grid / 0.36)
        R = Rotation.from_quat(np.tile([1.0, 0, 0, 0], (len(grid), 1)))
    else:
        # the moves sampled at 4 kHz (the smooth motion the events follow) and at 250 Hz (the
        # recorded trajectory); a rate taken from the recorded samples would be a staircase
        t, pos = [np.zeros(1)], [np.zeros((1, 3))]
        p, now = np.zeros(3), 0.0
        while now < total:
            d = rng.normal(size=3)
            d[2] *= 0.3
            d *= rng.uniform(0.05, 0.15) / np.linalg.norm(d)
            Tm = 1.875 * np.linalg.norm(d) / 0.3
            tau = np.linspace(0, 1, max(int(Tm * 4000), 2) + 1)[1:]
            t.append(now + Tm * tau)
            pos.append(p + (tau**3 * (10 - 15 * tau + 6 * tau**2))[:, None] * d)
            p = p + d
            now = now + Tm + rng.uniform(0.15, 0.4)
            t.append(np.array([now]))
            pos.append(p[None].copy())
        t = np.rint(np.concatenate(t) * 1e6) * 1e-6
        pos = np.concatenate(pos)
        keep = np.r_[True, np.diff(t) > 0]
        t, pos = t[keep], pos[keep]
        P = np.stack([np.interp(grid, t, pos[:, i]) for i in range(3)], 1)
        R = Rotation.from_matrix(np.tile(np.diag([1.0, -1.0, -1.0]), (len(grid), 1, 1)))
        true = Trajectory(T0 + np.rint(t * 1e6).astype(np.int64), pos,
                          Rotation.from_matrix(np.tile(np.diag([1.0, -1.0, -1.0]), (len(t), 1, 1))).as_quat())
    traj = Trajectory(T0 + np.rint(grid * 1e6).astype(np.int64), P, R.as_quat())
    if static or periodic:
        true = traj
    t0_ev = T0 + int(margin * 1e6) - int(offset_us)
    clock = ClockModel(int(offset_us), float(skew_ppm), t0_ev)
    bins = np.arange(t0_ev, t0_ev + int(duration_s * 1e6), 1000, dtype=np.int64)
    v, w, ok = true.speed(clock.pose_time(bins + 500))
    lam = np.where(ok, 25.0 * FX * (v / 0.5 + w), 0.0) + 2.0
    n = rng.poisson(lam)
    tt = np.sort(np.repeat(bins, n) + rng.integers(0, 1000, int(n.sum())))
    folder.mkdir(parents=True, exist_ok=True)
    write_events_h5(folder / "events.h5", EventArray(rng.integers(0, 64, len(tt)), rng.integers(0, 48, len(tt)), tt,
                                                     rng.integers(0, 2, len(tt))))
    traj.save_csv(folder / "trajectory.csv")
    cam = CameraModel([[FX, 0, 31.5], [0, FX, 23.5], [0, 0, 1]], [], 64, 48)
    import json

    (folder / "truth.json").write_text(json.dumps({"offset_us": int(offset_us), "skew_ppm": float(skew_ppm)}))
    SceneManifest(folder / "scene.toml", folder.name, cam, folder / "events.h5", folder / "trajectory.csv",
                  "cam", None, 0, 0.0, []).save()
    return folder


# ---------------------------------------------------------------------------- helpers
def table(title, header, rows):
    print(f"\n{title}")
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(header)]
    print("  " + "  ".join(str(h).rjust(w) for h, w in zip(header, widths)))
    for r in rows:
        print("  " + "  ".join(str(c).rjust(w) for c, w in zip(r, widths)))


def fmt(x, nd=2):
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.{nd}f}"


def med_max(v):
    v = np.abs(np.asarray([x for x in v if x is not None and np.isfinite(x)], dtype=float))
    return (float(np.median(v)), float(v.max())) if len(v) else (float("nan"), float("nan"))


# ---------------------------------------------------------------------------- 1. sync
PHASES_US = (137, 250, 500, 731)


_TIMES: dict = {}
#: (group label, error µs, reported offset_std_us) of every default-ML run on shifted bins
_STD_RUNS: list = []


def _event_times(scene) -> np.ndarray:
    """All event times of a scene, read once per events file (every variant and bin shift rebins them)."""
    key = str(scene.manifest.events_path)
    if key not in _TIMES:
        _TIMES.clear()                       # one scene at a time: keep memory flat
        _TIMES[key] = scene.events.read(0, scene.events.n_events).t
    return _TIMES[key]


def rebinned_sync(scene, phase_us, bin_us=1000, **kw):
    """:func:`evpose.core.align.estimate.estimate_clock` on the scene's events binned from ``phase_us`` after
    the first event (``EventStore.rate`` bins start at the first event)."""
    from evpose.core.align.estimate import estimate_clock
    from evpose.core.align.scene_proxy import scene_motion_proxy

    t = _event_times(scene)
    edges = np.arange(t[0] + phase_us - bin_us, t[-1] + bin_us, bin_us, dtype=np.int64)
    counts, _ = np.histogram(t, bins=edges)
    return estimate_clock(edges[:-1], counts, bin_us, scene_motion_proxy(scene), scene.clock, **kw)


def bench_sync(scenes: dict, speeds, seeds):
    from evpose.core.align.estimate import sync_scene
    from evpose.core.align.minima_baseline import sync_minima_baseline

    variants = [("ours 1 ms (default: Poisson ML)", dict(bin_us=1000)),
                ("ours 1 ms NCC refine", dict(bin_us=1000, refine="ncc")),
                ("ours 1 ms parabolic only", dict(bin_us=1000, refine=False)),
                ("ours 1 ms ML, speed proxy", dict(bin_us=1000, kind="speed")),
                ("ours 2 ms ML", dict(bin_us=2000)),
                ("ours 5 ms ML", dict(bin_us=5000)),
                ("ours 10 ms ML", dict(bin_us=10_000)),
                ("E-POSE minima baseline", None),
                ("ours 1 ms ML, bins shifted*", dict(phases=PHASES_US)),
                ("ours 1 ms NCC, bins shifted*", dict(phases=PHASES_US, refine="ncc"))]
    results = {}   # (variant, speed) -> list of (err_us, runtime)
    for sp in speeds:
        for seed in seeds:
            folder = scenes[f"sync_v{sp}_s{seed}"]
            truth = load_ground_truth(folder)["clock"]["offset_us"]
            scene = Scene.open(folder)
            for name, kw in variants:
                if kw is not None and "phases" in kw:
                    kw = dict(kw)
                    for ph in kw.pop("phases"):
                        t = time.perf_counter()
                        r = rebinned_sync(scene, ph, **kw)
                        rt = time.perf_counter() - t
                        if "refine" not in kw and r.offset_us is not None:
                            _STD_RUNS.append((f"8 s, {sp} m/s", r.offset_us - truth, r.offset_std_us))
                        results.setdefault((name, sp), []).append((None if r.offset_us is None else r.offset_us - truth,
                                                                  rt))
                    continue
                t = time.perf_counter()
                r = sync_minima_baseline(scene) if kw is None else sync_scene(scene, **kw)
                rt = time.perf_counter() - t
                err = None if r.offset_us is None else r.offset_us - truth
                results.setdefault((name, sp), []).append((err, rt))
            scene.close()
    rows = []
    for name, _ in variants:
        row = [name]
        for sp in speeds:
            v = results[(name, sp)]
            errs = [e for e, _ in v]
            m, mx = med_max([e / 1e3 for e in errs if e is not None])
            nrel = sum(e is not None for e in errs)
            row.append(f"{fmt(m)} / {fmt(mx)} ({nrel}/{len(v)})")
        row.append(fmt(np.median([rt for sp in speeds for _, rt in results[(name, sp)]]), 3))
        rows.append(row)
    table(f"SYNC offset error |ms| median / max (reliable/runs) over {len(seeds)} seeds x offsets from time_shifts.csv;"
          " 8 s rendered scenes at 87x65, prior offset 0",
          ["method"] + [f"{sp} m/s" for sp in speeds] + ["runtime s (median)"], rows)
    print("  * the store's 1 ms bins start at the first event, which the simulator puts on its own frame grid;\n"
          "    the likelihood then has a kink at the true offset that the ML can snap to (errors of exactly 0).\n"
          f"    The shifted rows bin the same events from {'/'.join(str(p) for p in PHASES_US)} us after it "
          "(one run per shift): these are the representative figures.")
    return results, variants


def bench_slow(scenes: dict, names: list):
    """Offset error at 0.1 m/s against sequence length: the estimate rests on where motion
    starts and stops, and a slow 8 s sequence holds only ~3 gradual moves."""
    from evpose.core.align.minima_baseline import sync_minima_baseline

    by_len: dict = {}
    for n in names:
        dur = int(n.split("_d")[1].split("_")[0])
        dur = f"{dur} s" + (" 346x260" if n.startswith("slowfull_") else "")
        folder = scenes[n]
        truth = load_ground_truth(folder)["clock"]["offset_us"]
        scene = Scene.open(folder)
        for label, kw in (("ours 1 ms ML, bins shifted*", {}), ("ours 1 ms NCC, bins shifted*", dict(refine="ncc"))):
            for ph in PHASES_US:
                t = time.perf_counter()
                r = rebinned_sync(scene, ph, **kw)
                by_len.setdefault((label, dur), []).append(
                    (None if r.offset_us is None else r.offset_us - truth, time.perf_counter() - t))
                if not kw and r.offset_us is not None:
                    _STD_RUNS.append((f"{dur}, 0.1 m/s", r.offset_us - truth, r.offset_std_us))
        t = time.perf_counter()
        r = sync_minima_baseline(scene)
        by_len.setdefault(("E-POSE minima baseline", dur), []).append(
            (None if r.offset_us is None else r.offset_us - truth, time.perf_counter() - t))
        scene.close()
    durs = sorted({d for _, d in by_len}, key=lambda d: ("346x260" in d, int(d.split()[0])))
    rows = []
    for label in ("ours 1 ms ML, bins shifted*", "ours 1 ms NCC, bins shifted*", "E-POSE minima baseline"):
        row = [label]
        for d in durs:
            v = by_len.get((label, d), [])
            errs = [e for e, _ in v]
            m, mx = med_max([e / 1e3 for e in errs if e is not None])
            row.append(f"{fmt(m)} / {fmt(mx)} ({sum(e is not None for e in errs)}/{len(v)})")
        row.append(fmt(np.median([rt for d in durs for _, rt in by_len.get((label, d), [])]), 3))
        rows.append(row)
    table("SYNC at 0.1 m/s against sequence length and resolution: offset error |ms| median / max (reliable/runs); "
          "rendered 87x65 scenes and full DAVIS346 (346x260, ~16x the events), seeds x bin shifts",
          ["method"] + list(durs) + ["runtime s (median)"], rows)
    return by_len


def bench_uncertainty():
    """How well the reported standard error (``SyncResult.offset_std_us``) describes the actual
    error of the default estimate, from the shifted-bin runs of the two tables above."""
    groups: dict = {}
    for g, err, std in _STD_RUNS:
        groups.setdefault(g, []).append((abs(err), std))
    rows = []
    for g, v in groups.items():
        err = np.array([e for e, _ in v], float)
        std = np.array([np.inf if s is None else s for _, s in v], float)
        rows.append([g, str(len(v)), fmt(np.median(err) / 1e3), fmt(np.median(std) / 1e3),
                     fmt(np.median(err / std)), f"{np.mean(err <= 2 * std) * 100:.0f} %"])
    table("SYNC standard error: reported 1 sigma (curvature of the likelihood) against the actual error of the "
          "default estimate (shifted-bin runs above)",
          ["sequences", "runs", "|error| ms median", "sigma ms median", "|error|/sigma median", "within 2 sigma"],
          rows)
    print("  sigma counts the Poisson noise of the rate only: model error (what the gain model and the motion proxy miss)\n"
          "  adds to it, so |error| / sigma above 1 is the share of the error the rate model does not explain.")


EDGE_VARIANTS = (("rate ML -> edges, 12 windows", 12), ("rate ML -> edges, 24 windows (clock only)", 24))


def _edge_group(name: str) -> str:
    if name.startswith("sync_v"):
        return f"8 s, {name.split('_v')[1].split('_')[0]} m/s"
    if name.startswith("skew20"):
        return "20 s skewed, 0.5 m/s"
    dur = name.split("_d")[1].split("_")[0]
    return f"{dur} s{' 346x260' if name.startswith('slowfull_') else ''}, 0.1 m/s"


def bench_sync_edges(scenes: dict, names: list):
    """The second stage: the offset (and skew) from event/edge alignment
    (:func:`evpose.core.align.sync_edges.refine_offset_from_sync`) started at the rate estimate (one
    shifted-bin run per scene), with the objects at their true poses (the assumption of that stage)."""
    from evpose.core.align.refine_result import RefineParams
    from evpose.core.align.sync_edges import refine_offset_from_sync

    res: dict = {}     # (method, group) -> list of (offset err us, |skew err| ppm or None, sigma us, runtime s)
    for n in names:
        folder = scenes[n]
        scene, gt = open_with_truth(folder, clock=False, poses=True)
        truth, true_skew = gt["clock"]["offset_us"], gt["clock"]["skew_ppm"]
        g = _edge_group(n)
        t = time.perf_counter()
        r = rebinned_sync(scene, PHASES_US[1])
        rt_rate = time.perf_counter() - t
        res.setdefault(("rate ML (default)", g), []).append(
            (None if r.offset_us is None else r.offset_us - truth,
             None if r.skew_ppm is None else abs(r.skew_ppm - true_skew), r.offset_std_us, rt_rate))
        for label, nw in EDGE_VARIANTS:
            e = refine_offset_from_sync(scene, r, params=RefineParams(n_windows=nw))
            res.setdefault((label, g), []).append(
                (e.offset_us - truth if e.accepted else None,
                 abs(e.skew_ppm - true_skew) if e.accepted and e.skew_estimated else None,
                 e.offset_std_us, rt_rate + e.runtime_s))
        scene.close()
    groups = list(dict.fromkeys(_edge_group(n) for n in names))
    rows = []
    for g in groups:
        for label in ["rate ML (default)"] + [v[0] for v in EDGE_VARIANTS]:
            v = res.get((label, g), [])
            errs = [x[0] for x in v if x[0] is not None]
            m, mx = med_max([e / 1e3 for e in errs])
            sk = [x[1] for x in v if x[1] is not None]
            ms, mxs = med_max(sk)
            ratio = [abs(x[0]) / x[2] for x in v if x[0] is not None and x[2]]
            sig = [x[2] / 1e3 for x in v if x[0] is not None and x[2] is not None]
            rows.append([g, label, f"{len(errs)}/{len(v)}", f"{fmt(m, 3)} / {fmt(mx, 3)}",
                         f"{fmt(ms, 1)} / {fmt(mxs, 1)} ({len(sk)})" if sk else "kept",
                         fmt(np.median(sig), 3) if sig else "n/a", fmt(np.median(ratio)) if ratio else "n/a",
                         fmt(np.median([x[3] for x in v]), 2)])
    table("SYNC, rate then edges: offset error |ms| and skew error |ppm| (median / max), one shifted-bin rate run per "
          "scene, objects at their true poses",
          ["sequences", "method", "accepted", "offset err ms", "skew err ppm (fitted)", "sigma ms median",
           "|err|/sigma median", "runtime s (total)"], rows)
    print("  edges: refine_offset_from_sync searches 3 sigma of the rate estimate; skew is fitted from the windows\n"
          "  and taken when pinned (std <= 15 ppm) or significant, else the rate's (or the prior) skew is kept.\n"
          "  sigma: the rate's likelihood curvature / the edges' jackknife over windows.")
    return res


def bench_skew(n_seeds, rendered_skew):
    from evpose.core.align.estimate import sync_scene

    rows, pts = [], []
    cases = []
    for i in range(n_seeds):
        rng = np.random.default_rng(100 + i)
        skew = float(rng.uniform(-1000, 1000)) if i else 1000.0
        off = int(rng.uniform(-120_000, 120_000))
        cases.append(rate_level_scene(DATA / f"rate20_{i}", 20.0, off, skew, 100 + i))
    variants = [("ML (default), 4 segments", dict(n_segments=4)), ("ML (default), 8 segments", dict(n_segments=8)),
                ("ML (default), 16 segments", dict(n_segments=16)),
                ("NCC refine, 8 segments", dict(refine="ncc")), ("NCC refine, 16 segments", dict(refine="ncc", n_segments=16)),
                ("Theil-Sen only, 8 segments", dict(refine=False))]
    import json

    for name, kw in variants:
        se, oe, rt = [], [], []
        for folder in cases:
            truth = json.loads((folder / "truth.json").read_text())
            scene = Scene.open(folder)
            t = time.perf_counter()
            r = sync_scene(scene, kind="speed", **kw)
            rt.append(time.perf_counter() - t)
            scene.close()
            se.append(None if r.skew_ppm is None else r.skew_ppm - truth["skew_ppm"])
            oe.append(None if r.offset_us is None else (r.offset_us - truth["offset_us"]) / 1e3)
        ms, mxs = med_max(se)
        mo, mxo = med_max(oe)
        rows.append([name, f"{fmt(ms, 1)} / {fmt(mxs, 1)}", f"{fmt(mo, 3)} / {fmt(mxo, 3)}",
                     f"{sum(x is not None for x in se)}/{len(se)}", fmt(np.median(rt), 3)])
        pts.append((name, float(np.median(rt)), ms))
    table(f"SKEW on {n_seeds} rate-level 20 s sequences (skews up to ±1000 ppm, offsets ±120 ms, ~330 k ev/s)",
          ["method", "skew err ppm med/max", "offset err ms med/max", "skew estimated", "runtime s"], rows)
    rows = []
    for folder in rendered_skew:
        gt = load_ground_truth(folder)["clock"]
        scene = Scene.open(folder)
        for name, kw in (("ML (default)", {}), ("NCC refine", dict(refine="ncc"))):
            r = sync_scene(scene, **kw)
            off_txt = "n/a" if r.offset_us is None else f"{(r.offset_us - gt['offset_us']) / 1e3:+.3f}"
            skew_txt = "not estimated" if r.skew_ppm is None else f"{r.skew_ppm - gt['skew_ppm']:+.1f}"
            rows.append([folder.name, f"{gt['skew_ppm']:+.0f}", f"{gt['offset_us'] / 1e3:+.1f}", name, skew_txt, off_txt,
                         fmt(r.runtime_s, 2)])
        scene.close()
    if rows:
        table("SKEW on rendered 20 s scenes (87x65, 0.5 m/s, default 4 segments)",
              ["scene", "true skew ppm", "true offset ms", "method", "skew err ppm", "offset err ms", "runtime s"], rows)
    return pts


def bench_unreliable():
    from evpose.core.align.estimate import sync_scene
    from evpose.core.align.minima_baseline import sync_minima_baseline

    rows = []
    for name, kw in (("static camera", dict(static=True)), ("periodic motion (period 360 ms)", dict(periodic=True))):
        folder = rate_level_scene(DATA / f"rate_{name.split()[0]}", 6.0, -40_000, 0.0, 7, **kw)
        scene = Scene.open(folder)
        r = sync_scene(scene)
        b = sync_minima_baseline(scene)
        scene.close()
        rows.append([name, str(r.reliable), r.reason[:70], str(b.reliable) + ("" if b.reliable else f" ({b.reason})"),
                     fmt(r.runtime_s, 3)])
    table("NO RELIABLE ESTIMATE", ["sequence", "ours reliable", "reason", "baseline reliable", "runtime s"], rows)


# ---------------------------------------------------------------------------- 4. score
def bench_score(folders):
    from evpose.core.align.score_table import score_windows

    rows = []
    for folder in folders:
        scene, gt = open_with_truth(folder)
        truth = {n: np.asarray(gt["objects"][n]["T_base_obj"]) for n in scene.object_names}
        a = score_windows(scene, poses=truth)
        b = score_windows(scene)
        for n in scene.object_names:
            res = []
            for key in ("score", "distance_px", "inside_fraction"):
                x, y = getattr(a, key)[n], getattr(b, key)[n]
                both = ~(x.mask | y.mask)
                better = (x.data[both] > y.data[both]) if key != "distance_px" else (x.data[both] < y.data[both])
                res.append(f"{better.mean():.2f}")
            rows.append([f"{folder.name}/{n}", *res, f"{a.mean_score(n):.3f} vs {b.mean_score(n):.3f}",
                         f"{1e3 * a.runtime_s / len(a):.1f}"])
        scene.close()
    table("SCORE: share of 10 ms windows where the true pose beats a 5 mm / 3 deg error (paired, valid windows)",
          ["scene/object", "kernel score", "edge distance", "inside fraction", "mean score true vs wrong",
           "ms per window (all objects)"], rows)


# ---------------------------------------------------------------------------- 5. refinement
def obj_errors(scene, name, T, gt):
    Tt = np.asarray(gt["objects"][name]["T_base_obj"])
    c = scene.model(name).bbox_center_m
    dt = np.linalg.norm((T[:3, :3] @ c + T[:3, 3]) - (Tt[:3, :3] @ c + Tt[:3, 3])) * 1e3
    return float(dt), float(np.degrees(pose_error(T, Tt)[1]))


def bench_refine(folders, window_counts):
    from evpose.core.align.pose_refine import refine_object
    from evpose.core.align.refine_result import RefineParams

    per_row, traces = {}, []
    for nw in window_counts:
        for folder in folders:
            scene, gt = open_with_truth(folder)
            for n in scene.object_names:
                if scene.manifest.object(n).symmetric:
                    continue
                r = refine_object(scene, n, params=RefineParams(n_windows=nw), with_scores=False)
                T = r.dT_base @ scene.manifest.object(n).T_base_obj
                before = obj_errors(scene, n, scene.T_base_obj(n), gt)
                after = obj_errors(scene, n, T, gt)
                per_row.setdefault(nw, []).append((f"{folder.name}/{n}", before, after, r.runtime_s, r.accepted))
                if nw == window_counts[-1]:
                    traces.append([(0, 0.0, *before)] + [(tr["iteration"], tr["elapsed_s"],
                                                          *obj_errors(scene, n, tr["T_base_obj"], gt)) for tr in r.trace])
            scene.close()
    rows = []
    for nw in window_counts:
        v = per_row[nw]
        dts = [a[0] for _, _, a, _, _ in v]
        drs = [a[1] for _, _, a, _, _ in v]
        rows.append([nw, f"{np.median(dts):.2f} / {max(dts):.2f}", f"{np.median(drs):.2f} / {max(drs):.2f}",
                     f"{np.median([x[1][0] for x in v]):.2f} mm / {np.median([x[1][1] for x in v]):.2f} deg",
                     f"{sum(x[4] for x in v)}/{len(v)}", f"{np.median([x[3] for x in v]):.1f}"])
    table("REFINE pose error after refinement (median / max over objects and seeds); half-res 173x130, 3 s, "
          "0.5 m/s, true clock", ["windows", "dt mm", "dR deg", "start (median)", "accepted", "runtime s (median)"],
          rows)
    detail = [[name, f"{b[0]:.2f} / {b[1]:.2f}", f"{a[0]:.2f} / {a[1]:.2f}", f"{rt:.1f}"]
              for name, b, a, rt, _ in per_row[window_counts[-1]]]
    table(f"REFINE per object ({window_counts[-1]} windows)", ["scene/object", "before mm / deg", "after mm / deg",
                                                                "runtime s"], detail)
    # error per iteration (median over objects at each iteration index, padded with the last value)
    L = max(len(t) for t in traces)
    pad = [t + [t[-1]] * (L - len(t)) for t in traces]
    arr = np.asarray(pad)       # (objects, L, 4): iteration, elapsed, dt, dR
    rows = [[i, f"{np.median(arr[:, i, 1]):.1f}", f"{np.median(arr[:, i, 2]):.2f}", f"{np.median(arr[:, i, 3]):.2f}"]
            for i in range(L)]
    table(f"REFINE error against iteration ({window_counts[-1]} windows; sigma 1.5 -> 0.08 px at half res)",
          ["outer iteration", "elapsed s (median)", "dt mm (median)", "dR deg (median)"], rows)
    return per_row, arr


def bench_offset_refine(folders):
    from evpose.core.align.clock_refine import refine_offset
    from evpose.core.align.refine_result import RefineParams

    rows = []
    for folder in folders:
        for poses in (True, False):
            scene, gt = open_with_truth(folder, poses=poses, offset_shift_us=1500)
            r = refine_offset(scene, params=RefineParams(n_windows=24))
            scene.close()
            rows.append([folder.name, "true" if poses else "5 mm / 3 deg off", "+1.50",
                         f"{(r.offset_us - gt['clock']['offset_us']) / 1e3:+.3f}", f"{r.runtime_s:.1f}"])
    table("OFFSET from edges (refine_offset, 24 windows): start 1.5 ms off", ["scene", "object poses",
                                                                               "start err ms", "final err ms",
                                                                               "runtime s"], rows)


# ---------------------------------------------------------------------------- plot
def plot(sync_results, sync_variants, speeds, skew_pts, refine_rows, refine_arr, window_counts):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(17, 5))
    markers = dict(zip(speeds, "os^"))
    for i, (name, _) in enumerate(sync_variants):
        for sp in speeds:
            v = [(abs(e) / 1e3, rt) for e, rt in sync_results[(name, sp)] if e is not None]
            if v:
                e, rt = np.median([x[0] for x in v]), np.median([x[1] for x in v])
                ax[0].scatter(rt, max(e, 1e-3), marker=markers[sp], color=plt.cm.tab20(i % 20),
                              label=name if sp == speeds[0] else None)
    ax[0].set_xscale("log")
    ax[0].set_yscale("log")
    ax[0].set_xlabel("run time (s)")
    ax[0].set_ylabel("median |offset error| (ms)")
    ax[0].set_title("sync: o 0.1, s 0.5, ^ 1.0 m/s")
    ax[0].legend(fontsize=7)
    for name, rt, e in skew_pts:
        ax[1].scatter(rt, e, label=name)
    ax[1].set_xlabel("run time (s)")
    ax[1].set_ylabel("median |skew error| (ppm)")
    ax[1].set_title("skew, 20 s rate-level sequences")
    ax[1].legend(fontsize=7)
    for nw in window_counts:
        v = refine_rows[nw]
        ax[2].scatter(np.median([x[3] for x in v]), np.median([x[2][0] for x in v]), marker="o", color="C0")
        ax[2].scatter(np.median([x[3] for x in v]), np.median([x[2][1] for x in v]), marker="s", color="C1")
        ax[2].annotate(f"{nw} win", (np.median([x[3] for x in v]), np.median([x[2][0] for x in v])), fontsize=8)
    ax[2].plot(np.median(refine_arr[:, :, 1], axis=0), np.median(refine_arr[:, :, 2], axis=0), "C0-", alpha=0.5,
               label="dt mm per iteration")
    ax[2].plot(np.median(refine_arr[:, :, 1], axis=0), np.median(refine_arr[:, :, 3], axis=0), "C1-", alpha=0.5,
               label="dR deg per iteration")
    ax[2].set_xlabel("run time (s)")
    ax[2].set_ylabel("median error (mm: o, deg: s)")
    ax[2].set_title("pose refinement from 5 mm / 3 deg")
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / "accuracy.png"
    fig.savefig(path, dpi=110)
    return path


# ---------------------------------------------------------------------------- main
SPEEDS = (0.1, 0.5, 1.0)


def scene_jobs(quick: bool):
    """The rendered scenes: name -> SynthConfig (the names encode everything that varies, so the
    cache in ``bench/.data/accuracy`` is shared by quick and full runs)."""
    seeds = (0,) if quick else (0, 1, 2)
    offs = published_offsets()
    pick = [offs[0], offs[len(offs) // 2], offs[-1], offs[len(offs) // 4], offs[3 * len(offs) // 4]]
    low = scaled_camera(87, 65)
    half = scaled_camera(173, 130)
    jobs = {}
    for i, sp in enumerate(SPEEDS):
        for seed in seeds:
            jobs[f"sync_v{sp}_s{seed}"] = SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B",
                                                     speed_mps=sp, duration_s=8.0,
                                                     offset_us=pick[(i + 3 * seed) % len(pick)], seed=seed,
                                                     camera=low, **RENDER)
    jobs["skew20"] = SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5, duration_s=20.0,
                                 offset_us=pick[1], skew_ppm=-150.0, seed=3, camera=low, **RENDER)
    if not quick:
        jobs["skew20_b"] = SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5,
                                       duration_s=20.0, offset_us=pick[3], skew_ppm=200.0, seed=4, camera=low,
                                       **RENDER)
    for dur in ((24,) if quick else (24, 40)):          # slow motion: accuracy against sequence length
        for seed in ((0,) if quick else (0, 1)):
            jobs[f"slow_v0.1_d{dur}_s{seed}"] = SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B",
                                                           speed_mps=0.1, duration_s=float(dur),
                                                           offset_us=pick[(2 + seed) % len(pick)], seed=10 + seed,
                                                           camera=low, **RENDER)
    for seed in ((0,) if quick else (0, 1)):          # slow motion at the sensor's full resolution
        jobs[f"slowfull_v0.1_d8_s{seed}"] = SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B",
                                                       speed_mps=0.1, duration_s=8.0,
                                                       offset_us=pick[(1 + seed) % len(pick)], seed=20 + seed,
                                                       **RENDER)
    ref_seeds = (0,) if quick else (0, 1)
    for seed in ref_seeds:
        jobs[f"refine_box_s{seed}"] = SynthConfig(objects=("box", "flatbox"), trajectory="B", speed_mps=0.5,
                                                  duration_s=3.0, pose_error_mm=5, pose_error_deg=3, seed=seed,
                                                  camera=half, **RENDER)
        if MODELS.is_dir():
            jobs[f"refine_ycb_s{seed}"] = SynthConfig(objects=("sugar_box", "cracker_box"), mesh_dir=str(MODELS),
                                                      trajectory="B", speed_mps=0.5, duration_s=3.0, pose_error_mm=5,
                                                      pose_error_deg=3, seed=seed + 1, camera=half,
                                                      **RENDER)
    return jobs, seeds


class _Tee:
    """stdout that is also kept (for ``docs/accuracy.txt``)."""

    def __init__(self, stream):
        import io

        self.stream, self.buf = stream, io.StringIO()

    def write(self, text):
        self.buf.write(text)
        return self.stream.write(text)

    def flush(self):
        self.stream.flush()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer seeds and window counts")
    ap.add_argument("--sections", default="classic,joint",
                    help="comma list of: classic (sections 1-5), joint (section 6); default both")
    ap.add_argument("--no-separate", action="store_true", help="joint section: skip the separate-stages rows")
    ap.add_argument("--json", action="store_true",
                    help="print one JSON document of the joint section's figures on stdout (tables on stderr)")
    ap.add_argument("--docs", action=argparse.BooleanOptionalAction, default=None,
                    help="also write docs/accuracy.png and docs/accuracy.txt (default: on for the full run)")
    args = ap.parse_args(argv)
    sections = {x.strip() for x in args.sections.split(",") if x.strip()}
    docs = (not args.quick and sections >= {"classic", "joint"}) if args.docs is None else args.docs
    real_stdout = sys.stdout
    tee = _Tee(sys.stderr if args.json else sys.stdout)
    sys.stdout = tee
    try:
        doc = _run(args, docs, tee, sections)
    finally:
        sys.stdout = tee.stream if not args.json else real_stdout
    if args.json:
        import json

        print(json.dumps(doc, default=str))


def _run(args, docs, tee, sections) -> dict:
    t_start = time.perf_counter()
    doc = {"benchmark": "accuracy", "sections": sorted(sections)}
    print(f"evpose accuracy benchmark - {platform.processor() or platform.machine()}, {os.cpu_count()} cpus; "
          f"scenes cached in {DATA}")
    path = None
    if "classic" in sections:
        path = _run_classic(args)
    if "joint" in sections:
        doc["joint"] = _run_joint(args)
    if path is not None:
        print(f"\nplot: {path}")
    print(f"total {time.perf_counter() - t_start:.0f} s (scene generation excluded when cached)")
    if docs and path is not None:
        import shutil

        DOCS.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, DOCS / "accuracy.png")
        (DOCS / "accuracy.txt").write_text(tee.buf.getvalue())
        print(f"docs: {DOCS / 'accuracy.png'}, {DOCS / 'accuracy.txt'}")
    doc["runtime_s"] = time.perf_counter() - t_start
    return doc


def _run_joint(args) -> dict:
    from accuracy_joint import bench_joint, joint_scene_jobs

    offs = published_offsets()
    pick = [offs[0], offs[len(offs) // 2], offs[-1], offs[len(offs) // 4], offs[3 * len(offs) // 4]]
    scenes = ensure_scenes(joint_scene_jobs(args.quick, pick, MODELS))
    ycb = None
    try:
        from synth_scenes import ensure_ycb_scene

        ycb = ensure_ycb_scene()
    except FileNotFoundError:
        print("  (the 5-object run-time scene needs the E-POSE meshes: skipped)")
    return bench_joint(scenes, table, ycb, separate=not args.no_separate)


def _run_classic(args):
    speeds = SPEEDS
    jobs, seeds = scene_jobs(args.quick)
    scenes = ensure_scenes(jobs)
    sync_results, sync_variants = bench_sync(scenes, speeds, seeds)
    bench_slow(scenes, [n for n in jobs if n.startswith(("slow_", "slowfull_"))])
    bench_uncertainty()
    edge_res = bench_sync_edges(scenes, [n for n in jobs if n.startswith(("sync_v", "slow_", "slowfull_", "skew20"))])
    for (label, g), v in edge_res.items():      # the 8 s groups join the error-against-run-time plot
        if g.startswith("8 s,") and label != "rate ML (default)":
            sync_results[(label, float(g.split(", ")[1].split()[0]))] = [(x[0], x[3]) for x in v]
    sync_variants = list(sync_variants) + [(label, None) for label, _ in EDGE_VARIANTS]
    skew_pts = bench_skew(3 if args.quick else 6, [scenes[n] for n in jobs if n.startswith("skew20")])
    bench_unreliable()
    ref_folders = [scenes[n] for n in jobs if n.startswith("refine_")]
    bench_score(ref_folders)
    windows = (6, 12, 24) if args.quick else (6, 12, 24, 48)
    refine_rows, refine_arr = bench_refine(ref_folders, windows)
    bench_offset_refine(ref_folders[:2])
    return plot(sync_results, sync_variants, speeds, skew_pts, refine_rows, refine_arr, windows)


if __name__ == "__main__":
    main()
