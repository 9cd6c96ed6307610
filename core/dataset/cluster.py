"""Where dataset work runs: a Dask ``LocalCluster`` evpose starts and stops, or an existing Dask cluster.

``--workers N`` starts ``N`` worker processes with one thread each on this machine (the default is the
machine's cores); ``--scheduler ADDR`` connects to a running scheduler (``dask scheduler`` +
``dask worker`` started by hand, or dask-jobqueue on SLURM). Workers open their inputs themselves from
paths, so every worker must see the dataset and the output folder under the same paths (a shared
filesystem); no event arrays go through the scheduler.

A ``--scheduler`` address is checked before Dask sees it (:func:`scheduler_address`: ``tcp://host:port`` or
``host:port``; ``inproc://``, ``tls://`` and other schemes are refused with one line), then probed with a
plain socket (:func:`probe_scheduler`): the host is resolved, the port connected and the scheduler's greeting
read, each within a few seconds, and the greeting must be a small Dask handshake. Dask's own connect reads
the peer's first message without a time limit and allocates whatever size its first 8 bytes announce, so a
port that accepts and stays silent hung it for ever, and one that answers garbage made it ask for exabytes.
"""
from __future__ import annotations

import contextlib
import logging
import os
import socket
import struct
import threading
import time
from dataclasses import dataclass

from evpose.core.errors import InputError

__all__ = ["ClusterError", "ClusterSpec", "open_client", "scheduler_address", "probe_scheduler", "MAX_LOCAL_WORKERS"]

#: A local cluster of more processes than this is refused (a typo, not a plan).
MAX_LOCAL_WORKERS = 256
#: Dask sets MALLOC_TRIM_THRESHOLD_=65536 in every worker to hand freed memory back early; for the export's
#: per-window image buffers that meant ~13x the page faults and 1.24x slower BOP windows on a quiet machine
#: (bench_dataset --malloc-compare, one worker: 2522 vs 191 faults per window, 22.3 vs 27.7 windows/s),
#: so local workers keep glibc's default. Workers started by hand: ``source resources/evpose-workers.env`` (it gives
#: the whole mapping: Dask lower-cases keys read from variable names, so ``..._ENVIRON__MALLOC_TRIM_THRESHOLD_=None``
#: would not replace the upper-case default).
WORKER_ENVIRON = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
#: A Dask worker's own periodic work, made rare in local clusters: the statistical profiler (a stack sample of every
#: thread each 10 ms, for the dashboard's profile page), the event loop's 20 ms tick (it only watches for a blocked
#: loop) and the 0.5 s system monitor. With Dask's defaults an idle worker took 4.2-4.6 % of a core and an export
#: worker 3-4 % more CPU a window; with these 0.8 %, and one worker did 0.95-1.0 of export_scene's windows/s in one
#: process against 0.90-0.95 (issue 27.1; ycb_5obj_5s, E-POSE). Given to the nannies as their ``config``: a worker a
#: nanny restarts after a kill came back with Dask's defaults when they were only set (``dask.config.set``) while the
#: cluster started. Workers started by hand: the README's environment.
WORKER_CONFIG = {"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "1s",
                 "distributed.admin.system-monitor.interval": "5s"}
#: Seconds allowed to resolve the scheduler's host name.
RESOLVE_TIMEOUT_S = 5.0
#: Seconds during which a refused or unanswered TCP connection to the scheduler is tried again (a scheduler
#: that is still starting); then the command ends with one line naming the address and what was tried.
CONNECT_TIMEOUT_S = 5.0
#: Seconds allowed for the scheduler's greeting once connected (a Dask server sends it at once).
HANDSHAKE_TIMEOUT_S = 5.0
#: Largest greeting accepted, bytes: Dask's handshake is ~60 bytes (compression, Python version, pickle
#: protocol); anything announcing more is not a Dask server and is never read.
MAX_HANDSHAKE_BYTES = 64 * 1024
#: Seconds Dask's client gets for the rest (registering with a scheduler that answered the probe).
CLIENT_TIMEOUT_S = 15.0
#: Seconds to wait for a first worker when the scheduler has none (a batch job still queued), then give up.
WORKER_WAIT_S = 120.0
#: Address schemes refused with a reason (anything else but tcp:// is an unknown scheme).
REFUSED_SCHEMES = {
    "inproc": "inproc:// addresses live inside one Python process and cannot be reached from evpose; give "
              "the scheduler's tcp://host:port",
    "tls": "tls:// needs the cluster's certificates (a Dask Security object), which evpose does not take; "
           "connect over tcp://host:port (e.g. through an SSH tunnel: ssh -L 8786:localhost:8786 HEAD, then "
           "--scheduler tcp://localhost:8786)",
}


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


