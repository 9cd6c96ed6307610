"""The dataset triage report's document (evpose.core.dataset.triage): two real scenes run through
``triage_task`` (the tiny scene with its true poses and clock, and the tiny scene as generated - its 20 ms
clock error and 5 mm / 3 degree pose errors - with a trajectory hole and its end cut off), then variants of
the clean one with one injected problem each (a shifted prior, a degraded object, a failed scene, a loose or
unreliable clock estimate, thin evidence). The ranking must put the injected problems first, with the
right reasons, and leave the clean scene out; the numbers must be the input's."""
from __future__ import annotations

import copy
import csv
import json
import shutil
import sys

import numpy as np
import pytest

from evpose.core.dataset import triage as tr
from evpose.core.dataset.triage_scores import HIST_EDGES, MIN_EVENTS_NEAR, WORST_WINDOWS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


# --------------------------------------------------------------------------------------- real scenes
def true_labels_scene(src, dst):
    """A copy of the tiny scene whose scene.toml holds the true object poses and the true clock (prior)."""
    import tomli_w

    shutil.copytree(src, dst)
    gt = json.loads((dst / "ground_truth.json").read_text())
    manifest = tomllib.loads((dst / "scene.toml").read_text())
    manifest["clock"]["offset_us"] = gt["clock"]["offset_us"]
    for obj in manifest["objects"]:
        obj["T_base_obj"] = gt["objects"][obj["name"]]["T_base_obj"]
    (dst / "scene.toml").write_text(tomli_w.dumps(manifest))
    return dst


def cut_trajectory(scene_dir, hole_ms: tuple[float, float], end_ms: float):
    """Drop the poses (pose clock, ms after the first pose) strictly inside ``hole_ms`` and after ``end_ms``."""
    path = scene_dir / "trajectory.csv"
    rows = list(csv.reader(path.open()))
    t_first = int(rows[1][0])
    keep = [rows[0]] + [r for r in rows[1:] if not (hole_ms[0] < (int(r[0]) - t_first) / 1e3 < hole_ms[1])
                        and (int(r[0]) - t_first) / 1e3 <= end_ms]
    with path.open("w", newline="") as f:
        csv.writer(f).writerows(keep)
    return scene_dir


def run_triage_task(scene_dir) -> dict:
    from evpose.core.align.sync_run import SyncOptions
    from evpose.core.dataset.tasks import triage_task

    return triage_task(str(scene_dir), None, SyncOptions())


@pytest.fixture(scope="module")
def clean_doc(tiny_scene_dir, tmp_path_factory):
    """The triage_task document of the tiny scene with its true poses and clock, the prior moved onto the
    rate estimate (the rate stage's few-ms model error is not what these tests are about)."""
    doc = run_triage_task(true_labels_scene(tiny_scene_dir, tmp_path_factory.mktemp("triage") / "clean"))
    return shift_prior(doc, doc["sync"]["offset_us"] - doc["info"]["clock"]["prior_offset_us"])


@pytest.fixture(scope="module")
def tiny_doc(tiny_scene_dir):
    """The triage_task document of the tiny scene as generated: its prior is 20 ms off the true clock, its
    object poses 5 mm / 3 degrees off."""
    return run_triage_task(tiny_scene_dir)


@pytest.fixture(scope="module")
def holes_doc(tiny_scene_dir, tmp_path_factory):
    """The tiny scene as generated (prior 20 ms off the truth, pose errors) with a 200 ms trajectory hole
    and no poses after 1000 ms of the pose clock (the events end at ~1080 ms)."""
    dst = tmp_path_factory.mktemp("triage") / "holes"
    shutil.copytree(tiny_scene_dir, dst)
    return run_triage_task(cut_trajectory(dst, (500.0, 700.0), 1000.0))


