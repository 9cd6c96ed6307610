"""The user's document: corrections on top of a scene, saved as ``corrections.json``.

What is corrected (all optional, identity by default):

* ``offset_us`` (int) and ``skew_ppm`` (float): added to the scene's clock prior;
* per-object pose deltas ``dT_base`` (4x4, base frame): ``T_base_obj' = dT_base @ T_base_obj``;
* a hand-eye delta ``dT_cam`` (4x4, camera frame): ``T_base_cam' = T_base_cam @ dT_cam``;
* review marks over event-time intervals ``[t0_us, t1_us)``: verified / rejected / flagged
  (rules in :mod:`core.review`);
* ``sigmas``: the 1-sigma of the values an automatic estimate set (``clock``: ``offset_us``, ``skew_ppm``;
  ``hand_eye`` and ``object:<name>``: ``mm``, ``deg``), stored with the estimate in the same undo step and cleared
  when the value is edited by hand (:meth:`evpose.core.document.history.History.set`); what the label sigma of the
  app and of ``export --label-sigma auto`` start from (tracker issue 28.3). Written only when there is one.

The raw data is never touched. JSON numbers are written with Python's shortest round-trip repr, so
offsets of 10 s and skews of 1000 ppm come back bit-identical.

Revision and concurrent writers
-------------------------------
The file carries ``"revision"`` (1, 2, ... one more per save; files without it are revision 0 and
are read as before). A document remembers what the file held when it was loaded or last saved
(:attr:`Corrections.base`). :meth:`Corrections.save` goes through :func:`evpose.core.document.corrections_file.save`:
under a lock it re-reads the file, and if another program changed it meanwhile, merges the two
edits field by field against that base (:mod:`evpose.core.document.corrections_merge`) or refuses with both values
named; the write is atomic and durable (temp file, fsync, rename, fsync of the directory) and goes
through a symlinked ``corrections.json`` to its target.

Object names the scene does not have are kept in the file (and written back) but not applied;
:meth:`Corrections.load` warns about each (:class:`CorrectionsWarning`) when given the scene's names.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from evpose.core.data.geometry import GeometryError, validate_T
from evpose.core.document.review import (
    REVIEW_STATUSES,
    MarkState,
    ReviewMark,
    effective_status,
    normalize_marks,
)
from evpose.core.errors import InputError

__all__ = ["CORRECTIONS_FORMAT", "CORRECTIONS_FILENAME", "REVIEW_STATUSES", "SIGMA_FIELDS", "Corrections",
           "CorrectionsError", "CorrectionsWarning", "ReviewMark", "MarkState", "change_field", "sigma_part"]

CORRECTIONS_FORMAT = "evpose-corrections/1"
CORRECTIONS_FILENAME = "corrections.json"
#: Tolerance for deltas read back from JSON: they were orthonormal when written.
_DELTA_TOLERANCE = 1e-6
#: Largest clock offset accepted (2**53 us, 285 years: exact in float64, no int64 overflow downstream).
MAX_OFFSET_US = 2 ** 53
#: Largest clock skew accepted (ppm).
MAX_SKEW_PPM = 1e6
#: Keys of the canonical document that a three-way merge compares (everything the user edits).
DOCUMENT_KEYS = ("clock", "objects", "hand_eye", "reviews", "sigmas")
#: The fields of each part of ``sigmas`` (units in the names: µs, ppm, mm, degrees).
SIGMA_FIELDS = {"clock": ("offset_us", "skew_ppm"), "hand_eye": ("mm", "deg"), "object": ("mm", "deg")}


class CorrectionsError(InputError):
    """A corrections file that cannot be used; the message names the file and the field."""


class CorrectionsWarning(UserWarning):
    """Something in a corrections file that is kept but not used (e.g. an unknown object name)."""


@dataclass(eq=False)
class Corrections:
    """Mutable correction document.

    Mutate it through :meth:`set` (by :mod:`evpose.core.document.history` commands in the app: the
    history is the one change notification, one per step, naming the fields of
    :func:`change_field`).

    Attributes
    ----------
    revision : int
        Revision of ``corrections.json`` this document was loaded from or last saved as (0: none).
    base : dict or None
        :meth:`canonical` form of the file's content at that moment (None: there was no file).
        A save compares the file on disk with it to detect another writer.
    """

    offset_us: int = 0
    skew_ppm: float = 0.0
    object_deltas: dict[str, np.ndarray] = field(default_factory=dict)
    hand_eye_delta: np.ndarray = field(default_factory=lambda: np.eye(4))
    reviews: list[ReviewMark] = field(default_factory=list)
    scene_name: str | None = None
    revision: int = 0
    #: part (``"clock"``, ``"hand_eye"``, ``"object:<name>"``) -> its estimate's sigmas (see the module docstring)
    sigmas: dict = field(default_factory=dict)

    def __post_init__(self):
        self.reviews = normalize_marks(self.reviews)
        self.base: dict | None = None
        #: ``(st_dev, st_ino, st_mtime_ns, st_size)`` of the file after our last load or save.
        self.disk_signature: tuple | None = None
        #: :class:`evpose.core.document.corrections_file.SaveReport` of the last :meth:`save` (None before).
        self.last_save = None

    # ------------------------------------------------------------------ accessors
    def object_delta(self, name: str) -> np.ndarray:
        """``dT_base`` of an object (identity when uncorrected); a copy."""
        d = self.object_deltas.get(name)
        return np.eye(4) if d is None else d.copy()

    def keys(self) -> list[tuple]:
        """Every command key of the document (objects: those with a correction)."""
        return ([("offset_us",), ("skew_ppm",), ("hand_eye",), ("reviews",)]
                + [("object", n) for n in sorted(self.object_deltas)] + [("sigma", p) for p in sorted(self.sigmas)])

    def sigma(self, part: str) -> dict | None:
        """The sigmas stored for ``part`` (``"clock"``, ``"hand_eye"`` or ``"object:<name>"``); None: none."""
        v = self.sigmas.get(part)
        return None if v is None else dict(v)

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
        if kind == "sigma":
            return self.sigma(key[1])
        raise KeyError(key)

    def set(self, key: tuple, value) -> None:
        """Set the value at a command key (see :meth:`get`)."""
        kind = key[0]
        if kind == "offset_us":
            self.offset_us = _as_int_us(value, "offset_us")
        elif kind == "skew_ppm":
            self.skew_ppm = _as_skew(value)
        elif kind == "object":
            T = np.array(value, dtype=np.float64)
            if np.array_equal(T, np.eye(4)):
                self.object_deltas.pop(key[1], None)
            else:
                self.object_deltas[key[1]] = T
        elif kind == "hand_eye":
            self.hand_eye_delta = np.array(value, dtype=np.float64)
        elif kind == "reviews":
            self.reviews = normalize_marks(value)
        elif kind == "sigma":
            if value is None:
                self.sigmas.pop(key[1], None)
            else:
                self.sigmas[key[1]] = _read_sigma(value, key[1], f"sigmas.{key[1]}")
        else:
            raise KeyError(key)

    def differing_keys(self, other: "Corrections") -> list[tuple]:
        """Command keys whose values differ between ``self`` and ``other`` (exact comparison)."""
        out = []
        for key in (("offset_us",), ("skew_ppm",), ("hand_eye",), ("reviews",)):
            a, b = self.get(key), other.get(key)
            same = np.array_equal(a, b) if key == ("hand_eye",) else (
                set(a) == set(b) if key == ("reviews",) else a == b)
            if not same:
                out.append(key)
        for n in sorted(set(self.object_deltas) | set(other.object_deltas)):
            if not np.array_equal(self.object_delta(n), other.object_delta(n)):
                out.append(("object", n))
        for p in sorted(set(self.sigmas) | set(other.sigmas)):
            if self.sigma(p) != other.sigma(p):
                out.append(("sigma", p))
        return out

    def review_status(self, t_us: int, obj: str | None = None) -> str | None:
        """Effective review status at ``t_us`` for ``obj`` (see :func:`evpose.core.document.review.effective_status`)."""
        return effective_status(self.reviews, t_us, obj)

    def copy(self) -> "Corrections":
        """An independent copy of the values (no disk state)."""
        return Corrections.from_json(self.to_json())

    # ------------------------------------------------------------------ JSON
    def to_json(self) -> dict:
        d = {
            "format": CORRECTIONS_FORMAT,
            "revision": int(self.revision),
            "scene": self.scene_name,
            "clock": {"offset_us": int(self.offset_us), "skew_ppm": float(self.skew_ppm)},
            "objects": {name: {"dT_base": T.tolist()} for name, T in sorted(self.object_deltas.items())},
            "hand_eye": {"dT_cam": self.hand_eye_delta.tolist()},
            "reviews": [m.to_json() for m in self.reviews],
        }
        if self.sigmas:           # only when an estimate left one: files without stay as they were
            d["sigmas"] = {p: dict(sorted(v.items())) for p, v in sorted(self.sigmas.items())}
        return d

    def canonical(self) -> dict:
        """The edited content only (no format, revision or scene name): equal for equal documents."""
        d = self.to_json()
        return {k: d[k] for k in DOCUMENT_KEYS if k in d}

    def digest(self) -> str:
        """SHA-256 (hex) of :meth:`canonical`: names the corrections an estimate was planned against, so a proposal
        is applied only to the document it was made for."""
        import hashlib
        import json

        return hashlib.sha256(json.dumps(self.canonical(), sort_keys=True).encode()).hexdigest()

    @classmethod
    def from_json(cls, data: dict, source: str = "corrections.json") -> "Corrections":
        if not isinstance(data, dict):
            raise CorrectionsError(f"{source}: expected a JSON object at the top level")
        fmt = data.get("format")
        if fmt != CORRECTIONS_FORMAT:
            raise CorrectionsError(f"{source}: format: expected {CORRECTIONS_FORMAT!r}, got {fmt!r}")
        revision = data.get("revision", 0)
        if isinstance(revision, bool) or not isinstance(revision, int) or revision < 0:
            raise CorrectionsError(f"{source}: revision: expected an integer >= 0, got {revision!r}")
        clock = data.get("clock", {})
        if not isinstance(clock, dict):
            raise CorrectionsError(f"{source}: clock: expected an object")
        try:
            offset = _as_int_us(clock.get("offset_us", 0), "offset_us")
        except ValueError as exc:
            raise CorrectionsError(f"{source}: clock.offset_us: {exc}") from None
        try:
            skew = _as_skew(clock.get("skew_ppm", 0.0))
        except ValueError as exc:
            raise CorrectionsError(f"{source}: clock.skew_ppm: {exc}") from None
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
                if not isinstance(r, dict):
                    raise TypeError("expected an object with t0_us, t1_us and status")
                t0, t1 = (_as_int_us(r[k], k) for k in ("t0_us", "t1_us"))
                at = MarkState.from_json(r["at"]) if "at" in r else None
                reviews.append(ReviewMark(t0, t1, str(r["status"]), str(r.get("note", "")), r.get("object"), at))
            except KeyError as exc:
                raise CorrectionsError(f"{source}: reviews[{i}].{exc.args[0]}: missing") from None
            except (TypeError, ValueError, OverflowError) as exc:
                raise CorrectionsError(f"{source}: reviews[{i}]: {exc}") from None
        # files without a revision predate the review rules: later marks won across scopes there
        reviews = normalize_marks(reviews, legacy="revision" not in data)
        raw_sigmas = data.get("sigmas", {})
        if not isinstance(raw_sigmas, dict):
            raise CorrectionsError(f"{source}: sigmas: expected an object keyed by part (clock, hand_eye, object:NAME)")
        try:
            sigmas = {p: _read_sigma(v, p, f"sigmas.{p}") for p, v in raw_sigmas.items()}
        except ValueError as exc:
            raise CorrectionsError(f"{source}: {exc}") from None
        return cls(offset, skew, deltas, hand_eye, reviews, data.get("scene"), revision, sigmas)

    def unknown_objects(self, known) -> list[tuple[str, str]]:
        """``(field, name)`` of every object name used here that is not in ``known``."""
        known = set(known)
        out = [(f"objects.{n}", n) for n in sorted(self.object_deltas) if n not in known]
        out += [(f"reviews[{i}].object", m.object) for i, m in enumerate(self.reviews)
                if m.object is not None and m.object not in known]
        return out

    def save(self, path, *, apply_merge: Callable[["Corrections"], None] | None = None,
             prefer: str | None = None) -> Path:
        """Save through :func:`evpose.core.document.corrections_file.save`: revision check, merge or refusal
        (:class:`~evpose.core.document.corrections_merge.CorrectionsConflict`), atomic durable write (through a
        symlink to its target). If another program's edits were merged, ``apply_merge(merged)``
        brings this document to the merged state (default :meth:`assign`; the app goes through its
        undo history). The :class:`~evpose.core.document.corrections_file.SaveReport` is kept in :attr:`last_save`."""
        from evpose.core.document.corrections_file import save

        report = save(path, self, prefer=prefer)
        if report.merged is not None:
            (apply_merge or self.assign)(report.merged)
        self.mark_saved(report)
        self.last_save = report
        return Path(path)

    def assign(self, other: "Corrections") -> list[tuple]:
        """Take every value of ``other`` that differs (through :meth:`set`); returns the keys set."""
        keys = self.differing_keys(other)
        for key in keys:
            self.set(key, other.get(key))
        return keys

    def mark_saved(self, report) -> None:
        """Record that the file now holds ``report.written`` (a :class:`evpose.core.document.corrections_file.SaveReport`)."""
        self.revision = report.revision
        self.base = report.written.canonical()
        self.disk_signature = report.signature

    @classmethod
    def load(cls, path, known_objects=None) -> "Corrections":
        """Read ``path`` (following a symlink); with ``known_objects`` (the scene's object names),
        warn about each object name the scene does not have (kept, not applied)."""
        from evpose.core.document.corrections_file import read

        doc, signature = read(path)
        if doc is None:
            raise CorrectionsError(f"{path}: cannot read (no such file)")
        doc.base = doc.canonical()
        doc.disk_signature = signature
        if known_objects is not None:
            for fld, name in doc.unknown_objects(known_objects):
                warnings.warn(f"{path}: {fld}: no object named {name!r} in the scene; kept in the file but "
                              "not applied", CorrectionsWarning, stacklevel=2)
        return doc


def change_field(key: tuple) -> str:
    """The field a command key sets, as change notifications name it: ``"clock"`` (offset and
    skew), ``"hand_eye"``, ``"reviews"`` or ``"object:<name>"``."""
    kind = key[0]
    if kind in ("offset_us", "skew_ppm"):
        return "clock"
    if kind == "object":
        return f"object:{key[1]}"
    if kind in ("hand_eye", "reviews"):
        return kind
    if kind == "sigma":
        return "sigmas"
    raise KeyError(key)


def sigma_part(key: tuple) -> str | None:
    """The ``sigmas`` part of a value's command key (``("object", name)`` -> ``"object:<name>"``); None for a key
    without one (reviews, a sigma itself)."""
    kind = key[0]
    if kind in ("offset_us", "skew_ppm"):
        return "clock"
    if kind == "object":
        return f"object:{key[1]}"
    return "hand_eye" if kind == "hand_eye" else None


def _read_sigma(value, part: str, where: str) -> dict:
    """A part's sigmas checked: its fields (:data:`SIGMA_FIELDS`) as finite numbers >= 0 (at least one)."""
    kind = part.split(":", 1)[0]
    fields = SIGMA_FIELDS.get(kind)
    if fields is None or (kind == "object") != (":" in part) or part.endswith(":"):
        raise ValueError(f"{where}: unknown part (expected clock, hand_eye or object:NAME)")
    if not isinstance(value, dict) or not value:
        raise ValueError(f"{where}: expected an object with {' and/or '.join(fields)}")
    out = {}
    for k, v in value.items():
        if k not in fields:
            raise ValueError(f"{where}.{k}: not a field (allowed: {', '.join(fields)})")
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not (
                math.isfinite(v) and v >= 0):
            raise ValueError(f"{where}.{k}: expected a finite number >= 0, got {v!r}")
        out[k] = float(v)
    return out


def _as_int_us(value, name: str) -> int:
    if isinstance(value, bool):
        raise ValueError(f"{name} must be an integer number of microseconds, got {value!r}")
    if isinstance(value, (int, np.integer)):
        v = int(value)
    elif isinstance(value, (float, np.floating)) and math.isfinite(value) and float(value).is_integer():
        v = int(value)
    else:
        raise ValueError(f"{name} must be an integer number of microseconds, got {value!r}")
    if abs(v) > MAX_OFFSET_US:
        raise ValueError(f"{name} must be within +-2**53 us (285 years), got {value!r}")
    return v


def _as_skew(value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"expected a finite number of ppm, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or abs(v) > MAX_SKEW_PPM:
        raise ValueError(f"expected a finite number of ppm within +-{MAX_SKEW_PPM:g}, got {value!r}")
    return v


def _read_T(value, where: str) -> np.ndarray:
    try:
        T, _ = validate_T(value, where, tolerance=_DELTA_TOLERANCE)
    except GeometryError as exc:
        raise CorrectionsError(str(exc)) from None
    # keep the stored bits exactly (validate_T re-projects; a delta written by us is orthonormal)
    return np.asarray(value, dtype=np.float64)
