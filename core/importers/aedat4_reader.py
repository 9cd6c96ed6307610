"""Reading an AEDAT4 file through ``dv-processing`` in a child process (:mod:`evpose.core.importers.aedat4_child`).

:class:`Aedat4Reader` starts the child, reads its frames through a pipe and turns every way it can fail into one
:class:`~evpose.core.importers.failure.ImportFailure` naming the file: the library's own refusal, a crash (a
signal), an early end, or a stall, which is how a corrupt packet shows: ``dv-processing`` then spins forever,
while opening the file as well as while reading it. The watchdog allows :data:`START_TIMEOUT_S` to start the
interpreter and load the library, :data:`STALL_TIMEOUT_S` plus one second per :data:`OPEN_BYTES_PER_S` bytes of
file to open it, and :data:`STALL_TIMEOUT_S` between frames once it reads (a healthy child sends a frame at least
every 0.2 s). The child is killed on any error, cancel or ``KeyboardInterrupt``.

Memory: one frame (at most 2**20 events, 13 bytes each) at a time here, plus the child (~165 MB resident with
numpy and the library, measured at 5 M and 50 M events alike). Both processes work at once: the child decodes
while this one validates and writes.
"""
from __future__ import annotations

import json
import os
import re
import select
import signal
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from evpose.core.importers.aedat4_copy import ReadableCopy
from evpose.core.importers.aedat4_layout import Layout, scan_layout
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.report import ImportContext

#: Seconds without data from the child that count as a stall.
STALL_TIMEOUT_S = 10.0
#: Seconds the child may take to start and load dv-processing (measured: ~0.5 s).
START_TIMEOUT_S = 30.0
#: Opening is given one more second per this many bytes of file (measured: ~0.1 µs per packet of ~10 kB).
OPEN_BYTES_PER_S = 50e6
_FRAME = struct.Struct("<cQ")
_MAX_FRAME = 1 << 31
_PIPE_BYTES = 1 << 20


def _one_line(msg: str) -> str:
    """dv-processing's multi-line C++ exception text as one line, without its source locations and its stack
    trace (``Stacktrace: 0# 0x... in dv_processing...so``)."""
    text = re.split(r"\bStack ?trace:", str(msg), maxsplit=1, flags=re.IGNORECASE)[0].replace("Error info:", "")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    keep = [ln for ln in lines if not re.search(r"\.(hpp|cpp|h)\(\d+\)", ln)] or lines
    return " ".join(" ".join(keep).split())[:500]


def child_command(path: Path, poses: bool) -> list[str]:
    """The command line of the reading process: this interpreter runs :mod:`evpose.core.importers.aedat4_child`
    by its file (it needs only numpy and dv-processing; skipping the package import saves start-up time), in
    isolated mode (``-I``: no folder of the user's shadows a module)."""
    from evpose.core.importers import aedat4_child

    boot = "import runpy, sys; runpy.run_path(sys.argv.pop(1), run_name='__main__')"
    return [sys.executable, "-I", "-c", boot, aedat4_child.__file__, str(path), "1" if poses else "0"]


