"""The user's document: corrections on top of a scene, saved as ``corrections.json``.

What is corrected (all optional, identity by default):

* ``offset_us`` (int) and ``skew_ppm`` (float): added to the scene's clock prior;
* per-object pose deltas ``dT_base`` (4x4, base frame): ``T_base_obj' = dT_base @ T_base_obj``;
* a hand-eye delta ``dT_cam`` (4x4, camera frame): ``T_base_cam' = T_base_cam @ dT_cam``;
* review marks over event-time intervals ``[t0_us, t1_us)``: verified / rejected / flagged.

The raw data is never touched. Saving is atomic (temp file, fsync, rename). JSON numbers are
written with Python's shortest round-trip repr, so offsets of 10 s and skews of 1000 ppm come
back bit-identical.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .fileio import atomic_write_text
from .geometry import GeometryError, validate_T

CORRECTIONS_FORMAT = "evpose-corrections/1"
CORRECTIONS_FILENAME = "corrections.json"
REVIEW_STATUSES = ("verified", "rejected", "flagged")
#: Tolerance for deltas read back from JSON: they were orthonormal when written.
_DELTA_TOLERANCE = 1e-6


class CorrectionsError(ValueError):
    """A corrections file that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class ReviewMark:
    """A review decision over the event-time interval ``[t0_us, t1_us)``.

    ``object`` is None for a mark that covers every object.
    """

    t0_us: int
    t1_us: int
    status: str
    note: str = ""
    object: str | None = None

    def __post_init__(self):
        if self.status not in REVIEW_STATUSES:
            raise ValueError(f"status must be one of {REVIEW_STATUSES}, got {self.status!r}")
        if int(self.t1_us) <= int(self.t0_us):
            raise ValueError(f"review interval must have t1_us > t0_us, got [{self.t0_us}, {self.t1_us})")
        object.__setattr__(self, "t0_us", int(self.t0_us))
        object.__setattr__(self, "t1_us", int(self.t1_us))

    def covers(self, t_us: int) -> bool:
        return self.t0_us <= t_us < self.t1_us

    def to_json(self) -> dict:
        d = {"t0_us": self.t0_us, "t1_us": self.t1_us, "status": self.status}
        if self.note:
            d["note"] = self.note
        if self.object is not None:
            d["object"] = self.object
        return d