# --------------------------------------------------------------------------------------- variants
def shift_prior(doc: dict, delta_us: int) -> dict:
    """The same scene with its manifest prior (and so the clock in effect) moved by ``delta_us``: the data,
    so the rate estimate, stay."""
    d = copy.deepcopy(doc)
    d["info"]["clock"]["prior_offset_us"] += delta_us
    d["info"]["clock"]["offset_us"] += delta_us
    d["sync"]["prior_offset_us"] += delta_us
    if d["sync"].get("correction"):
        d["sync"]["correction"]["offset_us"] -= delta_us
    return d


def degrade(doc: dict, name: str, by: float, worst: int | None = None, worst_score: float = -0.5) -> dict:
    """``name``'s valid scores lowered by ``by``, and window ``worst``'s set to ``worst_score``."""
    d = copy.deepcopy(doc)
    for w in d["score"]["windows"]:
        o = w["objects"][name]
        if o["valid"]:
            o["score"] = worst_score if w["index"] == worst else o["score"] - by
    return d


def batch(scenes: dict, failed: dict | None = None, runtime_s: float = 3.5) -> dict:
    return {"dataset": "synthetic", "scenes": scenes, "failed": failed or {}, "runtime_s": runtime_s}


def scene_rec(t: dict, name: str) -> dict:
    return next(r for r in t["scenes"] if r["name"] == name)


def valid_scores(doc: dict, name: str):
    return [(w["index"], w["objects"][name]["score"], w["objects"][name]["n_events_near"])
            for w in doc["score"]["windows"] if w["objects"][name]["valid"]]


# --------------------------------------------------------------------------------------- tests
def test_clean_scene_is_not_flagged_and_reports_its_numbers(clean_doc):
    t = tr.triage(batch({"clean": clean_doc}))
    assert t["ranked"] == []
    r = scene_rec(t, "clean")
    assert r["status"] == "ok" and r["flags"] == []
    info = clean_doc["info"]
    assert r["n_events"] == info["n_events"] > 100_000
    assert r["duration_s"] == pytest.approx(info["duration_s"])
    assert r["windows"]["n_windows"] == clean_doc["score"]["n_windows"] == 80
    assert r["windows"]["window_us"] == 10_000
    assert r["windows"]["unlabeled_share"] == 0.0
    c = r["clock"]
    assert c["delta_effect_us"] == 0 and c["n_sigma"] == 0.0 and c["reliable"]
    assert c["offset_std_us"] == pytest.approx(clean_doc["sync"]["offset_std_us"])
    assert c["offset_std_us"] < tr.CLOCK_LOOSE_STD_US
    for name in info["objects"]:
        s = r["scores"][name]
        vals = [v for _, v, _ in valid_scores(clean_doc, name)]
        assert s["n_valid"] == len(vals) > 40
        assert s["quantiles"]["p50"] == pytest.approx(float(np.median(vals)))
        assert s["quantiles"]["p50"] > tr.MIN_MEDIAN_SCORE       # true poses score well above the limit
        assert s["mean"] == pytest.approx(clean_doc["score"]["summary"][name]["mean_score"])
    assert r["review"] == clean_doc["review"]
    assert t["summary"] == {"n_scenes": 1, "n_failed": 0, "n_flagged": 0, "n_events": info["n_events"],
                            "duration_s": pytest.approx(info["duration_s"]), "n_windows": 80, "verified_windows": 0}


def test_real_holes_and_windows_outside_the_trajectory_are_counted_and_flagged(holes_doc):
    t = tr.triage(batch({"holes": holes_doc}))
    r = scene_rec(t, "holes")
    w = r["windows"]
    info, score = holes_doc["info"], holes_doc["score"]
    # the split by cause: holes from the reasons, and they agree with info's count of windows in holes
    assert w["in_holes"] == info["trajectory"]["windows_in_holes"] > 10
    assert w["outside_trajectory"] > 3
    assert w["in_holes"] + w["outside_trajectory"] == w["unlabeled"] == score["unlabeled"]
    assert w["unlabeled_share"] == pytest.approx(score["unlabeled"] / score["n_windows"])
    assert w["n_holes"] == 1
    kinds = {f["kind"]: f for f in r["flags"]}
    assert kinds["unlabeled"]["reason"] == (f"{100 * w['unlabeled_share']:.0f} % of windows unlabeled "
                                            "(trajectory holes, outside the trajectory)")
    assert kinds["unlabeled"]["severity"] == pytest.approx(w["unlabeled_share"] / tr.MAX_UNLABELED_SHARE, abs=1e-3)


