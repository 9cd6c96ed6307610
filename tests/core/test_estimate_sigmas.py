"""Issue 28.3: an applied estimate keeps its sigma in the document (``corrections.json``'s ``sigmas``), a hand edit
of the value drops it (undo brings both back), and the labels' sigma of the app and of ``export --label-sigma auto``
start from what is stored."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from evpose.core.data.geometry import T_from_rotvec
from evpose.core.document.corrections import Corrections, CorrectionsError
from evpose.core.document.estimates import apply_hand_eye_estimate, apply_pose_estimate
from evpose.core.document.history import History


def test_a_pose_estimate_keeps_its_sigma_and_a_hand_edit_drops_it():
    doc = Corrections()
    h = History(doc)
    T = T_from_rotvec([0, 0, 0.01], [0.002, 0, 0])
    apply_pose_estimate(h, "box", T, "refine box", std_mm=0.4, std_deg=0.2)
    assert len(h) == 1 and doc.sigma("object:box") == {"mm": 0.4, "deg": 0.2}
    apply_hand_eye_estimate(h, T, "hand-eye", std_mm=0.7, std_deg=float("inf"))     # an infinite sigma is no sigma
    assert doc.sigma("hand_eye") == {"mm": 0.7}
    h.set(("object", "box"), T @ T, text="move box")                              # by hand
    assert len(h) == 3 and doc.sigma("object:box") is None and doc.sigma("hand_eye") == {"mm": 0.7}
    h.undo()
    assert doc.sigma("object:box") == {"mm": 0.4, "deg": 0.2} and np.allclose(doc.object_delta("box"), T)
    h.set(("object", "box"), T, text="same value")                                 # no change: sigma kept
    assert doc.sigma("object:box") == {"mm": 0.4, "deg": 0.2} and h.index == 2 and h.can_redo
    h.set(("hand_eye",), np.eye(4), text="reset hand-eye")
    assert doc.sigma("hand_eye") is None


def test_sigmas_round_trip_and_a_document_without_them_is_written_as_before(tmp_path):
    doc = Corrections()
    assert "sigmas" not in doc.to_json() and "sigmas" not in doc.canonical()
    h = History(doc)
    apply_pose_estimate(h, "box", np.eye(4) @ T_from_rotvec([0, 0, 0.01], [0, 0, 0]), std_mm=0.5, std_deg=0.25)
    back = Corrections.from_json(json.loads(json.dumps(doc.to_json())))
    assert back.sigmas == {"object:box": {"mm": 0.5, "deg": 0.25}} and back.digest() == doc.digest()
    assert Corrections.from_json(Corrections().to_json()).digest() == Corrections().digest()


@pytest.mark.parametrize("sigmas, field", [
    ({"object:": {"mm": 1}}, "sigmas.object:"),
    ({"clock": {"mm": 1}}, "sigmas.clock.mm"),
    ({"hand_eye": {"mm": -1}}, "sigmas.hand_eye.mm"),
    ({"object:box": {"deg": "1"}}, "sigmas.object:box.deg"),
    ({"object:box": {}}, "sigmas.object:box"),
    ({"lens": {"mm": 1}}, "sigmas.lens"),
])
def test_a_bad_sigma_is_refused_naming_its_field(sigmas, field):
    d = Corrections().to_json()
    d["sigmas"] = sigmas
    with pytest.raises(CorrectionsError) as e:
        Corrections.from_json(d, source="x/corrections.json")
    assert str(e.value).startswith(f"x/corrections.json: {field}"), str(e.value)


def test_a_sigma_saved_meanwhile_by_another_program_is_merged(tmp_path):
    from evpose.core.document.corrections_merge import merge

    base = Corrections()
    disk, local = base.copy(), base.copy()
    apply_pose_estimate(History(disk), "box", T_from_rotvec([0, 0, 0.02], [0, 0, 0]), std_mm=0.3, std_deg=0.1)
    History(local).set(("object", "can"), T_from_rotvec([0, 0.02, 0], [0, 0, 0]))
    out = merge(base, local, disk)
    assert out.doc.sigma("object:box") == {"mm": 0.3, "deg": 0.1} and "sigmas.object:box" in out.from_disk


def test_stored_input_sigmas_say_what_is_missing():
    from evpose.core.label.uncertainty import stored_input_sigmas

    doc = Corrections()
    h = History(doc)
    apply_pose_estimate(h, "box", T_from_rotvec([0, 0, 0.02], [0, 0, 0]), std_mm=0.3, std_deg=0.1)
    s, missing = stored_input_sigmas(doc, "box")
    assert (s.pose_mm, s.pose_deg, s.offset_us) == (0.3, 0.1, 0.0) and missing == ["clock offset", "hand-eye"]
    s, missing = stored_input_sigmas(doc, "can")
    assert missing == ["clock offset", "object pose", "hand-eye"]


def test_the_joint_fit_applied_stores_its_sigmas_and_auto_label_sigmas_use_them(scene_copy):
    """Every part of an applied joint estimate carries its sigma into the document, and ``label_sigmas`` from the
    stored sigmas (auto) equal those of the same inputs given by hand, object by object."""
    from evpose.core.align.apply import apply_joint_result
    from evpose.core.align.joint_fit import refine_joint
    from evpose.core.align.joint_result import JointParams
    from evpose.core.data.scene import Scene
    from evpose.core.label.uncertainty import LabelSigmaOptions, label_sigmas, stored_input_sigmas

    with Scene.open(scene_copy) as scene:
        r = refine_joint(scene, params=JointParams(n_windows=12, skew="fixed"))
        h = History(scene.corrections)
        assert apply_joint_result(h, scene, r) and len(h) == 1
        c = scene.corrections
        assert c.sigma("clock") == {"offset_us": pytest.approx(r.offset_std_us)}
        for n, o in r.objects.items():
            if not np.array_equal(c.object_delta(n), np.eye(4)):
                assert c.sigma(f"object:{n}") == {"mm": pytest.approx(o.std_mm), "deg": pytest.approx(o.std_deg)}
            else:            # confirmed (within 2 sigma): kept, with the estimate's sigma and its distance in quadrature
                assert c.sigma(f"object:{n}") == {"mm": pytest.approx(math.hypot(o.dt_mm, o.std_mm)),
                                                  "deg": pytest.approx(math.hypot(o.dR_deg, o.std_deg))}
        t = np.linspace(scene.events.t_first_us, scene.events.t_last_us, 7).astype(np.int64)[1:-1]
        names = [n for n in scene.object_names if c.sigma(f"object:{n}")]
        assert names
        auto = LabelSigmaOptions(None).sigmas(scene, t, names)
        for k, n in enumerate(names):
            by_hand = label_sigmas(scene, t, [n], stored_input_sigmas(c, n)[0])
            assert np.allclose(auto.sigma_t_mm[:, k], by_hand.sigma_t_mm[:, 0])
            assert np.all(auto.sigma_t_mm[:, k][auto.valid] > 0)
        h.undo()
        assert c.sigmas == {}


def test_a_drag_that_drops_a_sigma_is_still_one_undo_step():
    """A drag's moves merge into one undo step; its first move also drops the estimate's sigma -- in that step."""
    doc = Corrections()
    h = History(doc, clock=lambda: 0.0)
    T = T_from_rotvec([0, 0, 0.01], [0.002, 0, 0])
    apply_pose_estimate(h, "box", T, std_mm=0.4, std_deg=0.2)
    for dx in (0.001, 0.002, 0.003):
        h.set(("object", "box"), T_from_rotvec([0, 0, 0.01], [0.002 + dx, 0, 0]), text="drag box", mergeable=True)
    assert len(h) == 2 and doc.sigma("object:box") is None and np.isclose(doc.object_delta("box")[0, 3], 0.005)
    h.undo()
    assert doc.sigma("object:box") == {"mm": 0.4, "deg": 0.2} and np.allclose(doc.object_delta("box"), T)
    h.redo()
    assert doc.sigma("object:box") is None and np.isclose(doc.object_delta("box")[0, 3], 0.005)


def test_a_sigma_follows_its_value_through_a_merge():
    """A hand edit on one side and an estimate's sigma on the other never meet (the review of issue 28.3): the side
    whose value the merge takes gives the sigma; a clock merged from both sides has no sigma unless they agree."""
    from evpose.core.document.corrections_merge import merge

    T0 = T_from_rotvec([0, 0, 0.02], [0, 0, 0])
    base = Corrections()
    History(base).set(("object", "box"), T0)
    kept, hand = base.copy(), base.copy()
    History(kept).set(("sigma", "object:box"), {"mm": 0.4, "deg": 0.1})        # an estimate confirmed the pose
    History(hand).set(("object", "box"), T0 @ T0)                              # another edit moved it by hand
    for local, disk in ((hand, kept), (kept, hand)):
        out = merge(base, local, disk).doc
        assert np.allclose(out.object_delta("box"), T0 @ T0) and out.sigma("object:box") is None
    same = merge(base, kept, kept.copy()).doc                                   # same value both sides: 3-way
    assert same.sigma("object:box") == {"mm": 0.4, "deg": 0.1}
    offset, skew = base.copy(), base.copy()
    History(offset).set(("offset_us",), 900)
    h = History(skew)
    with h.group("estimate"):
        h.set(("skew_ppm",), 3.0)
        h.set(("sigma", "clock"), {"offset_us": 30.0, "skew_ppm": 1.0})
    out = merge(base, offset, skew, prefer="disk").doc
    assert (out.offset_us, out.skew_ppm, out.sigma("clock")) == (900, 3.0, None)


def test_a_clock_estimate_that_keeps_the_skew_keeps_its_sigma(scene_copy):
    from evpose.core.data.scene import Scene
    from evpose.core.document.estimates import apply_clock_estimate

    with Scene.open(scene_copy) as scene:
        h = History(scene.corrections)
        apply_clock_estimate(h, scene, scene.clock.offset_us + 100, scene.clock.skew_ppm + 2.0, "sync",
                             offset_std_us=40.0, skew_std_ppm=1.5)
        apply_clock_estimate(h, scene, scene.clock.offset_us + 50, None, "edges", offset_std_us=10.0)
        assert scene.corrections.sigma("clock") == {"offset_us": 10.0, "skew_ppm": 1.5}
        apply_clock_estimate(h, scene, scene.clock.offset_us, scene.clock.skew_ppm + 1.0, "other skew",
                             offset_std_us=12.0)                               # a skew changed without its sigma
        assert scene.corrections.sigma("clock") == {"offset_us": 12.0}
