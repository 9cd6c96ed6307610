"""Alignment score (evpose.core.align.score): unit cases on hand-made label maps, every window of the tiny
synthetic scene (true vs erroneous poses), undefined scores for empty windows and objects out
of view, the CLI."""
from __future__ import annotations

import argparse
import io
import json
import math
from contextlib import redirect_stdout

import numpy as np
import pytest

from evpose.core.align import score, score_table
from evpose.core.data.events import Cancelled, EventArray
from evpose.core.data.scene import Scene
from evpose.core.sim.synth import load_ground_truth

P = score.ScoreParams(near_px=5, trunc_px=5, sigma_px=1.0, min_events=10, min_pixels=16)


def square_label(H=60, W=80, box=(20, 40, 30, 60)):
    """Label map with object 0 on rows box[0]:box[1], columns box[2]:box[3]; depth 0.5 m."""
    obj = np.full((H, W), -1, np.int16)
    obj[box[0]:box[1], box[2]:box[3]] = 0
    depth = np.where(obj >= 0, 0.5, np.inf).astype(np.float32)
    return obj, depth


def events_at(xy):
    xy = np.asarray(xy, dtype=np.int64).reshape(-1, 2)
    n = len(xy)
    return EventArray(xy[:, 0], xy[:, 1], np.arange(n, dtype=np.int64), np.ones(n, np.uint8))


def test_object_edges_silhouette_and_depth_jump():
    obj, depth = square_label()
    e = score.object_edges(obj, depth, 0)
    assert e[20, 45] and e[19, 45] and e[39, 45] and e[40, 45]   # both sides of top / bottom
    assert e[30, 30] and e[30, 29] and e[30, 59] and e[30, 60]
    assert not e[30, 45] and not e[5, 5]
    depth[20:40, 45:60] = 0.6                                     # a step inside the object
    e2 = score.object_edges(obj, depth, 0)
    assert e2[30, 44] and e2[30, 45] and not e[30, 44]


def test_score_window_edges_uniform_empty_and_invisible():
    obj, depth = square_label()
    rng = np.random.default_rng(0)
    # events on the silhouette
    ring = [(x, 20) for x in range(30, 60)] + [(x, 39) for x in range(30, 60)] + \
           [(30, y) for y in range(20, 40)] + [(59, y) for y in range(20, 40)]
    on_edge = score.score_window(events_at(ring), obj, depth, 1, P)[0]
    uniform = score.score_window(events_at(np.stack([rng.integers(20, 70, 3000), rng.integers(10, 50, 3000)], 1)),
                                 obj, depth, 1, P)[0]
    inside = score.score_window(events_at(np.stack([rng.integers(30, 60, 3000), rng.integers(20, 40, 3000)], 1)),
                                obj, depth, 1, P)[0]
    assert on_edge.valid and uniform.valid and inside.valid
    assert on_edge.score > 0.4
    assert abs(uniform.score) < 0.1
    assert inside.score > 0.2 and inside.inside_fraction == 1.0       # density contrast counts
    assert on_edge.distance_px < 0.5 < uniform.distance_px
    # nothing near the object, no events at all, object absent, object too small
    far = score.score_window(events_at([(2, 2)] * 50), obj, depth, 1, P)[0]
    empty = score.score_window(EventArray.empty(), obj, depth, 1, P)[0]
    absent = score.score_window(events_at(ring), np.full_like(obj, -1), depth, 1, P)[0]
    small, _ = square_label(box=(10, 13, 10, 13))
    tiny = score.score_window(events_at(ring), small, depth, 1, P)[0]
    for r, why in ((far, "events"), (empty, "events"), (absent, "out of view"), (tiny, "visible pixels")):
        assert not r.valid and why in r.reason
        assert math.isnan(r.score)
    # events outside the image are ignored, not an IndexError
    assert score.score_window(events_at([(500, 500)] * 30 + ring), obj, depth, 1, P)[0].valid


@pytest.fixture(scope="module")
def tiny(tiny_scene_dir):
    gt = load_ground_truth(tiny_scene_dir)
    scene = Scene.open(tiny_scene_dir, corrections=None)
    scene.corrections.offset_us = gt["clock"]["offset_us"] - scene.manifest.clock_offset_us
    truth = {n: np.asarray(gt["objects"][n]["T_base_obj"]) for n in scene.object_names}
    yield scene, truth
    scene.close()


