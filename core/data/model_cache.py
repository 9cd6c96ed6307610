"""Object models shared by the scenes of one process, by mesh file identity (issue 27.2).

A dataset's sequences share their objects (E-POSE: 18 sequences a scene, a few dozen YCB meshes for 306
sequences), and an export's driver and every Dask worker open scene after scene. Loading a YCB mesh with trimesh
and splitting its long edges for the rasteriser costs ~40-90 ms an object: 0.2-0.45 s a 5-object scene, paid once
per sequence by the driver (306 sequences: ~1-2 min of the driver's CPU, GIL-bound) and once per sequence by every
worker. The models are read-only (their arrays are write-protected), so scenes whose objects come from the same file
with the same scale and metadata share one :class:`~evpose.core.data.objects.ObjectModel`.

The key is the file's identity and state (real path, device, inode, size, modification time in ns) with the load
arguments: a mesh file replaced or edited between two scenes is loaded again. At most :data:`MAX_BYTES` of vertex
and face arrays are kept, least recently used first out; a model a scene still holds stays alive with that scene.
"""
from __future__ import annotations

import os
import threading
from collections import OrderedDict
from typing import Callable

__all__ = ["MAX_BYTES", "clear", "file_identity", "shared_model"]

#: Bytes of vertex and face arrays the cache keeps: ~40 objects of E-POSE's YCB meshes (0.75 MB each with its raster
#: variant: 12.5 k vertices, 25 k faces), small beside a worker's ~400 MB.
MAX_BYTES = 64 << 20

_lock = threading.Lock()
_models: OrderedDict = OrderedDict()
_bytes = 0


def file_identity(path) -> tuple | None:
    """``(real path, st_dev, st_ino, st_size, st_mtime_ns)`` of ``path``, or None when it cannot be
    stat-ed (the loader then raises its own error, naming the file)."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return os.path.realpath(path), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def _nbytes(model) -> int:
    return int(model.vertices_m.nbytes) + int(model.faces.nbytes)


def shared_model(key: tuple | None, load: Callable[[], object]):
    """The model cached under ``key``, or ``load()``'s (then kept). ``key`` None: not cached. Two threads
    asking for the same missing key may both load it (the first kept wins; both results are equal)."""
    global _bytes
    if key is None:
        return load()
    with _lock:
        model = _models.get(key)
        if model is not None:
            _models.move_to_end(key)
            return model
    model = load()                       # outside the lock: other scenes' lookups do not wait for a load
    with _lock:
        kept = _models.get(key)
        if kept is not None:
            return kept
        n = _nbytes(model)
        if n <= MAX_BYTES:
            _models[key] = model
            _bytes += n
            while _bytes > MAX_BYTES:
                _, old = _models.popitem(last=False)
                _bytes -= _nbytes(old)
    return model


def clear() -> None:
    """Forget every cached model."""
    global _bytes
    with _lock:
        _models.clear()
        _bytes = 0

