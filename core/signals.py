"""Change notification: one small typed signal whose subscribers are held weakly.

The models the views watch (:class:`~evpose.core.document.history.History`,
:class:`~evpose.core.session.model.Session`) each own a :class:`Signal` and emit one :class:`Change`
per edit, so a view never has to merge several notifications of one user action.

Subscribers are held the way napari's ``EventEmitter`` holds them: a bound method by a
:class:`weakref.WeakMethod` (a signal never keeps a view alive), a plain function or lambda
strongly (it has no owner to follow), and :meth:`Signal.connect` returns a :class:`Connection`
whose :meth:`~Connection.disconnect` ends the subscription either way. A subscriber that died
is dropped the next time the signal emits (or counts its subscribers).
"""
from __future__ import annotations

import inspect
import weakref
from dataclasses import dataclass
from typing import Any, Callable, Generic, TypeVar

__all__ = ["ALL_KINDS", "DOCUMENT", "HISTORY", "OBJECTS", "TIME", "VIEW", "Change", "Connection", "Signal"]

#: The kinds of :class:`Change` (see its docstring). A subscriber names the kinds it shows
#: (``Signal.connect(slot, kinds=...)``) and is not called for the others: a time step reaches only the views
#: that depend on the time.
DOCUMENT, HISTORY, TIME, VIEW, OBJECTS = "document", "history", "time", "view", "objects"
ALL_KINDS = frozenset({DOCUMENT, HISTORY, TIME, VIEW, OBJECTS})

T = TypeVar("T")


@dataclass(frozen=True)
class Change:
    """What one action changed.

    Attributes
    ----------
    kind : str
        ``"document"`` (the corrections: saved, undoable), ``"history"`` (only the undo stack or
        its clean state), or a kind of view state (not saved, not undoable): ``"time"`` (current
        time), ``"view"`` (window length, representation, overlays, display options),
        ``"objects"`` (visibility, selection).
    fields : frozenset of str
        For ``"document"``: the document fields the step set (``"clock"``, ``"hand_eye"``,
        ``"reviews"``, ``"object:<name>"``); for view kinds: the ``ViewState`` attributes
        that changed; empty for ``"history"``.
    """

    kind: str
    fields: frozenset = frozenset()

    def __post_init__(self):
        if self.kind not in ALL_KINDS:
            raise ValueError(f"Change kind {self.kind!r} is not one of {sorted(ALL_KINDS)}")


class Connection:
    """One subscription of a callable to a :class:`Signal`; :meth:`disconnect` ends it."""

    __slots__ = ("_signal", "_ref", "_strong", "kinds", "__weakref__")

    def __init__(self, signal: "Signal", slot: Callable, kinds=None):
        self._signal = signal
        self.kinds = None if kinds is None else frozenset(kinds)
        if inspect.ismethod(slot):
            self._ref, self._strong = weakref.WeakMethod(slot), None
        else:
            self._ref, self._strong = None, slot

    def slot(self) -> Callable | None:
        """The subscribed callable, or None when it died or was disconnected."""
        if self._signal is None:
            return None
        return self._strong if self._ref is None else self._ref()

    @property
    def connected(self) -> bool:
        return self.slot() is not None

    def disconnect(self, *_: Any) -> None:
        """End the subscription (idempotent; extra arguments ignored, so it can be a Qt slot)."""
        signal, self._signal, self._strong = self._signal, None, None
        if signal is not None:
            signal._drop(self)


class Signal(Generic[T]):
    """Calls every live subscriber with the payload of :meth:`emit`, in subscription order.

    Parameters
    ----------
    payload_type : type
        :meth:`emit` refuses any other payload (``TypeError``), so every subscriber can rely on it.
    """

    def __init__(self, payload_type: type):
        self.payload_type = payload_type
        self._connections: list[Connection] = []

    def connect(self, slot: Callable[[T], Any], kinds=None) -> Connection:
        """Subscribe ``slot(payload)``: a bound method weakly, anything else strongly. ``kinds`` (payloads with a
        ``kind``, as :class:`Change`): only those kinds reach ``slot`` (None: every payload)."""
        if not callable(slot):
            raise TypeError(f"cannot subscribe {slot!r}: not callable")
        if kinds is not None and not set(kinds) <= ALL_KINDS:
            raise ValueError(f"unknown change kinds {sorted(set(kinds) - ALL_KINDS)}")
        conn = Connection(self, slot, kinds)
        self._connections.append(conn)
        return conn

    def disconnect(self, slot: Callable) -> None:
        """End every subscription of ``slot`` (equal bound methods match)."""
        for conn in list(self._connections):
            if conn.slot() == slot:
                conn.disconnect()

    def emit(self, payload: T) -> None:
        """Call each subscriber connected when the emit starts and still connected at its turn;
        drop those that died. An exception of a subscriber propagates (the rest are not called)."""
        if not isinstance(payload, self.payload_type):
            raise TypeError(f"expected a {self.payload_type.__name__} payload, got {payload!r}")
        kind = getattr(payload, "kind", None)
        for conn in list(self._connections):
            slot = conn.slot()
            if slot is None:
                self._drop(conn)
            elif conn.kinds is None or kind in conn.kinds:
                slot(payload)

    def __len__(self) -> int:
        """Number of live subscribers (dead ones are dropped)."""
        for conn in list(self._connections):
            if conn.slot() is None:
                self._drop(conn)
        return len(self._connections)

    def _drop(self, conn: Connection) -> None:
        try:
            self._connections.remove(conn)
        except ValueError:
            pass
