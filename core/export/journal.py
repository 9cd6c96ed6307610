"""The journal of an export: the windows whose outputs are complete, one JSON line each.

For the file formats a window is *complete* when the parent recorded it in ``OUT/.evpose/journal.jsonl``
(it does so only after the worker renamed the window's last file into place and the files were made
durable) **and** that last file exists; a rerun with the same configuration skips complete windows.
"""
from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

from evpose.core.data.os_errors import with_path

__all__ = ["Journal", "journal_line"]


def journal_line(rec: dict) -> str:
    """A window's journal line (without its newline). Workers encode their records' lines themselves
    (:func:`evpose.core.export.pool.run_worker_chunk`), so the export's driver only appends text."""
    return json.dumps(rec, separators=(",", ":"))


class Journal:
    """Append-only JSON-lines record of the windows whose outputs are complete (parent process only).
    A line is valid JSON or it is ignored (a crash or a full disk may cut the last line; the next
    append starts on a fresh line).

    :meth:`append` only buffers in memory: nothing reaches the file before :meth:`sync`, which the
    caller runs after making the files the lines name durable (``syncfs``), then writes the lines
    and fsyncs them. So a journaled window is on disk even when the journal is written before its
    files could be (a buffered file object would write its buffer whenever it fills).
    """

    def __init__(self, path: Path, durable: bool = True):
        self.path = Path(path)
        self.durable = durable
        self._fd: int | None = None
        self._buf = bytearray()
        self._since_sync = 0

    def load(self) -> dict[int, dict]:
        out = {}
        if not self.path.exists():
            return out
        with open(self.path, "rb") as f:
            for line in f:
                try:
                    rec = json.loads(line)
                    out[int(rec["i"])] = rec
                except (ValueError, KeyError, TypeError):
                    continue
        return out

    @property
    def pending(self) -> int:
        """Lines appended since the last :meth:`sync` (not in the file yet)."""
        return self._since_sync

    def append(self, rec: dict, line: str | None = None) -> None:
        """Buffer ``rec``'s line (``line``: :func:`journal_line` of ``rec``, when the worker encoded it)."""
        self._buf += (journal_line(rec) if line is None else line).encode()
        self._buf += b"\n"
        self._since_sync += 1

    def _open(self) -> int:
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666)
        size = os.fstat(fd).st_size
        if size > 0:
            with open(self.path, "rb") as r:
                r.seek(size - 1)
                if r.read(1) != b"\n":      # a cut last line: start on a fresh one
                    self._buf[:0] = b"\n"
        return fd

    def sync(self) -> None:
        """Write the buffered lines and fsync them (``durable``). On an error the lines are dropped
        (their windows are redone by the next run) and the error names the journal."""
        if not self._since_sync:
            return
        try:
            if self._fd is None:
                self._fd = self._open()
            view = memoryview(bytes(self._buf))
            self._buf.clear()
            self._since_sync = 0
            while view:
                view = view[os.write(self._fd, view):]
            if self.durable:
                os.fsync(self._fd)
        except OSError as exc:
            self._buf.clear()
            self._since_sync = 0
            self._close_fd()
            raise with_path(exc, self.path) from None

    def _close_fd(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None

    def close(self) -> None:
        try:
            self.sync()
        finally:
            self._buf.clear()
            self._since_sync = 0
            self._close_fd()
