"""Dataset export on Dask (issue 13): per-task cost, scheduler overhead, throughput with 1 and 2 workers,
time to the first result, memory per worker, and a projection onto the E-POSE dataset.

Run: ``./run bench dataset`` or ``.venv/bin/python bench/bench_dataset.py [--duration 1.5]
[--formats bop,epose] [--workers 1,2] [--malloc-compare] [--scale-workers 16,64] [--json PATH]`` (about 5 minutes on
2 cores, and about 6-8 more for the scale part: ``--scale-workers ''`` leaves it out).

Everything issue 27 asks for in one run: per-worker efficiency (``vs base``) and the 2/1 ratio, tasks per scene and
their CPU, the drivers' CPU per scene and per window, memory per worker, then (:mod:`bench_cluster_scale`, same run)
the filesystem's file-creation, fsync and syncfs rates, an export on a real ``dask scheduler``, 16 and 64 worker
processes whose tasks sleep for the measured task durations, and the E-POSE projection with each limit costed.

The dataset (:func:`synth_scenes.ensure_ycb_dataset`, generated once into ``bench/.data/dataset_ycb``) is
3 synthetic DAVIS346 scenes with the real YCB meshes of E-POSE (3, 4 and 5 objects; trajectory B at
0.5 m/s), ``--duration`` seconds of events each, exported in 10 ms windows with the default durability
(one ``syncfs`` per chunk). Measured in one run:

- **baseline**: :func:`evpose.core.export.export_scene` with ``jobs=1`` in this process, scene after scene;
- **dask N**: :func:`evpose.core.dataset.export.export_dataset` on a fresh ``LocalCluster`` of N worker
  processes (:func:`evpose.core.dataset.cluster.open_client`), one cluster per format and N. From Dask's
  task stream: each chunk's compute time on its worker (the per-task cost), the first chunk's end (time
  to the first result, counted from before the cluster start), the median gap between two chunks on a
  worker, and the worker-seconds the export left idle (N x wall - the sum of the chunk times: scheduler,
  drivers, start-up and tail, per task). Memory: each worker's RSS sampled with psutil (pids from
  ``client.run``) every 0.1 s during the export, and its kernel peak (ru_maxrss). This process's CPU
  (scene drivers, client, and the LocalCluster's scheduler and nannies) during the export, idle after
  it, and per scene in an export that selects no window;
- **no-op tasks** on the largest cluster of the first format: ``client.submit(lambda: None)`` one at a time (round trip) and
  :data:`NOOP_BATCH` at once (the tasks/s the scheduler and client take), with this process's CPU per
  task (the LocalCluster's scheduler runs in this process);
- ``--malloc-compare``: the first format again on clusters whose workers get Dask's default
  ``MALLOC_TRIM_THRESHOLD_=65536`` (it makes glibc return every large numpy temporary to the kernel:
  many more page faults per window), which evpose's own clusters leave out.

Then the projection onto E-POSE (306 sequences, 333 k windows, 1.5 G events) on one 16-core machine and on
four, from those figures; the assumptions and limits are printed with it.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import shutil
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from synth_scenes import ensure_ycb_dataset, new_folder, run_dir, tree_size  # bench/ is the script's folder

#: No-op tasks submitted at once to measure the scheduler's rate; one at a time for the round trip.
NOOP_BATCH = 1000
NOOP_SEQUENTIAL = 200
#: Seconds this process's CPU is measured with the cluster idle (heartbeats, the sampler) after an export.
IDLE_S = 1.0
#: Seconds between two RSS samples of the workers.
RSS_PERIOD_S = 0.1
#: The environment variable Dask's nannies give every worker (``distributed.nanny.pre-spawn-environ``).
DASK_MALLOC_KEY = "MALLOC_TRIM_THRESHOLD_"
#: The E-POSE dataset (issue 13) and the machines of the projection.
EPOSE = {"sequences": 306, "windows": 333_000, "events": 1.5e9, "window_ms": 10}
CORES_PER_MACHINE = 16
MACHINES = 4


# ----------------------------------------------------------------------------------------------- measures
def central_cpu_s() -> float:
    """CPU seconds of this process (the client, the scene drivers, and a LocalCluster's scheduler and nannies)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def worker_probe() -> dict:
    """Run on a worker (``client.run``): its pid, RSS, kernel peak RSS and CPU seconds."""
    import resource as res

    import psutil

    p = psutil.Process()
    cpu, ru = p.cpu_times(), res.getrusage(res.RUSAGE_SELF)
    return {"pid": p.pid, "rss": p.memory_info().rss, "maxrss": ru.ru_maxrss * 1024, "cpu_s": cpu.user + cpu.system,
            "minflt": ru.ru_minflt}


class RssSampler:
    """Samples the RSS of the worker processes ``pids`` (worker address -> pid, from :func:`worker_probe`
    through ``client.run``) with psutil from a thread of this process until :meth:`stop` (reading
    ``/proc`` directly: the sampling sends nothing through Dask and costs the central process little)."""

    def __init__(self, pids: dict):
        import psutil

        self.procs = {addr: psutil.Process(pid) for addr, pid in pids.items()}
        self.peak, self.samples = {}, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self):
        while not self._stop.wait(RSS_PERIOD_S):
            self.sample()

    def sample(self):
        for addr, proc in self.procs.items():
            self.peak[addr] = max(self.peak.get(addr, 0), proc.memory_info().rss)
        self.samples += 1

    def stop(self) -> dict:
        self._stop.set()
        self._thread.join()
        self.sample()
        return self.peak


