"""Opening user input files safely: regular files only, bounded sizes, never blocking.

A FIFO blocks ``open()`` until some writer appears, a device such as ``/dev/zero`` never ends, and a
file of absurd size costs minutes and gigabytes before any parser can complain. Every input that
evpose reads whole (trajectory CSV, mesh, manifest) is checked here first:

* :func:`open_regular` opens with ``O_NONBLOCK`` (a FIFO cannot block the open), ``fstat``-s the open
  descriptor (no race between the check and the read), refuses anything that is not a regular file,
  and refuses files larger than ``max_bytes`` before reading a byte;
* :func:`check_regular` does the same by path (for readers such as trimesh and h5py that open the
  file themselves); it follows symlinks, so a link to a regular file is fine.

Errors are :class:`InputFileError` whose message names the path and what is wrong with it; callers
prefix the file and field that named the path (e.g. ``scene.toml: objects[0].mesh: ...``).
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from evpose.core.errors import InputError

__all__ = ["InputFileError", "MAX_MANIFEST_BYTES", "MAX_TRAJECTORY_BYTES", "MAX_MESH_BYTES", "check_regular",
           "open_regular", "describe_kind"]

#: ``scene.toml`` and other small text documents: a manifest with thousands of objects is < 1 MB.
MAX_MANIFEST_BYTES = 64 * 2**20
#: Trajectory CSV: ~150 bytes a row, so 1 GiB is ~7 M poses (2 hours at 1 kHz), far beyond any
#: recording the CSV parser (~1 µs per field) handles in reasonable time.
MAX_TRAJECTORY_BYTES = 2**30
#: Meshes are loaded whole into memory by trimesh; 1 GiB is ~40 M triangles of binary PLY.
MAX_MESH_BYTES = 2**30


class InputFileError(InputError):
    """An input path that is not a readable regular file of sane size; the message names the path."""

    def __init__(self, path, message: str):
        self.path, self.reason = str(path), message
        super().__init__(f"{path}: {message}")


def describe_kind(mode: int) -> str:
    """What a non-regular ``st_mode`` is, in words ("a folder", "a FIFO (named pipe)", ...)."""
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _check_stat(path, st: os.stat_result, max_bytes: int | None) -> os.stat_result:
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(path, f"is {describe_kind(st.st_mode)}, expected a regular file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise InputFileError(path, f"file too large ({st.st_size:,} bytes; the limit is {max_bytes:,} bytes)")
    return st


def check_regular(path, *, max_bytes: int | None = None) -> os.stat_result:
    """``stat`` ``path`` (following symlinks) and refuse anything but a regular file of at most
    ``max_bytes`` bytes. Never opens the file, so FIFOs and devices cannot block or stream."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot access ({exc.strerror or exc})") from None
    return _check_stat(path, st, max_bytes)


def open_regular(path, mode: str = "rb", *, max_bytes: int | None = None, encoding: str | None = None,
                 newline: str | None = None):
    """Open a regular file for reading without blocking on FIFOs; see the module docstring.

    Parameters
    ----------
    path : str or Path
    mode : {"rb", "r"}
    max_bytes : int, optional
        Refuse larger files (checked on the open descriptor, before anything is read).
    encoding, newline
        For text mode, as for :func:`open`.

    Returns
    -------
    A file object positioned at the start.
    """
    if mode not in ("rb", "r"):
        raise ValueError(f"open_regular: mode must be 'rb' or 'r', got {mode!r}")
    path = Path(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOCTTY", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except OSError as exc:
        # ENXIO: a socket or a FIFO opened without a reader/writer; EACCES; ELOOP ...
        raise InputFileError(path, f"cannot open ({exc.strerror or exc})") from None
    try:
        _check_stat(path, os.fstat(fd), max_bytes)
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        f = os.fdopen(fd, mode, encoding=encoding if mode == "r" else None, newline=newline if mode == "r" else None)
    except BaseException:
        os.close(fd)
        raise
    return f
