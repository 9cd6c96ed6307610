"""The autosave journal: unsaved corrections kept beside the scene until they are saved.

The app writes the document to ``.corrections.autosave.json`` now and then while it has unsaved
edits; a session that did not save (a crash) leaves it behind, and the next one offers to restore
it. The journal exists only while there is unsaved work: the session removes it when it saves, when its
document comes back to the saved content (undo, redo, edits that cancel out) and when it closes without
unsaved work. It records the state its edits started from (``base``: the saved file's content and
``base_revision``), so a restore merges its edits into what the file holds now instead of overwriting
it, and a journal whose edits the file already holds is not offered (:func:`journal_offer`). A journal that
cannot be read back whole is ignored and reported, never half applied: it is written atomically, and
it starts with the SHA-256 of the rest of its content, so a journal that lost bytes anywhere, also in
the middle (where the JSON may still parse), is refused.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from evpose.core.data.atomic import atomic_write_text
from evpose.core.document.corrections import CORRECTIONS_FORMAT, Corrections, CorrectionsError
from evpose.core.document.corrections_merge import Conflict, merge

JOURNAL_NAME = ".corrections.autosave.json"


def write_journal(path: Path, doc: Corrections) -> Path | None:
    """Write ``doc`` (with its base) to ``path`` atomically; None when the folder is not writable
    (the next save tells the user)."""
    data = doc.to_json()
    data["autosaved_at"] = time.time()
    data["base"] = doc.base
    data["base_revision"] = doc.revision
    data = {"sha256": _digest(json.loads(json.dumps(data))), **data}      # first: a cut cannot drop it alone
    try:
        return atomic_write_text(path, json.dumps(data, indent=1))
    except OSError:
        return None


def read_journal(path: Path) -> tuple[Corrections | None, str | None]:
    """The journal at ``path`` as ``(corrections, problem)``: ``(None, None)`` when there is none,
    ``(None, reason)`` when it cannot be used (cut short, not UTF-8, invalid, unreadable).

    The corrections carry the journal's starting state in :attr:`Corrections.base` (None for
    journals of earlier versions, which have none) and its revision."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        return None, None
    except OSError as exc:
        return None, f"{path}: cannot read the autosave journal ({exc.strerror}); ignored"
    try:
        data = json.loads(raw.decode("utf-8"))
        if isinstance(data, dict) and "sha256" in data and data.pop("sha256") != _digest(data):
            return None, (f"{path}: autosave journal is damaged (its content does not match its checksum: "
                          "cut or changed); ignored")
        return _parse(data, path), None
    except UnicodeDecodeError as exc:
        return None, f"{path}: autosave journal is not UTF-8 text (byte {exc.start}); ignored"
    except json.JSONDecodeError as exc:
        return None, (f"{path}: autosave journal is damaged or cut short (line {exc.lineno}, column "
                      f"{exc.colno}: {exc.msg}); ignored")
    except (CorrectionsError, RecursionError, TypeError, ValueError) as exc:
        return None, f"{path}: autosave journal is not usable ({exc}); ignored"


def _digest(data: dict) -> str:
    """SHA-256 (hex) of the journal's content as read back (every key but ``sha256``), in a canonical form."""
    return hashlib.sha256(json.dumps(data, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _parse(data, path: Path) -> Corrections:
    if not isinstance(data, dict):
        raise CorrectionsError(f"{path}: expected a JSON object at the top level")
    data.pop("autosaved_at", None)
    has_base = "base" in data                  # journals of earlier versions have none
    base, base_rev = data.pop("base", None), data.pop("base_revision", None)
    journal = Corrections.from_json(data, source=str(path))
    if has_base:
        if base is None:                       # there was no corrections.json: the identity
            base = Corrections().canonical()
        if not isinstance(base, dict):
            raise CorrectionsError(f"{path}: base: expected an object")
        journal.base = document_of(base, source=f"{path}: base").canonical()
    journal.revision = base_rev if isinstance(base_rev, int) and not isinstance(base_rev, bool) else 0
    return journal


def document_of(canonical: dict | None, source: str = "corrections.json") -> Corrections:
    """A document from its :meth:`Corrections.canonical` form (None: the identity)."""
    if canonical is None:
        return Corrections()
    return Corrections.from_json({"format": CORRECTIONS_FORMAT, "revision": 0, **canonical}, source=source)


def unsaved(doc: Corrections) -> bool:
    """Does ``doc`` differ in content from the file it was loaded from or last saved to (:attr:`Corrections.base`)?
    False also after edits that cancel out (undone, or a nudge and its opposite): then a journal holds no work."""
    base = doc.base if doc.base is not None else Corrections().canonical()
    return doc.canonical() != base


@dataclass
class JournalOffer:
    """What an autosave journal holds that the saved file does not (see :func:`journal_offer`)."""

    journal: Corrections
    #: The document a restore reaches when the saved file's value is kept for every field in :attr:`conflicts`.
    keep_saved: Corrections
    #: The document a restore reaches when the autosaved value is taken for every field in :attr:`conflicts`.
    take_autosaved: Corrections
    #: Fields the journal and the saved file both changed since the journal's edits began, to different values
    #: (``local`` = the autosaved value, ``disk`` = the saved one).
    conflicts: list[Conflict] = field(default_factory=list)
    #: The saved file was written after the journal was (its values are the newer ones).
    file_newer: bool = False

    def target(self, take_autosaved: bool = False) -> Corrections:
        return self.take_autosaved if take_autosaved else self.keep_saved


def journal_offer(journal: Corrections, current: Corrections, *, journal_mtime: float | None = None,
                  file_mtime: float | None = None, source: str = JOURNAL_NAME) -> JournalOffer | None:
    """What restoring ``journal`` over ``current`` (the saved file's document) would bring back, or None when the
    journal holds nothing newer than the saved file.

    A journal records the state its edits started from (``base``: the file's content and revision then). Its
    edits are merged into ``current`` three ways, so whatever the file gained since (another program's save, or a
    later save of this app that did not remove the journal) is kept. A field both changed to different values is
    a conflict: the offer carries both outcomes and the caller asks; with no choice made, the saved value is kept
    (:attr:`JournalOffer.keep_saved`). None when nothing of the journal is missing from the file, and also when
    all that is missing are conflicts the file settled later (``file_mtime`` after ``journal_mtime``): the
    journal's values there are the older ones.

    A journal of an earlier version (no ``base``) can only be taken as a whole: offered when it differs."""
    if journal.base is None:
        if journal.canonical() == current.canonical():
            return None
        return JournalOffer(journal, journal, journal)
    base = document_of(journal.base)
    keep = merge(base, journal, current, prefer="disk", source=source)
    take = merge(base, journal, current, prefer="local", source=source)
    now = current.canonical()
    if take.doc.canonical() == now:
        return None                              # every autosaved edit is in the file already
    file_newer = journal_mtime is not None and file_mtime is not None and file_mtime > journal_mtime
    if keep.doc.canonical() == now and file_newer:
        return None                              # only fields the file changed later: the journal's are older
    return JournalOffer(journal, keep.doc, take.doc, take.conflicts, file_newer)


def discard_journal(path: Path) -> None:
    """Remove the journal (nothing if it is not there or cannot be removed)."""
    try:
        os.unlink(path)
    except OSError:
        pass
