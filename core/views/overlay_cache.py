"""Overlay results computed ahead of the user (stepping, playback), bounded in bytes.

The overlay stage of a frame (:meth:`evpose.core.views.frame.FrameComputer.overlay_stages`:
rasterised labels, masks, contours, boxes, scores) is the expensive part of a frame. While its worker
is idle, :meth:`~evpose.core.views.frame.FrameComputer.prefetch_overlays` computes the next window
in the direction and step of the user's motion and keeps it here; when the user gets there, the
result is taken from here instead of being computed.

A result is reused only for a request that would compute exactly the same thing: same scene (manifest),
same corrections (their canonical JSON: offset, skew, hand-eye, object poses, review marks), same
window and same overlay settings. Anything else misses and is computed as usual.
"""
from __future__ import annotations

import json
from collections import OrderedDict

import numpy as np

__all__ = ["OverlayCache", "overlay_key", "OVERLAY_CACHE_BYTES"]

#: Default byte budget: ~1.5 MB per 5-object DAVIS346 frame (label map, depth, masks, RGBA), so a
#: handful of windows ahead.
OVERLAY_CACHE_BYTES = 16 << 20


def overlay_key(req) -> tuple:
    """What the overlay stage of a :class:`~evpose.core.views.frame.FrameRequest` depends on."""
    scene, view = req.scene, req.view
    w = view.window()
    corrections = json.dumps(scene.corrections.canonical(), sort_keys=True)
    # the event store object itself (held by the key, so its id cannot be reused by another scene's)
    return (scene.events, str(scene.manifest.path), corrections, w.t0_us, w.t1_us, tuple(view.overlays),
            tuple(sorted(view.hidden)), float(view.mask_alpha))


def _nbytes(obj, seen: set, depth: int = 0) -> int:
    """Bytes of the numpy arrays reachable from ``obj`` through dataclass fields, lists, tuples and dicts."""
    if obj is None or id(obj) in seen or depth > 4:
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if isinstance(obj, dict):
        return sum(_nbytes(v, seen, depth + 1) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(_nbytes(v, seen, depth + 1) for v in obj)
    if hasattr(obj, "__dict__"):
        return sum(_nbytes(v, seen, depth + 1) for v in vars(obj).values())
    return 0


class OverlayCache:
    """Least-recently-used results keyed by :func:`overlay_key`, at most ``max_bytes`` of arrays.

    Not thread-safe: one per worker (the overlay worker computes and reads it on its own thread).
    """

    def __init__(self, max_bytes: int = OVERLAY_CACHE_BYTES):
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict = OrderedDict()      # key -> (result, nbytes)
        self.nbytes = 0
        self.hits = 0

    def __contains__(self, key) -> bool:
        return key in self._items

    def __len__(self) -> int:
        return len(self._items)

    def get(self, key):
        """The result stored under ``key`` (now the most recently used), or None."""
        item = self._items.get(key)
        if item is None:
            return None
        self._items.move_to_end(key)
        self.hits += 1
        return item[0]

    def put(self, key, result) -> None:
        """Store ``result``; the least recently used results go until the budget holds (a result larger
        than the whole budget is not stored)."""
        size = _nbytes(result, set())
        if size > self.max_bytes:
            return
        if key in self._items:
            self.nbytes -= self._items.pop(key)[1]
        self._items[key] = (result, size)
        self.nbytes += size
        while self.nbytes > self.max_bytes:
            _, (_, n) = self._items.popitem(last=False)
            self.nbytes -= n

    def clear(self) -> None:
        self._items.clear()
        self.nbytes = 0