def noop_overhead(client) -> dict:
    """The scheduler's cost of a task: no-op round trips one at a time, and a batch submitted at once."""
    t = time.perf_counter()
    for _ in range(NOOP_SEQUENTIAL):
        client.submit(lambda: None, pure=False).result()
    round_trip_s = (time.perf_counter() - t) / NOOP_SEQUENTIAL
    c0, t = central_cpu_s(), time.perf_counter()
    futures = [client.submit(lambda: None, pure=False) for _ in range(NOOP_BATCH)]
    client.gather(futures)
    wall = time.perf_counter() - t
    cpu = central_cpu_s() - c0
    del futures
    return {"round_trip_ms": round_trip_s * 1e3, "batch_tasks_per_s": NOOP_BATCH / wall,
            "batch_ms_per_task": wall / NOOP_BATCH * 1e3, "central_cpu_ms_per_task": cpu / NOOP_BATCH * 1e3}


def scene_overhead(client, dataset, fmt: str, work: Path) -> dict:
    """This process's CPU and the wall time per scene of an export that selects no window (``only_verified``
    without review marks): the drivers' per-scene work (open the scene, fingerprint, tile the windows,
    interpolate, set up, write the aggregate files) without any task."""
    from evpose.core.dataset.export import export_dataset

    out = Path(tempfile.mkdtemp(prefix=f"zero_{fmt}-", dir=work))     # new, in this run's own folder
    c0, t = central_cpu_s(), time.perf_counter()
    result = export_dataset(client, dataset, fmt, out, only_verified=True)
    wall, cpu = time.perf_counter() - t, central_cpu_s() - c0
    shutil.rmtree(out, ignore_errors=True)
    if result.failed or any(s["written"] for s in result.scenes.values()):
        raise RuntimeError(f"the export of no window wrote windows or failed: {result.failed}")
    n = len(dataset.scenes)
    return {"scene_central_cpu_s": cpu / n, "scene_wall_s": wall / n}


def summaries_totals(summaries: list[dict]) -> dict:
    """Windows written and stage seconds summed over the scenes' export summaries."""
    stages: dict = {}
    for s in summaries:
        for k, v in s["timings_s"].items():
            stages[k] = stages.get(k, 0.0) + v
    return {"written": sum(s["written"] for s in summaries),
            "windows_total": sum(s["windows_total"] for s in summaries), "stages_s": stages}


# ----------------------------------------------------------------------------------------------- runs
#: The scene of the steady-state figures: one 501-window sequence, long enough that its chunks are the 4 s ones.
STEADY_SCENE = {"n_objects": 5, "duration_s": 5.0}


def steady_export(fmt: str, work: Path, tag: str, executor=None) -> float:
    """Windows/s of one export of the 5-object 5 s YCB scene (:data:`STEADY_SCENE`) in this process or through
    ``executor``, after a warm-up export of the same scene in 200 ms windows (so the workers have imported,
    loaded numba's kernels and measured the cost per window: the steady state of a long dataset export)."""
    from evpose.core.data.scene import Scene
    from evpose.core.export import export_scene
    from synth_scenes import ensure_ycb_scene

    path = ensure_ycb_scene(**STEADY_SCENE)
    warm, out = new_folder(work, f"steady_warm_{tag}"), new_folder(work, f"steady_{tag}")   # created here, empty
    export_scene(Scene.open(path), fmt, warm, executor=executor, window_us=200_000)
    t = time.perf_counter()
    s = export_scene(Scene.open(path), fmt, out, executor=executor)
    wps = s.written / (time.perf_counter() - t)
    for folder in (warm, out):         # removed as soon as measured (E-POSE: ~280 MB): only these exports' files
        shutil.rmtree(folder, ignore_errors=True)
    return wps


def run_baseline(dataset, fmt: str, work: Path) -> dict:
    """``export_scene(..., jobs=1)`` in this process, scene after scene."""
    from evpose.core.export import export_scene

    out = work / f"baseline_{fmt}"           # a new folder in this run's own folder
    c0, t = central_cpu_s(), time.perf_counter()
    summaries = [export_scene(ref.path, fmt, out / ref.name, jobs=1).to_json(with_files=False)
                 for ref in dataset.scenes]
    wall = time.perf_counter() - t
    cpu = central_cpu_s() - c0
    size, files = tree_size(out)
    shutil.rmtree(out, ignore_errors=True)
    tot = summaries_totals(summaries)
    return {"format": fmt, "run": "export_scene jobs=1", "workers": 1, "wall_s": wall, "cpu_s": cpu,
            "bytes": size, "files": files, **tot, "steady_wps": steady_export(fmt, work, f"base_{fmt}")}


