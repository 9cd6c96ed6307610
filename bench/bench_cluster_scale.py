"""The dataset engine at E-POSE scale (issue 27.3): a real ``dask scheduler`` and 16 / 64 worker processes on this
machine running tasks that sleep for the export's task duration, the driver's cost per window in a real export, the
filesystem's file creations, fsync and syncfs, and from these the projection of an E-POSE export (306 sequences,
333 k windows, 1.5 G events) onto one 16-core machine and four, with every limit costed.

Run: ``./run bench cluster_scale`` or ``.venv/bin/python bench/bench_cluster_scale.py [--workers 16,64]
[--durations 4,0.5,probe] [--measure-s 45] [--copies 3] [--json PATH]`` (about 10 minutes on 2 loaded cores).
``--print-json PATH`` prints the report of the figures an earlier ``--json`` wrote, measuring nothing.

Measured in one run, in this order:

1. **filesystem**, three times (at the start, after the real export, at the end: this VM's disk varies by the
   minute; the median is used): creations per second (a 4 kB file written under a temporary name, closed and
   renamed, as the export's atomic writes do) by one writer and by 2 writer processes at once, ``fsync`` per second
   (the same with an fsync before the rename) and ``syncfs`` (Linux) with 0, 68 and 680 freshly written files
   dirty (68: a probe chunk of 4 E-POSE windows) on tmpfs (``/dev/shm``) and on this VM's disk (``bench/.data``);
   a loopback NFS mount is tried only when the kernel offers ``nfs`` and ``mount.nfs`` exists (no server is
   installed).
2. **the driver in a real export**: :func:`evpose.core.dataset.export.export_dataset` of ``--copies`` links to
   the 5-object real-mesh scene (:func:`synth_scenes.ensure_ycb_scene`, 501 windows of 10 ms each) to E-POSE on a
   real ``dask scheduler`` with 2 ``dask worker`` processes (so this process is the driver and the client only),
   after a warm-up export (it pays what a process pays once: the meshes, shared by a dataset's sequences), in
   50 ms and in 10 ms windows, and once selecting no window: this process's CPU per window (the slope between the two
   exports: journal, records, flushes, pose interpolation, the chunks' arguments) and per scene (the rest), its
   client event loop's per chunk; the workers' measured CPU per window (the chunks' ``worker_cpu``), files and
   bytes per window, the chunk sizes the planner chose and the pickled size of a chunk's arguments.
3. **scheduler and client at 16 and 64 workers**: a real ``dask scheduler`` (127.0.0.1, a random port) and
   separate ``dask worker --nthreads 1 --no-nanny`` processes (16, then 48 more for 64). The tasks are submitted by
   the export's own ``DaskWindows.run`` (2 chunks per worker in flight, one more as each completes) from 3 driver
   threads (``SCENE_DRIVERS``), with ``run_chunk`` replaced in this process by :func:`sleep_chunk`: it sleeps
   ``d`` seconds (no CPU) and returns the records of its windows; each chunk carries arguments of the real export's
   pickled sizes and ``d / (CPU per window)`` windows. ``d`` = 4 s (the planner's ``TARGET_TASK_CPU_S``), 0.5 s,
   and a probe chunk (``PROBE_WINDOWS`` x the CPU per window). Over a steady interval: tasks/s completed, the CPU
   seconds per task of the scheduler process (``/proc/<pid>/stat``), of this process (client + driver threads)
   and of the workers (also net of their CPU with nothing to do), the end-to-end overhead per task
   ``(N x wall - sum of the sleeps in the interval) / tasks`` and the workers' idle share, the 1-minute load
   average and the processes' RSS.

On 2 cores, 64 processes contend with each other and with other jobs: the wall-clock rates here are those of this
machine; the CPU seconds per task of the scheduler and the client are what transfer to a machine where each has a
core of its own, and the projection uses them (it prints the rate as measured here beside it).
"""
from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from synth_scenes import DATA, ensure_ycb_scene, new_folder, run_dir, tree_size  # bench/ is the script's folder

REPO = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
#: The E-POSE dataset (issue 13) and the machines of the projection.
EPOSE = {"sequences": 306, "windows": 333_000, "events": 1.5e9, "window_ms": 10}
CORES_PER_MACHINE = 16
#: (name, machines, goal in seconds) of the projection's targets (issue 27).
TARGETS = (("1 x 16 cores", 1, 300.0), ("4 x 16 cores", 4, 120.0))
#: Tasks in flight per worker and per driver (evpose.core.dataset.dask_windows.DaskWindows.run).
IN_FLIGHT_PER_WORKER = 2
#: Size of the files of the filesystem probe (small files: an E-POSE window's masks are a few kB, its .mat more).
FILE_BYTES = 4096
#: Seconds each measure of the filesystem probe may take at most.
FS_BUDGET_S = 3.0
#: Writer processes of the parallel creation measure (one per core here).
PARALLEL_WRITERS = 2
#: Fallback CPU seconds per window when the real export is skipped (README: 45-51 windows/s per core).
DEFAULT_CPU_PER_WINDOW_S = 0.020
#: E-POSE files per 5-object window (events, mask all, 5 masks, segmented, 3-channel, ... ; bbox, mat) when the
#: real export is skipped.
DEFAULT_FILES_PER_WINDOW = 17


