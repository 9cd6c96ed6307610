"""Atomic file writing: temp file, fsync, rename, fsync of the folder -- the one stack every writer uses.

Data goes to a temporary file beside its target (:mod:`evpose.core.data.temp_files`, one naming
scheme), and is renamed over the target with :func:`os.replace` (atomic on POSIX and Windows), so a
reader sees the old file or the new one, never a partial one. Two ways in:

* :func:`atomic_path`, :func:`atomic_write_bytes`, :func:`atomic_write_text`: one document that people
  and other processes may also write (``corrections.json``, ``scene.toml``, a trajectory). Stale
  temporary files of the target are removed first, the temporary file is locked while it is written,
  it is fsync'ed before the rename and the folder after (the rename survives a power cut), and the
  replaced file's mode is kept.
* :class:`AtomicBatch`, :func:`write_atomic`: the files of an output folder whose lock the caller holds
  (an export). The files of a batch are renamed together, in the order they were added; the fsyncs
  are optional (``durable``: a caller may instead sync the whole filesystem once per many files,
  :func:`sync_filesystem`); each file is logged in an ownership log
  (:class:`evpose.core.data.owned_log.OwnedLog`) before it appears under its name.

An ``OSError`` without a file name (a failed ``write``) is re-raised naming the target. A target that
exists and is neither a regular file nor a symbolic link (a device, a FIFO, a socket, a folder) is never
replaced (:func:`check_replaceable`): the write is refused naming it.
"""
from __future__ import annotations

import contextlib
import os
import stat
from pathlib import Path

from evpose.core.data.input_files import describe_kind
from evpose.core.data.os_errors import with_path
from evpose.core.data.temp_files import clean_stale_temps, create_temp, open_locked_temp
from evpose.core.errors import NotOursError

__all__ = ["fsync_dir", "fsync_path", "sync_filesystem", "rename_durably", "check_replaceable", "atomic_path",
           "atomic_write_bytes", "atomic_write_text", "AtomicBatch", "write_atomic"]


def check_replaceable(path) -> None:
    """Refuse (:class:`~evpose.core.errors.NotOursError`) to rename a file onto ``path`` when it exists and is
    neither a regular file nor a symbolic link: a device, a FIFO or a socket is never replaced."""
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return                      # absent (or unreadable: the rename itself reports it)
    if not (stat.S_ISREG(mode) or stat.S_ISLNK(mode)):
        raise NotOursError(f"{path}: exists and is {describe_kind(mode)}, not a regular file; evpose never replaces it")


# ------------------------------------------------------------------------------------------- syncing
def fsync_dir(directory: Path) -> None:
    """Flush a directory entry (or a file's data) to disk; a no-op where it cannot be opened."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def fsync_path(path) -> None:
    """fsync a file's data; errors (``ENOSPC`` from delayed allocation, ``EIO``) are raised with the path."""
    try:
        with open(path, "rb+") as f:
            os.fsync(f.fileno())
    except OSError as exc:
        raise with_path(exc, path) from None


def sync_filesystem(path) -> None:
    """Flush every dirty file of the filesystem holding ``path`` (Linux ``syncfs``; ``os.sync``
    elsewhere): one commit for many files instead of one fsync per file."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        fd = os.open(path, os.O_RDONLY)
        try:
            if libc.syncfs(fd) == 0:
                return
        finally:
            os.close(fd)
    except (OSError, AttributeError):
        pass
    os.sync()


def rename_durably(src, dst) -> None:
    """Rename ``src`` (a file or a folder whose content is on disk already, e.g. after
    :func:`sync_filesystem`) to ``dst``, then fsync the folder(s) holding them: the new name survives a power
    cut. An existing ``dst`` is replaced as :func:`os.rename` does (an empty folder by a folder)."""
    os.rename(src, dst)
    for d in dict.fromkeys([Path(dst).parent, Path(src).parent]):
        fsync_dir(d)


# ------------------------------------------------------------------------------------------- one document
@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path to write; on success it replaces ``path`` atomically.

    Stale temporary files of ``path`` left by killed processes are removed first. The temporary
    file is locked while the block runs and removed if the block raises (including
    ``KeyboardInterrupt``), so no partial file is ever left at ``path`` or beside it. The writer
    inside the block must close the file; it is fsync'ed here before the rename, and the directory
    after it. An ``OSError`` without a file name (a failed ``write``) is re-raised naming ``path``.
    """
    path = Path(path)
    clean_stale_temps(path.parent, path.name)
    tmp, lock_fd = open_locked_temp(path)
    try:
        yield tmp
        fsync_path(tmp)
        # keep the mode of the file replaced (the temp file already has the umask default)
        with contextlib.suppress(OSError):
            os.chmod(tmp, os.stat(path).st_mode & 0o7777)
        check_replaceable(path)
        os.replace(tmp, path)
        fsync_dir(path.parent)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError):
            raise with_path(exc, path, replace_temp=tmp) from None
        raise
    finally:
        os.close(lock_fd)


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def atomic_write_text(path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode(encoding))


# ------------------------------------------------------------------------------------------- batches
class AtomicBatch:
    """Write several files atomically: each goes to a temporary file beside its target, is fsync'ed
    (``durable``), and only when all are written are they renamed onto their targets, followed by one
    fsync of each directory. A reader never sees a partial file; if anything raises (including
    KeyboardInterrupt) every temp file is removed and no target is touched. Files are renamed in the
    order they were added, so the last one added appears last.

    The temporary files are not locked (the caller holds the output folder's lock); ``log`` (an
    :class:`~evpose.core.data.owned_log.OwnedLog`) records each file, by the size and modification
    time it keeps through the rename, before the file appears under its name.
    """

    def __init__(self, durable: bool = True, log=None):
        self.durable = durable
        self.log = log
        self._pending: list[tuple[Path, Path]] = []
        self._stats: list[tuple[Path, int, int]] = []

    def add(self, path, data) -> None:
        path = Path(path)
        tmp, fd = create_temp(path)
        self._pending.append((tmp, path))
        try:
            view = memoryview(data)
            while view:
                k = os.write(fd, view)
                view = view[k:]
            if self.durable:
                os.fsync(fd)
            if self.log is not None:
                st = os.fstat(fd)          # size and mtime stay as they are through the rename
                self._stats.append((path, st.st_size, st.st_mtime_ns))
        except OSError as exc:
            raise with_path(exc, path) from None     # os.write errors name no file
        finally:
            os.close(fd)

    def commit(self) -> None:
        dirs = []
        if self.log is not None:       # logged before they appear under their names
            self.log.files(self._stats)
            self._stats = []
        for _tmp, path in self._pending:     # nothing renamed when one target may not be replaced
            check_replaceable(path)
        for tmp, path in self._pending:
            try:
                os.replace(tmp, path)
            except OSError as exc:
                raise with_path(exc, path, replace_temp=tmp) from None
            if path.parent not in dirs:
                dirs.append(path.parent)
        self._pending = []
        if self.durable:
            for d in dirs:
                fsync_dir(d)

    def discard(self) -> None:
        for tmp, _ in self._pending:
            with contextlib.suppress(OSError):
                tmp.unlink()
        self._pending = []
        self._stats = []

    def __enter__(self) -> "AtomicBatch":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            try:
                self.commit()
            except BaseException:
                self.discard()
                raise
        else:
            self.discard()


def write_atomic(path, data: bytes, durable: bool = True, log=None) -> Path:
    """One file through :class:`AtomicBatch` (logged in ``log`` before it appears)."""
    with AtomicBatch(durable, log) as b:
        b.add(path, data)
    return Path(path)
