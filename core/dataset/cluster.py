"""Where dataset work runs: a Dask ``LocalCluster`` evpose starts and stops, or an existing Dask cluster.

``--workers N`` starts ``N`` worker processes with one thread each on this machine (the default is the
machine's cores); ``--scheduler ADDR`` connects to a running scheduler (``dask scheduler`` +
``dask worker`` started by hand, or dask-jobqueue on SLURM). Workers open their inputs themselves from
paths, so every worker must see the dataset and the output folder under the same paths (a shared
filesystem); no event arrays go through the scheduler.
"""
from __future__ import annotations

import contextlib
import logging
import os
from dataclasses import dataclass

from evpose.core.errors import InputError

__all__ = ["ClusterError", "ClusterSpec", "open_client", "MAX_LOCAL_WORKERS"]

#: A local cluster of more processes than this is refused (a typo, not a plan).
MAX_LOCAL_WORKERS = 256
#: Dask sets MALLOC_TRIM_THRESHOLD_=65536 in every worker to hand freed memory back early; for the export's
#: per-window image buffers that meant ~13x the page faults and 1.24x slower BOP windows on a quiet machine
#: (bench_dataset --malloc-compare, one worker: 2522 vs 191 faults per window, 22.3 vs 27.7 windows/s),
#: so local workers keep glibc's default. Workers started by hand: set
#: DASK_DISTRIBUTED__NANNY__PRE_SPAWN_ENVIRON__MALLOC_TRIM_THRESHOLD_=None in their environment.
WORKER_ENVIRON = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
#: Seconds to wait for an existing scheduler to answer.
CONNECT_TIMEOUT_S = 20


class ClusterError(InputError):
    """The cluster options cannot be used (a bad worker count, an unreachable scheduler)."""


@dataclass(frozen=True)
class ClusterSpec:
    """How to get a Dask client: ``scheduler`` (an address) or a local cluster of ``workers``."""

    workers: int | None = None           # local worker processes (None: the machine's cores)
    scheduler: str | None = None         # e.g. "tcp://host:8786"
    memory_limit: str | None = "auto"    # per local worker: Dask's "auto" divides the RAM between workers

    def local_workers(self) -> int:
        n = self.workers if self.workers is not None else (os.cpu_count() or 1)
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_LOCAL_WORKERS:
            raise ClusterError(f"--workers: must be an integer from 1 to {MAX_LOCAL_WORKERS}, got {n!r}")
        return n

    def describe(self) -> str:
        return f"scheduler {self.scheduler}" if self.scheduler else f"local cluster of {self.local_workers()} workers"


def _has_dashboard() -> bool:
    try:
        import bokeh  # noqa: F401  (Dask serves its dashboard only with bokeh installed)
    except ImportError:
        return False
    return True


@contextlib.contextmanager
def _workers_ignore_sigint():
    """Start worker processes with SIGINT ignored (inherited across exec): Ctrl-C in a terminal reaches the
    whole process group, and this process, not each worker, answers it by cancelling and closing the cluster."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def open_client(spec: ClusterSpec, *, log=None):
    """A ``distributed.Client`` for ``spec``; a local cluster is stopped on exit.

    ``log(line)`` receives one line saying where the work runs and the dashboard address when there
    is one. Raises :class:`ClusterError` when the options are wrong or the scheduler does not answer.
    """
    import dask
    from distributed import Client, LocalCluster

    cluster, dashboard = None, None
    if spec.scheduler:
        if spec.workers is not None:
            raise ClusterError("--workers: not with --scheduler (the existing cluster has its own workers)")
        try:
            client = Client(spec.scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
        except (OSError, TimeoutError) as exc:
            raise ClusterError(f"--scheduler {spec.scheduler}: cannot connect ({exc})") from None
    else:
        n = spec.local_workers()
        dashboard = _has_dashboard()
        with _workers_ignore_sigint(), dask.config.set(WORKER_ENVIRON):
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                                   memory_limit=spec.memory_limit, silence_logs=logging.CRITICAL)
        client = Client(cluster)
    try:
        if log is not None:
            link = client.dashboard_link if (cluster is None or dashboard) else None
            log(f"running on {spec.describe()}" + (f"; Dask dashboard: {link}" if link else ""))
        yield client
    finally:
        with contextlib.suppress(Exception):
            client.close()
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close()
