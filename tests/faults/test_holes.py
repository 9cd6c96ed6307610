"""Holes in the robot trajectory (issue 11, item 5): no label is ever invented inside one.

A pose topic that drops messages leaves gaps; interpolating across a 200 ms gap of the tiny scene's
0.5 m/s motion put labels 14 mm / 3 degrees off. Samples further apart than ``max_gap_us`` (default 4
median steps; ``[trajectory] max_gap_us`` in scene.toml) bound a hole: windows whose label time falls
inside get no label, and ``info``, ``score``, the export summary/manifest and the app's timeline say so.
Sync and refinement use no window and no rate bin inside a hole.
"""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from fault_harness import assert_ok, run_cli, snapshot
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from evpose.core.data.manifest import SceneError
from evpose.core.data.manifest_reader import load_manifest
from evpose.core.data.scene import Scene
from evpose.core.data.trajectory import Trajectory
from evpose.core.data.trajectory_holes import MAX_GAP_STEPS, default_max_gap_us
from evpose.core.label.windows import time_windows

HOLE_US = 200_000


# ------------------------------------------------------------------------------------------------ helpers
def _rows(scene_dir: Path) -> tuple[str, list[str], np.ndarray]:
    lines = (scene_dir / "trajectory.csv").read_text().splitlines()
    return lines[0], lines[1:], np.array([int(ln.split(",", 1)[0]) for ln in lines[1:]], np.int64)


def cut_hole(scene_dir: Path, a_us: int, b_us: int) -> tuple[int, int]:
    """Remove the poses with a < t < b (pose clock) from the scene's trajectory.csv; returns the samples
    that bound the hole."""
    head, rows, t = _rows(scene_dir)
    keep = ~((t > a_us) & (t < b_us))
    (scene_dir / "trajectory.csv").write_text("\n".join([head] + [r for r, k in zip(rows, keep) if k]) + "\n")
    kept = t[keep]
    return int(kept[kept <= a_us].max()), int(kept[kept >= b_us].min())


def set_max_gap(scene_dir: Path, value) -> None:
    toml = scene_dir / "scene.toml"
    text = toml.read_text()
    text = re.sub(r"(\[trajectory\]\n)", lambda m: m.group(1) + f"max_gap_us = {value}\n", text, count=1)
    toml.write_text(text)


@pytest.fixture
def holed(tiny_scene_dir, tmp_path):
    """A copy of the tiny scene with 200 ms of poses removed around the middle of the events (the
    clock prior is 0, so event and pose clock agree); returns (folder, (t_a, t_b) bounding samples)."""
    dst = tmp_path / "holed"
    shutil.copytree(tiny_scene_dir, dst)
    s = Scene.open(tiny_scene_dir)
    mid = (s.events.t_first_us + s.events.t_last_us) // 2
    s.close()
    return dst, cut_hole(dst, mid - HOLE_US // 2, mid + HOLE_US // 2)


def label_times(scene, window_us=10_000):
    return np.array([w.t_label_us for w in time_windows(scene.events, window_us)], np.int64)


# ------------------------------------------------------------------------------------------------ labels
def test_a_200ms_hole_gives_no_label_instead_of_a_13mm_wrong_one(tiny_scene_dir, holed, tmp_path):
    holed_dir, (a, b) = holed
    full, cut = Scene.open(tiny_scene_dir), Scene.open(holed_dir)
    assert cut.trajectory.holes == [(a, b)] and full.trajectory.holes == []
    t = label_times(full)
    T_full, v_full = full.T_cam_obj(t)
    T_cut, v_cut = cut.T_cam_obj(t)
    in_hole = (t > a) & (t < b)                      # pose clock == event clock here (prior offset 0)
    assert v_full.all() and in_hole.sum() == 20
    assert np.array_equal(v_cut, ~in_hole)           # exactly the windows in the hole lose their label
    np.testing.assert_array_equal(T_cut[v_cut], T_full[v_cut])   # every label given is the true one
    # what bridging the hole would have given (the defect): labels 10+ mm off the true ones
    bridged_dir = tmp_path / "bridged"
    shutil.copytree(holed_dir, bridged_dir)
    set_max_gap(bridged_dir, 10**9)
    bridged = Scene.open(bridged_dir)
    T_br, v_br = bridged.T_cam_obj(t)
    assert v_br.all() and bridged.trajectory.holes == []
    err_mm = np.linalg.norm(T_br[in_hole][..., :3, 3] - T_full[in_hole][..., :3, 3], axis=-1).max() * 1e3
    assert err_mm > 10.0
    reasons = cut.unlabeled_reasons(t)
    assert all((r is None) == (not h) for r, h in zip(reasons, in_hole))
    assert {r for r in reasons if r} == {f"label time in a trajectory hole [{a}, {b}] us (pose clock): "
                                         f"{(b - a) / 1000:g} ms without a pose, more than max_gap_us = 16000"}
    for s in (full, cut, bridged):
        s.close()


def test_default_max_gap_is_four_median_steps_and_scene_toml_overrides_it(holed, tmp_path):
    holed_dir, (a, b) = holed
    s = Scene.open(holed_dir)
    assert s.manifest.trajectory_max_gap_us is None                   # an older manifest stays valid
    assert s.trajectory.max_gap_us == MAX_GAP_STEPS * 4000 == 16000    # 250 Hz poses
    s.close()
    set_max_gap(holed_dir, b - a)                                     # the gap itself is allowed: no hole
    s = Scene.open(holed_dir)
    assert s.trajectory.holes == [] and s.manifest.trajectory_max_gap_us == b - a
    assert load_manifest(holed_dir).to_toml_dict()["trajectory"]["max_gap_us"] == b - a   # written back
    s.close()


@pytest.mark.parametrize("value", ["0", "-5", "1.5", '"abc"', "true", "1e30"])
def test_bad_max_gap_is_refused_naming_the_field(holed, value):
    holed_dir, _ = holed
    set_max_gap(holed_dir, value)
    with pytest.raises(SceneError, match=r"scene\.toml: trajectory\.max_gap_us: "):
        load_manifest(holed_dir)


@settings(max_examples=60, deadline=None)
@given(steps=st.lists(st.sampled_from([1000, 1000, 1000, 1000, 2000, 3000, 5000, 50_000, 10**12]), min_size=3,
                      max_size=40),
       probes=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=30))