def test_real_clock_error_and_pose_errors_are_flagged(tiny_doc):
    t = tr.triage(batch({"tiny": tiny_doc}))
    r = scene_rec(t, "tiny")
    kinds = {f["kind"]: f for f in r["flags"]}
    # the generator's 20 ms clock error against a prior of 0
    c = r["clock"]
    assert c["reliable"] and c["prior_offset_us"] == c["effect_offset_us"] == 0
    assert 15_000 < c["delta_prior_us"] < 25_000
    assert c["n_sigma"] > tr.CLOCK_K_SIGMA
    assert kinds["clock"]["reason"] == (f"clock +{c['delta_prior_us'] / 1000:.1f} ms ± {c['offset_std_us'] / 1000:.1f} ms "
                                        f"from the prior ({c['n_sigma']:.0f} σ)")
    # objects scored under the wrong clock score low, and the reason says to look at the clock first
    objs = [f for f in r["flags"] if f["kind"] == "object"]
    assert objs and all("fix that first" in f["reason"] for f in objs)
    assert t["ranked"][0]["kind"] == "clock"


def test_ranking_puts_the_injected_problems_first(clean_doc):
    b = batch({"a_clean": clean_doc, "b_clock": shift_prior(clean_doc, 30_000),
               "c_object": degrade(clean_doc, "cylinder", 0.35, worst=40),
               "e_clean": clean_doc},
              failed={"d_broken": "d_broken/events.h5: not an HDF5 file"})
    t = tr.triage(b, order=["a_clean", "b_clock", "c_object", "d_broken", "e_clean"])
    assert [r["name"] for r in t["scenes"]] == ["a_clean", "b_clock", "c_object", "d_broken", "e_clean"]
    ranked = t["ranked"]
    assert [(e["rank"], e["scene"], e["kind"], e["object"]) for e in ranked] == [
        (1, "d_broken", "failed", None), (2, "b_clock", "clock", None), (3, "c_object", "object", "cylinder")]
    assert ranked[0]["reason"] == "failed: d_broken/events.h5: not an HDF5 file"
    assert ranked[0]["severity"] == tr.SEVERITY_FAILED
    clock = scene_rec(t, "b_clock")["clock"]
    std = clean_doc["sync"]["offset_std_us"]
    n_sigma = 30_000 / std                                       # the printed sigma, never widened later
    assert clock["delta_effect_us"] == clock["delta_prior_us"] == -30_000
    assert clock["n_sigma"] == pytest.approx(n_sigma)
    assert ranked[1]["reason"] == f"clock -30.0 ms ± {std / 1000:.1f} ms from the prior ({n_sigma:.0f} σ)"
    cyl = scene_rec(t, "c_object")["scores"]["cylinder"]
    median = cyl["quantiles"]["p50"]
    assert median < tr.MIN_MEDIAN_SCORE
    assert ranked[2]["window"] == 40 and cyl["worst"][0]["index"] == 40
    assert ranked[2]["t_label_us"] == clean_doc["score"]["windows"][40]["t_label_us"]
    assert ranked[2]["reason"] == f"cylinder: median score {median:.2f}, worst window 40 (-0.50)"
    assert ranked[0]["severity"] > ranked[1]["severity"] > ranked[2]["severity"] > 1.0
    # the other objects of the degraded scene, and the clean scenes, are not flagged
    assert scene_rec(t, "c_object")["flags"] == [{k: ranked[2][k] for k in ranked[2] if k not in ("rank", "scene")}]
    assert scene_rec(t, "a_clean")["flags"] == scene_rec(t, "e_clean")["flags"] == []
    failed = scene_rec(t, "d_broken")
    assert failed["status"] == "failed" and failed["error"] == "d_broken/events.h5: not an HDF5 file"
    assert t["summary"]["n_failed"] == 1 and t["summary"]["n_flagged"] == 3 and t["summary"]["n_scenes"] == 5
    # deterministic, and JSON as it stands (no NaN)
    assert tr.triage(copy.deepcopy(b), order=["a_clean", "b_clock", "c_object", "d_broken", "e_clean"]) == t
    assert json.loads(json.dumps(t, allow_nan=False)) == t


