"""Export throughput (windows/s) of the three formats with 1 and 2 worker processes.

Run: ``.venv/bin/python bench/bench_export.py [--quick] [--durable batch|file|none] [--formats epose,bop,h5]``.

The scene is a synthetic 3-object DAVIS346 sequence (``evpose.core.sim.synth.generate``: box, cylinder, flatbox,
trajectory B at 0.5 m/s, 2 s, seed 1), generated once into ``bench/.data/synth_3obj_2s``. Every run
exports all 10 ms windows (``--quick``: the first 0.6 s, through a verified review mark) into a fresh
folder with the full product set of the format: E-POSE (event, mask_all + 3 object masks, segmented +
3 object segmentations, three-channel, bbox.txt, .mat = 13 files per window), BOP (rgb + 6 masks),
HDF5 (label map, counts, three-channel frames and all label arrays).

Printed: one row per format and job count: windows, wall time, windows/s, the ratio 2 jobs / 1 job,
the pool start-up time, and the per-window time split in ms (wall time summed over the windows, all processes):
``events`` (read), ``annotate`` (poses, keypoints, rasterisation: evpose.core.label.annotate / evpose.core.label.raster),
``images`` (frames, masks, PNG encoding), ``mat`` (.mat encoding), ``write`` (temp files, renames,
syncfs per chunk / HDF5 writes). ``excl.ann`` is the windows/s the export would reach per process if
annotation were free (1000 / sum of the other stages), i.e. the throughput of this module's own work.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from synth_scenes import SCENE, ensure_scene, run_dir  # bench/ is the script's folder


def run(fmt: str, jobs: int, quick: bool, durable, work) -> dict:
    from evpose.core.data.scene import Scene
    from evpose.core.document.corrections import ReviewMark
    from evpose.core.export import export_scene

    out = work / f"{fmt}_{jobs}_{time.perf_counter_ns()}"     # a new folder in this run's own folder
    scene = Scene.open(SCENE)
    scene.corrections.set(("offset_us",), 20_000)
    kw = {}
    if quick:
        t0 = scene.events.t_first_us
        scene.corrections.set(("reviews",), [ReviewMark(t0, t0 + 600_000, "verified")])
        kw["only_verified"] = True
    opts = {"three_channel": True} if fmt == "h5" else None
    import resource

    def cpu():
        a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime

    c0, t = cpu(), time.perf_counter()
    s = export_scene(scene, fmt, out, jobs=jobs, durable=durable, format_options=opts, **kw)
    wall = time.perf_counter() - t
    cpu_s = cpu() - c0
    scene.close()
    n = s.written + s.unlabeled * (fmt == "h5")
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    shutil.rmtree(out, ignore_errors=True)
    per = {k: v / max(n, 1) * 1e3 for k, v in s.timings_s.items()}
    own = sum(v for k, v in per.items() if k != "annotate")
    return {"fmt": fmt, "jobs": jobs, "n": n, "wall": wall, "rate": n / wall, "per": per, "startup": s.pool_startup_s,
            "cpu": cpu_s / wall,
            "excl": 1000.0 / own if own > 0 else float("inf"), "mb": size / 1e6}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="first 0.6 s only")
    ap.add_argument("--durable", default="batch", choices=("batch", "file", "none"))
    ap.add_argument("--formats", default="epose,bop,h5")
    ap.add_argument("--jobs", default="1,2")
    ap.add_argument("--repeat", type=int, default=1, help="runs per configuration; the fastest is shown")
    args = ap.parse_args(argv)
    ensure_scene()
    import numpy as np

    load = os.getloadavg()
    print(f"numpy {np.__version__}, {os.cpu_count()} cores, load average {load[0]:.1f} {load[1]:.1f}; "
          f"scene {SCENE.name} (DAVIS346, 3 objects, 0.5 m/s), 10 ms windows, durable={args.durable}")
    rows = []
    with run_dir("export_out") as work:       # every export goes into this run's own folder, removed at the end
        for fmt in args.formats.split(","):
            for jobs in (int(j) for j in args.jobs.split(",")):
                runs = [run(fmt, jobs, args.quick, args.durable, work) for _ in range(max(1, args.repeat))]
                rows.append(max(runs, key=lambda r: r["rate"]))
                r = rows[-1]
                print(f"  done {fmt} jobs={jobs}: {r['rate']:.1f} windows/s", file=sys.stderr)
    hdr = (f"{'format':<7}{'jobs':>5}{'windows':>9}{'wall s':>8}{'start s':>8}{'win/s':>8}{'2j/1j':>7}{'excl.st':>8}{'cpu%':>6}{'w/cpu-s':>8}{'MB':>7}"
           f"{'events':>8}{'annot':>8}{'images':>8}{'mat':>7}{'write':>7}{'excl.ann':>9}")
    print(hdr)
    print("-" * len(hdr))
    base = {}
    for r in rows:
        if r["jobs"] == 1:
            base[r["fmt"]] = r["rate"]
        ratio = r["rate"] / base[r["fmt"]] if r["jobs"] != 1 and r["fmt"] in base else 1.0
        ratio_st = (r["n"] / max(r["wall"] - r["startup"], 1e-9)) / base[r["fmt"]] if r["fmt"] in base else 1.0
        p = r["per"]
        print(f"{r['fmt']:<7}{r['jobs']:>5}{r['n']:>9}{r['wall']:>8.2f}{r['startup']:>8.2f}{r['rate']:>8.1f}{ratio:>7.2f}{ratio_st:>8.2f}{r['cpu'] * 100:>6.0f}{r['rate'] / r['cpu']:>8.1f}{r['mb']:>7.1f}"
              f"{p['events']:>8.2f}{p['annotate']:>8.2f}{p['images']:>8.2f}{p['mat']:>7.2f}{p['write']:>7.2f}"
              f"{r['excl']:>9.0f}")
    print("2j/1j = windows/s with 2 jobs / with 1 job; excl.st = the same without the pool start-up;\n"
          "cpu% = CPU time of all processes / wall time (200 % = both cores busy); w/cpu-s = windows per\n"
          "CPU-second (= windows/s per fully available core, pool start-up included);\n"
          "start s = process-pool start-up (spawn, imports, scene) included in wall; per-window columns in ms\n"
          "(summed over processes; with 2 jobs 'write' includes the parent's syncfs while workers run);\n"
          "excl.ann = windows/s per process without annotation")
    return 0


if __name__ == "__main__":
    sys.exit(main())
