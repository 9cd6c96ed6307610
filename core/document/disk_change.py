"""Noticing that another program saved ``corrections.json`` (an ``evpose ... --apply``, a second app).

A document remembers what the file held when it was loaded or last saved (:attr:`Corrections.base`,
its revision and the file's signature). :func:`check_disk` compares the file with that: cheap when
nothing happened (one ``stat``), and a file saved with the content we know (e.g. by ourselves) is
no change. Taking the change over (reload or merge, one undo step) is the session's part.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from evpose.core.document.corrections import Corrections
from evpose.core.document.corrections_file import read, signature, target_of
from evpose.core.document.corrections_merge import field_name
from evpose.core.document.journal import document_of


@dataclass
class ExternalChange:
    """``corrections.json`` as another program saved it (see :func:`check_disk`)."""

    revision: int
    disk: Corrections
    signature: tuple | None
    #: Fields that differ from the state we last loaded or saved.
    fields: list


def base_document(doc: Corrections) -> Corrections:
    """The file's content when ``doc`` was loaded or last saved (the identity if there was none)."""
    return document_of(doc.base)


def check_disk(doc: Corrections, path: Path) -> ExternalChange | None:
    """Has another program saved ``path`` since ``doc`` was loaded or saved?

    Returns the change, or None (also when the file was removed: the next save recreates it, or
    when it holds the content we know: then ``doc`` takes over its revision and signature).
    Raises :class:`~evpose.core.document.corrections.CorrectionsError` when the file cannot be read."""
    sig = signature(target_of(path))
    if sig == doc.disk_signature:
        return None
    disk, sig = read(path)
    if disk is None:
        doc.disk_signature = None
        return None
    base = base_document(doc)
    if disk.canonical() == base.canonical():
        doc.disk_signature = sig
        doc.revision = disk.revision
        return None
    return ExternalChange(disk.revision, disk, sig, [field_name(k) for k in base.differing_keys(disk)])


def take_disk_state(doc: Corrections, change: ExternalChange) -> None:
    """Record that ``doc`` now builds on the file as ``change`` found it (base, revision, signature)."""
    doc.base = change.disk.canonical()
    doc.revision = change.revision
    doc.disk_signature = change.signature