def test_equal_severities_rank_in_dataset_order(clean_doc):
    shifted = shift_prior(clean_doc, 15_000)
    t = tr.triage(batch({"x": shifted, "a": shifted}), order=["x", "a"])
    assert [e["scene"] for e in t["ranked"]] == ["x", "a"]
    t = tr.triage(batch({"x": shifted, "a": shifted}))            # default order: as the scenes come
    assert [e["scene"] for e in t["ranked"]] == ["x", "a"]
    t = tr.triage(batch({"x": shifted}, failed={"f": "boom"}))     # default order: scenes, then the failed
    assert [r["name"] for r in t["scenes"]] == ["x", "f"]


def test_clock_within_k_sigma_is_not_flagged_beyond_is(clean_doc):
    sigma = clean_doc["sync"]["offset_std_us"]
    inside = int(0.95 * tr.CLOCK_K_SIGMA * sigma)
    outside = int(1.05 * tr.CLOCK_K_SIGMA * sigma)
    t = tr.triage(batch({"in": shift_prior(clean_doc, inside), "out": shift_prior(clean_doc, -outside)}))
    assert scene_rec(t, "in")["flags"] == []
    assert [f["kind"] for f in scene_rec(t, "out")["flags"]] == ["clock"]
    assert scene_rec(t, "out")["clock"]["n_sigma"] == pytest.approx(outside / sigma)


def test_an_applied_correction_is_judged_against_the_clock_in_effect(clean_doc):
    d = shift_prior(clean_doc, 30_000)
    d["info"]["clock"]["offset_us"] -= 30_000          # a stored correction brings the clock back onto the estimate
    r = scene_rec(tr.triage(batch({"s": d})), "s")
    assert r["flags"] == [] and r["clock"]["corrected"]
    assert r["clock"]["delta_prior_us"] == -30_000 and r["clock"]["delta_effect_us"] == 0
    d["info"]["clock"]["offset_us"] += 20_000          # ... a correction that is off (~4 sigma of the rate)
    r = scene_rec(tr.triage(batch({"s": d})), "s")
    std = clean_doc["sync"]["offset_std_us"] / 1000
    assert [f["reason"].split(" (")[0] for f in r["flags"]] == [f"clock -20.0 ms ± {std:.1f} ms from the clock in effect"]
    assert r["flags"][0]["reason"].endswith("; -30.0 ms from the prior")


@pytest.mark.parametrize("change, kind, reason", [
    ({"offset_std_us": 12_000.0}, "clock_uncertain", "clock estimate loose: σ 12.0 ms > 10 ms"),
    ({"offset_std_us": None, "offset_pinned": False}, "clock_uncertain",
     "clock not pinned by the event rate (σ unbounded): check it with sync --edges"),
    ({"offset_us": None, "reliable": False, "reason": "constant event rate: nothing to correlate",
      "offset_std_us": None, "offset_pinned": None}, "clock",
     "clock estimate not reliable: constant event rate: nothing to correlate"),
    ({"skew_ppm": 5000.0}, "skew", "skew +5000.0 ppm from the prior: +4.0 ms drift over the scene"),
])
def test_loose_unpinned_unreliable_and_skewed_clocks_are_flagged(clean_doc, change, kind, reason):
    d = copy.deepcopy(clean_doc)
    d["sync"].update(change)
    r = scene_rec(tr.triage(batch({"s": d})), "s")
    assert [(f["kind"], f["reason"]) for f in r["flags"]] == [(kind, reason)]
    assert r["flags"][0]["severity"] >= 1.0


