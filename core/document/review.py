"""Review marks: verified / rejected / flagged over event-time intervals, and the rules that keep them
consistent (pure Python, no Qt).

Rules
-----
* **Scope.** A mark covers one object (``object = name``) or every object (``object = None``).
* **No overlap in a scope.** Two marks of the same scope never overlap: a new mark *replaces* older
  marks of its scope on the overlap (they are trimmed; what lies outside the new mark stays). So one
  window is never both verified and rejected, and marking the same window twice leaves one mark.
  A new mark for all objects also trims object-specific marks on its overlap (it is the newer
  decision for every object).
* **Precedence.** For an object at time ``t`` the effective status is that of the object's own mark
  covering ``t``, else that of the all-objects mark covering ``t``, else none. With the two rules above
  this equals "the most recently added mark wins", and it does not depend on the order of the list,
  so review marks merge as a set (:mod:`evpose.core.document.corrections_merge`).
* **State at marking time.** A mark made in the app records the clock in effect (offset and skew) and
  a digest of each covered object's pose inputs (its ``T_base_obj``, its correction, the hand-eye and
  its correction): :class:`MarkState`, stored as ``"at"`` in ``corrections.json``. When the clock or
  that object's pose changes later, the mark is *stale* (:func:`stale_reasons`): the label it
  verified is not the label that would be exported. Marks without ``"at"`` (made before evpose
  recorded it, or written by other tools) are never stale.
* **Grid.** The app's current window is a cell of the export grid: windows of the view's length
  starting at the first event (:func:`grid_window`, the same tiling as
  :func:`evpose.core.label.windows.time_windows`), so a mark of the current window is an export window.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, replace

import numpy as np

REVIEW_STATUSES = ("verified", "rejected", "flagged")
#: Characters of the hex SHA-256 kept per pose digest (64 bits: a collision is not a practical concern).
DIGEST_CHARS = 16


@dataclass(frozen=True)
class MarkState:
    """The labelling state a mark was made under.

    Attributes
    ----------
    offset_us : int
        Clock offset in effect (scene prior plus correction), microseconds.
    skew_ppm : float
        Clock skew in effect (prior plus correction), ppm.
    poses : tuple of (str, str)
        ``(object name, digest)`` for every object the mark covers (see :func:`pose_digest`).
    """

    offset_us: int
    skew_ppm: float
    poses: tuple = ()

    def pose(self, name: str) -> str | None:
        for n, d in self.poses:
            if n == name:
                return d
        return None

    def to_json(self) -> dict:
        return {"offset_us": int(self.offset_us), "skew_ppm": float(self.skew_ppm), "poses": dict(self.poses)}

    @classmethod
    def from_json(cls, d) -> "MarkState":
        """Raises ``ValueError``/``TypeError`` with the offending key for a malformed entry."""
        if not isinstance(d, dict):
            raise TypeError("at: expected an object with offset_us, skew_ppm and poses")
        off, skew, poses = d.get("offset_us"), d.get("skew_ppm"), d.get("poses", {})
        if isinstance(off, bool) or not isinstance(off, int):
            raise ValueError(f"at.offset_us: expected an integer, got {off!r}")
        if isinstance(skew, bool) or not isinstance(skew, (int, float)) or not math.isfinite(skew):
            raise ValueError(f"at.skew_ppm: expected a finite number, got {skew!r}")
        if not isinstance(poses, dict) or not all(isinstance(v, str) for v in poses.values()):
            raise ValueError("at.poses: expected an object mapping object names to digests")
        return cls(int(off), float(skew), tuple(sorted(poses.items())))


@dataclass(frozen=True)
class ReviewMark:
    """A review decision over the event-time interval ``[t0_us, t1_us)``.

    ``object`` is None for a mark that covers every object; ``at`` is the :class:`MarkState` at
    marking time (None when unknown).
    """

    t0_us: int
    t1_us: int
    status: str
    note: str = ""
    object: str | None = None
    at: MarkState | None = None

    def __post_init__(self):
        if self.status not in REVIEW_STATUSES:
            raise ValueError(f"status must be one of {REVIEW_STATUSES}, got {self.status!r}")
        if int(self.t1_us) <= int(self.t0_us):
            raise ValueError(f"review interval must have t1_us > t0_us, got [{self.t0_us}, {self.t1_us})")
        if self.object is not None and not isinstance(self.object, str):
            raise ValueError(f"object must be a name or absent, got {self.object!r}")
        object.__setattr__(self, "t0_us", int(self.t0_us))
        object.__setattr__(self, "t1_us", int(self.t1_us))

    def covers(self, t_us: int) -> bool:
        return self.t0_us <= t_us < self.t1_us

    def overlaps(self, other: "ReviewMark") -> bool:
        return self.t0_us < other.t1_us and other.t0_us < self.t1_us

    def to_json(self) -> dict:
        d = {"t0_us": self.t0_us, "t1_us": self.t1_us, "status": self.status}
        if self.note:
            d["note"] = self.note
        if self.object is not None:
            d["object"] = self.object
        if self.at is not None:
            d["at"] = self.at.to_json()
        return d


def _sort_key(m: ReviewMark):
    return (m.t0_us, m.t1_us, m.object or "", m.status, m.note)


def insert_mark(marks, new: ReviewMark, *, trim_objects: bool = True) -> list[ReviewMark]:
    """``marks`` with ``new`` added: marks of its scope are trimmed to outside ``new`` (replaced on
    the overlap). With ``trim_objects`` a mark for all objects trims object-specific marks too.
    Returns a new list sorted by time."""
    out = []
    for m in marks:
        same_scope = m.object == new.object or (trim_objects and new.object is None)
        if same_scope and m.overlaps(new):
            if m.t0_us < new.t0_us:
                out.append(replace(m, t1_us=new.t0_us))
            if new.t1_us < m.t1_us:
                out.append(replace(m, t0_us=new.t1_us))
        else:
            out.append(m)
    out.append(new)
    return sorted(out, key=_sort_key)


def has_overlap(marks) -> bool:
    """True if two marks of the same scope overlap (O(n log n))."""
    by_scope: dict = {}
    for m in marks:
        by_scope.setdefault(m.object, []).append(m)
    for ms in by_scope.values():
        ms = sorted(ms, key=lambda m: (m.t0_us, m.t1_us))
        for a, b in zip(ms, ms[1:]):
            if b.t0_us < a.t1_us:
                return True
    return False


def normalize_marks(marks, *, legacy: bool = False) -> list[ReviewMark]:
    """Marks satisfying the no-overlap rule, later marks in the list winning on overlaps.

    ``legacy``: the list comes from a file written before these rules (where the most recently
    added mark covering a time won across scopes too): a later all-objects mark then also trims
    earlier object-specific ones, which keeps the statuses those files meant. Otherwise only marks of
    the same scope are trimmed; a list that already satisfies the rule is returned sorted and
    unchanged."""
    marks = list(marks)
    if not legacy and not has_overlap(marks):
        return sorted(marks, key=_sort_key)
    out: list[ReviewMark] = []
    for m in marks:
        out = insert_mark(out, m, trim_objects=legacy)
    return out


def effective_status(marks, t_us: int, obj: str | None = None) -> str | None:
    """Status at ``t_us`` for object ``obj``: its own mark, else the all-objects mark, else None.

    With ``obj=None``: the all-objects mark, else any object's mark covering ``t_us``."""
    glob = own = other = None
    for m in marks:
        if not m.covers(t_us):
            continue
        if m.object is None:
            glob = m.status
        elif obj is not None and m.object == obj:
            own = m.status
        elif obj is None and other is None:
            other = m.status
    if own is not None:
        return own
    if glob is not None:
        return glob
    return other