def test_property_a_time_is_valid_iff_its_segment_is_short_or_it_is_a_sample(steps, probes):
    t = np.concatenate([[0], np.cumsum(steps)]).astype(np.int64)
    rng = np.random.default_rng(len(steps))
    pos = rng.normal(size=(len(t), 3))
    q = Rotation.random(len(t), random_state=1).as_quat()
    max_gap = default_max_gap_us(t)
    assert max_gap == int(np.ceil(MAX_GAP_STEPS * np.median(np.diff(t))))
    tr = Trajectory(t, pos, q, max_gap_us=max_gap)
    query = np.concatenate([t, (np.asarray(probes) * t[-1]).astype(np.int64)])
    T, valid = tr.interpolate(query)
    seg = np.clip(np.searchsorted(t, query, side="right") - 1, 0, len(t) - 2)
    is_sample = np.isin(query, t)
    expect = is_sample | (np.diff(t)[seg] <= max_gap)
    assert np.array_equal(valid, expect)
    np.testing.assert_array_equal(T[~valid], np.broadcast_to(np.eye(4), ((~valid).sum(), 4, 4)))
    assert [h for h in tr.holes] == [(int(t[i]), int(t[i + 1])) for i in np.flatnonzero(np.diff(t) > max_gap)]
    assert (np.array(tr.reasons(query)) == None).tolist() == valid.tolist()   # noqa: E711
    v, w, ok = tr.speed(query)
    assert np.array_equal(ok, valid) and not v[~ok].any()


# ------------------------------------------------------------------------------------------------ reports
def test_info_lists_the_holes_and_the_windows_without_label(holed):
    holed_dir, (a, b) = holed
    before = snapshot(holed_dir)
    run = run_cli("info", holed_dir, "--json", timeout=60)
    assert_ok(run)
    tr = json.loads(run.stdout)["trajectory"]
    assert tr["max_gap_us"] == 16000 and tr["max_gap_source"] == "default"
    assert tr["holes"] == [{"t0_pose_us": a, "t1_pose_us": b, "t0_us": a, "t1_us": b, "gap_ms": (b - a) / 1000,
                            "n_windows": 20}]
    assert tr["windows_in_holes"] == 20 and tr["hole_window_us"] == 10_000
    text = run_cli("info", holed_dir, timeout=60)
    assert_ok(text)
    assert "20 windows of 10 ms get no label" in text.stdout and f"[{a}, {b}] us pose clock" in text.stdout
    assert snapshot(holed_dir) == before