def test_low_scores_point_at_a_wrong_clock_but_not_at_a_loose_one(clean_doc):
    d = degrade(shift_prior(clean_doc, 40_000), "box", 0.35)
    r = scene_rec(tr.triage(batch({"s": d})), "s")
    assert [f["kind"] for f in r["flags"]] == ["clock", "object"]
    assert r["flags"][1]["reason"].endswith(" (the clock or the mounting is flagged too: fix that first)")
    d["sync"].update(offset_std_us=None, offset_pinned=False)     # the rate does not pin the clock at all
    r = scene_rec(tr.triage(batch({"s": d})), "s")
    assert r["clock"]["n_sigma"] is None and r["clock"]["sigma_total_us"] is None
    assert r["clock"]["delta_effect_us"] == -40_000
    assert [f["kind"] for f in r["flags"]] == ["clock_uncertain", "object"]
    assert "fix that first" not in r["flags"][1]["reason"]


def test_loose_sigma_alone_does_not_make_a_disagreement(clean_doc):
    d = shift_prior(clean_doc, 30_000)
    d["sync"]["offset_std_us"] = 12_000.0             # 30 ms at a 12 ms sigma: within 3 sigma, but loose
    r = scene_rec(tr.triage(batch({"s": d})), "s")
    assert [f["kind"] for f in r["flags"]] == ["clock_uncertain"]


def test_score_distribution_and_histogram_are_the_inputs(clean_doc):
    r = scene_rec(tr.triage(batch({"s": clean_doc})), "s")
    for name, s in r["scores"].items():
        vals = np.array([v for _, v, _ in valid_scores(clean_doc, name)])
        for q, v in {"min": 0, "p10": 0.1, "p25": 0.25, "p50": 0.5, "p75": 0.75, "p90": 0.9, "max": 1}.items():
            assert s["quantiles"][q] == pytest.approx(float(np.quantile(vals, v)))
        h = s["histogram"]
        assert h["edges"] == list(HIST_EDGES) and len(h["counts"]) == len(HIST_EDGES) - 1
        assert sum(h["counts"]) == len(vals)
        k = int(np.searchsorted(HIST_EDGES, s["quantiles"]["p50"], side="right")) - 1
        assert h["counts"][k] > 0                       # the median's bin holds windows


def test_worst_windows_skip_thin_evidence(clean_doc):
    name = "box"
    vals = valid_scores(clean_doc, name)
    low_i = min(vals, key=lambda v: v[1])[0]
    d = degrade(clean_doc, name, 0.0, worst=low_i, worst_score=-0.9)
    thin = next(w for w in d["score"]["windows"] if w["index"] == low_i)
    thin["objects"][name]["n_events_near"] = MIN_EVENTS_NEAR - 1
    s = scene_rec(tr.triage(batch({"s": d})), "s")["scores"][name]
    assert s["quantiles"]["min"] == -0.9                  # still in the distribution (the first bin holds it) ...
    assert sum(s["histogram"]["counts"]) == s["n_valid"] and s["histogram"]["counts"][0] >= 1
    assert low_i not in [w["index"] for w in s["worst"]]  # ... but not named among the worst
    evidence = sorted((v, i) for i, v, n in valid_scores(d, name) if n >= MIN_EVENTS_NEAR)
    assert [w["index"] for w in s["worst"]] == [i for _, i in evidence[:WORST_WINDOWS]]
    assert s["n_evidence"] == len(evidence)
    assert all(w["n_events_near"] >= MIN_EVENTS_NEAR for w in s["worst"])
    thin["objects"][name]["n_events_near"] = MIN_EVENTS_NEAR      # at the minimum: it counts
    s = scene_rec(tr.triage(batch({"s": d})), "s")["scores"][name]
    assert s["worst"][0]["index"] == low_i and s["worst"][0]["score"] == -0.9


