"""Silhouette slices of the space-time view: where they sit in time, how they are computed, and the
byte-bounded cache that lets a step of the span reuse the slices it still covers.

A slice is the objects' visible silhouettes at one time: one z-buffered render of the objects in view
(:meth:`~evpose.core.label.annotate.Annotator.annotate` with a request for the label map only: no
keypoints, depth or occlusion tests), each object's contours (:func:`~evpose.core.label.overlay.mask_contours`
of its pixels in the label map, the frame view's visible mask) and its signed distance field
(:func:`~evpose.core.views.spacetime_band.signed_field`, for the events' distance to the silhouettes). Slices sit on a fixed grid counted from the
window grid's origin (:func:`slice_times`), so when the span moves by a window most of them keep their time
and, with unchanged poses, their cache key.
"""
from __future__ import annotations

from collections import OrderedDict

import numpy as np

from evpose.core.label.annotate import Annotator
from evpose.core.label.labels import Request
from evpose.core.label.overlay import mask_contours
from evpose.core.label.windows import Window
from evpose.core.views.spacetime_band import SliceValue, signed_field

#: At most this many slices are kept (eight spans of the default twelve slices).
SLICE_CACHE_SLICES = 96
#: And at most this many bytes of contours, fields and keys (a slice of five YCB objects on a DAVIS346 holds
#: 2-10 kB of contours and 50-150 kB of int8 signed fields).
SLICE_CACHE_BYTES = 16 << 20
#: Bytes counted per cached slice and per object on top of the arrays (dict entry, tuples, names).
_ENTRY_OVERHEAD_B, _OBJECT_OVERHEAD_B = 200, 120

#: The labels a slice needs: the label map (visible masks) only.
SLICE_REQUEST = Request(keypoints=False, masks_visible=False, masks_full=False, label_map=True, depth=False,
                        amodal=False)


def slice_times(t0_us: int, span_us: int, n_slices: int, origin_us: int = 0) -> np.ndarray:
    """Times of the silhouette slices in ``[t0_us, t0_us + span_us)``, µs: the multiples of
    ``span_us / n_slices`` (at least 1 µs) counted from ``origin_us``, so they stay put while the span moves."""
    step = max(int(span_us) // max(int(n_slices), 2), 1)
    k0 = -(-(int(t0_us) - int(origin_us)) // step)
    times = int(origin_us) + step * np.arange(k0, k0 + max(int(n_slices), 2) + 1, dtype=np.int64)
    return times[times < int(t0_us) + int(span_us)]


def slice_key(t_us: int, T_cam_obj: np.ndarray) -> tuple:
    """Cache key of a slice: its time and the objects' poses ``T_cam_obj`` (K, 4, 4) (the contours depend on
    nothing else for one scene and camera)."""
    return int(t_us), np.ascontiguousarray(T_cam_obj, dtype=np.float64).tobytes()


def compute_slice(ann: Annotator, t_us: int, T_cam_obj: np.ndarray, T_base_cam: np.ndarray) -> list:
    """``[(name, in_view, contours, field)]`` of every object at ``t_us`` with these poses: contours (list of
    (M, 2) pixel polylines) of the object's visible pixels in one z-buffered render (``[]`` out of view) and their
    :class:`~evpose.core.views.spacetime_band.SignedField` (None when no pixel is visible)."""
    lab = ann.annotate(Window(-1, int(t_us), int(t_us) + 1, int(t_us)), pose=(T_cam_obj, T_base_cam, True))
    out = SliceValue()
    for k, o in enumerate(lab.objects):
        mask = lab.label_map == k if o.in_view and lab.label_map is not None else None
        contours = mask_contours(mask) if mask is not None else []
        field = signed_field(mask) if contours else None
        out.append((o.name, bool(o.in_view), contours, field))
    return out


def slice_nbytes(key: tuple, value: list) -> int:
    """Bytes a cached slice holds: the key's pose bytes, the contour and field arrays and a fixed overhead."""
    n = _ENTRY_OVERHEAD_B + len(key[1])
    for _name, _in_view, contours, field in value:
        n += _OBJECT_OVERHEAD_B + sum(int(c.nbytes) for c in contours) + (field.nbytes if field is not None else 0)
    return n


class SliceCache:
    """Least-recently-used slices by :func:`slice_key`, bounded by count and by bytes (:attr:`nbytes`).

    Parameters
    ----------
    max_slices : int
    max_bytes : int
        A slice larger than this alone is not kept.
    """

    def __init__(self, max_slices: int = SLICE_CACHE_SLICES, max_bytes: int = SLICE_CACHE_BYTES):
        self.max_slices = int(max_slices)
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict = OrderedDict()   # key -> (value, nbytes)
        self._nbytes = 0
        #: slices served from the cache / computed since construction (tests and the benchmark read them)
        self.hits = 0
        self.misses = 0

    @property
    def nbytes(self) -> int:
        """Bytes held (see :func:`slice_nbytes`), never above ``max_bytes``."""
        return self._nbytes

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, key) -> bool:
        return key in self._items

    def clear(self) -> None:
        self._items.clear()
        self._nbytes = 0

    def get(self, key):
        """The cached slice (marked recently used) or None."""
        item = self._items.get(key)
        if item is None:
            return None
        self._items.move_to_end(key)
        return item[0]

    def put(self, key, value: list) -> None:
        """Keep ``value`` under ``key``, dropping the least recently used slices beyond the bounds."""
        nb = slice_nbytes(key, value)
        old = self._items.pop(key, None)
        if old is not None:
            self._nbytes -= old[1]
        if nb > self.max_bytes:
            return
        self._items[key] = (value, nb)
        self._nbytes += nb
        while len(self._items) > self.max_slices or self._nbytes > self.max_bytes:
            _, (_, b) = self._items.popitem(last=False)
            self._nbytes -= b

    def slice(self, ann: Annotator, t_us: int, T_cam_obj: np.ndarray, T_base_cam: np.ndarray) -> list:
        """The slice at ``t_us`` with these poses: from the cache, else computed (:func:`compute_slice`) and kept."""
        key = slice_key(t_us, T_cam_obj)
        hit = self.get(key)
        if hit is not None:
            self.hits += 1
            return hit
        self.misses += 1
        value = compute_slice(ann, t_us, T_cam_obj, T_base_cam)
        self.put(key, value)
        return value
