"""Undo/redo of edits to a :class:`~evpose.core.document.corrections.Corrections` document (pure Python).

Every edit is a :class:`~evpose.core.document.commands.Command` carrying its old and new values. :class:`History` runs
commands, merges repeated nudges of the same field into one step (as ``QUndoStack`` does with
``mergeWith``), groups several commands into one step, and tracks a clean index (the state
last saved). GUI frontends mirror it onto their Undo/Redo actions; they never mutate the
document directly.

:attr:`History.changed` is the document's one change notification: it emits one
:class:`~evpose.core.signals.Change` per step, after the step ran -- ``Change("document", fields)``
for a push, merge, group, undo, redo or external change (``fields``: the document fields the step
set, see :func:`~evpose.core.document.corrections.change_field`), ``Change("history")`` when only
the clean state or the stack changed (:meth:`History.set_clean`, :meth:`History.clear`). Nothing
is emitted for a no-op, inside a group, or for a group rolled back by an exception.
"""
from __future__ import annotations

import contextlib
import time
from typing import Callable

from evpose.core.document.commands import Command, Group, _same, set_command
from evpose.core.document.corrections import Corrections, change_field, sigma_part
from evpose.core.signals import Change, Signal


class History:
    """Linear undo history over one document.

    Parameters
    ----------
    doc : Corrections
    limit : int
        Maximum number of undo steps kept (oldest dropped first).
    merge_timeout_s : float
        Mergeable commands merge only if pushed within this time of the previous one (a pause
        starts a new undo step). :meth:`break_merge` ends a merge sequence explicitly.
    clock : callable
        Time source (seconds); injectable for tests.
    """

    def __init__(self, doc: Corrections, limit: int = 1000, merge_timeout_s: float = 1.5,
                 clock: Callable[[], float] = time.monotonic):
        self.doc = doc
        self.limit = limit
        self.merge_timeout_s = merge_timeout_s
        self._clock = clock
        self._stack: list[Command] = []
        self._index = 0  # number of commands applied
        self._clean: int | None = 0
        self._last_push_t = -float("inf")
        self._merge_open = False
        self._group: Group | None = None
        #: One :class:`~evpose.core.signals.Change` per step (see the module docstring).
        self.changed: Signal[Change] = Signal(Change)

    def _notify(self, cmd: Command | None = None) -> None:
        """Emit the change of one step: the fields ``cmd`` set, or only the history state."""
        if cmd is None:
            self.changed.emit(Change("history"))
        else:
            self.changed.emit(Change("document", frozenset(change_field(k) for k in cmd.keys())))

    # ------------------------------------------------------------------ state
    @property
    def index(self) -> int:
        return self._index

    def __len__(self) -> int:
        return len(self._stack)

    @property
    def can_undo(self) -> bool:
        return self._index > 0 and self._group is None

    @property
    def can_redo(self) -> bool:
        return self._index < len(self._stack) and self._group is None

    @property
    def undo_text(self) -> str:
        return self._stack[self._index - 1].text if self._index > 0 else ""

    @property
    def redo_text(self) -> str:
        return self._stack[self._index].text if self._index < len(self._stack) else ""

    @property
    def is_clean(self) -> bool:
        return self._clean == self._index

    def set_clean(self) -> None:
        """Mark the current state as saved (emits only if the clean state moved)."""
        was = self._clean
        self._clean = self._index
        self._merge_open = False
        if was != self._clean:
            self._notify()

    def break_merge(self) -> None:
        """The next mergeable command starts a new undo step."""
        self._merge_open = False

    # ------------------------------------------------------------------ editing
    def push(self, cmd: Command) -> None:
        """Run ``cmd`` and record it (merging into the previous step when allowed)."""
        cmd.redo(self.doc)
        if self._group is not None:
            self._group.commands.append(cmd)
            return
        self._record(cmd)

    def _record(self, cmd: Command, notify: bool = True) -> None:
        """Record ``cmd`` (already run) as a step, or merge it into the top one; emits one change
        when the document changed (unless ``notify`` is False: the caller emits)."""
        now = self._clock()
        top = self._stack[self._index - 1] if self._index > 0 else None
        can_merge = (top is not None and self._merge_open and self._index == len(self._stack)
                     and self._clean != self._index and cmd.merge_key is not None
                     and now - self._last_push_t <= self.merge_timeout_s)
        self._last_push_t = now
        if can_merge and top.merge(cmd):
            if top.is_noop():  # the burst went back to where it started
                self._stack.pop()
                self._index -= 1
                self._merge_open = False
            if notify:
                self._notify(cmd)
            return
        if cmd.is_noop():  # nothing changed: no undo step
            return
        del self._stack[self._index:]
        if self._clean is not None and self._clean > self._index:
            self._clean = None  # the saved state can no longer be reached
        self._stack.append(cmd)
        self._index += 1
        self._merge_open = cmd.merge_key is not None
        if len(self._stack) > self.limit:
            drop = len(self._stack) - self.limit
            del self._stack[:drop]
            self._index -= drop
            if self._clean is not None:
                self._clean = self._clean - drop if self._clean >= drop else None
        if notify:
            self._notify(cmd)

    def push_external(self, cmd: Command, clean: bool) -> None:
        """Run and record an edit that another program made to the file (taken over on reload,
        merge or save) as one undo step of its own, never merged with a neighbour.

        ``clean``: the document now equals the file on disk (the new step becomes the saved state);
        otherwise no state in the history equals the file any more (the clean index is dropped).
        Undoing the step returns to the state before it, which then differs from the file."""
        if self._group is not None:
            raise RuntimeError("an external change cannot be recorded inside a group")
        self._merge_open = False
        was_clean = self._clean
        cmd.redo(self.doc)
        self._record(cmd, notify=False)
        self._merge_open = False
        self._clean = self._index if clean else None
        if not cmd.is_noop():
            self._notify(cmd)
        elif self._clean != was_clean:
            self._notify()

    def set(self, key: tuple, new, text: str | None = None, mergeable: bool = False) -> None:
        """Shorthand: push a :class:`SetValue` from the current value to ``new`` (no-op if equal).

        A value that carries an estimate's sigma (:attr:`Corrections.sigmas`) loses it when it changes: the sigma
        said how far the estimate could be off, not a hand edit (the same undo step, so undo brings both back).
        An estimate stores its sigma after its value, in the same group (:mod:`evpose.core.document.estimates`)."""
        part = sigma_part(key)
        if part is None or self.doc.sigma(part) is None or _same(self.doc.get(key), new):
            self.push(set_command(self.doc, key, new, text=text, mergeable=mergeable))
            return
        value = set_command(self.doc, key, new, text=text, mergeable=mergeable)
        grp = Group(value.text, [value, set_command(self.doc, ("sigma", part), None, text=text)], value.merge_key)
        self.push(grp)

    @contextlib.contextmanager
    def group(self, text: str):
        """Collect every command pushed inside the block into one undo step.

        If the block raises, the commands already run are undone and nothing is recorded.
        Nested groups fold into the outermost one.
        """
        outer = self._group is None
        if outer:
            self._group = Group(text)
        try:
            yield
        except BaseException:
            if outer:
                grp, self._group = self._group, None
                grp.undo(self.doc)
            raise
        if outer:
            grp, self._group = self._group, None
            if grp.commands:
                self._merge_open = False
                self._record(grp)  # a net no-op group records nothing

    def undo(self) -> bool:
        if not self.can_undo:
            return False
        self._index -= 1
        self._stack[self._index].undo(self.doc)
        self._merge_open = False
        self._notify(self._stack[self._index])
        return True

    def redo(self) -> bool:
        if not self.can_redo:
            return False
        self._stack[self._index].redo(self.doc)
        self._index += 1
        self._merge_open = False
        self._notify(self._stack[self._index - 1])
        return True

    def clear(self) -> None:
        """Forget all steps (the document keeps its current state, which becomes clean)."""
        self._stack.clear()
        self._index = 0
        self._clean = 0
        self._merge_open = False
        self._notify()

