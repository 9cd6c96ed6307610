"""The autosave journal: unsaved corrections kept beside the scene until they are saved.

The app writes the document to ``.corrections.autosave.json`` now and then while it has unsaved
edits; a session that did not save (a crash) leaves it behind, and the next one offers to restore
it. The journal also records the state its edits started from (``base``, ``base_revision``), so a
restore merges with what another program saved since instead of overwriting it. A journal that
cannot be read back whole is ignored and reported, never half applied: it is written atomically, and
it starts with the SHA-256 of the rest of its content, so a journal that lost bytes anywhere, also in
the middle (where the JSON may still parse), is refused.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

from evpose.core.data.atomic import atomic_write_text
from evpose.core.document.corrections import CORRECTIONS_FORMAT, Corrections, CorrectionsError
from evpose.core.document.corrections_merge import merge

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


def restore_target(journal: Corrections, current: Corrections, source: str) -> tuple[Corrections, list]:
    """The document a restore should reach, and the conflicts it resolved.

    When the journal records the state its edits started from, its edits are merged into
    ``current`` (which may hold changes another program saved since): the autosaved value wins
    where both changed a field (:class:`evpose.core.document.corrections_merge.Conflict` each).
    Otherwise the journal is taken as it is."""
    if journal.base is None:
        return journal, []
    res = merge(document_of(journal.base), journal, current, prefer="local", source=source)
    return res.doc, res.conflicts


def discard_journal(path: Path) -> None:
    """Remove the journal (nothing if it is not there or cannot be removed)."""
    try:
        os.unlink(path)
    except OSError:
        pass
