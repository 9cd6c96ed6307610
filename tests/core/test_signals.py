"""The one change-notification mechanism (evpose.core.signals): typed payloads, bound methods held
weakly, functions held strongly until disconnected, dead subscribers dropped, safe re-entrance."""
import gc
import weakref

import pytest

from evpose.core.signals import Change, Signal


class View:
    def __init__(self):
        self.seen = []

    def on_change(self, change):
        self.seen.append(change)


def test_emit_calls_each_subscriber_once_in_order_with_the_payload():
    sig = Signal(Change)
    order = []
    a, b = View(), View()
    sig.connect(a.on_change)
    sig.connect(lambda c: order.append(("lambda", c)))
    sig.connect(b.on_change)
    change = Change("document", frozenset({"clock"}))
    sig.emit(change)
    assert a.seen == [change] and b.seen == [change] and order == [("lambda", change)]
    assert len(sig) == 3


def test_payload_type_is_enforced():
    sig = Signal(Change)
    with pytest.raises(TypeError, match="Change"):
        sig.emit("document")
    with pytest.raises(TypeError, match="not callable"):
        sig.connect(42)


def test_a_bound_method_does_not_keep_its_object_alive_and_is_dropped():
    sig = Signal(Change)
    view = View()
    sig.connect(view.on_change)
    ref = weakref.ref(view)
    del view
    gc.collect()
    assert ref() is None                      # the signal held it weakly
    assert len(sig) == 0                      # ... and dropped it
    sig.emit(Change("time"))                  # nothing to call, no error


def test_emitting_drops_a_dead_subscriber():
    sig = Signal(Change)
    view, other = View(), View()
    sig.connect(view.on_change)
    sig.connect(other.on_change)
    del view
    gc.collect()
    sig.emit(Change("time"))
    assert len(sig._connections) == 1 and other.seen == [Change("time")]


def test_a_lambda_is_held_strongly_until_its_connection_is_disconnected():
    sig = Signal(Change)
    seen = []
    conn = sig.connect(lambda c: seen.append(c))
    gc.collect()
    sig.emit(Change("view"))
    assert seen == [Change("view")] and conn.connected
    conn.disconnect()
    conn.disconnect()                         # idempotent
    sig.emit(Change("view"))
    assert seen == [Change("view")] and not conn.connected and len(sig) == 0


def test_disconnect_by_slot_and_by_connection_of_a_bound_method():
    sig = Signal(Change)
    a, b = View(), View()
    sig.connect(a.on_change)
    conn_b = sig.connect(b.on_change)
    sig.disconnect(a.on_change)               # a fresh bound method object compares equal
    conn_b.disconnect()
    sig.emit(Change("time"))
    assert a.seen == [] and b.seen == [] and len(sig) == 0


def test_a_subscriber_disconnected_during_an_emit_is_not_called_afterwards():
    sig = Signal(Change)
    late = View()
    conns = {}

    def first(change):
        conns["late"].disconnect()

    sig.connect(first)
    conns["late"] = sig.connect(late.on_change)
    sig.emit(Change("time"))
    assert late.seen == []


def test_a_subscriber_connected_during_an_emit_waits_for_the_next_one():
    sig = Signal(Change)
    added = View()
    sig.connect(lambda c: sig.connect(added.on_change) if not len(added.seen) and len(sig) < 2 else None)
    sig.emit(Change("time"))
    assert added.seen == []
    sig.emit(Change("view"))
    assert added.seen == [Change("view")]


def test_reentrant_emit_from_a_subscriber_reaches_everyone():
    sig = Signal(Change)
    seen = []

    def echo(change):
        seen.append(change.kind)
        if change.kind == "time":
            sig.emit(Change("view"))

    sig.connect(echo)
    sig.emit(Change("time"))
    assert seen == ["time", "view"]


def test_change_is_a_frozen_value():
    a = Change("document", frozenset({"clock"}))
    assert a == Change("document", frozenset({"clock"})) and hash(a) == hash(Change("document", frozenset({"clock"})))
    with pytest.raises(AttributeError):
        a.kind = "view"


def test_a_subscriber_gets_only_the_kinds_it_names():
    from evpose.core.signals import DOCUMENT, TIME, Change, Signal

    sig = Signal(Change)
    got, every = [], []
    sig.connect(got.append, kinds={TIME})
    sig.connect(every.append)
    sig.emit(Change(DOCUMENT, frozenset({"clock"})))
    sig.emit(Change(TIME, frozenset({"t_us"})))
    assert [c.kind for c in got] == [TIME] and [c.kind for c in every] == [DOCUMENT, TIME]
    with pytest.raises(ValueError, match="unknown change kinds"):
        sig.connect(got.append, kinds={"tiem"})
    with pytest.raises(ValueError, match="not one of"):
        Change("tiem")
