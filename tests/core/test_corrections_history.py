import json

import numpy as np
import pytest

from evpose.core.data.geometry import T_from_rotvec
from evpose.core.document.corrections import Corrections, CorrectionsError, ReviewMark
from evpose.core.document.commands import Group, SetValue
from evpose.core.document.history import History
from evpose.core.signals import Change


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_save_load_roundtrip_is_exact(tmp_path):
    c = Corrections(offset_us=-10_000_000, skew_ppm=-1000.0 + 1e-9, scene_name="s")
    c.set(("object", "drill"), T_from_rotvec([0.01, -0.02, 0.03], [0.001, 0.002, -0.003]))
    c.set(("hand_eye",), T_from_rotvec([0, 0.001, 0], [0, 0, 0.0005]))
    c.set(("reviews",), [ReviewMark(0, 10_000, "verified"), ReviewMark(5_000, 6_000, "flagged", "blur", "drill")])
    p = c.save(tmp_path / "corrections.json")
    back = Corrections.load(p)
    assert back.offset_us == -10_000_000 and back.skew_ppm == c.skew_ppm
    np.testing.assert_array_equal(back.object_deltas["drill"], c.object_deltas["drill"])
    np.testing.assert_array_equal(back.hand_eye_delta, c.hand_eye_delta)
    assert back.reviews == c.reviews
    assert back.review_status(5_500, "drill") == "flagged"
    assert back.review_status(5_500, "other") == "verified"
    assert back.review_status(20_000) is None


def test_save_is_atomic_and_keeps_old_file_on_failure(tmp_path, monkeypatch):
    p = tmp_path / "corrections.json"
    Corrections(offset_us=5).save(p)
    import evpose.core.data.atomic as fio

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(fio.os, "replace", boom)
    doc = Corrections.load(p)
    doc.set(("offset_us",), 7)
    with pytest.raises(OSError):
        doc.save(p)
    assert Corrections.load(p).offset_us == 5
    assert [x.name for x in tmp_path.iterdir()] == ["corrections.json"]  # no temp left behind


@pytest.mark.parametrize("payload,match", [
    ("{", "not valid JSON"),
    ('{"format": "other"}', "format"),
    ('{"format": "evpose-corrections/1", "clock": {"offset_us": 1.5}}', "clock.offset_us"),
    ('{"format": "evpose-corrections/1", "clock": {"skew_ppm": "x"}}', "clock.skew_ppm"),
    ('{"format": "evpose-corrections/1", "objects": {"a": {"dT_base": [[1,0],[0,1]]}}}', "objects.a.dT_base"),
    ('{"format": "evpose-corrections/1", "objects": {"a": {"dT_base": [[1,0,0,0],[0,1,0,0],[0,0.3,1,0],[0,0,0,1]]}}}',
     "objects.a.dT_base.*orthonormal"),
    ('{"format": "evpose-corrections/1", "reviews": [{"t0_us": 5, "t1_us": 1, "status": "verified"}]}', "reviews\\[0\\]"),
    ('{"format": "evpose-corrections/1", "reviews": [{"t0_us": 0, "t1_us": 1, "status": "maybe"}]}', "reviews\\[0\\]"),
    ('{"format": "evpose-corrections/1", "reviews": [{"t1_us": 1, "status": "verified"}]}', "reviews\\[0\\].t0_us"),
])
def test_invalid_files_name_the_field(tmp_path, payload, match):
    p = tmp_path / "corrections.json"
    p.write_text(payload)
    with pytest.raises(CorrectionsError, match=match) as ei:
        Corrections.load(p)
    assert str(p) in str(ei.value)