# ----------------------------------------------------------------------------------------------- helpers
def proc_cpu_s(pid: int) -> float:
    """utime + stime of process ``pid`` from ``/proc/<pid>/stat``, seconds."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def proc_rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def thread_cpu_s(tid: int) -> float | None:
    """CPU seconds of thread ``tid`` of this process (None when it has ended)."""
    try:
        with open(f"/proc/self/task/{tid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def self_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def mount_of(path: Path) -> tuple[str, str, str]:
    """(mount point, filesystem type, device) holding ``path`` (longest prefix in /proc/mounts)."""
    path = str(Path(path).resolve())
    best = ("/", "?", "?")
    with open("/proc/mounts") as f:
        for line in f:
            dev, mnt, kind = line.split()[:3]
            if (path == mnt or path.startswith(mnt.rstrip("/") + "/")) and len(mnt) >= len(best[0]):
                best = (mnt, kind, dev)
    return best


class Processes:
    """Subprocesses this run started, each in its own session (process group); :meth:`stop_all` ends them
    (SIGTERM, then SIGKILL after a grace period), only those, whatever happened."""

    def __init__(self, logdir: Path):
        self.logdir = logdir
        self.procs: list[subprocess.Popen] = []

    def start(self, args: list, name: str, extra_env: dict | None = None) -> subprocess.Popen:
        log = open(self.logdir / f"{name}.log", "wb")
        # bench/ on the path: the workers unpickle sleep_chunk and SleepSpec by reference from this module
        path = os.pathsep.join(x for x in (str(REPO / "bench"), os.environ.get("PYTHONPATH")) if x)
        env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=path, **(extra_env or {}))
        p = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, cwd=REPO,
                             env=env, start_new_session=True)
        log.close()
        self.procs.append(p)
        return p

    def stop(self, procs: list, grace_s: float = 10.0) -> None:
        for p in procs:
            if p.poll() is None:
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(p.pid, signal.SIGTERM)
        deadline = time.monotonic() + grace_s
        for p in procs:
            try:
                p.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        for p in procs:
            if p in self.procs:
                self.procs.remove(p)

    def stop_all(self) -> None:
        self.stop(list(reversed(self.procs)))    # workers first, the scheduler last


class Cluster:
    """A real ``dask scheduler`` (127.0.0.1, a random port, no reachable dashboard) and ``dask worker`` processes
    (one thread each, no nanny, 127.0.0.1, no dashboard), all stopped on exit."""

    def __init__(self, workdir: Path, tag: str, lean: bool = False):
        self.workdir = workdir
        self.tag = tag
        self.lean = lean          # workers without their own periodic work (LEAN_WORKER_ENV, no memory monitor)
        self.procs = Processes(workdir)
        self.scheduler = None
        self.workers: list[subprocess.Popen] = []
        self.address = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.procs.stop_all()

    def start_scheduler(self) -> str:
        sfile = self.workdir / f"{self.tag}-scheduler.json"
        self.scheduler = self.procs.start(
            [str(VENV_BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0",
             "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(sfile)], f"{self.tag}-scheduler")
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if self.scheduler.poll() is not None:
                raise RuntimeError(f"dask scheduler ended: {self.log_tail(f'{self.tag}-scheduler')}")
            with contextlib.suppress(OSError, ValueError):
                self.address = json.loads(sfile.read_text())["address"]
                return self.address
            time.sleep(0.2)
        raise RuntimeError("dask scheduler did not start within 120 s")

    def add_workers(self, n: int) -> None:
        for _ in range(n):
            k = len(self.workers)
            lean = ["--memory-limit", "0"] if self.lean else []
            self.workers.append(self.procs.start(
                [str(VENV_BIN / "dask"), "worker", self.address, "--host", "127.0.0.1", "--no-dashboard",
                 "--nthreads", "1", "--no-nanny", "--name", f"{self.tag}-{k}", *lean], f"{self.tag}-worker-{k}",
                LEAN_WORKER_ENV if self.lean else None))

    def wait_for_workers(self, client, n: int, timeout: float = 600) -> float:
        t = time.perf_counter()
        deadline = time.monotonic() + timeout
        while len(client.nthreads()) < n:
            dead = [p for p in self.workers if p.poll() is not None]
            if dead:
                raise RuntimeError(f"{len(dead)} dask worker(s) ended: {self.log_tail(f'{self.tag}-worker-0')}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"only {len(client.nthreads())} of {n} workers joined")
            time.sleep(0.5)
        return time.perf_counter() - t

    def log_tail(self, name: str) -> str:
        with contextlib.suppress(OSError):
            return (self.workdir / f"{name}.log").read_text(errors="replace")[-1500:]
        return ""

    def worker_pids(self) -> list[int]:
        return [p.pid for p in self.workers if p.poll() is None]


# ----------------------------------------------------------------------------------------------- 1. filesystem
def _write(path: Path, data: bytes, fsync: bool) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    try:
        os.write(fd, data)
        if fsync:
            os.fsync(fd)
    finally:
        os.close(fd)


def _syncfs(path: Path) -> None:
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    fd = os.open(path, os.O_RDONLY)
    try:
        if libc.syncfs(fd) != 0:
            raise OSError(ctypes.get_errno(), "syncfs failed")
    finally:
        os.close(fd)


def _creates_child(folder: str, t_start: float, budget_s: float) -> int:
    """One of the parallel writers of :func:`fs_measure`: creates files in ``folder`` from ``t_start`` (wall clock)
    for ``budget_s`` seconds; returns how many."""
    folder = Path(folder)
    folder.mkdir()
    data = os.urandom(FILE_BYTES)
    time.sleep(max(0.0, t_start - time.time()))
    n, end = 0, t_start + budget_s
    while time.time() < end:
        tmp = folder / f".{n}.tmp"
        _write(tmp, data, False)
        os.replace(tmp, folder / f"{n}.bin")
        n += 1
    return n


def fs_measure(root: Path) -> dict:
    """Creations/s, fsync/s and syncfs times in a new folder under ``root`` (removed after)."""
    mnt, kind, dev = mount_of(root)
    data = os.urandom(FILE_BYTES)
    out = {"root": str(root), "mount": mnt, "type": kind, "device": dev}
    with run_dir("fs_probe", root) as d:
        _syncfs(d)                                   # start with nothing of ours dirty

        def creates(sub: str, fsync: bool, limit: int) -> float:
            folder = d / sub
            folder.mkdir()
            n, t0 = 0, time.perf_counter()
            while n < limit and time.perf_counter() - t0 < FS_BUDGET_S:
                tmp = folder / f".{n}.tmp"
                _write(tmp, data, fsync)
                os.replace(tmp, folder / f"{n}.bin")
                n += 1
            return n / (time.perf_counter() - t0)

        out["creates_per_s"] = creates("create", False, 20000)
        _syncfs(d)
        import multiprocessing

        with multiprocessing.get_context("spawn").Pool(PARALLEL_WRITERS) as pool:   # each its own folder
            t_start = time.time() + 2.0                                                # after the children start
            counts = pool.starmap(_creates_child, [(str(d / f"par{k}"), t_start, FS_BUDGET_S)
                                                   for k in range(PARALLEL_WRITERS)])
        out["creates_per_s_parallel"] = sum(counts) / FS_BUDGET_S
        _syncfs(d)
        out["fsync_per_s"] = creates("fsync", True, 2000)
        sync = {}
        for n_files in (0, 68, 680):
            times, rep, t_all = [], 0, time.perf_counter()
            while rep < 20 and (rep < 3 or time.perf_counter() - t_all < FS_BUDGET_S):
                folder = d / f"sync{n_files}_{rep}"
                folder.mkdir()
                for i in range(n_files):
                    _write(folder / f"{i}.bin", data, False)
                t = time.perf_counter()
                _syncfs(d)
                times.append(time.perf_counter() - t)
                rep += 1
            sync[n_files] = statistics.median(times)
        out["syncfs_s"] = {str(k): v for k, v in sync.items()}
        # syncfs time ~ a + b x dirty files (least squares over the three medians)
        xs, ys = list(sync), list(sync.values())
        mx, my = statistics.mean(xs), statistics.mean(ys)
        b = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)
        out["syncfs_fixed_s"] = max(sync[0], 0.0)
        out["syncfs_per_file_s"] = max(b, 0.0)
        out["syncfs_per_s"] = 1.0 / max(sync[0], 1e-9)
    return out


def nfs_status() -> dict:
    """Whether a loopback NFS mount could be tried here without installing anything, and why not."""
    with open("/proc/filesystems") as f:
        kernel = any(line.split()[-1] in ("nfs", "nfs4") for line in f if line.strip())
    helper = shutil.which("mount.nfs") or shutil.which("mount.nfs4")
    server = [s for s in ("exportfs", "rpc.nfsd", "ganesha.nfsd", "unfsd") if shutil.which(s)]
    reasons = []
    if not kernel:
        reasons.append("the kernel offers no nfs/nfs4 filesystem (/proc/filesystems; no /lib/modules to load it from)")
    if not helper:
        reasons.append("no mount.nfs helper")
    if not server:
        reasons.append("no NFS server (exportfs, rpc.nfsd, ganesha.nfsd or unfsd) to export a folder over the loopback")
    return {"possible": not reasons, "measured": False,
            "why_not": "; ".join(reasons) if reasons else "possible but not attempted by this bench"}


# ----------------------------------------------------------------------------------------------- 2. real export
class ThreadCpu:
    """CPU seconds of this process's threads between :meth:`start` and :meth:`stop`: those alive at both
    (main thread, the client's event loop, ...) by name; the rest (threads that came and went: the scene drivers)
    as the process's total minus those."""

    def start(self):
        self.names = {t.native_id: t.name for t in threading.enumerate()}
        self.cpu0 = {tid: thread_cpu_s(tid) for tid in self.names}
        self.total0 = self_cpu_s()
        return self

    def stop(self) -> dict:
        total = self_cpu_s() - self.total0
        persistent = {}
        for tid, c0 in self.cpu0.items():
            c1 = thread_cpu_s(tid)
            if c0 is not None and c1 is not None:
                persistent[self.names[tid]] = persistent.get(self.names[tid], 0.0) + c1 - c0
        return {"total_s": total, "persistent_s": persistent, "transient_s": max(0.0, total - sum(persistent.values()))}


#: The sleeping workers' own periodic work, which a real node's worker pays on its own core (measured with the
#: defaults on the real export's workers: the projection's idle share), made rare so that 64 of them fit on 2
#: cores: the event loop's 20 ms tick, the 10 ms statistical profiler, the 0.5 s system monitor (and, by
#: ``--memory-limit 0``, the 0.1 s memory monitor). Nothing of the scheduler's work per task or per heartbeat.
LEAN_WORKER_ENV = {"DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL": "1s", "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False",
                   "DASK_DISTRIBUTED__ADMIN__SYSTEM_MONITOR__INTERVAL": "5s"}
#: A worker's idle CPU share with Dask's defaults when the real export is skipped (measured: 3-4 % of a core).
DEFAULT_WORKER_IDLE_SHARE = 0.035
#: Pickled sizes (bytes) of the export's spec and of one window's task when the real export is skipped.
ARG_BYTES = {"spec": 4000, "window": 700}
#: Window length of the second real export (fewer windows, the same scenes): the driver's CPU per window is the
#: slope between the two exports, its CPU per scene the rest.
LONG_WINDOW_US = 50_000


def _capture_args(captured: dict):
    """A :class:`DaskWindows` that keeps the first scene's spec and the chunks it hands out (for their pickled
    sizes); it does nothing else differently."""
    from evpose.core.dataset.dask_windows import DaskWindows

    class Capturing(DaskWindows):
        def run(self, spec, planner, key):
            if "spec" not in captured:
                captured["spec"], captured["chunks"] = spec, []
                handed_out = planner.next

                def next_():
                    chunk = handed_out()
                    if chunk:
                        captured["chunks"].append(chunk)
                    return chunk
                planner.next = next_
            return super().run(spec, planner, key)
    return Capturing


def _one_export(client, cl: "Cluster", dataset, out: Path, captured: dict | None = None, **options) -> dict:
    import evpose.core.dataset.export as dataset_export

    load0 = os.getloadavg()
    saved = dataset_export.DaskWindows
    if captured is not None:
        dataset_export.DaskWindows = _capture_args(captured)
    tc, t = ThreadCpu().start(), time.perf_counter()
    w0, s0 = sum(proc_cpu_s(p) for p in cl.worker_pids()), proc_cpu_s(cl.scheduler.pid)
    try:
        result = dataset_export.export_dataset(client, dataset, "epose", out, **options)
    finally:
        dataset_export.DaskWindows = saved
    wall, cpu = time.perf_counter() - t, tc.stop()
    if result.failed:
        raise RuntimeError(f"the export failed: {result.failed}")
    scenes = list(result.scenes.values())
    timings: dict = {}
    for s in scenes:
        for k, v in s["timings_s"].items():
            timings[k] = timings.get(k, 0.0) + v
    return {"wall_s": wall, "cpu": cpu, "written": sum(s["written"] for s in scenes), "timings": timings,
            "chunks": [c for s in scenes for c in s.get("chunks", [])],
            "worker_cpu_s": sum(proc_cpu_s(p) for p in cl.worker_pids()) - w0,
            "scheduler_cpu_s": proc_cpu_s(cl.scheduler.pid) - s0, "load_before": load0, "load_after": os.getloadavg()}


def context_cost(spec, task) -> dict:
    """Run on a worker (``client.run``): the CPU seconds of setting up a scene's worker context (what a worker pays
    the first time it gets a chunk of a scene: the scene, its meshes, the rasteriser, the writer's state) and of
    annotating one window cold (just after) and warm (again)."""
    import time as _t

    from evpose.core.export.worker import WorkerContext

    c0 = _t.thread_time()
    wctx = WorkerContext(spec)
    c1 = _t.thread_time()
    w = task.window
    ev = wctx.scene.events.read(w.i0, w.i1)
    pose = (task.T_cam_obj, task.T_base_cam, True)
    a0 = _t.thread_time()
    wctx.annotator.annotate(w, ev, pose=pose)
    a1 = _t.thread_time()
    wctx.annotator.annotate(w, ev, pose=pose)
    a2 = _t.thread_time()
    wctx.scene.close()
    return {"context_s": c1 - c0, "cold_annotate_s": a1 - a0, "warm_annotate_s": a2 - a1}


def real_export(work: Path, copies: int, workers: int = 2) -> dict:
    """``export_dataset`` to E-POSE of ``copies`` links to the 5-object YCB scene on a real scheduler with
    ``workers`` worker processes, in 10 ms windows, again in :data:`LONG_WINDOW_US` windows, and once selecting
    no window; this process's CPU split into the scene drivers' threads and the rest."""
    from distributed import Client

    from evpose.core.dataset.dataset import Dataset

    scene = ensure_ycb_scene(5, 5.0)
    ds = work / "dataset"
    ds.mkdir()
    for k in range(copies):
        (ds / f"seq{k}").symlink_to(scene, target_is_directory=True)
    dataset = Dataset.open(ds)
    with Cluster(work, "export") as cl:
        addr = cl.start_scheduler()
        cl.add_workers(workers)
        with Client(addr, timeout="60s") as client:
            cl.wait_for_workers(client, workers)
            out = new_folder(work, "export_epose")           # removed below: only this export's files are in it
            captured: dict = {}
            # a warm-up export first (not measured): it pays what a process pays once (the meshes, shared by the
            # sequences of a dataset: core/data/model_cache), which the slope would otherwise charge to the windows
            _one_export(client, cl, dataset, work / "export_warm", window_us=4 * LONG_WINDOW_US)
            b = _one_export(client, cl, dataset, work / "export_long", window_us=LONG_WINDOW_US)
            a = _one_export(client, cl, dataset, out, captured)
            size, files = tree_size(out)
            shutil.rmtree(out, ignore_errors=True)
            z = _one_export(client, cl, dataset, work / "export_none", only_verified=True)   # no window
            if z["written"]:
                raise RuntimeError("the export of no window wrote windows")
            idle = idle_rates(cl)         # the workers with Dask's defaults, idle after the exports
            setup = []
            if "spec" in captured and captured.get("chunks"):
                import dataclasses

                probe_dir = work / "context_probe"          # the context's owned-files log goes here
                probe_dir.mkdir()
                spec = dataclasses.replace(captured["spec"], out_dir=str(probe_dir))
                for _ in range(2):
                    setup += list(client.run(context_cost, spec, captured["chunks"][0][0]).values())
    written, tasks = a["written"], len(a["chunks"])
    slope = max(0.0, (a["cpu"]["transient_s"] - b["cpu"]["transient_s"]) / max(written - b["written"], 1))
    per_scene = max(0.0, a["cpu"]["transient_s"] - slope * written) / copies     # the scene threads' rest
    loop = sum(v for k, v in a["cpu"]["persistent_s"].items() if k != "MainThread")
    from distributed.protocol.pickle import dumps

    chunks_seen = captured.get("chunks") or [[]]
    arg_bytes = {"spec": len(dumps(captured["spec"])) if "spec" in captured else ARG_BYTES["spec"],
                 "window": round(sum(len(dumps(c)) for c in chunks_seen) / max(sum(len(c) for c in chunks_seen), 1))}
    whole = max(0.0, (a["cpu"]["total_s"] - b["cpu"]["total_s"]) / max(written - b["written"], 1))
    return {"copies": copies, "workers": workers, "scene": str(scene), "written": written, "wall_s": a["wall_s"],
            "load_before": a["load_before"], "load_after": a["load_after"], "tasks": tasks, "chunk_sizes": a["chunks"],
            "worker_cpu_per_window_s": a["timings"].get("worker_cpu", 0.0) / written,
            "worker_process_cpu_per_window_s": a["worker_cpu_s"] / written,
            "stage_ms_per_window": {k: v / written * 1e3 for k, v in a["timings"].items()},
            "scheduler_cpu_per_task_s": a["scheduler_cpu_s"] / max(tasks, 1),
            "process_cpu_s": a["cpu"]["total_s"], "threads_cpu_s": a["cpu"]["persistent_s"],
            "transient_cpu_s": a["cpu"]["transient_s"],
            "long": {"window_us": LONG_WINDOW_US, "written": b["written"], "wall_s": b["wall_s"],
                     "transient_cpu_s": b["cpu"]["transient_s"], "cpu_s": b["cpu"]["total_s"], "tasks": len(b["chunks"])},
            "none": {"wall_s": z["wall_s"], "cpu_s": z["cpu"]["total_s"], "transient_cpu_s": z["cpu"]["transient_s"]},
            "scene_cpu_s": per_scene, "scene_cpu_no_window_s": z["cpu"]["total_s"] / copies,
            "driver_cpu_per_window_s": whole, "driver_threads_cpu_per_window_s": slope, "arg_bytes": arg_bytes,
            "client_loop_cpu_per_task_s": loop / max(tasks, 1),
            "process_cpu_per_window_s": a["cpu"]["total_s"] / written,
            "files_per_window": files / written, "bytes_per_window": size / written,
            "idle": idle, "worker_idle_share": idle["workers"] / workers, "context_setups": setup,
            "context_setup_cpu_s": statistics.median(x["context_s"] + max(0.0, x["cold_annotate_s"] - x["warm_annotate_s"])
                                                     for x in setup) if setup else 0.0}


# ----------------------------------------------------------------------------------------------- 3. sleeping tasks
class SleepSpec:
    """Stands in for the export's ``WorkerSpec`` in the sleeping tasks: its ``out_dir`` (the scene's name for
    :class:`DaskWindows`) and ``blob``, bytes of the size the real spec pickles to, so that every task carries as
    much as the export's. Workers unpickle it from this module (``bench/`` is on their path)."""

    def __init__(self, out_dir: str, blob: bytes):
        self.out_dir = out_dir
        self.blob = blob


def sleep_chunk(spec, key: str, tasks: list):
    """Stands in for :func:`evpose.core.dataset.dask_windows.run_chunk` (same arguments): sleeps the seconds the
    key names (``sleep|<seconds>|<driver>``) and returns what ``run_chunk`` returns for ``len(tasks)`` E-POSE
    windows (their records, no payload, their journal lines, the stage timings), with the worker-side start and end times."""
    import time as _t

    d = float(key.split("|")[1])
    t0 = _t.time()
    _t.sleep(d)
    t1 = _t.time()
    n_events = round(EPOSE["events"] / EPOSE["windows"])
    results = [({"i": i, "status": "written", "n_events": n_events}, None,
                f'{{"i":{i},"status":"written","n_events":{n_events}}}') for i in range(len(tasks))]
    return results, {"events": 0.0, "annotate": 0.0, "images": 0.0, "mat": 0.0, "write": 0.0, "worker_cpu": 0.0,
                     "t0": t0, "t1": t1}


class _SleepPlanner:
    """Chunks of ``n`` stand-in windows (bytes of a pickled ``WindowTask``'s size) until ``stop`` is set."""

    def __init__(self, n: int, window_bytes: int, stop: threading.Event):
        self.n, self.window_bytes, self.stop = n, window_bytes, stop

    def next(self):
        if self.stop.is_set():
            return None
        return [bytes(self.window_bytes) for _ in range(self.n)]

    #: what DaskWindows.run asks of a ChunkPlanner: a known cost (no probes, no prior), nothing measured
    cpu_per_window_s = 0.0
    measured = None

    def may_submit(self, in_flight: int) -> bool:
        return True

    def record(self, *args) -> None:
        pass


def sleep_run(client, cl: Cluster, n: int, d: float, n_windows: int, measure_s: float, idle: dict,
              arg_bytes: dict) -> dict:
    """Tasks sleeping ``d`` s on ``n`` workers for a warm-up then ``measure_s``, submitted by the export's own
    :meth:`DaskWindows.run` (its ``run_chunk`` replaced by :func:`sleep_chunk` in this process) from
    :data:`~evpose.core.dataset.export.SCENE_DRIVERS` threads, each with its chunks of ``n_windows`` stand-in windows; ``arg_bytes``: the pickled
    sizes of the real spec and of a window's task; ``idle``: the processes' CPU shares with nothing to do
    (:func:`idle_rates`), taken off for the ``net`` figures."""
    from evpose.core.dataset import dask_windows
    from evpose.core.dataset.cluster_events import ClusterEvents

    import bench_cluster_scale as me       # by reference: pickled by value from __main__

    class Windows(dask_windows.DaskWindows):
        def _evict(self, key):             # per scene, not per task; the stand-in workers hold no context
            pass

    warm_s = max(2 * d, 5.0)
    stop = threading.Event()
    done: list = []          # (client time done, worker t0, worker t1)
    errors: list = []
    lock = threading.Lock()
    drain_until = [math.inf]       # after the interval: keep taking completions until then, submit nothing
    executor = Windows(client, events=ClusterEvents(client))
    spec = me.SleepSpec("sleep", bytes(arg_bytes["spec"]))

    def driver(k: int):
        gen = executor.run(spec, _SleepPlanner(n_windows, arg_bytes["window"], stop), f"sleep|{d}|{k}")
        try:
            for _results, timings in gen:
                with lock:
                    done.append((time.time(), timings["t0"], timings["t1"]))
                if stop.is_set() and time.time() > drain_until[0]:
                    break          # every task running at the interval's end has come back
        except Exception as exc:                      # noqa: BLE001 -- reported by the run
            errors.append(repr(exc))
        finally:
            gen.close()            # cancels this driver's chunks still queued

    saved = dask_windows.run_chunk
    dask_windows.run_chunk = me.sleep_chunk
    try:
        return _sleep_measure(client, cl, n, d, n_windows, measure_s, idle, warm_s, stop, done, errors, drain_until,
                              driver)
    finally:
        dask_windows.run_chunk = saved


def _sleep_measure(client, cl, n, d, n_windows, measure_s, idle, warm_s, stop, done, errors, drain_until, driver):
    from evpose.core.dataset.export import SCENE_DRIVERS

    pids = cl.worker_pids()
    threads = [threading.Thread(target=driver, args=(k,), name=f"sleep-driver-{k}", daemon=True)
               for k in range(SCENE_DRIVERS)]
    t_start = time.time()
    for th in threads:
        th.start()
    time.sleep(warm_s)

    def sample():
        return {"t": time.time(), "sched": proc_cpu_s(cl.scheduler.pid), "self": self_cpu_s(),
                "workers": sum(proc_cpu_s(p) for p in pids)}

    a = sample()
    time.sleep(measure_s)
    b = sample()
    load = os.getloadavg()
    rss = [proc_rss_mb(p) for p in pids]
    sched_rss = proc_rss_mb(cl.scheduler.pid)
    drain_until[0] = b["t"] + d + 2.0
    stop.set()
    for th in threads:
        th.join(timeout=max(30.0, 3 * d))
    # wait until the scheduler has nothing left (the cancelled tasks forgotten) before the next run
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and any(client.processing().values()):
        time.sleep(0.2)
    if errors:
        raise RuntimeError(f"sleeping tasks failed: {errors[:3]}")
    T = b["t"] - a["t"]
    completed = sum(1 for c, _, _ in done if a["t"] <= c < b["t"])
    # the sleeps running at b are counted by their completions after b (the drivers take them until drain_until);
    # each task counts by the share of its sleep inside the interval (completions alone jump by whole waves of N
    # tasks when the tasks are long: +-1 wave in 11 for 4 s tasks in 45 s)
    overlaps = [(max(0.0, min(t1, b["t"]) - max(t0, a["t"])), t1 - t0) for _, t0, t1 in done]
    busy = sum(o for o, _ in overlaps)
    k = sum(o / max(dur, 1e-9) for o, dur in overlaps)
    return {"workers": n, "task_s": d, "windows_per_task": n_windows, "warm_s": warm_s, "interval_s": T,
            "tasks": k, "completed": completed, "tasks_per_s": k / T, "ideal_tasks_per_s": n / d,
            "scheduler_cpu_per_task_s": (b["sched"] - a["sched"]) / max(k, 1),
            "scheduler_cpu_share": (b["sched"] - a["sched"]) / T,
            "scheduler_net_cpu_per_task_s": max(0.0, b["sched"] - a["sched"] - idle["scheduler"] * T) / max(k, 1),
            "client_cpu_per_task_s": (b["self"] - a["self"]) / max(k, 1),
            "client_cpu_share": (b["self"] - a["self"]) / T,
            "client_net_cpu_per_task_s": max(0.0, b["self"] - a["self"] - idle["client"] * T) / max(k, 1),
            "workers_cpu_per_task_s": (b["workers"] - a["workers"]) / max(k, 1),
            "workers_cpu_share": (b["workers"] - a["workers"]) / T,
            "workers_net_cpu_per_task_s": max(0.0, b["workers"] - a["workers"] - idle["workers"] * T) / max(k, 1),
            "overhead_per_task_s": max(0.0, n * T - busy) / max(k, 1),
            "idle_share": max(0.0, 1.0 - busy / (n * T)),
            "load1": load[0], "worker_rss_mb_median": statistics.median(rss), "worker_rss_mb_max": max(rss),
            "scheduler_rss_mb": sched_rss, "started": t_start}


def idle_rates(cl: Cluster, seconds: float = 5.0) -> dict:
    """CPU shares of the scheduler, this process and the workers with nothing to do (heartbeats)."""
    pids = cl.worker_pids()
    s0, c0, w0, t0 = proc_cpu_s(cl.scheduler.pid), self_cpu_s(), sum(proc_cpu_s(p) for p in pids), time.time()
    time.sleep(seconds)
    T = time.time() - t0
    return {"scheduler": (proc_cpu_s(cl.scheduler.pid) - s0) / T, "client": (self_cpu_s() - c0) / T,
            "workers": (sum(proc_cpu_s(p) for p in pids) - w0) / T, "load1": os.getloadavg()[0]}


def scale_runs(work: Path, counts: list[int], durations: list[float], cpu_per_window: float, measure_s: float,
               arg_bytes: dict) -> dict:
    from distributed import Client

    rows, starts, idle = [], {}, {}
    with Cluster(work, "sleep", lean=True) as cl:
        addr = cl.start_scheduler()
        with Client(addr, timeout="60s") as client:
            for n in sorted(counts):
                t = time.perf_counter()
                cl.add_workers(n - len(cl.workers))
                cl.wait_for_workers(client, n)
                starts[n] = time.perf_counter() - t
                idle[n] = idle_rates(cl)
                for d in durations:
                    w = max(1, min(512, round(d / cpu_per_window)))
                    short = max(measure_s * 2 / 3, min(30.0, measure_s))
                    rows.append(sleep_run(client, cl, n, d, w, measure_s if d >= 2 else short, idle[n], arg_bytes))
                    r = rows[-1]
                    print(f"  sleep {n} workers, {d:g} s tasks: {r['tasks_per_s']:.1f} tasks/s (ideal {r['ideal_tasks_per_s']:.1f}), "
                          f"load {r['load1']:.1f}", file=sys.stderr)
    return {"rows": rows, "worker_start_s": starts, "idle": idle}


# ----------------------------------------------------------------------------------------------- 4. projection
def planner_tasks(windows: int, workers: int, cpu_per_window_s: float, probes: bool = True) -> list[int]:
    """The chunk sizes :class:`evpose.core.export.chunks.ChunkPlanner` hands out for one sequence of ``windows``
    windows on ``workers`` workers, fed as :meth:`DaskWindows.run` feeds it (2 chunks per worker in flight once the
    cost is known, at most ``PROBE_CHUNKS`` probes before; one more as each completes, the completed chunk's CPU
    recorded first), every window costing ``cpu_per_window_s``. ``probes=False``: the cost known from the start
    (carried over from an earlier sequence, as ``DaskWindows.prior`` does)."""
    from evpose.core.export.chunks import ChunkPlanner

    planner = ChunkPlanner(list(range(windows)), prior=None if probes else (cpu_per_window_s, 0.0))
    flight: list[int] = []

    def fill() -> None:
        while len(flight) < IN_FLIGHT_PER_WORKER * workers and planner.may_submit(len(flight)):
            c = planner.next()
            if c is None:
                return
            flight.append(len(c))

    fill()
    while flight:
        k = flight.pop(0)
        planner.record(k, k * cpu_per_window_s)
        fill()
    return list(planner.sizes)


def epose_tasks(workers: int, cpu_per_window_s: float, probes: bool = True) -> dict:
    """Tasks of the E-POSE export on ``workers`` workers: the sequences' windows spread evenly (333 k / 306); with
    ``probes`` the first sequences (one per scene driver) probe, the others start from their measured cost."""
    from evpose.core.dataset.export import SCENE_DRIVERS
    from evpose.core.export.chunks import PROBE_WINDOWS

    q, r = divmod(EPOSE["windows"], EPOSE["sequences"])
    sizes = {k: planner_tasks(k, workers, cpu_per_window_s, False) for k in (q, q + 1)}
    first = planner_tasks(q, workers, cpu_per_window_s, probes)
    n_first = SCENE_DRIVERS if probes else 0
    all_sizes = first * n_first + sizes[q] * (EPOSE["sequences"] - r - n_first) + sizes[q + 1] * r
    probes = [s for s in first if s <= PROBE_WINDOWS] * n_first if probes else []
    # every worker that gets a chunk of a sequence sets its context up once (at least: more when it dropped it)
    contexts = (EPOSE["sequences"] - r) * min(workers, len(sizes[q])) + r * min(workers, len(sizes[q + 1]))
    return {"tasks": len(all_sizes), "probe_tasks": len(probes), "probe_windows": sum(probes), "contexts": contexts,
            "full_tasks": len(all_sizes) - len(probes), "sizes_per_sequence": sizes[q],
            "max_size": max(all_sizes)}


def _rows_at(rows: list, d: float) -> list[dict]:
    """For each worker count, its measured row whose task duration is nearest ``d``."""
    out = []
    for n in sorted({r["workers"] for r in rows}):
        out.append(min((r for r in rows if r["workers"] == n), key=lambda r: abs(math.log(r["task_s"] / d))))
    return out


def unsaturated(rows: list) -> list[dict]:
    """The rows whose tasks/s reached 90 % of N / task s: this machine kept up, so their gaps are the round trip's."""
    return [r for r in rows if r["tasks_per_s"] >= 0.9 * r["ideal_tasks_per_s"]]


def project(m: dict) -> list[dict]:
    """Each target's limits in seconds and the binding one (see the notes printed with the table).

    CPU seconds per task (scheduler, client, workers; net of their idle CPU) are taken at the task duration's rows,
    the largest over the worker counts (the 64-worker rows complete few tasks on 2 cores); the end-to-end gap per
    task is the largest of the rows this machine was not saturated in; a worker's idle CPU share is the measured
    one at the worker count nearest the target's."""
    ex, fs, sc = m.get("export"), m["fs"], m["scale"]
    c = m["cpu_per_window_s"]
    files_w = ex["files_per_window"] if ex else DEFAULT_FILES_PER_WINDOW
    driver_w = ex["driver_cpu_per_window_s"] if ex else 0.0
    per_scene = ex["scene_cpu_s"] if ex else 0.0
    W, S = EPOSE["windows"], EPOSE["sequences"]
    rows_m = sc["rows"]
    counts = sorted({r["workers"] for r in rows_m})
    disk, shm = fs["disk"], fs["tmpfs"]
    probe_d = m["probe_task_s"]
    gap = max((r["overhead_per_task_s"] for r in unsaturated(rows_m)), default=None)
    if gap is None:
        gap = min(r["overhead_per_task_s"] for r in rows_m)
    out = []
    for (name, machines, goal), probes in [(tg, True) for tg in TARGETS] + [(tg, False) for tg in TARGETS]:
        name = name if probes else f"{name}, no probes"
        cores = CORES_PER_MACHINE * machines
        n_meas = min(counts, key=lambda k: abs(k - cores))            # 16 -> 16, 64 -> 64
        t = epose_tasks(cores, c, probes)
        full_d = min(4.0, (W - t["probe_windows"]) / max(t["full_tasks"], 1) * c)
        r_probe, r_full = _rows_at(rows_m, probe_d), _rows_at(rows_m, full_d)

        def per_task(key):       # summed over the probe and the full tasks, each at its duration's rows
            return (t["probe_tasks"] * max(r[key] for r in r_probe) + t["full_tasks"] * max(r[key] for r in r_full))

        idle = sc["idle"].get(n_meas) or sc["idle"][str(n_meas)]      # int keys, str after JSON
        sched_cpu = per_task("scheduler_net_cpu_per_task_s")
        client_cpu = per_task("client_net_cpu_per_task_s")
        worker_task_cpu = per_task("workers_net_cpu_per_task_s")
        gaps = t["tasks"] * gap
        # a worker's own CPU share with nothing to do, with Dask's defaults (the real export's workers)
        worker_idle = ex["worker_idle_share"] if ex else DEFAULT_WORKER_IDLE_SHARE
        driver = S * per_scene + W * driver_w + client_cpu
        setup = ex["context_setup_cpu_s"] if ex else 0.0
        work = W * c + worker_task_cpu + t["contexts"] * setup
        if machines == 1:          # scheduler and driver on the same 16 cores as the workers
            work += driver + sched_cpu
        cpu = work / (cores * (1.0 - worker_idle))
        # as measured on this machine (2 cores): the tasks at the rates reached here with this worker count
        rp = next(r for r in r_probe if r["workers"] == n_meas)
        rf = next(r for r in r_full if r["workers"] == n_meas)
        here = t["probe_tasks"] / max(rp["tasks_per_s"], 1e-9) + t["full_tasks"] / max(rf["tasks_per_s"], 1e-9)
        files = W * files_w
        limits = {
            "cpu": cpu,
            "cpu+gaps": cpu + gaps / cores,
            "scheduler": sched_cpu / max(1.0 - idle["scheduler"], 0.05),
            "driver": driver,
            "creates": files / disk["creates_per_s"],
            "syncfs": (t["tasks"] * disk["syncfs_fixed_s"] + files * disk["syncfs_per_file_s"]) / machines,
        }
        binding = max(limits, key=lambda k: limits[k] if k != "cpu" else -1)   # cpu+gaps includes cpu
        total = limits[binding]
        out.append({"target": name, "probes": probes, "machines": machines, "cores": cores, "goal_s": goal, "measured_workers": n_meas,
                    **t, "full_task_s": full_d, "probe_task_s": probe_d, "limits_s": limits,
                    "scheduler_as_measured_here_s": here, "worker_idle_share": worker_idle, "gap_per_task_s": gap,
                    "cpu_only_s": W * c / cores, "setup_s": t["contexts"] * setup / cores,
                    "setup_every_chunk_s": t["tasks"] * setup / cores, "driver_parts_s": {"scenes": S * per_scene, "windows": W * driver_w,
                                                                      "client_per_task": client_cpu},
                    "creates_tmpfs_s": files / shm["creates_per_s"], "files": files,
                    "creates_parallel_s": files / disk.get("creates_per_s_parallel", disk["creates_per_s"]),
                    "creates_needed_per_s": files / goal, "total_s": total, "binding": binding,
                    "met": total <= goal,
                    "cpu_side": max(("cpu+gaps", "scheduler", "driver"), key=lambda k: limits[k]),
                    "second": sorted(((v, k) for k, v in limits.items() if k not in (binding, "cpu")), reverse=True)[0][1]})
    return out


# ----------------------------------------------------------------------------------------------- report
def print_fs(fs: dict, nfs: dict) -> None:
    n = len(fs["disk"].get("rounds", [0]))
    print(f"Filesystem (one writer; files of 4 kB written under a temporary name, closed, renamed); median of {n} rounds"
          " (start, after the export, end), the range in brackets")
    hdr = (f"{'kind':<7}{'where':<24}{'type':<6}{'creates/s':>21}{f'{PARALLEL_WRITERS} writers':>21}{'fsync/s':>21}"
           f"{'syncfs/s':>21}{'syncfs ms @0/68/680 files':>27}{'ms/file':>8}")
    print(hdr)
    print("-" * len(hdr))
    for kind in ("tmpfs", "disk"):
        f = fs[kind]
        s = f["syncfs_s"]
        rs = f.get("rounds", [f])

        def rng(key):
            v = [r[key] for r in rs]
            return f"{f[key]:.0f} ({min(v):.0f}-{max(v):.0f})"
        print(f"{kind:<7}{f['root'][-23:]:<24}{f['type']:<6}{rng('creates_per_s'):>21}{rng('creates_per_s_parallel'):>21}"
              f"{rng('fsync_per_s'):>21}{rng('syncfs_per_s'):>21}{'/'.join(f'{s[k] * 1e3:.2f}' for k in ('0', '68', '680')):>27}"
              f"{f['syncfs_per_file_s'] * 1e3:>8.3f}")
    print(f"{PARALLEL_WRITERS} writers = processes creating files at once, each in its own folder (their total rate);"
          " syncfs/s = 1 / an empty syncfs;\nms/file = its time per dirty file (fit over 0/68/680 files).\n"
          f"NFS over the loopback: not measured: {nfs['why_not']}\n")


def print_export(ex: dict) -> None:
    print(f"Driver in a real export: export_dataset to E-POSE of {ex['copies']} links to the 5-object YCB scene "
          f"({ex['written']} windows) on a real scheduler + {ex['workers']} workers; load {ex['load_before'][0]:.1f} -> "
          f"{ex['load_after'][0]:.1f}")
    sizes = ex["chunk_sizes"]
    print(f"  wall {ex['wall_s']:.1f} s, {ex['written'] / ex['wall_s']:.1f} windows/s; {ex['tasks']} chunks "
          f"(sizes {min(sizes)}-{max(sizes)}, in order of the first scene: {sizes[:12]})")
    st = ", ".join(f"{k} {v:.1f}" for k, v in ex["stage_ms_per_window"].items())
    print(f"  workers: {ex['worker_cpu_per_window_s'] * 1e3:.1f} ms CPU per window in the chunks (worker_cpu; the whole worker "
          f"processes {ex['worker_process_cpu_per_window_s'] * 1e3:.1f} ms); stages ms/window: {st}")
    print(f"  {ex['files_per_window']:.2f} files and {ex['bytes_per_window'] / 1e3:.1f} kB per window; scheduler "
          f"{ex['scheduler_cpu_per_task_s'] * 1e3:.1f} ms CPU per chunk")
    th = ", ".join(f"{k} {v:.2f} s" for k, v in ex["threads_cpu_s"].items())
    print(f"  this process (driver + client): {ex['process_cpu_s']:.2f} s CPU = {ex['process_cpu_per_window_s'] * 1e3:.2f} ms per "
          f"window; scene-driver threads {ex['transient_cpu_s']:.2f} s, threads alive throughout: {th}")
    lg, no = ex["long"], ex["none"]
    print(f"  again in {lg['window_us'] / 1e3:.0f} ms windows: {lg['written']} windows, {lg['cpu_s']:.2f} s CPU (scene-driver"
          f" threads {lg['transient_cpu_s']:.2f} s); an export of no window: {no['cpu_s']:.2f} s CPU ({no['wall_s']:.1f} s wall)")
    print(f"  -> driver {ex['driver_cpu_per_window_s'] * 1e3:.2f} ms CPU per window (this process's CPU: the slope between the"
          f" two exports; its scene threads' alone {ex['driver_threads_cpu_per_window_s'] * 1e3:.2f}), {ex['scene_cpu_s']:.2f} s per"
          f" scene (the scene threads' rest; {ex['scene_cpu_no_window_s']:.2f} s in the export of no window, which loads no mesh);"
          f" client event loop {ex['client_loop_cpu_per_task_s'] * 1e3:.1f} ms per chunk; a chunk's arguments pickle to"
          f" {ex['arg_bytes']['spec'] / 1e3:.1f} kB (spec) + {ex['arg_bytes']['window']} bytes per window")
    if ex.get("context_setups"):
        cs = ex["context_setups"]
        print(f"  a scene's context on a worker: {ex['context_setup_cpu_s']:.2f} s CPU to set up (median of {len(cs)}: context"
              f" {statistics.median(x['context_s'] for x in cs):.2f} s + first window's annotation cold"
              f" {statistics.median(x['cold_annotate_s'] for x in cs) * 1e3:.0f} ms vs warm"
              f" {statistics.median(x['warm_annotate_s'] for x in cs) * 1e3:.0f} ms)")
    print(f"  idle after the exports, Dask's defaults: each worker {ex['worker_idle_share'] * 100:.1f} % of a core (event loop"
          f" tick, profiler, monitors, heartbeats), the scheduler {ex['idle']['scheduler'] * 100:.1f} %\n")


def print_scale(sc: dict) -> None:
    print("Scheduler and client at 16 and 64 workers: tasks that sleep (no CPU), submitted by DaskWindows.run from 3 driver\n"
          "threads (2 chunks per worker in flight); the workers' own periodic work made rare (LEAN_WORKER_ENV) so that 64 fit")
    for n, s in sc["worker_start_s"].items():
        i = sc["idle"][n]
        print(f"  {n} workers up in {s:.0f} s (cumulative start); idle: scheduler {i['scheduler'] * 100:.1f} %, client "
              f"{i['client'] * 100:.1f} %, workers {i['workers'] * 100:.0f} % of a core (heartbeats), load {i['load1']:.1f}")
    hdr = (f"{'N':>3}{'task s':>7}{'win/task':>9}{'T s':>5}{'tasks':>6}{'tasks/s':>8}{'ideal':>7}{'sched ms/task':>15}"
           f"{'client ms/task':>15}{'workers ms/task':>16}{'overhead s/task':>16}{'idle %':>7}{'load1':>6}{'RSS MB w/s':>12}")
    print(hdr)
    print("-" * len(hdr))
    for r in sc["rows"]:
        def both(key):
            return f"{r[key + '_cpu_per_task_s'] * 1e3:.2f} ({r[key + '_net_cpu_per_task_s'] * 1e3:.2f})"
        print(f"{r['workers']:>3}{r['task_s']:>7.2f}{r['windows_per_task']:>9}{r['interval_s']:>5.0f}{r['tasks']:>6.0f}"
              f"{r['tasks_per_s']:>8.1f}{r['ideal_tasks_per_s']:>7.1f}{both('scheduler'):>15}{both('client'):>15}"
              f"{both('workers'):>16}{r['overhead_per_task_s']:>16.3f}{r['idle_share'] * 100:>7.1f}{r['load1']:>6.1f}"
              f"{r['worker_rss_mb_median']:>7.0f}/{r['scheduler_rss_mb']:<4.0f}")
    print("tasks = the tasks' sleeps inside the interval T, each by its share in it; ideal = N / task s;\n"
          "sched / client / workers ms per task = CPU of the scheduler process, this process (the\n"
          "client and the 3 driver threads) and all workers over the interval / tasks completed in it, in brackets net of\n"
          "their CPU with nothing to do (heartbeats; the lines above); overhead = (N x T - sum of the sleeps inside T) /\n"
          "tasks; idle = the workers' idle share; load1 = 1-minute load average at the end; RSS = median worker /\n"
          "scheduler. On 2 cores the scheduler's and the client's CPU per task transfer to a machine where each has a core;\n"
          "the wall-clock rates (tasks/s, overhead, idle) are this machine's.")
    for n, i in sc["idle"].items():
        if i["workers"] > 0.5 * (os.cpu_count() or 2):
            print(f"{n} workers with nothing to do took {i['workers']:.2f} cores ({i['workers'] / int(n) * 100:.1f} % each: "
                  "heartbeats, event loops): this machine is saturated before any task; the rows of "
                  f"{n} workers show that, not the scheduler's limit.")
    print()


def print_projection(m: dict, rows: list) -> None:
    c = m["cpu_per_window_s"]
    src = "measured in the real export above" if m.get("export") else "README figure (export skipped)"
    print(f"Projection: E-POSE ({EPOSE['sequences']} sequences, {EPOSE['windows'] // 1000} k windows of 10 ms, "
          f"{EPOSE['events'] / 1e9:.1f} G events), {c * 1e3:.1f} ms CPU per window ({src}); chunks as the ChunkPlanner\n"
          f"cuts them (probes of 4 windows while the first chunks are out, then ~{4.0 / c:.0f} windows = 4 s of CPU)")
    hdr = (f"{'target':<25}{'tasks':>7}{'probes':>7}{'probe win':>10}{'cpu':>6}{'+gaps':>6}{'sched':>6}{'driver':>7}"
           f"{'creates':>8}{'syncfs':>7}{'overall':>8}{'goal':>5}  binding (next)")
    print(hdr)
    print("-" * (len(hdr) + 18))
    for p in rows:
        L = p["limits_s"]
        print(f"{p['target']:<25}{p['tasks']:>7}{p['probe_tasks']:>7}{p['probe_windows']:>10}{L['cpu']:>6.0f}"
              f"{L['cpu+gaps']:>6.0f}{L['scheduler']:>6.0f}{L['driver']:>7.0f}{L['creates']:>8.0f}{L['syncfs']:>7.0f}"
              f"{p['total_s']:>8.0f}{p['goal_s']:>5.0f}  {p['binding']} ({p['second']}): "
              f"{'met' if p['met'] else 'MISSED'}")
    print("""seconds. cpu = (windows x CPU per window + tasks x the workers' CPU per task + contexts x a context's set-up) /
  (cores x (1 - a worker's idle CPU share with Dask's defaults)), contexts = per sequence min(workers, chunks);
  on 1 x 16 the driver's and the scheduler's CPU share those 16 cores; on 4 x 16 they run beside them;
+gaps = cpu + tasks x the end-to-end overhead per task (worker idle time) / cores, the largest overhead of the rows
  this machine kept up in (>= 90 % of N / task s);
sched = tasks x the scheduler's net CPU per task / its non-idle share (a core of its own); CPU per task (scheduler,
  client, workers) at the task duration's rows, the largest over 16 and 64 workers;
driver = one process (GIL): sequences x CPU per scene + windows x driver CPU per window + tasks x client CPU per task;
creates = files / this VM's disk creates/s (one writer, taken as serial: on one machine a pessimistic bound, since
  ext4 creates in separate folders overlap and their CPU is in the window's; on a shared filesystem, the server's);
syncfs = (chunks x an empty syncfs + files x its time per dirty file) / machines, this VM's disk;
probe tasks at the probe rows, full tasks at the rows nearest their mean duration; overall = the largest
(cpu+gaps stands for the workers); 'no probes': what-if, the planner knowing the cost per window from the start.""")
    for p in rows:
        if not p["probes"]:
            continue
        d = p["driver_parts_s"]
        print(f"- {p['target']}: {p['tasks']} tasks ({p['probe_tasks']} probes of <= 4 windows holding "
              f"{p['probe_windows'] / EPOSE['windows'] * 100:.0f} % of the windows, {p['full_tasks']} of ~{p['full_task_s']:.1f} s);"
              f" a sequence: {len(p['sizes_per_sequence'])} chunks, {p['sizes_per_sequence'][0]} x {p['probe_tasks'] // EPOSE['sequences']}"
              f" then {p['sizes_per_sequence'][-2:]}; CPU alone {p['cpu_only_s']:.0f} s, context set-ups {p['contexts']}:"
              f" {p['setup_s']:.0f} s ({p['setup_every_chunk_s']:.0f} s if every chunk met a cold context); driver = scenes {d['scenes']:.0f} +"
              f" windows {d['windows']:.0f} + client {d['client_per_task']:.0f} s; the tasks at the rates reached here"
              f" {p['scheduler_as_measured_here_s']:.0f} s; {p['files'] / 1e6:.2f} M files need"
              f" {p['creates_needed_per_s']:.0f} creates/s for the goal (tmpfs here: {p['creates_tmpfs_s']:.0f} s)")
    print("- 4 x 16 needs a shared filesystem: its (NFS) creates/s and syncfs were not measured (see above); this VM's\n"
          "  disk stands in for them.")
    print("Verdict:")
    for p in rows:
        if not p["probes"]:
            continue
        L, k = p["limits_s"], p["cpu_side"]
        fs_part = (f"{p['binding']} {p['total_s']:.0f} s" if p["binding"] in ("creates", "syncfs") else "")
        print(f"- {p['target']}: {'met' if p['met'] else 'MISSED'} ({p['total_s']:.0f} s against {p['goal_s']:.0f} s);"
              + (f" binding: {fs_part} at this disk's one-writer rate ({p['creates_parallel_s']:.0f} s at the"
                 f" {PARALLEL_WRITERS} writers' rate);" if fs_part else "")
              + f" without the filesystem {k} {L[k]:.0f} s ({'met' if L[k] <= p['goal_s'] else 'missed'}); CPU alone"
              f" {p['cpu_only_s']:.0f} s (+ context set-ups {p['setup_s']:.0f} s), driver {L['driver']:.0f} s, scheduler"
              f" {L['scheduler']:.0f} s;"
              f" the goal needs <= {p['goal_s'] * p['cores'] / EPOSE['windows'] * 1e3:.1f} ms CPU per window on"
              f" {p['cores']} cores, <= {p['goal_s'] / EPOSE['windows'] * 1e3:.2f} ms of driver per window and"
              f" >= {p['creates_needed_per_s']:.0f} creates/s")


def report(m: dict) -> list:
    lb, la = m["load_before"], m["load_after"]
    print(f"{m['cores']} cores, load average {lb[0]:.1f} {lb[1]:.1f} {lb[2]:.1f} before, {la[0]:.1f} {la[1]:.1f} {la[2]:.1f} after "
          f"(shared machine); bench {m['bench_s']:.0f} s\n")
    print_fs(m["fs"], m["nfs"])
    if m.get("export"):
        print_export(m["export"])
    print_scale(m["scale"])
    rows = project(m)
    print_projection(m, rows)
    return rows


# ----------------------------------------------------------------------------------------------- main
def fs_round(rounds: dict) -> None:
    for kind, root in (("tmpfs", Path("/dev/shm")), ("disk", DATA)):
        rounds.setdefault(kind, []).append(fs_measure(root))


def fs_summary(rounds: dict) -> dict:
    """Per kind: the median of each figure over the rounds (the table's), and every round."""
    out = {}
    for kind, rs in rounds.items():
        med = dict(rs[0])
        for key in ("creates_per_s", "creates_per_s_parallel", "fsync_per_s", "syncfs_per_s", "syncfs_fixed_s",
                    "syncfs_per_file_s"):
            med[key] = statistics.median(r[key] for r in rs)
        med["syncfs_s"] = {k: statistics.median(r["syncfs_s"][k] for r in rs) for k in rs[0]["syncfs_s"]}
        med["rounds"] = rs
        out[kind] = med
    return out


def measure(args) -> dict:
    from evpose.core.export.chunks import PROBE_WINDOWS

    load0, t0 = os.getloadavg(), time.perf_counter()
    rounds: dict = {}
    fs_round(rounds)                # the filesystem three times: its rates vary by the minute on this VM
    print(f"  done filesystem: disk {rounds['disk'][-1]['creates_per_s']:.0f} creates/s", file=sys.stderr)
    with run_dir("cluster_scale") as work:
        ex = None
        if args.copies > 0:
            ex = real_export(work, args.copies)
            print(f"  done real export: {ex['worker_cpu_per_window_s'] * 1e3:.1f} ms CPU per window", file=sys.stderr)
        fs_round(rounds)
        print(f"  done filesystem: disk {rounds['disk'][-1]['creates_per_s']:.0f} creates/s", file=sys.stderr)
        c = args.cpu_per_window_ms / 1e3 if args.cpu_per_window_ms else (
            ex["worker_cpu_per_window_s"] if ex else DEFAULT_CPU_PER_WINDOW_S)
        probe_d = PROBE_WINDOWS * c
        durations = [probe_d if d == "probe" else float(d) for d in args.durations.split(",")]
        counts = [int(n) for n in args.workers.split(",")]
        scale = scale_runs(work, counts, durations, c, args.measure_s, ex["arg_bytes"] if ex else ARG_BYTES)
    fs_round(rounds)
    return {"fs": fs_summary(rounds), "nfs": nfs_status(), "export": ex, "scale": scale, "cpu_per_window_s": c,
            "probe_task_s": probe_d, "load_before": load0, "load_after": os.getloadavg(),
            "bench_s": time.perf_counter() - t0, "cores": os.cpu_count()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", default="16,64", help="worker process counts (default 16,64)")
    ap.add_argument("--durations", default="4,0.5,probe",
                    help="task durations, s; 'probe' = a probe chunk's (4 windows x the CPU per window)")
    ap.add_argument("--measure-s", type=float, default=45.0,
                    help="steady interval of each run with tasks of >= 2 s (shorter tasks: 2/3 of it, >= 30 s)")
    ap.add_argument("--copies", type=int, default=3, help="links to the 5-object scene in the real export (0: skip it)")
    ap.add_argument("--cpu-per-window-ms", type=float, help="use this instead of the real export's figure")
    ap.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    ap.add_argument("--print-json", type=Path, metavar="PATH",
                    help="measure nothing: print the report of the figures an earlier --json wrote")
    args = ap.parse_args(argv)
    # a SIGTERM (e.g. `timeout`) ends the run through the finally clauses, which stop every process it started
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    m = json.loads(args.print_json.read_text()) if args.print_json else measure(args)
    rows = report(m)
    if args.json:
        doc = dict(m, projection=rows)
        args.json.write_text(json.dumps(doc, indent=1, default=str) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
