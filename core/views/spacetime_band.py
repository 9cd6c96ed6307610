"""Each event's distance to the nearest projected silhouette at its own time, and that silhouette's object: what
the space-time view needs to draw the events near the silhouettes (a band) in their object's colour and dim the
rest, so that "do events and model move together?" reads at a glance.

Per silhouette slice and object, a *signed field*: the distance (px) to the object's silhouette edge, > 0 outside
and < 0 inside, from two distance transforms of its visible mask (the label map of the slice), kept in a crop
around the silhouette, clipped to +-``FIELD_CLIP_PX`` and quantised to ``1 / FIELD_SCALE`` px (int8). Per slice
the objects' fields are merged into the nearest object's field; an event between two slices takes the linear
interpolation in time of the two slices' signed distances when both name the same nearest object (a signed
distance interpolates correctly across a moving edge, an unsigned one would not), else the nearer slice's.
"""
from __future__ import annotations

import weakref
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

#: Signed distances are kept within +- this many px (beyond: "far").
FIELD_CLIP_PX = 16.0
#: int8 units per px (quarter pixels: +-16 px fits in +-64).
FIELD_SCALE = 4.0
#: The int8 value meaning "no silhouette within reach" in a merged field.
FAR = np.int8(127)
#: Default band half-width (px) of the events drawn in their object's colour.
DEFAULT_BAND_PX = 3.0
#: Bytes of merged fields kept by :class:`MergedFieldCache` (180 kB each on a DAVIS346: 46 of them, two spans
#: and the prefetch; 1.8 MB each on a 1280 x 720 sensor).
MERGED_CACHE_BYTES = 8 << 20


@dataclass(frozen=True)
class SignedField:
    """An object's signed distance to its silhouette edge in a crop of the image: ``sd[r, c]`` (int8, units of
    ``1 / FIELD_SCALE`` px, > 0 outside, < 0 inside) is pixel ``(u, v) = (x0 + c, y0 + r)``."""

    x0: int
    y0: int
    sd: np.ndarray

    @property
    def nbytes(self) -> int:
        return int(self.sd.nbytes)


def signed_field(mask: np.ndarray, clip_px: float = FIELD_CLIP_PX) -> SignedField | None:
    """The :class:`SignedField` of a visible mask (H, W) bool (None when empty). A pixel just outside the mask is
    +0.5 px from the edge, one just inside -0.5 px (the edge lies between pixel centres)."""
    import cv2

    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    if len(rows) == 0:
        return None
    H, W = mask.shape
    m = int(np.ceil(clip_px)) + 1
    y0, y1 = max(int(rows[0]) - m, 0), min(int(rows[-1]) + m + 1, H)
    x0, x1 = max(int(cols[0]) - m, 0), min(int(cols[-1]) + m + 1, W)
    crop = mask[y0:y1, x0:x1].astype(np.uint8)
    outside = (crop == 0).astype(np.uint8)
    d_out = cv2.distanceTransform(outside, cv2.DIST_L2, 5)      # outside pixels: to the nearest mask pixel
    if outside.any():
        d_in = cv2.distanceTransform(crop, cv2.DIST_L2, 5)      # inside pixels: to the nearest outside pixel
    else:
        d_in = np.full(crop.shape, clip_px + 1.0, np.float32)
    sd = np.where(crop > 0, -(d_in - 0.5), d_out - 0.5)
    q = np.clip(np.rint(sd * FIELD_SCALE), -clip_px * FIELD_SCALE, clip_px * FIELD_SCALE).astype(np.int8)
    return SignedField(x0, y0, q)