def test_undo_redo_and_listeners():
    c = Corrections()
    seen = []
    h = History(c)
    h.changed.connect(seen.append)
    h.set(("offset_us",), 1000)
    h.set(("skew_ppm",), 2.5)
    assert (c.offset_us, c.skew_ppm) == (1000, 2.5)
    assert h.undo() and c.skew_ppm == 0.0
    assert h.undo() and c.offset_us == 0
    assert not h.undo()
    assert h.redo() and c.offset_us == 1000
    assert seen == [Change("document", frozenset({"clock"}))] * 5
    h.set(("offset_us",), 1000)  # no-op: no step, and the redo branch survives
    assert h.index == 1 and h.can_redo and len(h) == 2


def test_nudges_merge_within_timeout_and_not_across_a_pause():
    clock = FakeClock()
    c = Corrections()
    h = History(c, clock=clock, merge_timeout_s=1.0)
    for k in range(1, 6):
        clock.t += 0.2
        h.set(("offset_us",), k * 100, mergeable=True)
    assert len(h) == 1 and c.offset_us == 500
    clock.t += 5.0
    h.set(("offset_us",), 600, mergeable=True)
    assert len(h) == 2
    h.undo()
    assert c.offset_us == 500
    h.undo()
    assert c.offset_us == 0


def test_merge_that_returns_to_start_removes_the_step():
    clock = FakeClock()
    c = Corrections()
    h = History(c, clock=clock)
    h.set(("offset_us",), 100, mergeable=True)
    h.set(("offset_us",), 0, mergeable=True)
    assert len(h) == 0 and h.is_clean


def test_different_fields_and_break_merge_do_not_merge():
    c = Corrections()
    h = History(c)
    h.set(("offset_us",), 1, mergeable=True)
    h.set(("skew_ppm",), 1.0, mergeable=True)
    assert len(h) == 2
    h.break_merge()
    h.set(("skew_ppm",), 2.0, mergeable=True)
    assert len(h) == 3


def test_clean_marker_and_no_merge_into_saved_state():
    c = Corrections()
    h = History(c)
    assert h.is_clean
    h.set(("offset_us",), 1, mergeable=True)
    assert not h.is_clean
    h.set_clean()
    h.set(("offset_us",), 2, mergeable=True)  # must not merge into the saved step
    assert len(h) == 2 and not h.is_clean
    h.undo()
    assert h.is_clean and c.offset_us == 1
    h.undo()
    h.set(("skew_ppm",), 3.0)  # branches off: the saved state is unreachable
    assert not h.is_clean
    assert all(not h.is_clean for _ in [h.undo(), h.redo()])


def test_group_is_one_step_and_rolls_back_on_error():
    c = Corrections()
    h = History(c)
    with h.group("accept sync"):
        h.set(("offset_us",), 35_000)
        h.set(("skew_ppm",), 12.0)
    assert len(h) == 1 and h.undo_text == "accept sync"
    h.undo()
    assert (c.offset_us, c.skew_ppm) == (0, 0.0)
    h.redo()
    with pytest.raises(RuntimeError):
        with h.group("broken"):
            h.set(("offset_us",), 1)
            raise RuntimeError("x")
    assert c.offset_us == 35_000 and len(h) == 1


def test_object_delta_command_and_limit():
    c = Corrections()
    h = History(c, limit=3)
    T = T_from_rotvec([0, 0, 0.1], [0.01, 0, 0])
    h.push(SetValue(("object", "a"), c.get(("object", "a")), T))
    np.testing.assert_array_equal(c.object_delta("a"), T)
    h.undo()
    assert "a" not in c.object_deltas  # identity is not stored
    h.redo()
    for k in range(5):
        h.set(("offset_us",), k + 1)
    assert len(h) == 3
    while h.undo():
        pass
    assert c.offset_us == 2  # the oldest steps were dropped, the state is consistent
    assert isinstance(Group("g", []), Group)


def test_json_is_stable_text(tmp_path):
    c = Corrections(offset_us=3)
    p = c.save(tmp_path / "c.json")
    d = json.loads(p.read_text())
    assert d["clock"] == {"offset_us": 3, "skew_ppm": 0.0}
