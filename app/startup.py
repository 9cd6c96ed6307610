"""What ``evpose gui`` does before it imports Qt: malloc settings and the engine's imports (tracker issue 14;
why and the measurements: :mod:`evpose.app.memory`). Imports no Qt."""
from __future__ import annotations

import ctypes
import ctypes.util
import importlib
import sys

#: Allocations from this size on are mapped and unmapped on their own (glibc's ``M_MMAP_THRESHOLD``).
MMAP_THRESHOLD_BYTES = 256 << 10
#: glibc malloc arenas at most (``M_ARENA_MAX``).
ARENA_MAX = 2
_M_MMAP_THRESHOLD, _M_ARENA_MAX = -3, -8          # mallopt parameters (malloc.h)

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


def configure_malloc() -> bool:
    """Set glibc's mmap threshold to :data:`MMAP_THRESHOLD_BYTES` and its arena limit to :data:`ARENA_MAX` for
    this process (threads started later use the limit). False off glibc (nothing changed)."""
    lib = libc()
    if lib is None or not hasattr(lib, "mallopt"):
        return False
    lib.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    lib.mallopt.restype = ctypes.c_int
    return bool(lib.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(lib.mallopt(_M_ARENA_MAX, ARENA_MAX))


#: Imported by :func:`preload_engine` before PySide6 (what the main window would import after it).
ENGINE_MODULES = ("numpy", "scipy.spatial", "scipy.optimize", "cv2", "h5py", "trimesh", "evpose.core.label.raster",
                  "evpose.core.label.annotate", "evpose.core.session.model", "evpose.core.views.frame",
                  "evpose.core.views.spacetime", "evpose.core.align.score", "evpose.core.data.scene")


def preload_engine() -> list[str]:
    """Import :data:`ENGINE_MODULES` unless PySide6 is already imported (then it is too late to matter).
    Returns the modules imported here."""
    if "PySide6" in sys.modules:
        return []
    done = []
    for name in ENGINE_MODULES:
        if name not in sys.modules:
            importlib.import_module(name)
            done.append(name)
    return done


def prepare_process() -> None:
    """What ``evpose gui`` does first: :func:`configure_malloc`, then :func:`preload_engine`."""
    configure_malloc()
    preload_engine()