def chunk_figures(stream: list, t_nothing: float, t_export: float) -> dict:
    """Per-task figures of the export's chunks (``run_chunk`` tasks) from Dask's task stream."""
    chunks = []
    for rec in stream:
        if not str(rec["key"]).startswith("run_chunk"):
            continue
        for ss in rec["startstops"]:
            if ss["action"] == "compute":
                chunks.append((ss["start"], ss["stop"], rec["worker"]))
    chunks.sort()
    durations = [b - a for a, b, _ in chunks]
    first_per_worker, last_stop, gaps = {}, {}, []
    for a, b, w in chunks:
        first_per_worker.setdefault(w, b - a)
        if w in last_stop:
            gaps.append(a - last_stop[w])
        last_stop[w] = b
    med = statistics.median(durations) if durations else 0.0
    return {"tasks": len(chunks), "compute_s": sum(durations), "cold_chunks": sum(d > 3 * med for d in durations), "gap_median_s": statistics.median(gaps) if gaps else 0.0,
            "chunk_median_s": statistics.median(durations) if durations else 0.0,
            "chunk_max_s": max(durations, default=0.0),
            "first_chunk_per_worker_s": statistics.mean(first_per_worker.values()) if first_per_worker else 0.0,
            "first_result_s": min((b for _, b, _ in chunks), default=t_export) - t_nothing,
            "first_result_after_export_start_s": min((b for _, b, _ in chunks), default=t_export) - t_export}


@contextlib.contextmanager
def malloc_config(malloc: str):
    """``"glibc"``: the workers evpose starts (:func:`evpose.core.dataset.cluster.open_client` leaves out Dask's
    ``MALLOC_TRIM_THRESHOLD_``: glibc's dynamic mmap threshold); ``"dask"``: the same with Dask's default
    ``MALLOC_TRIM_THRESHOLD_=65536``, put into this process's environment while the cluster starts (the
    workers inherit it) and restored after."""
    if malloc == "glibc":
        yield
        return
    saved = os.environ.get(DASK_MALLOC_KEY)
    os.environ[DASK_MALLOC_KEY] = "65536"
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(DASK_MALLOC_KEY, None)
        else:
            os.environ[DASK_MALLOC_KEY] = saved


def run_cluster(dataset, fmt: str, n: int, work: Path, noop: bool, malloc: str = "glibc") -> dict:
    """``export_dataset`` on a fresh LocalCluster of ``n`` workers (and the no-op tasks when ``noop``)."""
    from distributed import get_task_stream

    from evpose.core.dataset.cluster import ClusterSpec, open_client
    from evpose.core.dataset.export import export_dataset

    out = work / f"dask{n}_{fmt}_{malloc}"   # a new folder in this run's own folder
    t_nothing, t0 = time.time(), time.perf_counter()
    with malloc_config(malloc), open_client(ClusterSpec(workers=n)) as client:
        client.wait_for_workers(n)
        start_s = time.perf_counter() - t0
        before = client.run(worker_probe)
        sampler = RssSampler({a: d["pid"] for a, d in before.items()})
        c0, t_export = central_cpu_s(), time.time()
        with get_task_stream(client) as ts:
            result = export_dataset(client, dataset, fmt, out)
        wall = time.time() - t_export
        cpu = central_cpu_s() - c0
        after = client.run(worker_probe)
        c1 = central_cpu_s()
        time.sleep(IDLE_S)
        idle_rate = (central_cpu_s() - c1) / IDLE_S
        peak = sampler.stop()
        per_scene = scene_overhead(client, dataset, fmt, work)
        overhead = noop_overhead(client) if noop else None
        from evpose.core.dataset.dask_windows import DaskWindows

        steady = steady_export(fmt, work, f"dask{n}_{fmt}_{malloc}", DaskWindows(client))
    if result.failed:
        raise RuntimeError(f"dataset export failed: {result.failed}")
    size, files = tree_size(out)
    shutil.rmtree(out, ignore_errors=True)
    tot = summaries_totals(list(result.scenes.values()))
    chunks = chunk_figures(ts.data, t_nothing, t_export)
    label = f"dask {n}, Dask's malloc trim" if malloc == "dask" else f"dask {n} worker{'s' * (n > 1)}"
    return {"format": fmt, "run": label, "workers": n, "malloc": malloc, "wall_s": wall, "steady_wps": steady,
            "cpu_s": cpu, "idle_cpu_rate": idle_rate, "bytes": size, "files": files, "cluster_start_s": start_s, **tot, **chunks,
            "idle_worker_s": max(0.0, n * wall - chunks["compute_s"]),
            "worker_cpu_s": sum(after[a]["cpu_s"] - before[a]["cpu_s"] for a in after if a in before),
            "worker_page_faults": sum(after[a]["minflt"] - before[a]["minflt"] for a in after if a in before),
            "peak_rss_sampled_mb": {a: v / 1e6 for a, v in peak.items()},
            "peak_rss_kernel_mb": {a: d["maxrss"] / 1e6 for a, d in after.items()},
            "rss_samples": sampler.samples, "noop": overhead, **per_scene}


