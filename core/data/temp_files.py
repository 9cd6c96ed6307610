"""evpose's temporary files: one naming scheme, locks, and the cleaning of what killed writers left.

Names
-----
Every temporary file evpose makes is named ``.<target name>.<pid>-<tag>.tmp`` (:data:`TEMP_RE`):
hidden, beside its target (same filesystem, so the final rename is atomic), carrying the id of the
process that made it and a per-process counter ``tag`` (hex). :func:`create_temp` makes one with
``O_EXCL`` (a name left by a dead process that had our pid is skipped, never reused).

Stale files
-----------
A temporary file is *stale* -- left by a process that was killed -- when its process id is not alive
**and** no process holds a ``flock`` on it (:func:`is_stale`). :func:`clean_stale_temps` removes only
stale files, so a live writer in another process is never disturbed; a recycled pid only delays the
cleaning. :func:`clean_temp_files` removes every evpose temporary file under a folder whose lock the
caller holds (an export folder), and never a file of another name (a user's ``.notes.tmp`` stays).
"""
from __future__ import annotations

import contextlib
import itertools
import os
import re
from pathlib import Path

from evpose.core.data.os_errors import with_path

__all__ = ["TEMP_RE", "create_temp", "open_locked_temp", "temp_path_for", "pid_alive", "lock_is_free", "is_stale",
           "clean_stale_temps", "clean_temp_files"]

#: Temporary names made by evpose: ``.<target>.<pid>-<hex tag>.tmp``.
TEMP_RE = re.compile(r"^\.(?P<target>.+)\.(?P<pid>\d+)-(?P<tag>[0-9a-f]+)\.tmp$")

#: Mode bits of a new file before the umask (the kernel applies the umask, as ``open(path, "w")``).
NEW_FILE_MODE = 0o666

_counter = itertools.count(1)      # next() is atomic in CPython: unique names across threads


def create_temp(path: Path, flags: int = os.O_WRONLY) -> tuple[Path, int]:
    """Create a new temporary file beside ``path`` (``O_CREAT | O_EXCL`` plus ``flags``; the mode of a
    plain ``open(path, "w")``). Returns ``(temp path, fd)``; an ``OSError`` names ``path``."""
    path = Path(path)
    while True:
        tmp = path.with_name(f".{path.name}.{os.getpid()}-{next(_counter):x}.tmp")
        try:
            return tmp, os.open(tmp, flags | os.O_CREAT | os.O_EXCL, NEW_FILE_MODE)
        except FileExistsError:      # left by a dead process that had our pid: take the next name
            continue
        except OSError as exc:
            raise with_path(exc, path) from None


def _flock(fd: int, flags: int) -> bool:
    """``flock(fd, flags)``; False when another open file holds the lock (non-blocking)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: no locks, the pid check alone decides
        return True
    try:
        fcntl.flock(fd, flags)
    except BlockingIOError:
        return False
    except OSError:       # a file system without flock: the pid check alone decides
        return True
    return True


def try_lock_folder(path) -> int | None:
    """An exclusive, non-blocking ``flock`` on the folder ``path``: the open descriptor (close it to release the
    lock), or None when another open file holds it (on a file system without flock the lock is not enforced)."""
    import fcntl

    fd = os.open(path, os.O_RDONLY)
    if _flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB):
        return fd
    os.close(fd)
    return None


def open_locked_temp(path) -> tuple[Path, int]:
    """Create a new temporary file beside ``path`` (read-write) and lock it (``flock`` exclusive).

    Returns ``(temp path, fd)``: the lock lasts until ``fd`` is closed, so :func:`clean_stale_temps`
    in another process leaves the file alone while this one lives.
    """
    import fcntl

    tmp, fd = create_temp(path, os.O_RDWR)
    _flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return tmp, fd


def temp_path_for(path: Path) -> Path:
    """A new, empty temporary file beside ``path``, not locked: its pid alone keeps
    :func:`clean_stale_temps` away while this process lives."""
    tmp, fd = create_temp(path)
    os.close(fd)
    return tmp


# ------------------------------------------------------------------------------------------- stale temps
def pid_alive(pid: int) -> bool:
    """Whether a process with this id exists on this machine (``kill(pid, 0)``)."""
    if pid <= 0:
        return False
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:     # exists, owned by another user
        return True
    except OSError:             # pragma: no cover - be conservative
        return True
    return True


def lock_is_free(path) -> bool:
    """True when no process holds a ``flock`` on ``path`` (a file or a folder); False when one does
    or when it cannot be opened."""
    import fcntl

    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        return _flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    finally:
        os.close(fd)            # releases the probe's own lock


def is_stale(path, pid: int) -> bool:
    """A temporary file or staging folder whose writer is gone: its pid is not alive and nobody
    holds its lock."""
    return not pid_alive(pid) and lock_is_free(path)


def clean_stale_temps(directory, target: str | None = None) -> list[Path]:
    """Remove the stale evpose temporary files (:data:`TEMP_RE`) directly in ``directory`` (only those
    of ``target`` when given); returns the removed paths. Files of live writers are kept."""
    removed = []
    try:
        it = os.scandir(directory)
    except OSError:
        return removed
    with it:
        for e in it:
            m = TEMP_RE.match(e.name)
            if m is None or (target is not None and m["target"] != target):
                continue
            try:
                if not e.is_file(follow_symlinks=False):
                    continue
            except OSError:
                continue
            if is_stale(e.path, int(m["pid"])):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(e.path)
                    removed.append(Path(e.path))
    return removed


def clean_temp_files(root) -> int:
    """Remove every evpose temporary file (:data:`TEMP_RE`) under ``root``, live or not: the caller
    holds the folder's lock, so no other evpose process writes there. Returns how many were removed."""
    root = Path(root)
    if not root.is_dir():
        return 0
    n = 0
    for dirpath, _dirs, files in os.walk(root):
        for f in files:
            if TEMP_RE.match(f):
                with contextlib.suppress(OSError):
                    os.unlink(os.path.join(dirpath, f))
                    n += 1
    return n
