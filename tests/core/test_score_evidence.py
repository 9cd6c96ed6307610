"""The evidence behind alignment scores (evpose.core.align.score_evidence): image motion, share in view, events
near the edges; the low-evidence state; the worst window lands only on windows with evidence."""
from __future__ import annotations

import numpy as np
import pytest

from evpose.core.align import score, score_table
from evpose.core.align.score_evidence import (
    EvidenceParams,
    image_motion_px_s,
    in_view_fraction,
    low_evidence_reason,
    view_rect,
)
from evpose.core.data.camera import CameraModel
from evpose.core.data.scene import Scene
from evpose.core.label.windows import time_windows
from evpose.core.sim.synth import load_ground_truth

CAM = CameraModel(np.array([[100.0, 0, 49.5], [0, 100.0, 39.5], [0, 0, 1]]), (), width=100, height=80)
SQUARE = np.array([[x, y, 0.0] for x in (-0.01, 0.01) for y in (-0.01, 0.01)])   # 2 cm square, object frame


def pose(x=0.0, y=0.0, z=1.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def test_image_motion_is_pixels_per_second():
    # 1 cm sideways at 1 m in 10 ms with fx = 100: 1 px in 10 ms = 100 px/s
    v = image_motion_px_s(CAM, SQUARE, pose()[None], pose(x=0.01)[None], np.array([10_000]))
    assert v[0] == pytest.approx(100.0)
    still = image_motion_px_s(CAM, SQUARE, pose()[None], pose()[None], np.array([10_000]))
    assert still[0] == 0.0
    # empty window, all points behind the camera: unknown, not zero
    assert np.isnan(image_motion_px_s(CAM, SQUARE, pose()[None], pose(x=0.01)[None], np.array([0]))[0])
    assert np.isnan(image_motion_px_s(CAM, SQUARE, pose(z=-1)[None], pose(z=-1)[None], np.array([10_000]))[0])


def test_in_view_fraction_of_the_projected_box():
    assert view_rect(CAM) == pytest.approx((-0.5, -0.5, 99.5, 79.5))
    # the square spans 2 px around the centre: all in; its centre on the left border: half; far out: none
    x_half = (-0.5 - 49.5) / 100.0
    f = in_view_fraction(CAM, SQUARE, np.stack([pose(), pose(x=x_half), pose(x=5.0), pose(z=-1.0)]))
    assert f == pytest.approx([1.0, 0.5, 0.0, 0.0])
    # points behind the camera count as out of view: one end of a rod through the camera plane
    rod = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    assert in_view_fraction(CAM, rod, pose(z=0.5)[None])[0] == pytest.approx(0.5)
    # a lens with distortion sees more than its pinhole rectangle at the borders (barrel): the inscribed one
    d = CameraModel.davis346()
    u0, v0, u1, v1 = view_rect(d)
    assert u0 < -0.5 and v0 < -0.5 and u1 > d.width - 0.5 and v1 > d.height - 0.5


def test_low_evidence_reasons():
    p = EvidenceParams(min_edge_events=100, min_motion_px=0.05, min_in_view=0.5)
    assert low_evidence_reason(100, 5.0, 0.5, 5.0, p) == ""
    assert low_evidence_reason(99, 5.0, 1.0, 5.0, p) == "too few events near the edges (99 < 100)"
    assert low_evidence_reason(500, 4.9, 1.0, 5.0, p).startswith("no image motion")
    assert low_evidence_reason(500, float("nan"), 1.0, 5.0, p) == ""       # unknown motion is no reason
    assert low_evidence_reason(500, 50.0, 0.49, 5.0, p).startswith("object mostly out of view")
    assert low_evidence_reason(3, 0.0, 0.1, 5.0, p).count("; ") == 2
    # the motion threshold is pixels per window at fx = 146, given as a speed
    assert p.min_motion_px_s(146.0, 10_000) == pytest.approx(5.0)
    assert p.min_motion_px_s(292.0, 20_000) == pytest.approx(5.0)


def test_score_window_counts_events_near_the_edges():
    obj = np.full((60, 80), -1, np.int16)
    obj[20:40, 30:60] = 0
    depth = np.where(obj >= 0, 0.5, np.inf).astype(np.float32)
    P = score.ScoreParams(near_px=3, trunc_px=3, sigma_px=1.0, min_events=1, min_pixels=16)
    ring = np.array([(x, 20) for x in range(30, 60)] + [(x, 39) for x in range(30, 60)])
    centre = np.array([(45, 30)] * 40)                                  # inside, > 3 px from every edge
    xy = np.concatenate([ring, centre])
    from evpose.core.data.events import EventArray

    ev = EventArray(xy[:, 0], xy[:, 1], np.arange(len(xy), dtype=np.int64), np.ones(len(xy), np.uint8))
    r = score.score_window(ev, obj, depth, 1, P)[0]
    assert r.valid and r.n_events_near == len(xy) and r.n_edge_events == len(ring)


@pytest.fixture(scope="module")
def tiny(tiny_scene_dir):
    """The tiny scene with its true clock; its second half is a dwell (the camera stands still)."""
    gt = load_ground_truth(tiny_scene_dir)
    scene = Scene.open(tiny_scene_dir, corrections=None)
    scene.corrections.offset_us = gt["clock"]["offset_us"] - scene.manifest.clock_offset_us
    yield scene
    scene.close()


def test_worst_lands_on_evidence_never_on_a_stationary_window(tiny):
    """With ``min_events=1`` the dwell's few noise events get a score, and the lowest of all is one of
    them: the raw minimum is a stationary window. The worst window is the lowest among moving windows."""
    wins = time_windows(tiny.events, 10_000)
    P = score.ScoreParams(min_events=1)
    tab = score_table.score_windows(tiny, wins, ["box"], params=P)
    s, ok = tab.score["box"], tab.informative("box")
    motion = tab.motion_px_s["box"]
    raw = int(np.ma.argmin(s))
    thr = tab.evidence.min_motion_px_s(float(tiny.camera.K[0, 0]), 10_000)
    # the construction: the raw minimum is a stationary window with few events, and scores there exist
    assert motion[raw] < thr and tab.n_edge_events["box"][raw] < 50, (raw, motion[raw])
    still = tab.valid["box"] & (motion < thr)
    assert still.sum() >= 10
    assert np.all(tab.state("box")[still] == "low_evidence")
    assert all("no image motion" in tab.evidence_reasons["box"][i] for i in np.flatnonzero(still))
    w = score_table.worst_window(tab, "box")
    assert w is not None and w != raw and ok[w] and motion[w] >= thr
    assert tab.n_edge_events["box"][w] >= tab.evidence.min_edge_events
    assert s[w] == s.data[ok].min()
    assert score_table.worst_note(tab, "box") is None
    doc = tab.to_json()
    assert doc["summary"]["box"]["worst_window"] == w
    assert doc["windows"][raw]["objects"]["box"]["state"] == "low_evidence"


def test_no_window_with_evidence_has_no_worst_and_says_why(tiny):
    wins = time_windows(tiny.events, 10_000)[55:75]                     # all in the dwell
    tab = score_table.score_windows(tiny, wins, ["box"], params=score.ScoreParams(min_events=1))
    assert tab.valid["box"].sum() >= 10 and not tab.informative("box").any()
    assert score_table.worst_window(tab, "box") is None
    note = score_table.worst_note(tab, "box")
    assert note.startswith("no window has enough evidence") and "no image motion" in note
    s = tab.to_json()["summary"]["box"]
    assert s["worst_window"] is None and s["worst_note"] == note and s["n_ok"] == 0
    # without any score at all: said differently
    empty = score_table.score_windows(tiny, wins, ["box"])
    assert score_table.worst_note(empty, "box") == "no window has a score"


def test_evidence_thresholds_are_parameters(tiny):
    wins = time_windows(tiny.events, 10_000)[:20]                        # moving, many events
    tab = score_table.score_windows(tiny, wins, ["box"])
    assert tab.informative("box").sum() == tab.valid["box"].sum() > 10
    strict = score_table.score_windows(tiny, wins, ["box"], evidence=EvidenceParams(min_edge_events=10**9))
    assert not strict.informative("box").any() and strict.valid["box"].sum() == tab.valid["box"].sum()
    assert all(r.startswith("too few events near the edges") for r in strict.evidence_reasons["box"].values())
    # the count of events near the edges is of the whole window (the score subsamples long windows)
    few = score_table.score_windows(tiny, wins, ["box"], params=score.ScoreParams(max_events=500))
    ratio = few.n_edge_events["box"][tab.valid["box"]] / tab.n_edge_events["box"][tab.valid["box"]]
    assert np.all(np.abs(ratio - 1) < 0.25)