@dataclass(eq=False)
class Corrections:
    """Mutable correction document with change notification.

    Mutate only through the ``set_*``/``*_review`` methods (normally via :mod:`core.history`
    commands) so listeners are told what changed: ``"clock"``, ``"object:<name>"``,
    ``"hand_eye"`` or ``"reviews"``.
    """

    offset_us: int = 0
    skew_ppm: float = 0.0
    object_deltas: dict[str, np.ndarray] = field(default_factory=dict)
    hand_eye_delta: np.ndarray = field(default_factory=lambda: np.eye(4))
    reviews: list[ReviewMark] = field(default_factory=list)
    scene_name: str | None = None

    def __post_init__(self):
        self._listeners: list[Callable[[str], None]] = []

    # ------------------------------------------------------------------ observation
    def subscribe(self, callback: Callable[[str], None]) -> Callable[[], None]:
        """Call ``callback(what)`` after every change; returns an unsubscribe function."""
        self._listeners.append(callback)
        return lambda: self._listeners.remove(callback) if callback in self._listeners else None

    def _changed(self, what: str) -> None:
        for cb in list(self._listeners):
            cb(what)

    # ------------------------------------------------------------------ accessors
    def object_delta(self, name: str) -> np.ndarray:
        """``dT_base`` of an object (identity when uncorrected); a copy."""
        d = self.object_deltas.get(name)
        return np.eye(4) if d is None else d.copy()

    def get(self, key: tuple):
        """Value at a command key: ``("offset_us",)``, ``("skew_ppm",)``, ``("object", name)``,
        ``("hand_eye",)`` or ``("reviews",)``."""
        kind = key[0]
        if kind == "offset_us":
            return self.offset_us
        if kind == "skew_ppm":
            return self.skew_ppm
        if kind == "object":
            return self.object_delta(key[1])
        if kind == "hand_eye":
            return self.hand_eye_delta.copy()
        if kind == "reviews":
            return list(self.reviews)
        raise KeyError(key)

    def set(self, key: tuple, value) -> None:
        """Set the value at a command key (see :meth:`get`) and notify listeners."""
        kind = key[0]
        if kind == "offset_us":
            self.offset_us = _as_int_us(value, "offset_us")
            self._changed("clock")
        elif kind == "skew_ppm":
            v = float(value)
            if not math.isfinite(v):
                raise ValueError("skew_ppm must be finite")
            self.skew_ppm = v
            self._changed("clock")
        elif kind == "object":
            T = np.array(value, dtype=np.float64)
            if np.allclose(T, np.eye(4), rtol=0, atol=0):
                self.object_deltas.pop(key[1], None)
            else:
                self.object_deltas[key[1]] = T
            self._changed(f"object:{key[1]}")
        elif kind == "hand_eye":
            self.hand_eye_delta = np.array(value, dtype=np.float64)
            self._changed("hand_eye")
        elif kind == "reviews":
            self.reviews = list(value)
            self._changed("reviews")
        else:
            raise KeyError(key)

    def review_status(self, t_us: int, obj: str | None = None) -> str | None:
        """Status of the most recently added mark covering ``t_us`` (for ``obj`` or all objects)."""
        for mark in reversed(self.reviews):
            if mark.covers(t_us) and (mark.object is None or obj is None or mark.object == obj):
                return mark.status
        return None

    def is_identity(self) -> bool:
        return (self.offset_us == 0 and self.skew_ppm == 0.0 and not self.object_deltas
                and np.array_equal(self.hand_eye_delta, np.eye(4)) and not self.reviews)

    def copy(self) -> "Corrections":
        return Corrections.from_json(self.to_json())

    # ------------------------------------------------------------------ JSON
    def to_json(self) -> dict:
        return {
            "format": CORRECTIONS_FORMAT,
            "scene": self.scene_name,
            "clock": {"offset_us": int(self.offset_us), "skew_ppm": float(self.skew_ppm)},
            "objects": {name: {"dT_base": T.tolist()} for name, T in sorted(self.object_deltas.items())},
            "hand_eye": {"dT_cam": self.hand_eye_delta.tolist()},
            "reviews": [m.to_json() for m in self.reviews],
        }

    @classmethod
    def from_json(cls, data: dict, source: str = "corrections.json") -> "Corrections":
        if not isinstance(data, dict):
            raise CorrectionsError(f"{source}: expected a JSON object at the top level")
        fmt = data.get("format")
        if fmt != CORRECTIONS_FORMAT:
            raise CorrectionsError(f"{source}: format: expected {CORRECTIONS_FORMAT!r}, got {fmt!r}")
        clock = data.get("clock", {})
        if not isinstance(clock, dict):
            raise CorrectionsError(f"{source}: clock: expected an object")
        try:
            offset = _as_int_us(clock.get("offset_us", 0), "offset_us")
        except ValueError as exc:
            raise CorrectionsError(f"{source}: clock.offset_us: {exc}") from None
        skew = clock.get("skew_ppm", 0.0)
        if isinstance(skew, bool) or not isinstance(skew, (int, float)) or not math.isfinite(skew):
            raise CorrectionsError(f"{source}: clock.skew_ppm: expected a finite number, got {skew!r}")
        deltas = {}
        objects = data.get("objects", {})
        if not isinstance(objects, dict):
            raise CorrectionsError(f"{source}: objects: expected an object keyed by object name")
        for name, entry in objects.items():
            fld = f"objects.{name}.dT_base"
            if not isinstance(entry, dict) or "dT_base" not in entry:
                raise CorrectionsError(f"{source}: {fld}: missing")
            deltas[name] = _read_T(entry["dT_base"], f"{source}: {fld}")
        he_entry = data.get("hand_eye", {})
        if not isinstance(he_entry, dict):
            raise CorrectionsError(f"{source}: hand_eye: expected an object with dT_cam")
        hand_eye = _read_T(he_entry.get("dT_cam", np.eye(4).tolist()), f"{source}: hand_eye.dT_cam")
        reviews = []
        raw_reviews = data.get("reviews", [])
        if not isinstance(raw_reviews, list):
            raise CorrectionsError(f"{source}: reviews: expected a list")
        for i, r in enumerate(raw_reviews):
            try:
                reviews.append(ReviewMark(int(r["t0_us"]), int(r["t1_us"]), str(r["status"]),
                                          str(r.get("note", "")), r.get("object")))
            except KeyError as exc:
                raise CorrectionsError(f"{source}: reviews[{i}].{exc.args[0]}: missing") from None
            except (TypeError, ValueError) as exc:
                raise CorrectionsError(f"{source}: reviews[{i}]: {exc}") from None
        return cls(offset, float(skew), deltas, hand_eye, reviews, data.get("scene"))

    def save(self, path) -> Path:
        """Write atomically (temp + fsync + rename)."""
        return atomic_write_text(path, json.dumps(self.to_json(), indent=1) + "\n")

    @classmethod
    def load(cls, path) -> "Corrections":
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise CorrectionsError(f"{path}: cannot read ({exc.strerror})") from None
        except json.JSONDecodeError as exc:
            raise CorrectionsError(f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None
        return cls.from_json(data, source=str(path))


def _as_int_us(value, name: str) -> int:
    if isinstance(value, bool):
        raise ValueError(f"{name} must be an integer number of microseconds, got {value!r}")
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)) and math.isfinite(value) and float(value).is_integer():
        return int(value)
    raise ValueError(f"{name} must be an integer number of microseconds, got {value!r}")


def _read_T(value, where: str) -> np.ndarray:
    try:
        T, _ = validate_T(value, where, tolerance=_DELTA_TOLERANCE)
    except GeometryError as exc:
        raise CorrectionsError(str(exc)) from None
    # keep the stored bits exactly (validate_T re-projects; a delta written by us is orthonormal)
    return np.asarray(value, dtype=np.float64)
