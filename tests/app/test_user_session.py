"""The verify task end to end, as a user does it in the app (tracker issue 16): open the demo scene (35 ms clock
error, every pose 5 mm / 3 deg off), read the offset off the kymograph, run Auto and accept it, drag one object off
and bring it back with Refine, mark a range verified, export only the verified windows as BOP, and compare the
exported labels with the ground truth."""
from __future__ import annotations

import json

import numpy as np
import pytest

from evpose.core.data.geometry import inv_T, pose_error, rotation_error_about_symmetry
from evpose.core.data.scene import Scene
from evpose.core.document.corrections import Corrections
from evpose.core.sim.synth import load_ground_truth
from tests.app.test_auto_sync import _centres, _pose_errors_mm, _wait_frame

pytestmark = [pytest.mark.gl, pytest.mark.slow]


def _truth_scene(folder, gt) -> Scene:
    """The scene with the true clock and poses as its corrections."""
    scene = Scene.open(folder, corrections=None)
    doc = Corrections()
    doc.offset_us = gt["clock"]["offset_us"] - scene.manifest.clock_offset_us
    doc.skew_ppm = gt["clock"]["skew_ppm"] - scene.manifest.clock_skew_ppm
    for n in scene.object_names:
        doc.object_deltas[n] = np.asarray(gt["objects"][n]["T_base_obj"]) @ inv_T(scene.manifest.object(n).T_base_obj)
    return scene.with_corrections(doc)


def test_the_whole_verify_task_on_the_demo_scene(qtbot, window, demo_copy, tmp_path):
    gt = load_ground_truth(demo_copy)
    true_offset = gt["clock"]["offset_us"]
    s = window.controller.open_scene(demo_copy)
    s.set_time(s.busiest_time())
    _wait_frame(qtbot, window)

    # 1. the kymograph across an edge shows the clock error: events lag the projected edges by tens of ms (the
    #    5 mm / 3 deg pose errors bias the reading by a few ms: it is a look, the fit comes next)
    window.spacetime.controls.kymograph_button.click()
    qtbot.waitUntil(lambda: window.kymograph.data is not None, timeout=60_000)
    lag_before = window.kymograph.shift_ms
    if lag_before is not None:                                    # the true error: 35 ms
        assert -50.0 < lag_before < -20.0, lag_before
    else:     # issue 23.8: with every pose 5 mm / 3 deg off the lines across the objects read -53, -18 and -26 ms,
        # +- 4-6 ms: the honest answer is that they disagree, not one of them
        assert "disagree" in window.kymograph.data.lag.weak, window.kymograph.data.lag.weak

    # 2. Auto: the clock and every pose from the events, accepted (one undo step)
    window.auto_answer["auto"] = True
    pc = window.align.proposals
    window.actions_by_name["auto_sync"].trigger()
    qtbot.waitUntil(lambda: pc.state not in ("running", "proposal"), timeout=600_000)
    assert pc.state == "accepted", (pc.state, pc.proposal and pc.proposal.reason)
    assert abs(s.scene.clock.offset_us - true_offset) <= 500
    assert max(_pose_errors_mm(s.scene, gt).values()) <= 1.5
    shown = window.kymograph.data                     # the kymograph follows: events and edge tracks now agree
    qtbot.waitUntil(lambda: window.kymograph.data is not shown and window.kymograph.shift_ms is not None,
                    timeout=60_000)
    assert abs(window.kymograph.shift_ms) < 5.0, window.kymograph.shift_ms

    # 3. drag one object ~8 px on the frame (one undo step), then Refine brings it back
    name = s.object_names[0]
    uv = _centres(_wait_frame(qtbot, window))[name]
    n_steps = len(s.history)
    assert s.begin_drag(name)
    for dx in (2.0, 5.0, 8.0):
        s.drag_object(uv, uv + np.array([dx, 0.0]))
    s.end_drag()
    assert len(s.history) == n_steps + 1
    dragged = _pose_errors_mm(s.scene, gt)[name]
    assert dragged > 2.0, dragged
    window.auto_answer["refine"] = True
    s.select(name)
    window.actions_by_name["refine_selected"].trigger()
    qtbot.waitUntil(lambda: pc.state not in ("running", "proposal"), timeout=600_000)
    assert pc.state == "accepted", (pc.state, pc.proposal and pc.proposal.reason)
    assert _pose_errors_mm(s.scene, gt)[name] <= 1.5

    # 4. mark 0.2 s around the busiest time verified
    t = s.busiest_time()
    s.add_review("verified", t - 100_000, t + 100_000)

    # 5. export only the verified windows as BOP
    out = tmp_path / "bop"
    window.controller.start_export(fmt="bop", out_dir=str(out), window_us=10_000, only_verified=True)
    window.last_export = None
    qtbot.waitUntil(lambda: bool(window.last_export is not None or window.last_error), timeout=300_000)
    assert window.last_error is None, window.last_error
    scene_dir = next(p for p in (out / "test").iterdir() if p.is_dir())
    scene_gt = json.loads((scene_dir / "scene_gt.json").read_text())
    times = json.loads((scene_dir / "scene_times.json").read_text())
    assert 10 <= len(scene_gt) <= 20                   # 10 ms windows inside the verified 0.2 s (those with objects)
    assert len(scene_gt) == window.last_export.written

    # 6. the exported labels against the truth: every instance within 1.5 mm / 0.5 deg
    truth = _truth_scene(demo_copy, gt)
    from evpose.core.export.bop import bop_obj_ids

    ids = bop_obj_ids(truth, truth.object_names)          # which obj_id stands for which object
    worst_mm, worst_deg = 0.0, 0.0
    for im_id, instances in scene_gt.items():
        T_true, valid = truth.T_cam_obj(np.array([times[im_id]["t_label_us"]]))
        assert valid[0]
        for inst in instances:
            k = [n for n, i in ids.items() if i == inst["obj_id"]]
            assert k, inst["obj_id"]
            T = np.eye(4)
            T[:3, :3] = np.asarray(inst["cam_R_m2c"]).reshape(3, 3)
            T[:3, 3] = np.asarray(inst["cam_t_m2c"]) * 1e-3
            T_t = T_true[0, truth.object_names.index(k[0])]
            et, _ = pose_error(T, T_t)
            # a solid of revolution's spin is invisible to the events and held at its start by the fit (issue 23.6):
            # its label is right up to that spin, which models_info.json's symmetries_continuous declares
            kind, axis = truth.raster_model(k[0]).symmetry
            er = rotation_error_about_symmetry(T[:3, :3], T_t[:3, :3], axis if kind == "radial" else None)
            worst_mm = max(worst_mm, float(np.linalg.norm(et)) * 1e3)
            worst_deg = max(worst_deg, float(np.degrees(er)))
    truth.close()
    print(f"\nexported {len(scene_gt)} verified windows: worst label error {worst_mm:.2f} mm, {worst_deg:.2f} deg")
    assert worst_mm <= 1.5 and worst_deg <= 0.5
