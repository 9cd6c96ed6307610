"""Output errors of the operating system: free-space checks and one-line messages naming the path.

:data:`OUTPUT_ERRNOS` are the ``errno`` values meaning "the output cannot be written" (full disk,
quota, read-only file system, permission). :func:`with_path` attaches the path to an ``OSError``
that lacks one (``os.write`` errors name no file), :func:`os_error_from_hdf5` recovers the errno
HDF5 buries in its message, and :func:`describe_os_error` gives the one line the CLI prints.
:func:`ensure_free_space` refuses a write that a full disk would leave half done, before it starts.
"""
from __future__ import annotations

import errno
import os
import re
from pathlib import Path

__all__ = ["OUTPUT_ERRNOS", "free_bytes", "ensure_free_space", "with_path", "describe_os_error", "is_output_error",
           "os_error_from_hdf5"]

#: errno values of an output that cannot be written (as opposed to bad input).
OUTPUT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG})


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