def scheduler_address(text: str) -> tuple[str, str, int]:
    """``(address, host, port)`` of a ``--scheduler`` value: ``tcp://host:port`` or ``host:port`` (IPv6
    hosts in brackets, ``tcp://[::1]:8786``); ``address`` is the ``tcp://`` form Dask is given.

    Raises :class:`ClusterError` (the message says what is wrong, without the option's name) for another
    scheme, a missing or bad port or a malformed host; nothing is resolved or connected here.
    """
    s = str(text).strip()
    scheme, sep, rest = s.partition("://")
    if not sep:
        scheme, rest = "tcp", s
    scheme = scheme.lower()
    if scheme in REFUSED_SCHEMES:
        raise ClusterError(REFUSED_SCHEMES[scheme])
    if scheme != "tcp":
        raise ClusterError(f"unknown address scheme {scheme + '://'!r}: evpose connects to tcp://host:port")
    if rest.startswith("["):
        host, close, port = rest[1:].partition("]")
        if not close or not port.startswith(":"):
            raise ClusterError("expected [IPv6 address]:port, e.g. tcp://[::1]:8786")
        port = port[1:]
    else:
        host, colon, port = rest.rpartition(":")
        if not colon:
            raise ClusterError("missing port: give host:port (a Dask scheduler listens on 8786 by default)")
        if ":" in host:
            raise ClusterError("write an IPv6 address in brackets, e.g. tcp://[::1]:8786")
    if not host or any(c.isspace() or c in "/@?#[]" for c in host):
        raise ClusterError(f"expected host:port, got the host {host!r}")
    if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
        raise ClusterError(f"the port must be a number from 1 to 65535, got {port!r}")
    shown = f"[{host}]" if ":" in host else host
    return f"tcp://{shown}:{int(port)}", host, int(port)


def probe_scheduler(host: str, port: int) -> bytes:
    """Check that a Dask server answers at ``host:port`` before Dask's client connects; returns its greeting.

    Resolves the host (:data:`RESOLVE_TIMEOUT_S`), connects (retried for :data:`CONNECT_TIMEOUT_S`),
    reads the greeting every Dask server sends first (:data:`HANDSHAKE_TIMEOUT_S`, at most
    :data:`MAX_HANDSHAKE_BYTES`) and decodes it; then sends it back as this side's handshake (so the
    scheduler logs no aborted connection) and closes. Raises :class:`ClusterError` saying what was tried.
    """
    infos = _resolve(host, port)
    sock = _connect(infos)
    try:
        deadline = time.monotonic() + HANDSHAKE_TIMEOUT_S
        head = _recv_exactly(sock, 8, deadline)
        (n,) = struct.unpack("Q", head)
        if not 8 <= n <= MAX_HANDSHAKE_BYTES:
            raise ClusterError(f"the peer does not speak the Dask protocol (its first message announces {n} "
                               f"bytes; a Dask greeting is under {MAX_HANDSHAKE_BYTES // 1024} KiB): is this the "
                               "scheduler's port (8786 by default), not its dashboard or another service?")
        body = _recv_exactly(sock, n, deadline)
        _check_greeting(body)
        with contextlib.suppress(OSError):
            sock.sendall(head + body)
        return body
    finally:
        sock.close()


def _resolve(host: str, port: int) -> list:
    """``getaddrinfo`` in a helper thread (it has no timeout of its own; a dead DNS server blocks it)."""
    out: dict = {}

    def run():
        try:
            out["infos"] = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        except (OSError, UnicodeError) as exc:
            out["error"] = exc

    th = threading.Thread(target=run, name="evpose-resolve", daemon=True)
    th.start()
    th.join(RESOLVE_TIMEOUT_S)
    if th.is_alive():
        raise ClusterError(f"cannot resolve the host name {host!r}: no answer within {RESOLVE_TIMEOUT_S:g} s")
    if "error" in out:
        exc = out["error"]
        raise ClusterError(f"cannot resolve the host name {host!r} ({getattr(exc, 'strerror', None) or exc})")
    return out["infos"]


def _connect(infos: list) -> socket.socket:
    """A connected socket to the first of ``infos`` that accepts, trying all again until :data:`CONNECT_TIMEOUT_S`."""
    start = time.monotonic()
    deadline = start + CONNECT_TIMEOUT_S
    attempts, errors = 0, {}
    while True:
        for family, kind, proto, _, sockaddr in infos:
            sock = socket.socket(family, kind, proto)
            sock.settimeout(max(deadline - time.monotonic(), 0.05))
            attempts += 1
            try:
                sock.connect(sockaddr)
                return sock
            except OSError as exc:
                sock.close()
                errors[str(sockaddr[0])] = "no answer" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        left = deadline - time.monotonic()
        if left <= 0:
            break
        time.sleep(min(0.25, left))
    why = "; ".join(f"{a}: {e}" for a, e in errors.items())
    raise ClusterError(f"cannot connect ({why}; {attempts} attempt(s) over {time.monotonic() - start:.0f} s): "
                       "is `dask scheduler` running there and the port open?")