# ----------------------------------------------------------------------------------------------- projection
def project(run: dict, noop: dict, facts: dict, workers: int) -> dict:
    """E-POSE on ``workers`` single-threaded workers, from the figures of one measured ``run``.

    Three terms, the longest bounds the run (``limit``):

    - workers: the first result's latency, then every window costs the measured chunk compute time per
      window and every task the measured median gap between two chunks on a worker, shared by
      ``workers``, plus one chunk for the tail;
    - drivers (this process, serial under the GIL): the measured CPU per scene (an export of no window)
      and per window (the export's CPU without the scenes' and the tasks' share and the idle CPU rate); on
      one machine (LocalCluster) the scheduler shares the process, so its CPU per task (no-ops) is added;
      the process's idle CPU rate (heartbeats) takes its share of the time;
    - scheduler: the tasks at the measured no-op rate.
    """
    from bench_cluster_scale import planner_tasks     # the ChunkPlanner's sizes, fed as DaskWindows feeds it

    w_total, scenes = EPOSE["windows"], EPOSE["sequences"]
    per_seq = round(w_total / scenes)
    n = run["written"]
    c_wall, c_cpu = run["compute_s"] / n, run["worker_cpu_s"] / n
    tasks = scenes * len(planner_tasks(per_seq, workers, c_cpu))
    sched_cpu = noop["central_cpu_ms_per_task"] / 1e3
    n_scenes = len(facts["scenes"])
    idle = run["idle_cpu_rate"]
    drv_window = max(0.0, (run["cpu_s"] - idle * run["wall_s"] - n_scenes * run["scene_central_cpu_s"]
                           - run["tasks"] * sched_cpu) / n)
    t_drivers = scenes * run["scene_central_cpu_s"] + w_total * drv_window
    if workers <= CORES_PER_MACHINE:
        t_drivers += tasks * sched_cpu
    t_drivers /= max(1.0 - idle, 0.05)

    def t_workers(c):
        return run["first_result_s"] + (w_total * c + tasks * run["gap_median_s"]) / workers + w_total / tasks * c

    terms = {"workers": t_workers(c_wall), "drivers": t_drivers, "scheduler": tasks / noop["batch_tasks_per_s"]}
    limit = max(terms, key=terms.get)
    total = terms[limit]
    total_cpu = max(t_workers(c_cpu), t_drivers, terms["scheduler"])
    ev_scale = (EPOSE["events"] / w_total) / facts["events_per_window"]
    read_ms = run["stages_s"].get("events", 0.0) / n * 1e3
    return {"workers": workers, "tasks": tasks, "windows_per_task": w_total / tasks, "hours": total / 3600,
            "hours_cpu_bound": total_cpu / 3600, "limit": limit, "terms_h": {k: v / 3600 for k, v in terms.items()},
            "windows_per_s": w_total / total, "driver_ms_per_window": drv_window * 1e3,
            "write_mb_per_s": w_total * run["bytes"] / n / total / 1e6,
            "files_per_s": w_total * run["files"] / n / total,
            "syncfs_per_s": tasks / total,
            "event_read_mb_per_s": w_total * facts["event_bytes_per_event"] * facts["events_per_window"] * ev_scale
            / total / 1e6,
            "event_read_share": read_ms / (c_wall * 1e3), "scheduler_tasks_per_s": tasks / total}


# ----------------------------------------------------------------------------------------------- output
def dataset_facts(dataset) -> dict:
    from evpose.core.data.scene import Scene

    scenes, events, dur, nbytes = [], 0, 0.0, 0
    for ref in dataset.scenes:
        s = Scene.open(ref.path)
        try:
            n_ev, d = len(s.events), (s.events.t_last_us - s.events.t_first_us) / 1e6
            scenes.append({"name": ref.name, "objects": len(s.object_names), "events": n_ev, "duration_s": d})
            events, dur = events + n_ev, dur + d
            nbytes += Path(s.events.path).stat().st_size
        finally:
            s.close()
    windows = dur / (EPOSE["window_ms"] / 1e3)
    return {"root": str(dataset.root), "scenes": scenes, "events": events, "duration_s": dur,
            "events_per_window": events / windows, "event_bytes_per_event": nbytes / events}