class Aedat4Reader:
    """The frames of one AEDAT4 file, read by ``dv-processing`` in a child process.

    Parameters
    ----------
    path : Path
        The recording (opened read-only by the library).
    ctx : ImportContext
        For cancel checks.
    poses : bool
        Also read the first pose stream (``poses`` if there is one by that name).

    Use as a context manager: entering starts the child (which loads while the caller reads its other inputs);
    :attr:`header` waits for the child's ``H`` frame (camera, streams, resolution, time range); :meth:`events`
    yields ``(t_us int64, x int16, y int16, p int8)`` arrays, then :attr:`poses` holds the pose samples
    ``(t_us (N,), values (N, 7))`` and :attr:`done` the final counts.
    """

    def __init__(self, path: Path, ctx: ImportContext, *, poses: bool):
        self.path, self.ctx, self.want_poses = Path(path), ctx, poses
        self.proc: subprocess.Popen | None = None
        self.err = tempfile.TemporaryFile()
        self._header: dict | None = None
        self.done: dict | None = None
        self.pose_parts: list[tuple[np.ndarray, np.ndarray]] = []
        self.n_events = 0
        self.layout: Layout | None = None
        self.copy: ReadableCopy | None = None

    # ------------------------------------------------------------------ process
    def __enter__(self) -> "Aedat4Reader":
        """Check the file's layout (:func:`scan_layout`; a file cut off at the end is read up to the cut, from a
        readable copy when its packet table is gone), then start the reading process."""
        try:
            self.layout = scan_layout(self.path)
            if self.layout.cut is not None:
                self._report_cut()
                if self.layout.table_position >= 0:          # dv-processing refuses a file whose table is gone
                    self.copy = ReadableCopy(self.path, self.layout)
            self._start()
        except BaseException:
            self.close()
            raise
        return self

    def _start(self) -> None:
        source = self.copy.path if self.copy is not None else self.path
        self.proc = subprocess.Popen(child_command(source, self.want_poses), stdin=subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=self.err, close_fds=True)
        self.fd = self.proc.stdout.fileno()
        try:
            import fcntl

            fcntl.fcntl(self.fd, 1031, _PIPE_BYTES)          # F_SETPIPE_SZ: fewer, larger reads
        except (ImportError, OSError):
            pass

    def _stop(self) -> None:
        if self.proc is not None:
            if self.proc.poll() is None:
                self.proc.kill()
            self.proc.wait()
            self.proc.stdout.close()
            self.proc = None

    def _report_cut(self) -> None:
        lay, rep = self.layout, self.ctx.report
        lost = lay.file_size - lay.packets_end
        rep.warn(f"{self.path.name}: the file is cut off at the end ({lay.cut}): read up to the cut, the "
                 f"{lay.n_packets:,} complete packet(s) before byte {lay.packets_end:,}; {lost:,} byte(s) ignored")
        rep.counts["aedat4_packets_read"] = lay.n_packets
        rep.counts["aedat4_bytes_ignored"] = lost

    @property
    def header(self) -> dict:
        """The file's description (the child's ``H`` frame), waited for on first use. When dv-processing refuses
        a file whose packet table is in it, the packets are read once more without the table (a readable copy),
        reported; if that fails too, its first refusal is the error."""
        if self._header is None:
            kind, payload = self._open_frames()
            if kind == b"X" and self.copy is None and self.layout is not None and self.layout.table_usable:
                first = (kind, bytes(payload))
                self._stop()
                self.copy = ReadableCopy(self.path, self.layout)
                self._start()
                kind, payload = self._open_frames()
                if kind != b"H":
                    kind, payload = first
                else:
                    self.ctx.report.warn(f"{self.path.name}: dv-processing cannot read its packet table ("
                                         f"{_one_line(json.loads(first[1]).get('error', '?'))}): its "
                                         f"{self.layout.n_packets:,} packet(s) were read without it")
            if kind != b"H":
                self._unexpected(kind, payload, "(file)")
            self._header = json.loads(bytes(payload))
        return self._header

    def _open_frames(self) -> tuple[bytes, memoryview]:
        """The child's first frame after loading the library (``H``, or ``X`` when it refuses the file)."""
        kind, payload = self._frame(START_TIMEOUT_S)
        if kind == b"S":
            kind, payload = self._frame(STALL_TIMEOUT_S + self.path.stat().st_size / OPEN_BYTES_PER_S)
        return kind, payload

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._stop()
        if self.copy is not None:
            self.copy.remove()
            self.copy = None
        self.err.close()

    # ------------------------------------------------------------------ frames
    def events(self):
        """Yield the event columns ``(t, x, y, p)`` frame by frame, then read the pose frames and the end."""
        self.header                                         # noqa: B018 - the H frame comes first
        while True:
            kind, payload = self._frame()
            if kind == b"E":
                n = struct.unpack_from("<Q", payload)[0]
                if len(payload) != 8 + 13 * n:
                    raise ImportFailure(self.path, self._where(), "events", "internal: malformed event frame")
                o = 8
                t = np.frombuffer(payload, np.int64, n, o)
                x = np.frombuffer(payload, np.int16, n, o + 8 * n)
                y = np.frombuffer(payload, np.int16, n, o + 10 * n)
                p = np.frombuffer(payload, np.int8, n, o + 12 * n)
                self.n_events += n
                yield t, x, y, p
            elif kind == b"P":
                n = struct.unpack_from("<Q", payload)[0]
                t = np.frombuffer(payload, np.int64, n, 8).copy()
                self.pose_parts.append((t, np.frombuffer(payload, np.float64, 7 * n, 8 + 8 * n).reshape(n, 7).copy()))
            elif kind == b"D":
                self.done = json.loads(bytes(payload))
                return
            else:
                self._unexpected(kind, payload, self._where())

    @property
    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.pose_parts:
            return np.zeros(0, np.int64), np.zeros((0, 7))
        return (np.concatenate([a for a, _ in self.pose_parts]), np.concatenate([b for _, b in self.pose_parts]))

    def _where(self) -> str:
        return f"event packets after {self.n_events:,} events" if self.n_events else "(file)"

    def _unexpected(self, kind: bytes, payload, record: str):
        if kind == b"X":
            msg = _one_line(json.loads(bytes(payload)).get("error", "?"))
            raise ImportFailure(self.path, record, "-", f"dv-processing cannot read it: {msg}")
        raise ImportFailure(self.path, record, "-", f"internal: unexpected frame {kind!r} from the AEDAT4 reader")

    def _frame(self, timeout: float | None = None) -> tuple[bytes, memoryview]:
        head = self._read(_FRAME.size, timeout or STALL_TIMEOUT_S)
        kind, n = _FRAME.unpack(head)
        if n > _MAX_FRAME:
            raise ImportFailure(self.path, self._where(), "-", "internal: oversized frame from the AEDAT4 reader")
        return kind, memoryview(self._read(n, STALL_TIMEOUT_S))

    def _read(self, n: int, timeout: float) -> bytearray:
        """Exactly ``n`` bytes from the child, or an ImportFailure on its end, crash or stall."""
        buf = bytearray(n)
        mv, got = memoryview(buf), 0
        deadline = time.monotonic() + timeout
        while got < n:
            ready, _, _ = select.select([self.fd], [], [], min(0.25, max(deadline - time.monotonic(), 0.0)))
            self.ctx.check_cancel()
            if not ready:
                if time.monotonic() >= deadline:
                    raise ImportFailure(self.path, self._where(), "-", f"dv-processing produced nothing for "
                                        f"{timeout:.3g} s (it spins on a corrupt packet): the file is damaged")
                continue
            k = os.readv(self.fd, [mv[got:]])
            if k == 0:
                self._ended()
            got += k
            deadline = time.monotonic() + timeout
        return buf

    def _ended(self):
        """The child closed the pipe before its last frame: a crash (signal) or an error exit."""
        try:
            rc = self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            rc = None
        if rc is not None and rc < 0:
            try:
                name = signal.Signals(-rc).name
            except ValueError:
                name = f"signal {-rc}"
            what = f"dv-processing crashed ({name}) reading it: the file is damaged"
        else:
            self.err.seek(0)
            lines = [ln for ln in self.err.read()[-4000:].decode("utf-8", "replace").splitlines() if ln.strip()]
            what = f"the AEDAT4 reader stopped (exit code {rc}){': ' + lines[-1].strip() if lines else ''}"
        raise ImportFailure(self.path, self._where(), "-", what)
