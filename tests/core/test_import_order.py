"""Issue 22: the event sink's verdict on time order, in process (the CLI cases are in
``tests/faults/test_import_strict.py``).

An event out of order by at most the reorder window is put in place (counted), a later one is refused (or with
``--repair`` dropped, counted); the verdict, the refusal's message and what is written must not depend on how
the stream is cut into chunks (packets, messages, read blocks). And dv-processing's C++ exception text reaches the
user as one line without its stack trace.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evpose.core.data.events import EventArray
from evpose.core.importers.event_sink import EventSink
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.options import ImportOptions
from evpose.core.importers.report import ImportContext

WINDOW_US = 1000


class Collect:
    """An EventWriter stand-in that keeps what it is given."""

    def __init__(self):
        self.parts = []

    def append(self, ev):
        self.parts.append(ev)


def sink_outcome(t: np.ndarray, cuts: list[int], repair: bool):
    """``(refusal message or None, written times, counts)`` of ``t`` fed in the chunks ``cuts`` delimit."""
    ctx = ImportContext("t", [], ImportOptions(reorder_window_us=WINDOW_US, repair=repair), log=None)
    w = Collect()
    sink = EventSink(ctx, w, 10, 10)
    n = len(t)
    x = np.arange(n) % 10                              # x and y tell the events apart in the output
    y = np.arange(n) // 10 % 10
    try:
        for a, b in zip([0, *cuts], [*cuts, n]):
            if b > a:
                sink.add(x[a:b], y[a:b], t[a:b], np.zeros(b - a, np.uint8), file="f", record=f"[{a}, {b})", first=a)
        sink.close()
    except ImportFailure as exc:
        return str(exc), None, None
    got = EventArray.concatenate(w.parts) if w.parts else None
    out = (got.t, got.x, got.y) if got is not None else None
    # events_decreasing_steps counts steps inside chunks: it depends on the chunks by definition
    return None, out, {k: v for k, v in ctx.report.counts.items()
                       if k.startswith("events_") and k != "events_decreasing_steps"}


@st.composite
def streams(draw):
    """A sorted stream with some events moved back by up to 3 windows, and a random cut into chunks."""
    n = draw(st.integers(2, 120))
    t = np.cumsum(draw(st.lists(st.integers(0, 400), min_size=n, max_size=n))).astype(np.int64) + 10**6
    back = draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(1, 3 * WINDOW_US)), max_size=6))
    for i, d in back:
        t[i] -= d
    cuts = sorted(draw(st.sets(st.integers(1, n - 1), max_size=8))) if n > 1 else []
    return t, cuts


@settings(max_examples=150, deadline=None, derandomize=True)
@given(streams(), st.booleans())
def test_time_order_verdict_does_not_depend_on_the_chunks(stream, repair):
    t, cuts = stream
    whole = sink_outcome(t, [], repair)
    chunked = sink_outcome(t, cuts, repair)
    assert whole[0] == chunked[0] and whole[2] == chunked[2]
    if whole[1] is not None:
        for a, b in zip(whole[1], chunked[1]):
            np.testing.assert_array_equal(a, b)
    if whole[0] is None:                               # written sorted, no time changed, nothing dropped
        got_t = whole[1][0]                            # unless --repair dropped (and counted) late ones
        assert np.all(np.diff(got_t) >= 0)
        dropped = whole[2].get("events_dropped_late", 0)
        assert (dropped > 0) == (len(got_t) < len(t)) and len(got_t) + dropped == len(t)
        assert repair or got_t.tolist() == sorted(t.tolist())


def test_out_of_order_within_the_window_is_counted_beyond_it_refused():
    t = np.array([0, 10, 20, 15, 30, 30 - WINDOW_US - 1, 50], np.int64) + 10**6
    msg, _, _ = sink_outcome(t, [3], repair=False)
    assert msg == (f"f: event 5: t: t={t[5]} µs is {WINDOW_US + 1} µs older than an event before it (t={t[4]} µs): "
                   f"out of time order by more than the reorder window ({WINDOW_US} µs). Pass --repair to drop such "
                   "events, or a larger --reorder-window-ms")
    msg, (got, _, _), counts = sink_outcome(np.delete(t, 5), [2], repair=False)
    assert msg is None and got.tolist() == sorted(np.delete(t, 5).tolist())
    assert counts["events_out_of_order"] == 1
    msg, (got, _, _), counts = sink_outcome(t, [], repair=True)
    assert counts["events_dropped_late"] == 1 and counts["events_out_of_order"] == 1 and len(got) == 6


def test_dv_processing_error_loses_its_cpp_stack_trace(tmp_path):
    """A real dv-processing exception (an empty file) as the reading process reports it: one line, no stack."""
    dv = pytest.importorskip("dv_processing")
    from evpose.core.importers.aedat4_reader import _one_line

    (tmp_path / "empty.aedat4").write_bytes(b"")
    with pytest.raises(Exception) as ei:
        dv.io.MonoCameraRecording(str(tmp_path / "empty.aedat4"))
    text = f"{ei.value} ({type(ei.value).__name__})"
    assert "Stacktrace" in text                               # what the library says
    line = _one_line(text)
    assert "\n" not in line and "Stacktrace" not in line and "0x0" not in line and "End-Of-File" in line