def print_runs(runs: list[dict]) -> None:
    hdr = (f"{'format':<7}{'run':<21}{'windows':>8}{'start s':>8}{'first s':>8}{'wall s':>8}{'win/s':>7}"
           f"{'vs base':>8}{'2/1':>6}{'cpu%':>6}{'RSS MB/worker':>15}{'kB/win':>8}{'files/win':>10}")
    print(hdr)
    print("-" * len(hdr))
    base, one = {}, {}
    for r in runs:
        rate = r["written"] / r["wall_s"]
        cpu = (r["cpu_s"] + r.get("worker_cpu_s", 0.0)) / r["wall_s"] * 100
        if r["run"].startswith("export_scene"):
            base[r["format"]] = rate
        key = (r["format"], r.get("malloc"))
        if r["workers"] == 1 and "malloc" in r:
            one[key] = rate
        ratio = f"{rate / one[key]:.2f}" if r["workers"] > 1 and key in one else "-"
        rss = "-" if "peak_rss_kernel_mb" not in r else "/".join(
            f"{max(a, b):.0f}" for a, b in zip(r["peak_rss_sampled_mb"].values(), r["peak_rss_kernel_mb"].values()))
        start = f"{r['cluster_start_s']:.1f}" if "cluster_start_s" in r else "-"
        first = f"{r['first_result_s']:.1f}" if "first_result_s" in r else "-"
        print(f"{r['format']:<7}{r['run']:<21}{r['written']:>8}{start:>8}{first:>8}{r['wall_s']:>8.1f}{rate:>7.1f}"
              f"{rate / base[r['format']]:>8.2f}{ratio:>6}{cpu:>6.0f}{rss:>15}{r['bytes'] / r['written'] / 1e3:>8.0f}"
              f"{r['files'] / r['written']:>10.1f}")


def print_steady(runs: list[dict]) -> None:
    """Steady state: the 501-window scene exported by warm workers (issue 27.1's per-worker efficiency and 2/1)."""
    rows = [r for r in runs if r.get("steady_wps") and r.get("malloc", "glibc") == "glibc"]
    if not rows:
        return
    print("\nSteady state: ycb_5obj_5s (5 objects, 501 windows of 10 ms) after a warm-up export of it (workers imported,"
          " numba loaded,\ncost per window known), win/s; eff = win/s / (workers x export_scene's in this process)")
    for fmt in dict.fromkeys(r["format"] for r in rows):
        base = next((r for r in rows if r["format"] == fmt and r["run"].startswith("export_scene")), None)
        if base is None:
            continue
        line = f"  {fmt:<6} export_scene {base['steady_wps']:.1f}"
        by_n = {r["workers"]: r["steady_wps"] for r in rows if r["format"] == fmt and r is not base}
        for n, w in sorted(by_n.items()):
            line += f"; {n} worker{'s' * (n > 1)} {w:.1f} (eff {w / (n * base['steady_wps']):.2f})"
        if 1 in by_n and 2 in by_n:
            line += f"; 2/1 = {by_n[2] / by_n[1]:.2f}"
        print(line)
    print()


def print_cpu_note(runs: list[dict], cores: int) -> None:
    """How much CPU the runs with several workers got: on a shared machine it bounds the N/1 ratio."""
    for r in runs:
        if r["workers"] > 1:
            used = (r["cpu_s"] + r["worker_cpu_s"]) / r["wall_s"]
            wait = 1.0 - r["worker_cpu_s"] / max(r["compute_s"], 1e-9)
            print(f"  {r['format']} {r['run']}: this process and the workers used {used:.2f} of {cores} cores on average;"
                  f" the workers' chunks spent {wait * 100:.0f} % of their time off a CPU (waiting for one, or for I/O)")
    print()


def print_tasks(runs: list[dict]) -> None:
    hdr = (f"{'format':<7}{'run':<21}{'tasks':>6}{'win/task':>9}{'s/chunk':>8}{'1st':>6}{'cold':>5}{'gap ms':>7}{'ms/win':>7}"
           f"{'cpu ms/win':>11}{'idle s/task':>12}{'wall-Σ/N':>9}{'central ms/win':>15}{'s/scene':>8}"
           f"{'events':>7}{'annot':>7}{'images':>7}{'mat':>6}{'write':>6}")
    print(hdr)
    print("-" * len(hdr))
    for r in runs:
        n, st = r["written"], {k: v / r["written"] * 1e3 for k, v in r["stages_s"].items()}
        stages = "".join(f"{st.get(k, 0.0):>{w}.1f}" for k, w in
                         (("events", 7), ("annotate", 7), ("images", 7), ("mat", 6), ("write", 6)))
        if "tasks" not in r:
            print(f"{r['format']:<7}{r['run']:<21}{'-':>6}{'-':>9}{'-':>8}{'-':>6}{'-':>5}{'-':>7}{r['wall_s'] / n * 1e3:>7.1f}"
                  f"{r['cpu_s'] / n * 1e3:>11.1f}{'-':>12}{'-':>9}{'-':>15}{'-':>8}{stages}")
            continue
        print(f"{r['format']:<7}{r['run']:<21}{r['tasks']:>6}{n / r['tasks']:>9.1f}{r['chunk_median_s']:>8.2f}"
              f"{r['first_chunk_per_worker_s']:>6.2f}{r['cold_chunks']:>5}{r['gap_median_s'] * 1e3:>7.1f}{r['compute_s'] / n * 1e3:>7.1f}"
              f"{r['worker_cpu_s'] / n * 1e3:>11.1f}{r['idle_worker_s'] / r['tasks']:>12.3f}"
              f"{r['wall_s'] - r['compute_s'] / r['workers']:>9.2f}{r['cpu_s'] / n * 1e3:>15.1f}"
              f"{r['scene_central_cpu_s']:>8.2f}{stages}")


