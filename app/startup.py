"""What ``evpose gui`` does before it imports Qt: malloc settings and the engine's imports (tracker issue 14;
why and the measurements: :mod:`evpose.app.memory`). Imports no Qt."""
from __future__ import annotations

import ctypes
import importlib
import sys

from evpose.core.data.heap import libc  # noqa: F401  (glibc, shared with the Dask workers' heap trim)

#: Allocations from this size on are mapped and unmapped on their own (glibc's ``M_MMAP_THRESHOLD``).
MMAP_THRESHOLD_BYTES = 256 << 10
#: glibc malloc arenas at most (``M_ARENA_MAX``).
ARENA_MAX = 2
_M_MMAP_THRESHOLD, _M_ARENA_MAX = -3, -8          # mallopt parameters (malloc.h)



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