def test_export_summary_and_manifest_give_the_hole_as_the_reason(holed, tmp_path):
    holed_dir, (a, b) = holed
    out = tmp_path / "out"
    run = run_cli("export", holed_dir, "--format", "bop", "--out", out, "--json", "-q", timeout=120)
    assert_ok(run)
    s = json.loads(run.stdout)
    reason = next(r for r in s["unlabeled_reasons"] if r.startswith("label time in a trajectory hole"))
    assert f"[{a}, {b}] us" in reason and s["unlabeled_reasons"][reason] == 20 and s["unlabeled"] == 20
    man = json.loads((out / "export_manifest.json").read_text())
    assert man["unlabeled_reasons"] == s["unlabeled_reasons"]
    in_hole = [u["index"] for u in man["unlabeled"] if u["reason"] == reason]
    assert all(a < u["t_label_us"] < b for u in man["unlabeled"] if u["reason"] == reason) and len(in_hole) == 20
    gt = json.loads(next(out.rglob("scene_gt.json")).read_text())
    written = {int(k) for k in gt}
    assert not written & set(in_hole)               # nothing written for a window in the hole


def test_score_gives_no_score_in_the_hole(holed):
    holed_dir, (a, b) = holed
    run = run_cli("score", holed_dir, "--json", timeout=120)
    assert_ok(run)
    doc = json.loads(run.stdout)
    (reason, n), = doc["unlabeled_reasons"].items()
    assert n == 20 and f"trajectory hole [{a}, {b}]" in reason and doc["unlabeled"] == 20
    for w in doc["windows"]:
        hole = a < w["t_label_us"] < b
        for o in w["objects"].values():
            assert (o["score"] is None and o["reason"] == reason) if hole else o["reason"] != reason
    text = run_cli("score", holed_dir, "-q", timeout=120)
    assert f"no score (no pose) in 20 window(s): {reason}" in text.stdout


def test_an_11_day_gap_is_a_hole_and_nothing_hangs(tiny_scene_dir, tmp_path):
    """The robot clock jumps 11.6 days (10**12 us) mid-recording: everything after the jump is far away."""
    d = tmp_path / "jump"
    shutil.copytree(tiny_scene_dir, d)
    head, rows, t = _rows(d)
    s = Scene.open(d)
    mid = (s.events.t_first_us + s.events.t_last_us) // 2
    s.close()
    jump = 10**12
    rows = [f"{ti + jump if ti > mid else ti},{r.split(',', 1)[1]}" for ti, r in zip(t, rows)]
    (d / "trajectory.csv").write_text("\n".join([head] + rows) + "\n")
    run = run_cli("info", d, "--json", timeout=60)
    assert_ok(run)
    (hole,) = json.loads(run.stdout)["trajectory"]["holes"]
    assert hole["gap_ms"] > 1e9 - 10 and hole["n_windows"] > 30
    sync = run_cli("sync", d, "--json", "--baseline", timeout=15)     # takes ~2 s; a day-long grid took 30+
    assert_ok(sync)


# ------------------------------------------------------------------------------------------------ sync, refine
def test_sync_and_refine_use_no_window_and_no_bin_in_a_hole(holed):
    from evpose.core.align.event_windows import EventWindow, choose_windows
    from evpose.core.align.scene_proxy import scene_motion_proxy

    holed_dir, (a, b) = holed
    s = Scene.open(holed_dir)
    proxy = scene_motion_proxy(s)
    t0 = proxy.t0_us
    assert proxy.holes_us.tolist() == [[a - t0, b - t0]]
    starts = np.arange(a - 50_000, b + 50_000, 1000) - t0
    _, ok = proxy.mean_over(starts, starts + 1000)
    touches = (starts < b - t0) & (starts + 1000 > a - t0)
    assert np.array_equal(ok, ~touches & (starts >= 0))
    wins = choose_windows(s, 200, 10_000, s.object_names)
    assert wins and all(w1 <= a or w0 >= b for w0, w1 in wins)          # no chosen window overlaps the hole
    w = EventWindow(s, a - 5000, b + 5000, s.clock, 10**6)               # a window forced across the hole
    inside = (w.ev_t > a) & (w.ev_t < b)
    assert inside.any() and not w.ok[inside].any() and w.ok[~inside].all()
    s.close()


# ------------------------------------------------------------------------------------------------ app
def test_timeline_shades_the_holes(holed, qtbot):
    from evpose.core.session.model import Session
    from evpose.core.views.timeline import timeline_data
    from evpose.widgets.timeline.view import Timeline

    holed_dir, (a, b) = holed
    session = Session.open(holed_dir)
    td = timeline_data(session.scene)
    t_ref = session.scene.t_ref_us
    np.testing.assert_allclose(td.holes_s, [[(a - t_ref) * 1e-6, (b - t_ref) * 1e-6]])
    inside = (td.t_s > td.holes_s[0, 0] + 1e-3) & (td.t_s < td.holes_s[0, 1] - 1e-3)
    assert inside.sum() > 150 and not td.speed_valid[inside].any()
    tl = Timeline(session)
    qtbot.addWidget(tl)
    assert len(tl.hole_items) == 1
    np.testing.assert_allclose(tl.hole_items[0].getRegion(), td.holes_s[0])
    session.close()
