"""Events in memory (:class:`EventArray`) and the errors of event files, with the file layout.

File layout (DSEC style, DESIGN section 4)::

    events/x  uint16   pixel column
    events/y  uint16   pixel row
    events/t  int64 or uint32, µs, relative to ``t_offset`` (0 when absent)
    events/p  uint8    polarity 0/1
    t_offset  int64 scalar, µs (optional)
    ms_to_idx int64/uint64 (optional): ms_to_idx[k] = first index with t >= k * 1000 µs (t relative to t_offset)

All times handed out are int64 microseconds of the absolute event clock (``t_offset`` added).
Windows are half-open ``[t0, t1)``, so consecutive windows tile the recording exactly.
:mod:`evpose.core.data.event_store` reads such a file (lazily, through the ms index of
:mod:`evpose.core.data.event_index`, validated once by :mod:`evpose.core.data.event_validation`);
:mod:`evpose.core.data.event_writer` writes one.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evpose.core.errors import InputError

__all__ = ["EventFileError", "Cancelled", "EventArray"]


class EventFileError(InputError):
    """A malformed event file; the message names the file and the HDF5 field at fault."""

    def __init__(self, path, field: str, message: str):
        self.path, self.field = str(path), field
        super().__init__(f"{path}: {field}: {message}")


class Cancelled(Exception):
    """Raised when a ``cancel()`` callback returned True; the operation left nothing behind."""


def _as_int_array(a, dtype, name, lo, hi, kinds="iu"):
    a = np.asarray(a)
    if a.dtype == dtype:
        return a
    if a.size == 0:
        return a.astype(dtype)
    if a.dtype.kind not in kinds:
        raise TypeError(f"{name}: expected integers, got dtype {a.dtype}")
    if a.dtype.kind != "b" and (int(a.min()) < lo or int(a.max()) > hi):
        raise ValueError(f"{name}: values outside [{lo}, {hi}]")
    return a.astype(dtype)


@dataclass(frozen=True, eq=False)
class EventArray:
    """A time-sorted batch of events (sortedness is the producer's duty; :class:`~evpose.core.data.event_writer.EventWriter` checks it).

    Attributes
    ----------
    x, y : np.ndarray of uint16
        Pixel column and row.
    t : np.ndarray of int64
        Absolute event-clock time, µs.
    p : np.ndarray of uint8
        Polarity, 0 or 1.
    """

    x: np.ndarray
    y: np.ndarray
    t: np.ndarray
    p: np.ndarray

    def __post_init__(self):
        cast = {"x": _as_int_array(self.x, np.uint16, "x", 0, 65535),
                "y": _as_int_array(self.y, np.uint16, "y", 0, 65535),
                "t": _as_int_array(self.t, np.int64, "t", -(2**63), 2**63 - 1),
                "p": _as_int_array(self.p, np.uint8, "p", 0, 1, kinds="iub")}
        n = len(cast["t"]) if cast["t"].ndim == 1 else -1
        for name, a in cast.items():
            if a.ndim != 1 or len(a) != n:
                raise ValueError(f"EventArray: {name} has shape {a.shape}, expected ({max(n, 0)},) like t")
            object.__setattr__(self, name, a)

    def __len__(self) -> int:
        return len(self.t)

    def __getitem__(self, sl) -> "EventArray":
        if isinstance(sl, (int, np.integer)):
            raise TypeError("EventArray: index with a slice or an index/boolean array, not a scalar")
        return EventArray(self.x[sl], self.y[sl], self.t[sl], self.p[sl])

    def __repr__(self) -> str:
        span = f", t=[{self.t[0]}, {self.t[-1]}] µs" if len(self) else ""
        return f"EventArray(n={len(self)}{span})"

    @staticmethod
    def empty() -> "EventArray":
        return EventArray(np.empty(0, np.uint16), np.empty(0, np.uint16), np.empty(0, np.int64), np.empty(0, np.uint8))

    @staticmethod
    def concatenate(parts) -> "EventArray":
        parts = list(parts)
        if not parts:
            return EventArray.empty()
        return EventArray(*(np.concatenate([getattr(e, f) for e in parts]) for f in "xytp"))
