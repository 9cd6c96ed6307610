"""Undoable edits of a :class:`~evpose.core.document.corrections.Corrections` document (pure Python).

A :class:`Command` carries its old and new values (glue's ``core/command.py``): :class:`SetValue`
sets one document key, :class:`Group` runs several as one step. Commands never open dialogs nor
notify anyone; :class:`~evpose.core.document.history.History` runs, merges and records them.
"""
from __future__ import annotations

import numpy as np

from evpose.core.document.corrections import Corrections


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(np.asarray(a), np.asarray(b))
    return a == b


class Command:
    """One undoable edit. Subclasses implement :meth:`redo` and :meth:`undo`."""

    text = "edit"
    #: Commands with equal, non-None keys may merge into one undo step.
    merge_key = None

    def redo(self, doc: Corrections) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def undo(self, doc: Corrections) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def merge(self, other: "Command") -> bool:
        """Absorb ``other`` (pushed right after self); return True if merged."""
        return False

    def is_noop(self) -> bool:
        return False

    def keys(self) -> list[tuple]:
        """The document keys (see :meth:`Corrections.get`) that :meth:`redo` and :meth:`undo` set."""
        return []


class SetValue(Command):
    """Set the document value at ``key`` (see :meth:`Corrections.get`) from ``old`` to ``new``.

    ``mergeable`` commands with the same key merge: the result keeps the first ``old`` and the
    last ``new``, so a burst of keyboard nudges or a slider drag is one undo step.
    """

    def __init__(self, key: tuple, old, new, text: str | None = None, mergeable: bool = False):
        self.key = tuple(key)
        self.old = old
        self.new = new
        self.text = text or f"set {'/'.join(str(k) for k in self.key)}"
        self.merge_key = self.key if mergeable else None

    def redo(self, doc: Corrections) -> None:
        doc.set(self.key, self.new)

    def undo(self, doc: Corrections) -> None:
        doc.set(self.key, self.old)

    def merge(self, other: Command) -> bool:
        if not isinstance(other, SetValue) or other.merge_key is None or other.merge_key != self.merge_key:
            return False
        self.new = other.new
        return True

    def is_noop(self) -> bool:
        return _same(self.old, self.new)

    def keys(self) -> list[tuple]:
        return [self.key]


class Group(Command):
    """Several commands as one undo step (redo in order, undo in reverse). With a ``merge_key``, a
    :class:`SetValue` of that key pushed right after merges into the group's first command (a drag that dropped
    an estimate's sigma with its first move stays one undo step)."""

    def __init__(self, text: str, commands: list[Command] | None = None, merge_key=None):
        self.text = text
        self.commands: list[Command] = list(commands or [])
        self.merge_key = merge_key

    def merge(self, other: Command) -> bool:
        return self.merge_key is not None and bool(self.commands) and self.commands[0].merge_key == self.merge_key \
            and self.commands[0].merge(other)

    def redo(self, doc: Corrections) -> None:
        for c in self.commands:
            c.redo(doc)

    def undo(self, doc: Corrections) -> None:
        for c in reversed(self.commands):
            c.undo(doc)

    def is_noop(self) -> bool:
        return all(c.is_noop() for c in self.commands)

    def keys(self) -> list[tuple]:
        return [k for c in self.commands if not c.is_noop() for k in c.keys()]


def set_command(doc: Corrections, key: tuple, new, text: str | None = None, mergeable: bool = False) -> SetValue:
    """A :class:`SetValue` whose ``old`` is the document's current value at ``key``."""
    return SetValue(key, doc.get(key), new, text=text, mergeable=mergeable)
