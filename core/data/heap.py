"""Giving freed heap memory back to the kernel (glibc's ``malloc_trim``), for long-lived processes whose work
comes in bursts: a Dask worker between scenes, the app when idle. Without it glibc keeps the free pages of its
arenas (hundreds of MB after an export's chunks) and the process stays at its peak size."""
from __future__ import annotations

import ctypes
import ctypes.util

__all__ = ["libc", "trim_heap"]

_LIBC = None


def libc():
    """glibc, or None (another C library, or none found)."""
    global _LIBC
    if _LIBC is None:
        try:
            lib = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            lib.malloc_trim.argtypes = [ctypes.c_size_t]
            lib.malloc_trim.restype = ctypes.c_int
            _LIBC = lib
        except (OSError, AttributeError):
            _LIBC = False
    return _LIBC or None


def trim_heap() -> bool:
    """``malloc_trim(0)``: give the free pages of every malloc arena back to the kernel. False when the C
    library has no ``malloc_trim`` (not glibc) or nothing could be released."""
    lib = libc()
    return bool(lib.malloc_trim(0)) if lib is not None else False