def print_noop(runs: list[dict]) -> None:
    for r in runs:
        o = r.get("noop")
        if o:
            print(f"  {r['run']}: round trip {o['round_trip_ms']:.2f} ms per task one at a time; "
                  f"{NOOP_BATCH} at once: {o['batch_tasks_per_s']:.0f} tasks/s ({o['batch_ms_per_task']:.2f} ms per task), "
                  f"scheduler+client CPU {o['central_cpu_ms_per_task']:.2f} ms per task")


def print_malloc(runs: list[dict]) -> None:
    """The runs with Dask's worker environment against those without its ``MALLOC_TRIM_THRESHOLD_``."""
    pairs = [(r, g) for r in runs if r.get("malloc") == "dask" for g in runs
             if g.get("malloc") == "glibc" and (g["format"], g["workers"]) == (r["format"], r["workers"])]
    if not pairs:
        return
    print(f"\nDask's {DASK_MALLOC_KEY}=65536 in the workers (distributed.nanny.pre-spawn-environ) against glibc's"
          " default (what evpose's workers run since this figure):")
    for r, g in pairs:
        rate_r, rate_g = r["written"] / r["wall_s"], g["written"] / g["wall_s"]
        print(f"  {r['format']} {r['workers']} worker(s): {rate_r:.1f} vs {rate_g:.1f} windows/s ({rate_g / rate_r:.2f}x), "
              f"annotate {r['stages_s'].get('annotate', 0) / r['written'] * 1e3:.0f} vs "
              f"{g['stages_s'].get('annotate', 0) / g['written'] * 1e3:.0f} ms/window, page faults per window "
              f"{r['worker_page_faults'] / r['written']:.0f} vs {g['worker_page_faults'] / g['written']:.0f}")


def print_projection(rows: list, run: dict, facts: dict) -> None:
    """The projection table (``rows``: (target, source run, :func:`project` figures)) and the notes, whose
    figures are those of ``run`` (the first rows)."""
    hdr = (f"{'target':<22}{'from run':<27}{'workers':>8}{'tasks':>8}{'win/task':>9}{'hours':>7}{'h (cpu)':>8}"
           f"{'win/s':>7}{'limit':>17}{'write MB/s':>11}{'files/s':>8}{'syncfs/s':>9}{'read MB/s':>10}{'tasks/s':>8}")
    print(hdr)
    print("-" * len(hdr))
    for name, source, p in rows:
        print(f"{name:<22}{source:<27}{p['workers']:>8}{p['tasks']:>8}{p['windows_per_task']:>9.1f}{p['hours']:>7.2f}"
              f"{p['hours_cpu_bound']:>8.2f}{p['windows_per_s']:>7.0f}{p['limit']:>17}{p['write_mb_per_s']:>11.1f}"
              f"{p['files_per_s']:>8.0f}{p['syncfs_per_s']:>9.0f}{p['event_read_mb_per_s']:>10.1f}"
              f"{p['scheduler_tasks_per_s']:>8.0f}")
    print_notes(rows[1][2], rows[2][2], run, facts)


