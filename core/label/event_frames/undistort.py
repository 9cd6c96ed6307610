"""Events moved to undistorted pixels through a per-pixel lookup table, cached per camera (bounded in bytes)."""
from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from evpose.core.data.events import EventArray
from evpose.core.label.event_frames.accumulate import check_events, check_size, pixel_keys


class EventUndistorter:
    """Move events to undistorted integer pixels through a per-pixel lookup table.

    The table is computed once: every distorted pixel centre goes through ``camera.undistort_points``
    (iterative, accurate to ~1e-12 px) into the pinhole camera ``K_new`` (default ``camera.K``) and is
    rounded to the nearest pixel (ties to even). Pixels that land outside the output image, or where
    undistortion does not converge / lands beyond the monotonic distortion radius (``camera.pixel_rays``),
    map to -1 and their events are dropped. Each kept event moves to exactly one pixel, so counting the
    moved events conserves the counts (resampling a count image would not).

    Parameters
    ----------
    camera : CameraModel
        The distorted camera; events must lie on its ``width x height`` sensor.
    K_new : (3, 3) array, optional
        Intrinsics of the undistorted image, pixels (default ``camera.K``).
    size : (width, height), optional
        Size of the undistorted image, pixels (default the camera's).

    Attributes
    ----------
    lut : (H, W, 2) int32
        ``lut[v, u] = (u', v')``, the undistorted pixel of distorted pixel ``(u, v)``, or ``(-1, -1)``.
    width, height : int
        Output image size, pixels.
    identity : bool
        True when the camera has no distortion, ``K_new == K`` and the size is unchanged (``apply`` then
        returns the events unchanged).
    """

    def __init__(self, camera, K_new=None, size=None):
        self.in_width, self.in_height = camera.width, camera.height
        K = np.asarray(camera.K, np.float64)
        K_new = K if K_new is None else np.asarray(K_new, np.float64)
        self.K_new = K_new.copy()
        self.width, self.height = check_size(*(size if size is not None else (camera.width, camera.height)))
        W, H = self.in_width, self.in_height
        self.identity = (not camera.has_distortion and np.array_equal(K_new, K)
                         and (self.width, self.height) == (W, H))
        vv, uu = np.mgrid[0:H, 0:W]
        if self.identity:
            uv_new = np.stack([uu, vv], axis=-1).reshape(-1, 2)
            ok = np.ones(H * W, bool)
        else:
            uv = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
            uv_new = np.rint(camera.undistort_points(uv, K_new))
            ok = np.asarray(camera.pixel_rays()[1]).ravel().copy()
            with np.errstate(invalid="ignore"):
                ok &= ((uv_new[:, 0] >= 0) & (uv_new[:, 0] < self.width)
                       & (uv_new[:, 1] >= 0) & (uv_new[:, 1] < self.height))
            uv_new = np.where(ok[:, None], uv_new, -1).astype(np.int64)
        self._ok = ok
        self._x = np.where(ok, uv_new[:, 0], 0).astype(np.uint16)
        self._y = np.where(ok, uv_new[:, 1], 0).astype(np.uint16)
        lut = np.where(ok[:, None], uv_new, -1).astype(np.int32).reshape(H, W, 2)
        lut.setflags(write=False)
        self.lut = lut
        self.n_valid = int(ok.sum())

    @property
    def nbytes(self) -> int:
        """Bytes of the tables (13 per input pixel: 1.2 MB for a DAVIS346, 12 MB for 1280x720)."""
        return self.lut.nbytes + self._ok.nbytes + self._x.nbytes + self._y.nbytes

    def apply(self, ev: EventArray) -> EventArray:
        """Events moved to their undistorted pixels; events whose pixel maps outside are dropped.

        Order, times and polarities of the kept events are unchanged.

        Raises
        ------
        ValueError
            If an event lies outside the input sensor (naming ``x`` or ``y``).
        """
        check_events(ev, self.in_width, self.in_height)
        if self.identity or len(ev) == 0:
            return ev
        k = pixel_keys(ev, self.in_width, self.in_height, polarity=False)
        keep = self._ok[k]                     # (one pass: the output is as large as the input anyway)
        if keep.all():
            return EventArray(self._x[k], self._y[k], ev.t, ev.p)
        k = k[keep]
        return EventArray(self._x[k], self._y[k], ev.t[keep], ev.p[keep])

    def __repr__(self) -> str:
        return (f"EventUndistorter({self.in_width}x{self.in_height} -> {self.width}x{self.height}, "
                f"{self.n_valid} of {self.in_width * self.in_height} pixels kept)")


_CACHE: OrderedDict = OrderedDict()
_CACHE_LOCK = threading.Lock()
#: Bytes of tables kept by :func:`undistorter_for` (least recently used dropped first): a few HD cameras.
UNDISTORTER_CACHE_BYTES = 48 << 20


def _camera_key(camera, K_new, size) -> tuple:
    K_new = None if K_new is None else np.asarray(K_new, np.float64).tobytes()
    size = None if size is None else (int(size[0]), int(size[1]))
    return (np.asarray(camera.K, np.float64).tobytes(), np.asarray(camera.dist, np.float64).tobytes(),
            camera.width, camera.height, K_new, size)


def undistorter_for(camera, K_new=None, size=None) -> EventUndistorter:
    """The :class:`EventUndistorter` for these camera parameters, built once and reused.

    Keyed by value (``K``, ``dist``, sensor size, ``K_new``, ``size``), so equal cameras share one table even
    when they are different objects. Thread-safe; the most recently used tables are kept up to
    :data:`UNDISTORTER_CACHE_BYTES` (a table larger than that is returned, not kept).
    """
    key = _camera_key(camera, K_new, size)
    with _CACHE_LOCK:
        u = _CACHE.get(key)
        if u is not None:
            _CACHE.move_to_end(key)
            return u
    u = EventUndistorter(camera, K_new, size)      # built outside the lock (tens of ms)
    if u.nbytes > UNDISTORTER_CACHE_BYTES:
        return u
    with _CACHE_LOCK:
        u = _CACHE.setdefault(key, u)
        _CACHE.move_to_end(key)
        while _CACHE and undistorter_cache_nbytes() > UNDISTORTER_CACHE_BYTES:
            _CACHE.popitem(last=False)
    return u


def undistorter_cache_nbytes() -> int:
    """Bytes of the tables :func:`undistorter_for` keeps now."""
    return sum(u.nbytes for u in list(_CACHE.values()))


def clear_undistorter_cache() -> None:
    """Forget all cached undistorters."""
    with _CACHE_LOCK:
        _CACHE.clear()