def _recv_exactly(sock: socket.socket, n: int, deadline: float) -> bytes:
    """``n`` bytes from ``sock`` before ``deadline`` (monotonic), or :class:`ClusterError`."""
    buf = bytearray()
    while len(buf) < n:
        left = deadline - time.monotonic()
        try:
            if left <= 0:
                raise TimeoutError
            sock.settimeout(left)
            chunk = sock.recv(min(n - len(buf), 65536))
        except TimeoutError:
            raise ClusterError(f"the port accepts connections but sent {'no' if not buf else 'an incomplete'} Dask "
                               f"greeting within {HANDSHAKE_TIMEOUT_S:g} s (a Dask scheduler greets at once): is "
                               "this the scheduler's port (8786 by default)?") from None
        except OSError as exc:
            raise ClusterError(f"the connection failed while reading the greeting ({exc.strerror or exc})") from None
        if not chunk:
            raise ClusterError(f"the peer closed the connection after {len(buf)} of {n} bytes of its greeting: "
                               "not a Dask scheduler?")
        buf += chunk
    return bytes(buf)


def _check_greeting(body: bytes) -> None:
    """``body`` (the frames after the 8-byte length) decodes to Dask's handshake dict (one msgpack frame,
    decoded with msgpack itself: Dask's ``loads`` logs a traceback on bad input)."""
    import msgpack

    bad = ClusterError("the peer does not speak the Dask protocol (its greeting is not a Dask handshake): "
                       "is this the scheduler's port (8786 by default)?")
    (n_frames,) = struct.unpack_from("Q", body)
    if not 1 <= n_frames <= 16 or len(body) < 8 * (1 + n_frames):
        raise bad
    lengths = struct.unpack_from(f"{n_frames}Q", body, 8)
    if 8 * (1 + n_frames) + sum(lengths) != len(body):
        raise bad
    start = 8 * (1 + n_frames)
    try:
        msg = msgpack.loads(body[start:start + lengths[0]], raw=False, use_list=False, strict_map_key=False)
    except Exception:                       # noqa: BLE001 -- any decoding failure means "not Dask"
        raise bad from None
    if not isinstance(msg, dict) or "compression" not in msg:
        raise bad


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


def _connect_client(text: str):
    """A ``distributed.Client`` of the scheduler at ``text``, checked and probed first."""
    try:
        address, host, port = scheduler_address(text)
        probe_scheduler(host, port)
    except ClusterError as exc:
        raise ClusterError(f"--scheduler {text}: {exc}") from None
    from distributed import Client

    try:
        return Client(address, timeout=f"{CLIENT_TIMEOUT_S}s")
    except Exception as exc:               # noqa: BLE001 -- a Dask server that is not a usable scheduler
        raise ClusterError(f"--scheduler {text}: the Dask server at {address} answered but the client could not "
                           f"register ({type(exc).__name__}: {exc}); is it the scheduler, not a worker?") from None


def _wait_for_a_worker(client, text: str, log) -> None:
    """Wait (at most :data:`WORKER_WAIT_S`) until the scheduler has a worker: without one, tasks wait for ever."""
    if client.scheduler_info().get("workers"):
        return
    if log is not None:
        log(f"the scheduler has no workers yet: waiting up to {WORKER_WAIT_S:g} s for one")
    try:
        client.wait_for_workers(1, timeout=WORKER_WAIT_S)
    except (TimeoutError, OSError):
        raise ClusterError(f"--scheduler {text}: no worker joined the scheduler within {WORKER_WAIT_S:g} s; start "
                           f"some with `dask worker {text}` (they must see the dataset under the same paths)") from None


@contextlib.contextmanager
def open_client(spec: ClusterSpec, *, log=None):
    """A ``distributed.Client`` for ``spec``; a local cluster is stopped on exit.

    ``log(line)`` receives one line saying where the work runs and the dashboard address when there
    is one. Raises :class:`ClusterError` when the options are wrong or the scheduler does not answer.
    """
    cluster, dashboard = None, None
    if spec.scheduler:
        if spec.workers is not None:
            raise ClusterError("--workers: not with --scheduler (the existing cluster has its own workers)")
        client = _connect_client(spec.scheduler)       # checked and probed before Dask is imported
    else:
        import dask
        from distributed import Client, LocalCluster

        n = spec.local_workers()
        dashboard = _has_dashboard()
        with _workers_ignore_sigint(), dask.config.set(WORKER_ENVIRON):
            # scheduler, workers and dashboard on the loopback interface only: a local run talks to nothing else
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address="127.0.0.1:0",
                                   memory_limit=spec.memory_limit, silence_logs=logging.CRITICAL,
                                   config=dict(WORKER_CONFIG))   # the workers' settings, kept by their nannies
        client = Client(cluster)
    try:
        if log is not None:
            link = client.dashboard_link if (cluster is None or dashboard) else None
            log(f"running on {spec.describe()}" + (f"; Dask dashboard: {link}" if link else ""))
        if cluster is None:
            _wait_for_a_worker(client, spec.scheduler, log)
        yield client
    finally:
        with contextlib.suppress(Exception):
            client.close()
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close()
