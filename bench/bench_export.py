"""Export throughput (windows/s, one process) of the three formats on two scenes, against a baseline commit
measured in the same run.

Run: ``.venv/bin/python bench/bench_export.py [--quick] [--repeat N] [--json] [--formats epose,bop,h5]
[--scenes ycb,synth3] [--baseline REV | --no-baseline] [--durable batch|file|none] [--jobs 1] [--out-root DIR]``
(``--json``: the JSON document on stdout, the table on stderr).

Scenes (``bench/synth_scenes.py``, generated once into ``bench/.data``):

- ``ycb``: ``ycb_5obj_5s``, the realistic scene of issue 14: 5 objects with E-POSE's real YCB meshes,
  5 s, ~5 M events, 495 windows of 10 ms;
- ``synth3``: ``synth_3obj_2s``, 3 coarse built-in shapes (box, cylinder, flatbox), 2 s, 201 windows.

Every export writes all 10 ms windows (``--quick``: the first 0.6 s, through a verified review mark) of the
full product set of its format into a fresh folder of this run: E-POSE (event, mask_all + one mask per
object, segmented + one per object, three-channel, bbox.txt, .mat: 13 files per window with 3 objects, 17
with 5), BOP (rgb + 2 masks per object), HDF5 (label map, counts, three-channel frames, all label arrays).
The run's folder is made under ``--out-root`` (default: the system temp folder). Before the exports the
filesystem's own cost per new file is measured there and in ``bench/.data`` and printed: on the development
VM, ``/work`` (where the checkout lives) takes 0.7-0.9 ms to create a file against 0.04-0.06 ms in ``/tmp`` on
the same disk, which alone would cost a 5-object BOP window (11 files) ~10 ms and an E-POSE window (17 files)
~15 ms, whatever the code does.

Baseline: the code of ``--baseline`` (default ``8c676cd``, "before issue 14 export work") checked out with
``git worktree`` into this run's folder and imported in a child process through a ``PYTHONPATH`` folder
whose ``evpose`` links to it; the current tree runs in the same kind of child process, and the two are
interleaved (baseline, current, then current, baseline on the next repeat). Each child first exports one
window (imports, compiled kernels from numba's disk cache: not timed), then times one export of the scene
with ``jobs`` processes; scene opening, meshes, rasteriser set-up and the aggregate files are part of the
timed export, as for a user. Printed per scene, format and code: windows, windows/s (median and range over
the repeats), windows per CPU-second of the child (less sensitive to other processes and to disk waits),
the per-window time split in ms (``events`` read, ``annotate`` = poses, keypoints, rasterisation,
``images`` = frames, masks, PNG encoding, ``mat`` = .mat encoding, ``write`` = temp files, renames, syncfs
per chunk / HDF5 writes), and current / baseline. The load average is printed with every figure: the
machine's cores may be shared.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from synth_scenes import DATA, SCENE, ensure_scene, ensure_ycb_scene, file_create_ms, run_dir  # bench/ is the script's folder

REPO = Path(__file__).resolve().parents[1]
BASELINE = "8c676cd"
#: The --formats name of BOP written as BOP-webdataset shards.
SHARDED = "bop-shards"
SCENES = {"ycb": "ycb_5obj_5s (5 real YCB meshes, 5 s)", "synth3": "synth_3obj_2s (3 coarse shapes, 2 s)"}
PYTHON = sys.executable


# ------------------------------------------------------------------------------------------- child
def child(args: dict) -> dict:
    """One timed export in this (child) process; returns its figures."""
    import evpose
    from evpose.core.data.scene import Scene
    from evpose.core.document.corrections import ReviewMark
    from evpose.core.export import export_scene

    fmt, out = args["fmt"], Path(args["out"])
    opts = {"three_channel": True} if fmt == "h5" else None
    if fmt == SHARDED:                       # BOP-webdataset shards (issue 27.4; only the current code has them)
        from evpose.core.export.bop_shards import DEFAULT_SHARD_WINDOWS

        fmt, opts = "bop", {"shard_windows": DEFAULT_SHARD_WINDOWS}

    def export(folder, span_us):
        scene = Scene.open(args["scene"])
        scene.corrections.set(("offset_us",), 20_000)
        kw = {}
        if span_us is not None:
            t0 = scene.events.t_first_us
            scene.corrections.set(("reviews",), [ReviewMark(t0, t0 + span_us, "verified")])
            kw["only_verified"] = True
        try:
            return export_scene(scene, fmt, folder, jobs=args["jobs"], durable=args["durable"],
                                format_options=opts, **kw)
        finally:
            scene.close()

    export(out / "warm", 10_000)                   # imports, kernels: not timed

    def cpu():
        a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime

    load0 = os.getloadavg()[0]
    c0, t = cpu(), time.perf_counter()
    s = export(out / "timed", 600_000 if args["quick"] else None)
    wall, cpu_s = time.perf_counter() - t, cpu() - c0
    n = s.written + s.unlabeled * (fmt == "h5")
    files = sum(len(fs) for _, _, fs in os.walk(out / "timed"))
    return {"evpose": str(Path(evpose.__file__).resolve().parent), "n": n, "wall_s": wall, "cpu_s": cpu_s,
            "files_per_window": files / max(n, 1),
            "rate": n / wall, "cpu_rate": n / max(cpu_s, 1e-9), "load": [load0, os.getloadavg()[0]],
            "stages_ms": {k: v / max(n, 1) * 1e3 for k, v in s.timings_s.items()}}


def run_child(code_path: Path | None, **args) -> dict:
    """Run :func:`child` in a fresh interpreter, importing evpose from ``code_path`` (a folder whose
    ``evpose`` entry is the code to measure; None: the installed tree)."""
    env = dict(os.environ)
    if code_path is not None:
        env["PYTHONPATH"] = str(code_path) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    p = subprocess.run([PYTHON, __file__, "--child", json.dumps(args)], env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"export child failed ({code_path or 'current'}):\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------------------------- baseline code
def add_baseline(work: Path, rev: str) -> tuple[Path, str]:
    """Check out ``rev`` with ``git worktree`` under ``work``; returns the PYTHONPATH folder whose
    ``evpose`` links to it, and the commit's one-line description."""
    tree = work / "baseline_tree"
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-q", str(tree), rev], check=True)
    path = work / "baseline_path"
    path.mkdir()
    (path / "evpose").symlink_to(tree)
    desc = subprocess.run(["git", "-C", str(REPO), "log", "-1", "--format=%h %s", rev], capture_output=True,
                          text=True, check=True).stdout.strip()
    return path, desc