# ---------------------------------------------------------------------------- state and staleness
def _bytes(T) -> bytes:
    return np.ascontiguousarray(np.asarray(T, dtype=np.float64)).tobytes()


def pose_digest(scene, name: str) -> str:
    """Digest of everything that places object ``name`` relative to the camera apart from the clock:
    its manifest ``T_base_obj``, its correction ``dT_base``, the manifest hand-eye and its
    correction ``dT_cam`` (the inputs, not products, so the digest is bit-stable)."""
    m = scene.manifest
    he = np.eye(4) if m.hand_eye is None else m.hand_eye
    h = hashlib.sha256()
    for part in (m.object(name).T_base_obj, scene.corrections.object_delta(name), he,
                 scene.corrections.hand_eye_delta):
        h.update(_bytes(part))
    return h.hexdigest()[:DIGEST_CHARS]


def clock_in_effect(scene) -> tuple[int, float]:
    """(offset_us, skew_ppm) in effect: scene prior plus correction (no event file is read)."""
    m, c = scene.manifest, scene.corrections
    return int(m.clock_offset_us) + int(c.offset_us), float(m.clock_skew_ppm) + float(c.skew_ppm)


def mark_state(scene, obj: str | None = None) -> MarkState:
    """The :class:`MarkState` of ``scene`` now, for one object or (``None``) all of them."""
    off, skew = clock_in_effect(scene)
    names = scene.object_names if obj is None else [obj]
    return MarkState(off, skew, tuple(sorted((n, pose_digest(scene, n)) for n in names
                                             if n in scene.object_names)))


def stale_reasons(scene, mark: ReviewMark, obj: str | None = None, now: MarkState | None = None) -> list[str]:
    """Why ``mark`` no longer verifies the current labels (empty: it does).

    ``obj`` limits the pose check to one object (the export asks per exported object); by default
    every object the mark covers is checked. ``now``: :func:`mark_state` of the scene for all
    objects, when the caller checks many marks (computed here otherwise)."""
    at = mark.at
    if at is None:
        return []
    if now is None:
        now = mark_state(scene)
    out = []
    off, skew = now.offset_us, now.skew_ppm
    if at.offset_us != off or at.skew_ppm != skew:
        text = f"{mark.status} at offset {at.offset_us} us"
        if at.skew_ppm != skew:
            text += f", skew {at.skew_ppm:g} ppm"
        text += f" (now {off} us" + (f", {skew:g} ppm)" if at.skew_ppm != skew else ")")
        out.append(text)
    if obj is not None:
        names = [obj]
    else:
        names = [mark.object] if mark.object is not None else [n for n, _ in now.poses]
    moved = [n for n in names if at.pose(n) is not None and now.pose(n) is not None and at.pose(n) != now.pose(n)]
    if moved:
        out.append(f"pose of {', '.join(moved)} changed since marking")
    return out


# ---------------------------------------------------------------------------- grid
def grid_window(t_us: int, origin_us: int, window_us: int) -> tuple[int, int]:
    """``[t0, t1)`` of the grid cell (windows of ``window_us`` from ``origin_us``) holding ``t_us``;
    times before the origin fall into the first cell."""
    w = int(window_us)
    if w <= 0:
        raise ValueError(f"window length must be positive, got {window_us} us")
    k = max((int(t_us) - int(origin_us)) // w, 0)
    t0 = int(origin_us) + k * w
    return t0, t0 + w
