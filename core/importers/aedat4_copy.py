"""A readable copy of an AEDAT4 file whose packet table is gone or damaged (:class:`ReadableCopy`).

``dv-processing`` reads a file through its packet table and refuses one whose table was cut off or does not
verify, while it reads a file without a table (``dataTablePosition = -1``, a recording interrupted before DV
wrote it) by scanning the packets. So such a file is copied up to its last complete packet
(:class:`~evpose.core.importers.aedat4_layout.Layout`) with that one header field set to -1, into the user cache
folder (never beside the source, which is never modified), read from there and deleted.
"""
from __future__ import annotations

import contextlib
import itertools
import os
import re
import struct
from pathlib import Path

from evpose.core.importers.aedat4_layout import Layout
from evpose.core.importers.failure import ImportFailure

def copy_folder() -> Path:
    """Where readable copies go: ``$XDG_CACHE_HOME/evpose/aedat4`` (never beside the source)."""
    from evpose.core.data.event_index import default_cache_dir

    return default_cache_dir().parent / "aedat4"


class ReadableCopy:
    """A copy of an AEDAT4 file up to its last complete packet with ``dataTablePosition = -1``, which
    dv-processing reads by scanning the packets. It lives in :func:`copy_folder` as ``NAME.<pid>-<tag>.aedat4``
    (dv-processing wants that suffix), locked while this process holds it, until :meth:`remove`; a copy left by
    a killed import (its process gone, no lock) is removed by the next one.
    """

    def __init__(self, source: Path, layout: Layout):
        folder = copy_folder()
        try:
            folder.mkdir(parents=True, exist_ok=True)
            _remove_stale_copies(folder)
            self.path, self.fd = _create_locked(folder, source.stem)
        except OSError as exc:
            raise ImportFailure(folder, "(readable copy)", "-", f"cannot create a copy of {source.name} to read "
                                f"({exc.strerror or exc})") from None
        try:
            self._write(source, layout)
        except OSError as exc:
            self.remove()
            raise ImportFailure(self.path, "(readable copy)", "-", f"cannot write a copy of {source.name} up to its "
                                f"last complete packet ({layout.packets_end:,} bytes): {exc.strerror or exc}") from None

    def _write(self, source: Path, layout: Layout) -> None:
        """The header with ``dataTablePosition = -1``, then the packets copied by the kernel (``sendfile``)."""
        with open(source, "rb") as src:
            head = bytearray(src.read(layout.first_packet))
            if layout.table_field is not None:
                struct.pack_into("<q", head, layout.table_field, -1)
            with open(self.fd, "wb", closefd=False) as dst:
                dst.write(head)
            pos = layout.first_packet
            while pos < layout.packets_end:
                sent = os.sendfile(self.fd, src.fileno(), pos, layout.packets_end - pos)
                if sent == 0:
                    raise OSError(0, f"{source} shrank while it was copied")
                pos += sent

    def remove(self) -> None:
        """Delete the copy and release its lock."""
        with contextlib.suppress(OSError):
            os.unlink(self.path)
        with contextlib.suppress(OSError):
            os.close(self.fd)


_COPY_RE = re.compile(r"^(?P<stem>.+)\.(?P<pid>\d+)-(?P<tag>[0-9a-f]+)\.aedat4$")
_tags = itertools.count(1)


def _create_locked(folder: Path, stem: str) -> tuple[Path, int]:
    """A new file ``folder/STEM.<pid>-<tag>.aedat4`` (``O_EXCL``), locked (``flock``); ``(path, fd)``."""
    import fcntl

    while True:
        path = folder / f"{stem}.{os.getpid()}-{next(_tags):x}.aedat4"
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o600)
        except FileExistsError:        # left by a dead process that had our pid: take the next name
            continue
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return path, fd


def _remove_stale_copies(folder: Path) -> None:
    """Remove the copies whose process is gone and which nobody holds locked."""
    from evpose.core.data.temp_files import is_stale

    for entry in os.scandir(folder):
        m = _COPY_RE.match(entry.name)
        if m is not None and entry.is_file(follow_symlinks=False) and is_stale(entry.path, int(m["pid"])):
            with contextlib.suppress(FileNotFoundError):
                os.unlink(entry.path)