def remove_baseline(work: Path) -> None:
    tree = work / "baseline_tree"
    if tree.exists():
        subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)], check=False)


# ------------------------------------------------------------------------------------------- report
def summarise(runs: list[dict]) -> dict:
    rates = [r["rate"] for r in runs]
    return {"n": runs[0]["n"], "rate_median": statistics.median(rates), "rate_min": min(rates),
            "rate_max": max(rates), "cpu_rate_median": statistics.median(r["cpu_rate"] for r in runs),
            "load": [round(v, 2) for r in runs for v in r["load"]],
            "stages_ms": {k: statistics.median(r["stages_ms"][k] for r in runs) for k in runs[0]["stages_ms"]},
            "files_per_window": runs[0].get("files_per_window"),
            "runs": len(runs)}


def print_table(results: dict, baseline_desc: str | None, file=None) -> None:
    hdr = (f"{'scene':<8}{'format':<11}{'code':<9}{'windows':>8}{'win/s':>8}{'range':>13}{'w/cpu-s':>9}"
           f"{'ratio':>7}{'events':>8}{'annot':>8}{'images':>8}{'mat':>7}{'write':>7}  load")
    print(hdr, file=file)
    print("-" * len(hdr), file=file)
    for scene, per_fmt in results.items():
        for fmt, codes in per_fmt.items():
            for code in ("current", "baseline"):
                r = codes.get(code)
                if r is None:
                    continue
                ratio = (f"{codes['ratio']:>7.2f}" if code == "current" and "ratio" in codes else f"{'':>7}")
                p = r["stages_ms"]
                print(f"{scene:<8}{fmt:<11}{code:<9}{r['n']:>8}{r['rate_median']:>8.1f}"
                      f"{r['rate_min']:>6.1f}-{r['rate_max']:<6.1f}{r['cpu_rate_median']:>9.1f}{ratio}"
                      f"{p['events']:>8.2f}{p['annotate']:>8.2f}{p['images']:>8.2f}{p['mat']:>7.2f}{p['write']:>7.2f}"
                      f"  {'/'.join(f'{v:.1f}' for v in r['load'])}", file=file)
    for scene, per_fmt in results.items():
        print(f"{scene}: files in the export folder per window: "
              + ", ".join(f"{fmt} {c['current']['files_per_window']:.2f}" for fmt, c in per_fmt.items()
                          if c["current"].get("files_per_window") is not None), file=file)
    print(f"baseline = {baseline_desc}" if baseline_desc else "no baseline measured", file=file)
    from evpose.core.export.bop_shards import DEFAULT_SHARD_WINDOWS

    print(f"{SHARDED}: BOP with --bop-shards {DEFAULT_SHARD_WINDOWS}; its ratio is against plain BOP of the current "
          "code in this run", file=file)
    print("win/s = median over the repeats (range: min-max); w/cpu-s = windows per CPU-second of the export's\n"
          "process(es); ratio = current / baseline (medians; bop-shards: / bop); per-window stage columns in ms\n"
          "(medians); load = 1-minute load average at the start/end of each timed export", file=file)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="first 0.6 s of each scene only")
    ap.add_argument("--repeat", type=int, default=1, help="timed exports per scene, format and code")
    ap.add_argument("--formats", default="epose,bop,h5", help=f"comma list of: epose, bop, h5, {SHARDED}")
    ap.add_argument("--scenes", default="ycb,synth3", help="comma list of: " + ", ".join(SCENES))
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--durable", default="batch", choices=("batch", "file", "none"))
    ap.add_argument("--baseline", default=BASELINE, help="git revision measured against (default %(default)s)")
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--out-root", type=Path, default=Path(tempfile.gettempdir()),
                    help="folder under which this run's exports are written (default: the system temp folder, "
                    "%(default)s)")
    ap.add_argument("--json", action="store_true", help="print one JSON document of the headline figures")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return 0
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    bad = [s for s in scenes if s not in SCENES]
    if bad:
        ap.error(f"--scenes: unknown {bad}; choose from {list(SCENES)}")
    paths = {"ycb": lambda: ensure_ycb_scene(), "synth3": lambda: ensure_scene()}
    scene_dirs = {s: paths[s]() for s in scenes}
    formats = [f.strip() for f in args.formats.split(",") if f.strip()]
    log = sys.stderr
    load = os.getloadavg()
    print(f"{os.cpu_count()} cores, load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}; 10 ms windows, "
          f"jobs={args.jobs}, durable={args.durable}, repeat={args.repeat}{', quick' if args.quick else ''}",
          file=log)
    create_ms = {"out_root": file_create_ms(args.out_root), "bench_data": file_create_ms(DATA)}
    print(f"file creation (create + 3 kB write + rename, median): {create_ms['out_root']:.3f} ms in "
          f"{args.out_root} (the exports), {create_ms['bench_data']:.3f} ms in {DATA}", file=log)
    raw: dict = {}
    baseline_desc = None
    with run_dir("evpose_bench_export", args.out_root) as work:   # every export and the baseline checkout
        try:
            codes = [("current", None)]
            if not args.no_baseline:
                base_path, baseline_desc = add_baseline(work, args.baseline)
                codes.append(("baseline", base_path))
            k = 0
            for rep in range(max(1, args.repeat)):
                order = codes if rep % 2 else codes[::-1]          # interleaved: baseline first, then current...
                for scene in scenes:
                    for fmt in formats:
                        for code, path in order:
                            if fmt == SHARDED and code == "baseline":
                                continue             # the baseline has no shards: compared with BOP in this run
                            k += 1
                            r = run_child(path, scene=str(scene_dirs[scene]), fmt=fmt, jobs=args.jobs,
                                          durable=args.durable, quick=args.quick, out=str(work / f"run{k}"))
                            raw.setdefault(scene, {}).setdefault(fmt, {}).setdefault(code, []).append(r)
                            print(f"  {scene} {fmt} {code}: {r['n']} windows, {r['rate']:.1f} windows/s, "
                                  f"{r['cpu_rate']:.1f} per CPU-s, {r['files_per_window']:.2f} files/window, "
                                  f"load {r['load'][0]:.1f}/{r['load'][1]:.1f} "
                                  f"({r['evpose']})", file=log)
                            subprocess.run(["rm", "-rf", str(work / f"run{k}")], check=False)
        finally:
            remove_baseline(work)
    results = {}
    for scene, per_fmt in raw.items():
        for fmt, per_code in per_fmt.items():
            entry = {code: summarise(runs) for code, runs in per_code.items()}
            if "baseline" in entry:
                entry["ratio"] = entry["current"]["rate_median"] / entry["baseline"]["rate_median"]
                entry["cpu_ratio"] = entry["current"]["cpu_rate_median"] / entry["baseline"]["cpu_rate_median"]
            results.setdefault(scene, {})[fmt] = entry
        if SHARDED in results.get(scene, {}) and "bop" in results[scene]:
            sh, bop = results[scene][SHARDED], results[scene]["bop"]["current"]
            sh["ratio"] = sh["current"]["rate_median"] / bop["rate_median"]        # against BOP, same code and run
            sh["cpu_ratio"] = sh["current"]["cpu_rate_median"] / bop["cpu_rate_median"]
    if args.json:
        doc = {"benchmark": "export", "unit": "windows/s", "jobs": args.jobs, "durable": args.durable,
               "quick": args.quick, "repeat": args.repeat, "cores": os.cpu_count(),
               "load_average_end": [round(v, 2) for v in os.getloadavg()],
               "baseline": baseline_desc, "scenes": {s: SCENES[s] for s in scenes},
               "out_root": str(args.out_root), "file_create_ms": {k: round(v, 3) for k, v in create_ms.items()},
               "results": results}
        print_table(results, baseline_desc, file=sys.stderr)      # the table for people, the JSON on stdout
        print(json.dumps(doc, indent=1))
    else:
        print_table(results, baseline_desc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