def test_every_window_true_pose_scores_higher(tiny):
    scene, truth = tiny
    calls = []
    wrong = score_table.score_windows(scene, progress=lambda f, m: calls.append(f))
    right = score_table.score_windows(scene, poses=truth)
    assert len(wrong) == len(right) == 80          # 0.8 s in 10 ms windows
    assert wrong.runtime_s > 0 and right.runtime_s > 0
    assert calls and calls[-1] == pytest.approx(1.0)
    for n in scene.object_names:
        s_w, s_r = wrong.score[n], right.score[n]
        assert isinstance(s_r, np.ma.MaskedArray) and s_r.count() > 30
        assert np.isfinite(s_r.mean()) and np.isfinite(s_w.mean())
        assert right.mean_score(n) > wrong.mean_score(n) + 0.05, n
        both = ~(s_r.mask | s_w.mask)
        assert (s_r.data[both] > s_w.data[both]).mean() > 0.7, n
        # hidden data is NaN, visible data finite
        assert np.all(np.isnan(s_r.data[s_r.mask])) and np.all(np.isfinite(s_r.data[~s_r.mask]))
        # the worst window: the lowest score among windows backed by evidence (tests/core/test_score_evidence.py)
        w = score_table.worst_window(right, n)
        ok = right.informative(n)
        assert w is not None and ok[w] and right.score[n][w] == s_r.data[ok].min()
        # events near the object: at least min_events where the score is defined, and the count
        # the reason names where too few made it undefined
        near = right.n_events_near[n]
        assert near.dtype.kind == "i" and np.all(near[right.valid[n]] >= right.params.min_events), n
        few = {i: r for i, r in right.reasons[n].items() if "events near the object" in r}
        assert few and all(r == f"only {near[i]} events near the object" and near[i] < right.params.min_events
                   for i, r in few.items()), n
    doc = right.to_json()
    json.dumps(doc)
    assert doc["n_windows"] == 80 and set(doc["summary"]) == set(scene.object_names)


def test_empty_zero_length_and_outside_windows(tiny):
    scene, truth = tiny
    t0, t1 = scene.events.t_first_us, scene.events.t_last_us
    wins = [(t0 + 300_000, t0 + 300_000),            # zero length
            (t0 + 400_000, t0 + 390_000),            # reversed
            (t1 + 10_000_000, t1 + 10_010_000),      # far outside the trajectory
            (t0 + 400_000, t0 + 410_000)]            # a normal window
    tab = score_table.score_windows(scene, wins, poses=truth)
    for n in scene.object_names:
        assert tab.valid[n][:3].tolist() == [False, False, False]
        assert tab.reasons[n][2].startswith("label time outside the trajectory: pose time after its last pose")
        assert "events" in tab.reasons[n][0]
        assert tab.n_events_near[n][:3].tolist() == [0, 0, 0]
    assert any(tab.valid[n][3] for n in scene.object_names)
    assert len(score_table.score_windows(scene, [])) == 0


def test_object_out_of_view_is_masked_not_zero(tiny):
    scene, truth = tiny
    away = {n: T.copy() for n, T in truth.items()}
    for T in away.values():
        T[:3, 3] += [0.0, 0.0, 50.0]     # 50 m above the table: behind / outside every view
    tab = score_table.score_windows(scene, scene_windows(scene)[:20], poses=away)
    for n in scene.object_names:
        assert tab.score[n].count() == 0
        assert tab.mean_score(n) is None and score_table.worst_window(tab, n) is None
        assert np.ma.is_masked(tab.score[n].mean())
    doc = tab.to_json()
    assert all(v["score"] is None for w in doc["windows"] for v in w["objects"].values())


def scene_windows(scene):
    from evpose.core.label.windows import time_windows

    return time_windows(scene.events, 10_000)


def test_cancel(tiny):
    scene, _ = tiny
    with pytest.raises(Cancelled):
        score_table.score_windows(scene, cancel=lambda: True)


def test_cli_score_json(tiny_scene_dir):
    from evpose.app.cli.align import add_align_parsers

    p = argparse.ArgumentParser(prog="evpose")
    add_align_parsers(p.add_subparsers(dest="command", required=True))
    args = p.parse_args(["score", str(tiny_scene_dir), "--json", "--window-ms", "20"])
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert args.func(args) == 0
    data = json.loads(buf.getvalue())
    assert data["n_windows"] == 40 and len(data["windows"]) == 40
    w = data["windows"][10]
    assert set(w["objects"]) == {"box", "cylinder", "flatbox"}
    assert {"score", "distance_px", "inside_fraction", "n_events_near", "valid"} <= set(w["objects"]["box"])
    # the evidence of every window and object, its state; the thresholds used
    assert {"n_edge_events", "motion_px_s", "in_view_fraction", "state", "evidence_reason"} <= set(w["objects"]["box"])
    assert set(data["evidence"]) == {"min_edge_events", "min_motion_px", "min_in_view"}
    for w in data["windows"]:
        for o in w["objects"].values():
            assert o["state"] == ("undefined" if not o["valid"] else "low_evidence" if o["evidence_reason"] else "ok")
    for name, s in data["summary"].items():
        assert s["n_ok"] + s["n_low_evidence"] == s["n_valid"]
        assert (s["worst_window"] is None) == (s["worst_note"] is not None)
        if s["worst_window"] is not None:
            assert data["windows"][s["worst_window"]]["objects"][name]["state"] == "ok"
