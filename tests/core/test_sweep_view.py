"""The silhouette sweep (evpose.core.views.sweep, issue 25.2), without Qt, on the tiny scene with the true clock and
poses: its extents are the frame view's visible masks, its top / side images the span's events in the silhouette's
rows / columns; an object moved along the line of sight is swept bigger; the cases with nothing to show say why.
(Reading a depth error off the events' spread was tried and is not asserted: on the tiny scene the spread of one
object's events over ~8 ms varied by +-5 px with the true pose, as much as a 28 mm depth error changes the outline.)"""
from __future__ import annotations

import numpy as np
import pytest

from evpose.core.data.geometry import inv_T
from evpose.core.data.scene import Scene
from evpose.core.sim.synth import load_ground_truth
from evpose.core.views.sweep import silhouette_sweep


@pytest.fixture(scope="module")
def truth(tiny_scene_dir):
    gt = load_ground_truth(tiny_scene_dir)
    scene = Scene.open(tiny_scene_dir, corrections=None)
    scene.corrections.offset_us = gt["clock"]["offset_us"] - scene.manifest.clock_offset_us
    for n in scene.object_names:
        scene.corrections.object_deltas[n] = np.asarray(gt["objects"][n]["T_base_obj"]) @ inv_T(
            scene.manifest.object(n).T_base_obj)
    yield scene
    scene.close()


def _centre(scene):
    return scene.events.t_first_us + 300_000     # the camera moves; box and cylinder wholly in view


def test_extents_are_the_frame_views_masks_and_counts_the_events_near_their_outlines(truth):
    """Each slice's extent is that of the object's visible mask in the frame view's labels at that time, and the top
    / side images count exactly the span's events within SWEEP_EDGE_PX of the outline of the slice nearest in time
    (a brute-force histogram; the distance by OpenCV's distance transform of that mask, not the sweep's field)."""
    import cv2

    from evpose.core.label.windows import Window
    from evpose.core.views.frame import FrameComputer
    from evpose.core.views.sweep import SWEEP_EDGE_PX

    name, tc = "box", _centre(truth)
    s = silhouette_sweep(truth, name, tc, 200_000, n_slices=8, n_bins=50)
    assert not s.reason and s.top.shape == (50, truth.camera.width) and s.side.shape == (50, truth.camera.height)
    ann = FrameComputer()._annotator_for(truth)
    k = truth.object_names.index(name)
    t_slices = tc + np.round(s.extent[:, 0] * 1e3).astype(np.int64)
    T_co, T_bc, valid = ann.poses(t_slices)
    dist = []
    for i, t in enumerate(t_slices):
        lab = ann.annotate(Window(-1, int(t), int(t) + 1, int(t)), pose=(T_co[i], T_bc[i], bool(valid[i])))
        m = lab.objects[k].mask_visible
        cols, rows = np.flatnonzero(m.any(axis=0)), np.flatnonzero(m.any(axis=1))
        assert tuple(s.extent[i, 1:]) == (cols[0], cols[-1], rows[0], rows[-1])
        u8 = m.astype(np.uint8)          # distance to the edge between pixel centres: +-0.5 px next to it
        dist.append(np.where(m, cv2.distanceTransform(u8, cv2.DIST_L2, 5),
                             cv2.distanceTransform(1 - u8, cv2.DIST_L2, 5)) - 0.5)
    ev = truth.events.window(s.t0_us, s.t1_us)
    near_slice = np.argmin(np.abs(ev.t[:, None] - t_slices[None, :]), axis=1)
    d = np.array([dist[j][yy, xx] for j, xx, yy in zip(near_slice, ev.x, ev.y)])
    near = d <= SWEEP_EDGE_PX + 0.26             # the sweep's field is quantised to 1/4 px
    b = ((ev.t - s.t0_us) * 50) // 200_000
    top = np.zeros_like(s.top, np.int64)
    np.add.at(top, (b[near], ev.x[near]), 1)
    side = np.zeros_like(s.side, np.int64)
    np.add.at(side, (b[near], ev.y[near]), 1)
    agree = 1 - np.abs(top - s.top.astype(np.int64)).sum() / max(top.sum(), 1)
    assert s.n_events > 1000 and agree > 0.97, (s.n_events, near.sum(), agree)
    assert np.abs(side - s.side.astype(np.int64)).sum() <= 0.03 * side.sum()


def test_an_object_moved_towards_the_camera_is_swept_bigger(truth):
    """The sweep draws the poses in effect: the box 8 % closer to the camera (~28 mm along the line of sight) has a
    silhouette ~9 % taller at every slice (its events, from the true pose, stay where they were)."""
    name, tc = "box", _centre(truth)
    T = np.asarray(truth.T_base_obj(name))
    cam = truth.T_base_cam(np.array([tc]))[0][0]
    step = np.eye(4)
    step[:3, 3] = 0.08 * (cam[:3, 3] - T[:3, 3])
    closer = truth.with_corrections(truth.corrections.copy())
    closer.corrections.object_deltas[name] = step @ truth.corrections.object_deltas[name]
    a, b = (silhouette_sweep(sc, name, tc, 200_000, n_slices=8) for sc in (truth, closer))
    ha, hb = a.extent[:, 4] - a.extent[:, 3], b.extent[:, 4] - b.extent[:, 3]
    assert np.all(hb > ha) and 1.04 < np.median(hb / ha) < 1.15, (ha, hb)


def test_the_cases_with_nothing_to_show(truth):
    name = truth.object_names[0]
    ev = truth.events
    late = silhouette_sweep(truth, name, ev.t_last_us + 10_000_000)
    assert late.reason and late.top.shape[0] == 0
    assert silhouette_sweep(truth, "no such object", _centre(truth)).reason == "no object 'no such object'"