def test_object_flag_follows_the_median_not_the_mean(clean_doc):
    d = copy.deepcopy(clean_doc)
    wins = [w for w in d["score"]["windows"] if w["objects"]["box"]["valid"]]
    for w in wins[: int(0.4 * len(wins))]:             # 40 % of the windows very bad: the mean drops, the median not
        w["objects"]["box"]["score"] = -0.9
    r = scene_rec(tr.triage(batch({"s": d})), "s")
    assert r["scores"]["box"]["mean"] < tr.MIN_MEDIAN_SCORE < r["scores"]["box"]["quantiles"]["p50"]
    assert r["flags"] == []
    for w in wins[: int(0.6 * len(wins))]:             # 60 %: the median drops too
        w["objects"]["box"]["score"] = -0.9
    r = scene_rec(tr.triage(batch({"s": d})), "s")
    assert [f["reason"].split(",")[0] for f in r["flags"]] == ["box: median score -0.90"]


def test_an_object_without_any_score_is_flagged(clean_doc):
    d = copy.deepcopy(clean_doc)
    for w in d["score"]["windows"]:
        w["objects"]["flatbox"].update(valid=False, score=None)
    r = scene_rec(tr.triage(batch({"s": d})), "s")
    assert r["scores"]["flatbox"]["quantiles"] is None and r["scores"]["flatbox"]["worst"] == []
    assert [(f["object"], f["reason"]) for f in r["flags"]] == [
        ("flatbox", "flatbox: no window scored (out of view or too few events)")]


def test_unlabeled_share_limit(clean_doc):
    d = copy.deepcopy(clean_doc)
    n = d["score"]["n_windows"]
    k = int(tr.MAX_UNLABELED_SHARE * n)                   # exactly at the limit: not flagged
    d["score"]["unlabeled"] = k
    d["score"]["unlabeled_reasons"] = {"label time in a trajectory hole [1, 2] us (pose clock): ...": k}
    assert scene_rec(tr.triage(batch({"s": d})), "s")["flags"] == []
    d["score"]["unlabeled"] = k + 1
    d["score"]["unlabeled_reasons"] = {"label time in a trajectory hole [1, 2] us (pose clock): ...": k + 1}
    r = scene_rec(tr.triage(batch({"s": d})), "s")
    assert [f["reason"] for f in r["flags"]] == [f"{100 * (k + 1) / n:.0f} % of windows unlabeled (trajectory holes)"]


def test_a_malformed_document_names_the_scene_and_the_field(clean_doc):
    d = copy.deepcopy(clean_doc)
    del d["sync"]["offset_std_us"]
    with pytest.raises(tr.TriageError, match=r"scenes\.bad: missing field 'offset_std_us'"):
        tr.triage(batch({"ok": clean_doc, "bad": d}))


def test_report_files_replace_only_their_own_siblings_and_record_what_changed(clean_doc, tmp_path):
    """REPORT.csv and REPORT.json beside the HTML: written with it; a rerun compares with the last JSON; another
    program's file of either name is refused (one line naming it) and left as it was."""
    from evpose.core.dataset.report_files import check_report_siblings, write_report_files
    from evpose.core.errors import NotOursError

    html = tmp_path / "r.html"
    first = tr.triage(batch({"s1": clean_doc, "s2": shift_prior(clean_doc, 30_000)}))
    write_report_files(first, html, check_report_siblings(html))
    assert first["since_last"] is None and (tmp_path / "r.csv").read_text().count("\n") == 2
    second = tr.triage(batch({"s1": shift_prior(clean_doc, 30_000), "s2": clean_doc}))
    write_report_files(second, html, check_report_siblings(html))
    assert second["since_last"] == {"new": ["s1"], "resolved": ["s2"], "changed": []}
    assert "Since the last report" in html.read_text() and "no longer flagged" in html.read_text()
    third = tr.triage(batch({"s1": shift_prior(clean_doc, 30_000), "s2": clean_doc}))
    third["options"] = {"edges": True, "windows": 24}                    # not like for like: said so
    write_report_files(third, html, check_report_siblings(html))
    assert third["since_last"]["options_changed"] == {"was": None, "now": {"edges": True, "windows": 24}}
    assert "made with other options than the last" in html.read_text()
    from evpose.core.dataset.report_files import flagged_scenes

    assert flagged_scenes(tmp_path / "r.json") == ["s1"] and flagged_scenes(tmp_path / "r.json", ("pose",)) == []
    with pytest.raises(NotOursError, match="no such report"):
        flagged_scenes(tmp_path / "missing.json")
    for name, text in (("r.csv", "a,b\n1,2\n"), ("r.json", '{"mine": 1}')):
        other = tmp_path / "other"
        other.mkdir(exist_ok=True)
        (other / name).write_text(text)
        with pytest.raises(NotOursError, match=name.replace(".", r"\.")):
            check_report_siblings(other / "r.html")
        assert (other / name).read_text() == text
        (other / name).unlink()