def print_notes(p16: dict, p64: dict, run: dict, facts: dict) -> None:
    """The assumptions of the projection and what would limit it (figures of ``run``)."""
    n, noop = run["written"], run["noop"]
    print(f"""
Assumptions (figures of the '{run['run']}' {run['format']} run above):
- one single-threaded worker per core, doing a window in the measured {run['compute_s'] / n * 1e3:.0f} ms of chunk time
  ({run['worker_cpu_s'] / n * 1e3:.0f} ms of CPU: 'h (cpu)' assumes a core of its own, which this loaded machine did not give),
  {run['gap_median_s'] * 1e3:.0f} ms between two chunks on a worker (median), the first result after {run['first_result_s']:.1f} s, one chunk of tail;
- the scene drivers (one process, serial under the GIL): {run['scene_central_cpu_s']:.2f} s CPU per scene (measured: an
  export that selects no window) and {p16['driver_ms_per_window']:.1f} ms per window (the rest of the process's CPU during the
  export: journal, flush, futures); {run['idle_cpu_rate'] * 100:.1f} % of a core idle (heartbeats, nannies; {IDLE_S:g} s after the export);
- the scheduler: {noop['central_cpu_ms_per_task']:.2f} ms CPU per task and {noop['batch_tasks_per_s']:.0f} tasks/s (no-ops); in the drivers' process on
  one machine, its own process (--scheduler) on four;
- {EPOSE['sequences']} sequences of ~{EPOSE['windows'] // EPOSE['sequences']} windows, cut into chunks as the export does (ChunkPlanner: 2 probes
  of 4 windows per worker, then 4 s of CPU each, at most 512 windows); the per-window cost of these 3-5-object YCB scenes;
  no queueing for nodes (SLURM), no failures. 'limit' names the longest of the three terms.

What would limit it:
- CPU (workers): {p16['terms_h']['workers']:.2f} h on 16 cores, {p64['terms_h']['workers']:.2f} h on 4 x 16; annotation (rasterising the
  meshes) and image encoding are most of a window (stage columns above).
- The drivers' process: {p16['terms_h']['drivers']:.2f} h on one machine (with the scheduler's CPU), {p64['terms_h']['drivers']:.2f} h with
  64 workers: one Python process feeds every worker, so it caps the dataset at about
  {EPOSE['windows'] / max(p64['terms_h']['drivers'] * 3600, 1e-9):.0f} windows/s whatever the number of workers.
- The scheduler: {p64['tasks']} tasks on 64 workers, {p64['scheduler_tasks_per_s']:.0f} tasks/s at the projected speed:
  {p64['scheduler_tasks_per_s'] / noop['batch_tasks_per_s'] * 100:.0f} % of the {noop['batch_tasks_per_s']:.0f} no-op tasks/s measured here (one at a time: {noop['round_trip_ms']:.1f} ms round
  trip); on 16 cores {p16['scheduler_tasks_per_s'] / noop['batch_tasks_per_s'] * 100:.0f} %.
- HDF5 reads: the event read is {p16['event_read_share'] * 100:.0f} % of a window's chunk time here ({run['stages_s'].get('events', 0.0) / n * 1e3:.1f} ms per
  window at {facts['events_per_window'] / 1e3:.1f} k events; E-POSE averages {EPOSE['events'] / EPOSE['windows'] / 1e3:.1f} k): {p64['event_read_mb_per_s']:.1f} MB/s of events
  from the shared filesystem on 64 workers ({facts['event_bytes_per_event']:.1f} bytes per event on disk): not a limit.
- The shared filesystem's writes: {run['bytes'] / n / 1e3:.0f} kB and {run['files'] / n:.1f} files per window, so on 64 workers
  {p64['write_mb_per_s']:.0f} MB/s, {p64['files_per_s']:.0f} file creations/s and {p64['syncfs_per_s']:.0f} syncfs/s (one per chunk): the file
  creation rate and syncfs, not the bandwidth, are what a network filesystem feels first.""")


# ----------------------------------------------------------------------------------------------- main
def measure(args) -> dict:
    from evpose.core.dataset.dataset import Dataset

    root = ensure_ycb_dataset(args.duration)
    dataset = Dataset.open(root)
    facts = dataset_facts(dataset)
    formats = args.formats.split(",")
    workers = [int(w) for w in args.workers.split(",")]
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    runs = []
    with run_dir("dataset_out") as work:      # every export goes into this run's own folder, removed at the end
        for fmt in formats:
            runs.append(run_baseline(dataset, fmt, work))
            print(f"  done {fmt} baseline: {runs[-1]['written'] / runs[-1]['wall_s']:.1f} windows/s", file=sys.stderr)
            mallocs = ("glibc", "dask") if fmt == formats[0] and args.malloc_compare else ("glibc",)
            for n in workers:          # alternated, so that the machine's load drifts alike over both
                for malloc in mallocs:
                    noop = fmt == formats[0] and malloc == "glibc" and n == max(workers)
                    runs.append(run_cluster(dataset, fmt, n, work, noop=noop, malloc=malloc))
                    print(f"  done {fmt} {runs[-1]['run']}: {runs[-1]['written'] / runs[-1]['wall_s']:.1f} "
                          "windows/s", file=sys.stderr)
    out = {"facts": facts, "runs": runs, "load_before": load0, "load_after": os.getloadavg(),
           "bench_s": time.perf_counter() - t0, "cores": os.cpu_count()}
    if args.scale_workers:         # the same run: a real scheduler at 16 and 64 workers, the filesystem, the projection
        import bench_cluster_scale

        out["cluster_scale"] = bench_cluster_scale.measure(argparse.Namespace(
            workers=args.scale_workers, durations=args.scale_durations, measure_s=args.scale_measure_s,
            copies=args.scale_copies, cpu_per_window_ms=None))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=1.5, help="seconds of events per scene (default 1.5)")
    ap.add_argument("--formats", default="bop,epose")
    ap.add_argument("--workers", default="1,2", help="LocalCluster sizes (default 1,2)")
    ap.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    ap.add_argument("--malloc-compare", action="store_true",
                    help=f"also run the first format without Dask's {DASK_MALLOC_KEY} in the workers (adds ~1 min)")
    ap.add_argument("--scale-workers", default="16,64",
                    help="also measure a real scheduler with this many worker processes whose tasks sleep, the "
                         "filesystem and a real-scheduler export (bench_cluster_scale.py; about 6-8 minutes; '' skips it)")
    ap.add_argument("--scale-durations", default="4,probe", help="their task durations, s (bench_cluster_scale.py)")
    ap.add_argument("--scale-measure-s", type=float, default=30.0, help="steady seconds of each scale run")
    ap.add_argument("--scale-copies", type=int, default=3, help="scenes of the real-scheduler export")
    ap.add_argument("--print-json", type=Path, metavar="PATH",
                    help="measure nothing: print the report of the figures an earlier --json wrote")
    args = ap.parse_args(argv)
    m = json.loads(args.print_json.read_text()) if args.print_json else measure(args)
    rows = report(m)
    if args.json:
        doc = {k: v for k, v in m.items() if k != "projection"}
        doc["projection"] = [{"target": t, "from": src, **p} for t, src, p in rows]
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


