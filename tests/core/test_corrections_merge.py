"""Three-way merge of corrections (evpose.core.document.corrections_merge): per field, review marks as a set."""
import numpy as np
import pytest

from evpose.core.data.geometry import T_from_rotvec
from evpose.core.document.corrections import Corrections, ReviewMark
from evpose.core.document.corrections_merge import CorrectionsConflict, merge
from evpose.core.document.review import insert_mark


def _doc(**kw):
    d = Corrections()
    for k, v in kw.items():
        d.set((k,) if k != "box" else ("object", "box"), v)
    return d


def test_fields_changed_on_one_side_each_are_combined():
    base = _doc(offset_us=1, skew_ppm=0.5)
    local = _doc(offset_us=1, skew_ppm=0.5, box=T_from_rotvec([0, 0, 0.1]))
    disk = _doc(offset_us=7, skew_ppm=0.5)
    res = merge(base, local, disk)
    assert res.doc.offset_us == 7 and np.array_equal(res.doc.object_delta("box"), local.object_delta("box"))
    assert res.from_disk == ["clock.offset_us"] and res.conflicts == []


def test_same_change_on_both_sides_is_not_a_conflict():
    res = merge(_doc(), _doc(skew_ppm=2.0), _doc(skew_ppm=2.0))
    assert res.doc.skew_ppm == 2.0 and res.from_disk == []


@pytest.mark.parametrize("key,lv,dv,field,shown", [
    ("offset_us", 10, 20, "clock.offset_us", ("10 us", "20 us")),
    ("skew_ppm", 1.25, -3.0, "clock.skew_ppm", ("1.25 ppm", "-3.0 ppm")),
    ("box", T_from_rotvec([0, 0, 0], [0.001, 0, 0]), T_from_rotvec([0, 0, 0], [0.002, 0, 0]), "objects.box.dT_base",
     ("dt (1.00, 0.00, 0.00) mm", "dt (2.00, 0.00, 0.00) mm")),
])
def test_conflict_names_field_and_both_values(key, lv, dv, field, shown):
    with pytest.raises(CorrectionsConflict) as ei:
        merge(_doc(), _doc(**{key: lv}), _doc(**{key: dv}), source="S/corrections.json")
    msg = str(ei.value)
    assert msg.startswith("S/corrections.json: " + field) and shown[0] in msg and shown[1] in msg
    assert merge(_doc(), _doc(**{key: lv}), _doc(**{key: dv}), prefer="local").doc.get(
        ("object", "box") if key == "box" else (key,)) is not None


def test_prefer_resolves_conflicts_either_way():
    assert merge(_doc(), _doc(offset_us=1), _doc(offset_us=2), prefer="local").doc.offset_us == 1
    r = merge(_doc(), _doc(offset_us=1), _doc(offset_us=2), prefer="disk")
    assert r.doc.offset_us == 2 and [c.field for c in r.conflicts] == ["clock.offset_us"]


def _with(marks):
    d = Corrections()
    d.set(("reviews",), marks)
    return d


def test_reviews_merge_as_a_set():
    a, b, c = ReviewMark(0, 10, "verified"), ReviewMark(10, 20, "verified"), ReviewMark(20, 30, "flagged")
    base = _with([a])
    local = _with([a, b])                 # added b
    disk = _with([c])                     # removed a, added c
    res = merge(base, local, disk)
    assert set(res.doc.reviews) == {b, c} and "reviews" in res.from_disk


def test_reviews_overlapping_additions_with_different_status_conflict():
    base = _with([])
    local = _with([ReviewMark(0, 10, "verified")])
    disk = _with([ReviewMark(5, 15, "rejected")])
    with pytest.raises(CorrectionsConflict, match=r"reviews: changed here to verified \[0, 10\) us .* rejected \[5, 15\)"):
        merge(base, local, disk)
    kept = merge(base, local, disk, prefer="local").doc.reviews
    assert [(m.t0_us, m.t1_us, m.status) for m in kept] == [(0, 10, "verified")]


def test_reviews_trimmed_on_one_side_stay_trimmed():
    whole = ReviewMark(0, 100, "verified")
    base = _with([whole])
    local = _with(insert_mark([whole], ReviewMark(40, 50, "rejected")))   # split by a rejection
    disk = _with([whole, ReviewMark(200, 210, "flagged")])
    doc = merge(base, local, disk).doc
    assert doc.review_status(45) == "rejected" and doc.review_status(10) == "verified"
    assert doc.review_status(205) == "flagged"
    assert sum(m.covers(45) for m in doc.reviews) == 1
