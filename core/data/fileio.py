"""Atomic file writing, ownership of temporary files, free-space checks and output-error messages.

Atomic writes
-------------
Data goes to a temporary file in the destination directory, is flushed and fsync'ed, then renamed
over the destination with :func:`os.replace` (atomic on POSIX and Windows), and the directory is
fsync'ed so the rename itself survives a power cut (:func:`atomic_path`).

Temporary files and staging folders
-----------------------------------
Every temporary name evpose makes carries the id of the process that made it,
``.<target name>.<pid>-<tag>.tmp`` (``tag``: hex), and :func:`atomic_path` holds an exclusive
``flock`` on its temporary file while it writes. A temporary file is *stale* -- left by a process
that was killed -- when no process holds its lock **and** its process id is not alive
(:func:`is_stale`); only stale files are removed (:func:`clean_stale_temps`), so a live writer in
another process is never disturbed. A recycled pid only delays the cleaning; it never removes a live file.

Output errors
-------------
:data:`OUTPUT_ERRNOS` are the ``errno`` values meaning "the output cannot be written" (full disk,
quota, read-only file system, permission). :func:`with_path` attaches the path to an ``OSError``
that lacks one (``os.write`` errors name no file) and :func:`describe_os_error` gives the one-line
message the CLI prints.
"""
from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
from pathlib import Path

__all__ = ["OUTPUT_ERRNOS", "TEMP_RE", "temp_path_for", "open_locked_temp", "fsync_dir", "fsync_path",
           "sync_filesystem", "atomic_path", "atomic_write_bytes", "atomic_write_text", "pid_alive", "lock_is_free",
           "is_stale", "clean_stale_temps", "free_bytes", "ensure_free_space", "with_path", "describe_os_error",
           "is_output_error", "os_error_from_hdf5"]

#: errno values of an output that cannot be written (as opposed to bad input).
OUTPUT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG})

#: Temporary names made by evpose: ``.<target>.<pid>-<hex tag>.tmp``.
TEMP_RE = re.compile(r"^\.(?P<target>.+)\.(?P<pid>\d+)-(?P<tag>[0-9a-f]+)\.tmp$")

#: Mode bits of a new file before the umask (the kernel applies the umask, as ``open(path, "w")``).
_NEW_FILE_MODE = 0o666


def _temp_name(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp")


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


def open_locked_temp(path) -> tuple[Path, int]:
    """Create a new hidden temporary file beside ``path`` and lock it (``flock`` exclusive).

    Returns ``(temp path, fd)``: the lock lasts until ``fd`` is closed, so :func:`clean_stale_temps`
    in another process leaves the file alone while this one lives. The file has the mode of a plain
    ``open(path, "w")`` (0o666 minus the umask).
    """
    import fcntl

    path = Path(path)
    while True:
        tmp = _temp_name(path)
        try:
            fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL, _NEW_FILE_MODE)
        except FileExistsError:       # pragma: no cover - 32 random bits collided
            continue
        except OSError as exc:
            raise with_path(exc, path) from None
        _flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return tmp, fd


def temp_path_for(path: Path) -> Path:
    """A unique hidden temporary name beside ``path`` (same filesystem, so rename is atomic).

    The file is created empty (mode of a plain ``open``) and not locked: its pid alone keeps
    :func:`clean_stale_temps` away while this process lives.
    """
    tmp, fd = open_locked_temp(path)
    os.close(fd)
    return tmp


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


# ------------------------------------------------------------------------------------------- atomic writes
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


# ------------------------------------------------------------------------------------------- free space
def free_bytes(path) -> int | None:
    """Bytes available to this user on the filesystem of ``path`` (its nearest existing ancestor);
    None when unknown."""
    p = Path(path)
    while True:
        try:
            st = os.statvfs(p)
            return int(st.f_bavail) * int(st.f_frsize)
        except FileNotFoundError:
            if p.parent == p:
                return None
            p = p.parent
        except (OSError, AttributeError):
            return None


def ensure_free_space(path, need_bytes: int, what: str = "") -> None:
    """Raise ``OSError(ENOSPC)`` naming ``path`` unless at least ``need_bytes`` are free on its
    filesystem (checked before a write that a full disk would leave half done)."""
    free = free_bytes(path)
    if free is None or free >= need_bytes:
        return
    mb = 1 << 20
    detail = f" for {what}" if what else ""
    raise OSError(errno.ENOSPC, f"No space left on device (needs about {need_bytes / mb:.1f} MB{detail}, "
                                f"{free / mb:.1f} MB free)", str(path))


# ------------------------------------------------------------------------------------------- messages
def with_path(exc: OSError, path, replace_temp=None) -> OSError:
    """``exc`` naming ``path`` when it names no file (or names the temporary file ``replace_temp``)."""
    if not isinstance(exc, OSError) or exc.errno is None:
        return exc
    if exc.filename is not None and (replace_temp is None or str(exc.filename) != str(replace_temp)):
        return exc
    what = exc.strerror if exc.strerror and "\n" not in exc.strerror else os.strerror(exc.errno)
    new = OSError(exc.errno, what, str(path))
    new.__traceback__ = exc.__traceback__
    return new


def is_output_error(exc: BaseException) -> bool:
    """An ``OSError`` meaning the output cannot be written (:data:`OUTPUT_ERRNOS`)."""
    return isinstance(exc, OSError) and exc.errno in OUTPUT_ERRNOS


_HINTS = {
    errno.ENOSPC: "free some space and rerun the same command (it resumes where it can)",
    errno.EDQUOT: "free some space and rerun the same command (it resumes where it can)",
    errno.EROFS: "choose a writable folder",
}


def describe_os_error(exc: OSError) -> str:
    """One line: ``PATH: problem (hint)`` -- for the CLI's error message."""
    what = exc.strerror or (os.strerror(exc.errno) if exc.errno else str(exc))
    where = exc.filename if exc.filename is not None else "(unknown path)"
    if exc.filename2 is not None:
        where = f"{where} -> {exc.filename2}"
    hint = _HINTS.get(exc.errno)
    line = f"{where}: {what}" + (f"; {hint}" if hint else "")
    return " ".join(line.split())


def os_error_from_hdf5(exc: BaseException, path) -> BaseException:
    """An h5py error as an ``OSError`` naming ``path`` when it carries an errno (h5py puts the C
    library's ``errno = N`` only into the message text); other exceptions unchanged."""
    if isinstance(exc, (OSError, RuntimeError, ValueError)):
        m = re.search(r"errno = (\d+)", str(exc))
        if m:                        # HDF5's own multi-line text: keep the errno, name the path
            code = int(m.group(1))
            return OSError(code, os.strerror(code), str(path))
    if isinstance(exc, OSError) and exc.errno is not None:
        return with_path(exc, path)
    return exc