def report(m: dict) -> list:
    """Print the tables and notes of the measured figures ``m``; returns the projection rows."""
    facts, runs = m["facts"], m["runs"]
    lb, la = m["load_before"], m["load_after"]
    objs = ", ".join(f"{s['name']} {s['objects']}" for s in facts["scenes"])
    print(f"{m['cores']} cores, load average {lb[0]:.1f} {lb[1]:.1f} {lb[2]:.1f} before, {la[0]:.1f} {la[1]:.1f} {la[2]:.1f} after "
          f"(shared machine); bench {m['bench_s']:.0f} s")
    print(f"dataset: 3 scenes with the real YCB meshes ({objs} objects), {facts['duration_s']:.1f} s, "
          f"{facts['events'] / 1e6:.1f} M events, {facts['events_per_window'] / 1e3:.1f} k events per 10 ms window; "
          f"durable=batch (syncfs per chunk)\n")
    print("Export throughput (baseline: export_scene jobs=1 in this process, scene after scene)")
    print_runs(runs)
    print("start s = cluster start (LocalCluster + workers up); first s = from nothing (before the cluster start)"
          " to the first chunk's\nfiles written; vs base = win/s / baseline; 2/1 = 2 workers / 1 worker; cpu% = CPU of"
          " this process + the workers / wall;\nRSS = peak per worker, max of psutil samples and the kernel's"
          " ru_maxrss, one figure per worker")
    print_cpu_note(runs, m["cores"])
    print_steady(runs)
    print("Per task (a chunk of windows on a worker; Dask task stream) and the stage split per window (ms, summary timings_s)")
    print_tasks(runs)
    print("s/chunk = median compute time of a chunk; 1st = mean first chunk per worker, s (opens the scene, meshes);\n"
          "cold = chunks longer than 3 x the median (a worker setting up a scene); gap = median time between two chunks\n"
          "on a worker; ms/win = chunk compute time per window (cpu: the workers' CPU); idle s/task = (N x wall - sum of\n"
          "chunk times) / tasks; wall-Σ/N = export wall - chunk time / N, s; central = this process's CPU per window\n"
          "(scene drivers, journal, client, the LocalCluster's scheduler and nannies); s/scene = this process's CPU per\n"
          "scene of an export that selects no window\n")
    print("Scheduler overhead per task (no-op tasks, client.submit(lambda: None))")
    print_noop(runs)
    print_malloc(runs)
    top = max(r["workers"] for r in runs)
    ref = next(r for r in runs if r.get("noop") and r["workers"] == top)
    sources = [ref] + [r for r in runs if r["workers"] == top and r is not ref and r.get("malloc")]
    targets = [("this machine", 2), ("1 machine x 16 cores", CORES_PER_MACHINE),
               (f"{MACHINES} machines x 16 cores", CORES_PER_MACHINE * MACHINES)]
    rows = [(name, f"{r['format']} {r['run']}", project(r, ref["noop"], facts, w)) for r in sources for name, w in targets]
    bases = ", ".join(f"{r['format']} {r['written'] / r['wall_s']:.1f} windows/s = "
                      f"{EPOSE['windows'] / (r['written'] / r['wall_s']) / 3600:.1f} h" for r in runs if "malloc" not in r)
    print(f"\nProjection from the LocalCluster figures: E-POSE ({EPOSE['sequences']} sequences, {EPOSE['windows'] // 1000} k "
          f"windows of 10 ms, {EPOSE['events'] / 1e9:.1f} G events); the single-scene baseline here: {bases}")
    print_projection(rows, ref, facts)
    if m.get("cluster_scale"):
        import bench_cluster_scale

        print("\n" + "=" * 100 + "\nAt scale (bench_cluster_scale.py, same run): the filesystem, an export on a real scheduler,"
              " 16 and 64 worker processes\nwhose tasks sleep, and the projection with each limit costed (this one"
              " supersedes the LocalCluster projection above)\n")
        rows = rows + [("scale", "", p) for p in bench_cluster_scale.report(m["cluster_scale"])]
    return rows


if __name__ == "__main__":
    sys.exit(main())