def merged_field(fields, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The nearest object's signed distance and index per pixel, ``(sd (H, W) int8, obj (H, W) int8)``, from
    ``fields`` ``[(object index, SignedField)]``; ``FAR`` and -1 where no object is within reach."""
    sd = np.full((height, width), FAR, np.int8)
    obj = np.full((height, width), -1, np.int8)
    for k, f in fields:
        h, w = f.sd.shape
        region = sd[f.y0:f.y0 + h, f.x0:f.x0 + w]
        closer = np.abs(f.sd.astype(np.int16)) < np.abs(region.astype(np.int16))
        region[closer] = f.sd[closer]
        obj[f.y0:f.y0 + h, f.x0:f.x0 + w][closer] = k
    return sd, obj


def event_edge_distance(x: np.ndarray, y: np.ndarray, t: np.ndarray, slice_t: np.ndarray, fields
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Each event's distance (px, float32; inf when no silhouette is within reach) to the nearest silhouette at
    its time, and that object's index (int8, -1 none).

    Parameters
    ----------
    x, y : (N,) pixel coordinates of the events
    t : (N,) event times in increasing order (as events are stored), any unit shared with ``slice_t``
    slice_t : (S,) increasing slice times
    fields : (S, H, W, 2) int8 array or sequence of S (H, W, 2) arrays
        The slices' :func:`merged_field` (signed distance, object) side by side (see :func:`stacked_fields` and
        :class:`MergedFieldCache`).
    """
    n, S = len(x), len(slice_t)
    if n == 0 or S == 0:
        return np.full(n, np.inf, np.float32), np.full(n, -1, np.int8)
    flats = [np.ascontiguousarray(f).view(np.int16).reshape(-1) for f in fields]   # (sd, obj) pairs at once
    W = fields[0].shape[1]
    pix = np.asarray(y, np.int32) * W + np.asarray(x, np.int32)
    p0 = np.empty(n, np.int16)
    p1 = np.empty(n, np.int16)
    a = np.zeros(n, np.float32)
    if S == 1:
        p0[:] = p1[:] = flats[0][pix]
    else:
        # events sorted by time: slice interval j holds a contiguous run (the first and last take the ends too)
        bounds = np.concatenate([[0], np.searchsorted(t, slice_t[1:-1], side="left"), [n]])
        ts = np.asarray(slice_t, np.float64)
        for j in range(S - 1):
            lo, hi = int(bounds[j]), int(bounds[j + 1])
            if hi <= lo:
                continue
            p0[lo:hi] = flats[j][pix[lo:hi]]
            p1[lo:hi] = flats[j + 1][pix[lo:hi]]
            a[lo:hi] = np.clip((t[lo:hi] - ts[j]) / (ts[j + 1] - ts[j]), 0.0, 1.0)
    q0, q1 = p0.view(np.int8).reshape(n, 2), p1.view(np.int8).reshape(n, 2)
    s0, o0 = q0[:, 0].astype(np.float32), q0[:, 1]
    s1, o1 = q1[:, 0].astype(np.float32), q1[:, 1]
    later = a >= 0.5
    same = o0 == o1
    d = np.where(same, s0 + a * (s1 - s0), np.where(later, s1, s0))
    np.abs(d, out=d)
    d *= 1.0 / FIELD_SCALE
    k = np.where(same | ~later, o0, o1)
    d[k < 0] = np.inf
    return d, k


def stacked_fields(merged: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The slices' merged fields ``[(sd, obj)]`` as one (S, H, W, 2) int8 array for :func:`event_edge_distance`."""
    return np.stack([np.stack([sd, obj], axis=-1) for sd, obj in merged])


class SliceValue(list):
    """One silhouette slice ``[(name, in_view, contours, field)]`` (a list that can be weakly referenced): the
    caches derived from slices (:class:`MergedFieldCache`, :class:`~evpose.core.views.spacetime_surface.SurfaceCache`)
    recognise a slice by identity without keeping it alive, so the slice cache's byte bound holds for everything
    a slice carries."""

    __slots__ = ("__weakref__",)


def value_ref(value):
    """A weak reference to ``value`` (a :class:`SliceValue`); any other object is held by a strong one."""
    try:
        return weakref.ref(value)
    except TypeError:
        return lambda: value


def drop_dead(items: OrderedDict) -> int:
    """Remove the entries of a derived cache whose slice values are gone (``entry[0]`` a :func:`value_ref`, or a
    tuple of them; ``entry[1]`` the derived data); returns the bytes of the arrays removed."""
    dead = [k for k, v in items.items() if any(r() is None for r in (v[0] if isinstance(v[0], tuple) else (v[0],)))]
    nb = 0
    for k in dead:
        nb += derived_nbytes(items.pop(k)[1])
    return nb


def derived_nbytes(value) -> int:
    """Bytes of the arrays in ``value`` (an array, or a tuple / list of them)."""
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, (tuple, list)):
        return sum(derived_nbytes(v) for v in value)
    return 0


class MergedFieldCache:
    """The merged fields of silhouette slices, ``(H, W, 2)`` int8 (signed distance, object), by slice value
    (the cached slice list itself: the same object for the same time and poses; recognised by identity, not
    kept alive: the fields of a slice the slice cache dropped go with it) and hidden objects; least recently used
    first out beyond ``max_bytes`` (:attr:`nbytes`; a field larger than that alone is not kept)."""

    def __init__(self, max_bytes: int = MERGED_CACHE_BYTES):
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict = OrderedDict()
        self.nbytes = 0

    def __len__(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        self._items.clear()
        self.nbytes = 0

    def merged(self, value: list, names: list, hidden, height: int, width: int) -> np.ndarray:
        """The merged field of one slice's value ``[(name, in_view, contours, field)]`` without ``hidden``."""
        key = (id(value), frozenset(hidden))
        hit = self._items.get(key)
        if hit is not None and hit[0]() is value:
            self._items.move_to_end(key)
            return hit[1]
        shown = {n: k for k, n in enumerate(names) if n not in hidden}
        sd, obj = merged_field([(shown[n], f) for n, _, _, f in value if f is not None and n in shown], height, width)
        pair = np.stack([sd, obj], axis=-1)
        self.nbytes -= drop_dead(self._items)     # fields of slices the slice cache dropped
        old = self._items.pop(key, None)          # a reused id of a dead value
        if old is not None:
            self.nbytes -= old[1].nbytes
        if pair.nbytes <= self.max_bytes:
            self._items[key] = (value_ref(value), pair)   # not kept alive by this cache; a reused id fails the check
            self.nbytes += pair.nbytes
        while self.nbytes > self.max_bytes:
            self.nbytes -= self._items.popitem(last=False)[1][1].nbytes
        return pair


def events_band(ev, slices: list, names: list, hidden, width: int, height: int,
                cache: MergedFieldCache | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`event_edge_distance` of the events ``ev`` (an ``EventArray``) against the silhouette slices
    ``[(t_us, [(name, in_view, contours, field)])]`` (time order), the objects in ``hidden`` left out; merged
    fields come from (and go to) ``cache`` when given."""
    if not slices or len(ev) == 0:
        return np.full(len(ev), np.inf, np.float32), np.full(len(ev), -1, np.int8)
    cache = cache if cache is not None else MergedFieldCache()
    fields = [cache.merged(value, names, hidden, height, width) for _, value in slices]
    t = np.array([s[0] for s in slices], np.int64)
    return event_edge_distance(ev.x, ev.y, ev.t, t, fields)
