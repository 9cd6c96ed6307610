"""Three-way merge of two edits of one ``corrections.json`` (pure Python).

``base`` is the document both sides started from (what the file held when it was loaded), ``local``
the document about to be saved, ``disk`` what another program saved meanwhile. The merge works per
*field*: the clock offset, the clock skew, the hand-eye correction, each object's pose correction,
and the review marks as a set.

* A field changed on one side only takes that side's value.
* A field changed on both sides to the same value takes it.
* A field changed on both sides to different values is a **conflict**: :func:`merge` raises
  :class:`CorrectionsConflict` naming the field and both values (or, with ``prefer``, takes that
  side's value and lists the conflict in the result).
* Review marks: marks added on either side are added, marks removed (or trimmed) on either side are
  removed. Marks added on both sides that overlap in time for the same object (or for all objects)
  with different statuses are a conflict; with the same status the local one wins on the overlap.
  The result obeys the rules of :mod:`core.review` (no overlap within a scope).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evpose.core.data.geometry import rotation_angle
from evpose.core.document.corrections import Corrections, CorrectionsError
from evpose.core.document.review import ReviewMark, insert_mark


@dataclass(frozen=True)
class Conflict:
    """One field both sides changed to different values (values as display text)."""

    field: str
    local: str
    disk: str

    def text(self, local_name: str = "here", disk_name: str = "in the file") -> str:
        return f"{self.field}: {self.local} {local_name}, {self.disk} {disk_name}"


class CorrectionsConflict(CorrectionsError):
    """Both sides changed the same field to different values; nothing was written."""

    def __init__(self, message: str, conflicts: list[Conflict]):
        super().__init__(message)
        self.conflicts = conflicts


@dataclass
class MergeResult:
    doc: Corrections
    #: Fields whose value came from ``disk`` (the other writer's edits taken over).
    from_disk: list[str] = field(default_factory=list)
    #: Conflicts resolved by ``prefer`` (empty without it).
    conflicts: list[Conflict] = field(default_factory=list)


def describe_delta(T) -> str:
    """A pose correction as text: translation in mm and rotation angle in degrees."""
    T = np.asarray(T, dtype=np.float64)
    if np.array_equal(T, np.eye(4)):
        return "no correction"
    t = T[:3, 3] * 1e3
    return f"dt ({t[0]:.2f}, {t[1]:.2f}, {t[2]:.2f}) mm, dR {float(np.degrees(rotation_angle(T[:3, :3]))):.3f} deg"


def _describe_mark(m: ReviewMark) -> str:
    scope = "all objects" if m.object is None else m.object
    return f"{m.status} [{m.t0_us}, {m.t1_us}) us ({scope})"


def field_name(key: tuple) -> str:
    """The JSON field of a command key (as error messages name it)."""
    if key[0] == "sigma":
        return f"sigmas.{key[1]}"
    return {"offset_us": "clock.offset_us", "skew_ppm": "clock.skew_ppm", "hand_eye": "hand_eye.dT_cam",
            "reviews": "reviews"}.get(key[0]) or f"objects.{key[1]}.dT_base"


def _show(key: tuple, value) -> str:
    if key[0] == "offset_us":
        return f"{int(value)} us"
    if key[0] == "skew_ppm":
        return f"{float(value)!r} ppm"
    if key[0] == "sigma":
        return "no sigma" if value is None else ", ".join(f"{k} {v:g}" for k, v in sorted(value.items()))
    return describe_delta(value)


def _same(key: tuple, a, b) -> bool:
    return a == b if key[0] in ("offset_us", "skew_ppm", "sigma") else np.array_equal(a, b)


def merge(base: Corrections, local: Corrections, disk: Corrections, prefer: str | None = None,
          source: str = "corrections.json") -> MergeResult:
    """Merge ``local`` and ``disk`` against their common ``base`` (see the module docstring).

    Parameters
    ----------
    prefer : None, "local" or "disk"
        None: raise :class:`CorrectionsConflict` on the first conflict (all are listed in
        ``.conflicts``); otherwise take that side's value for conflicting fields.
    source : str
        The file named in messages.
    """
    if prefer not in (None, "local", "disk"):
        raise ValueError(f"prefer must be None, 'local' or 'disk', got {prefer!r}")
    out = local.copy()
    out.scene_name = local.scene_name or disk.scene_name
    from_disk: list[str] = []
    conflicts: list[Conflict] = []
    keys = [("offset_us",), ("skew_ppm",), ("hand_eye",)]
    keys += [("object", n) for n in sorted(set(base.object_deltas) | set(local.object_deltas)
                                            | set(disk.object_deltas))]
    for key in keys:
        b, l, d = base.get(key), local.get(key), disk.get(key)
        if _same(key, d, b) or _same(key, l, d):
            continue                       # nothing new on disk: keep local
        if _same(key, l, b) or prefer == "disk":
            out.set(key, d)                # only the other writer changed it
            from_disk.append(field_name(key))
            if not _same(key, l, b):
                conflicts.append(Conflict(field_name(key), _show(key, l), _show(key, d)))
            continue
        conflicts.append(Conflict(field_name(key), _show(key, l), _show(key, d)))
    for part in sorted(set(base.sigmas) | set(local.sigmas) | set(disk.sigmas)):
        _merge_sigma(part, base, local, disk, out, from_disk, conflicts, prefer)
    reviews, review_conflicts, taken = _merge_reviews(base.reviews, local.reviews, disk.reviews, prefer)
    conflicts += review_conflicts
    if taken:
        from_disk.append("reviews")
    out.set(("reviews",), reviews)
    if conflicts and prefer is None:
        c = conflicts[0]
        more = f" (and {len(conflicts) - 1} more)" if len(conflicts) > 1 else ""
        raise CorrectionsConflict(
            f"{source}: {c.field}: changed here to {c.local} but another program saved {c.disk} "
            f"since this copy was loaded{more}; nothing saved", conflicts)
    return MergeResult(out, from_disk, conflicts)


def _value_keys(part: str) -> list[tuple]:
    """The value keys whose estimate a sigma part describes."""
    if part == "clock":
        return [("offset_us",), ("skew_ppm",)]
    if part == "hand_eye":
        return [("hand_eye",)]
    return [("object", part.split(":", 1)[1])]


def _merge_sigma(part: str, base, local, disk, out, from_disk: list, conflicts: list, prefer) -> None:
    """A sigma follows its value: the side whose value the merge took gives its sigma (a hand edit on one side and
    an estimate's sigma on the other never meet); when both sides hold the same value the sigmas merge three ways
    like a value; when the merged value is neither side's (a clock's offset from one, its skew from the other), no
    sigma describes it unless both sides agree."""
    key = ("sigma", part)
    vk = _value_keys(part)
    as_local = all(_same(k, out.get(k), local.get(k)) for k in vk)
    as_disk = all(_same(k, out.get(k), disk.get(k)) for k in vk)
    b, l, d = base.get(key), local.get(key), disk.get(key)
    if as_local and as_disk:
        if d == b or l == d:
            return
        if l == b or prefer == "disk":
            out.set(key, d)
            from_disk.append(field_name(key))
            if l != b:
                conflicts.append(Conflict(field_name(key), _show(key, l), _show(key, d)))
            return
        conflicts.append(Conflict(field_name(key), _show(key, l), _show(key, d)))
    elif as_disk:
        if l != d:
            out.set(key, d)
            from_disk.append(field_name(key))
    elif not as_local:
        out.set(key, l if l == d else None)


def _scopes_meet(a: ReviewMark, b: ReviewMark) -> bool:
    return a.object is None or b.object is None or a.object == b.object


def _merge_reviews(base, local, disk, prefer):
    B, L, D = set(base), set(local), set(disk)
    kept = [m for m in base if m in L and m in D]
    added_l = [m for m in local if m not in B]
    added_d = [m for m in disk if m not in B]
    conflicts = []
    clash = set()
    for a in added_l:
        for b in added_d:
            if a != b and a.overlaps(b) and _scopes_meet(a, b) and a.status != b.status:
                conflicts.append(Conflict("reviews", _describe_mark(a), _describe_mark(b)))
                clash.add(b if prefer != "disk" else a)
    # kept base marks first, then the other writer's additions, then ours (later wins on overlaps)
    first, second = (added_l, added_d) if prefer == "disk" else (added_d, added_l)
    out: list[ReviewMark] = []
    for m in kept + [m for m in first if m not in clash] + [m for m in second if m not in clash]:
        out = insert_mark(out, m, trim_objects=False)
    taken = bool(set(added_d) - clash) or bool((B - D) & L)
    return out, conflicts, taken