def test_a_worst_window_verified_in_review_is_looked_at_until_a_correction_makes_the_mark_stale(tiny_scene_dir,
                                                                                                tmp_path):
    """Issue 24.3: the object flagged for low scores, its worst window verified in review with a note (a person
    looked and it is fine) -> reported as "looked at, fine" with the note, not flagged; after a correction of its
    pose the mark is stale and the flag is back."""
    import numpy as np

    from evpose.core.data.geometry import make_T
    from evpose.core.data.scene import Scene
    from evpose.core.dataset.report_html import render_report
    from evpose.core.document.estimates import apply_pose_estimate
    from evpose.core.document.history import History
    from evpose.core.document.review import ReviewMark, mark_state

    scene_dir = tmp_path / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    before = tr.triage(batch({"s": run_triage_task(scene_dir)}))
    flagged = [f["object"] for f in scene_rec(before, "s")["flags"] if f["kind"] == "object"]
    assert flagged
    name = flagged[0]
    with Scene.open(scene_dir) as scene:
        t0, t1 = scene.events.t_first_us, scene.events.t_last_us + 1
        mark = ReviewMark(t0, t1, "verified", "motion blur, label fine", name, mark_state(scene, name))
        scene.corrections.set(("reviews",), [mark])
        scene.save_corrections()
    after = tr.triage(batch({"s": run_triage_task(scene_dir)}))
    rec = scene_rec(after, "s")
    assert name in rec["looked_at"] and rec["looked_at"][name]["note"] == "motion blur, label fine"
    assert name not in [f["object"] for f in rec["flags"] if f["kind"] == "object"]
    assert "Looked at, fine" in render_report(after)
    with Scene.open(scene_dir) as scene:                        # a pose correction: the verified look is stale
        apply_pose_estimate(History(scene.corrections), name, make_T(np.eye(3), [0.002, 0.0, 0.0]), "nudge")
        scene.save_corrections()
    again = scene_rec(tr.triage(batch({"s": run_triage_task(scene_dir)})), "s")
    assert name not in again["looked_at"] and name in [f["object"] for f in again["flags"] if f["kind"] == "object"]


def test_worst_window_thumbnails_draw_each_object_or_name_the_error(tiny_scene_dir, monkeypatch):
    import base64

    import cv2
    import numpy as np

    from evpose.core.align.score_table import score_windows
    from evpose.core.data.json_values import plain
    from evpose.core.data.scene import Scene
    from evpose.core.dataset import thumbnails

    with Scene.open(tiny_scene_dir) as scene:
        score = plain(score_windows(scene, window_us=10_000).to_json())
        th = thumbnails.worst_window_thumbnails(scene, score)
        assert set(th) <= set(scene.object_names) and th
        for t in th.values():
            img = cv2.imdecode(np.frombuffer(base64.b64decode(t["png_b64"]), np.uint8), cv2.IMREAD_COLOR)
            assert img.shape == (scene.camera.height, scene.camera.width, 3)
        assert th == thumbnails.worst_window_thumbnails(scene, score)            # the same bytes again

        def broken(*a, **k):
            raise ValueError("no poses there")
        monkeypatch.setattr(thumbnails, "window_thumbnail", broken)
        bad = thumbnails.worst_window_thumbnails(scene, score)
    assert set(bad) == set(th) and all(b["error"] == "ValueError: no poses there" for b in bad.values())
