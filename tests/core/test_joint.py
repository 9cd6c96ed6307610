"""The joint refinement of clock, object poses and hand-eye from edges (core/align/joint_*.py, tracker issue 15):
the analytic derivatives against finite differences, the fit on rendered scenes with a clock error and pose errors
(and a hand-eye error), honest standard errors, objects without evidence held, the ``sync --edges`` JSON contract
(final estimate at the top, stages nested) and ``refine --joint --apply`` as one undo step."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evpose.core.align import joint_fit, joint_second_look
from evpose.core.align.joint_model import EdgeData, he_delta, jacobian
from evpose.core.align.joint_result import JointParams
from evpose.core.align.joint_solve import Layout, kernel_curvature, kernel_derivs
from evpose.core.align.pose_refine import delta_T
from evpose.core.data.clock import ClockModel
from evpose.core.data.geometry import inv_T, make_T, pose_error
from evpose.core.data.scene import Scene
from evpose.core.document.history import History
from evpose.core.sim.synth import load_ground_truth
from tests.core.test_sync import _cli
from tests.evpose_testing import half_davis_camera

K = np.array([[146.3, 0.0, 86.1], [0.0, 146.6, 64.8], [0.0, 0.0, 1.0]])


# ---------------------------------------------------------------------------- derivatives
def _distance(x_e, n, P_obj, T_bo, c, r, T_cb0, w_cb, t_rel, theta):
    """The signed distance of the model, computed directly from the parameters ``theta`` (offset µs, skew ppm,
    hand-eye 6, object 6): camera <- base moving with ``w_cb`` m/µs (translation) in pose time."""
    tau = theta[0] + theta[1] * 1e-6 * t_rel
    T_cb = T_cb0.copy()
    T_cb[:3, 3] += w_cb * tau
    c_now = T_bo[:3, :3] @ c + T_bo[:3, 3]
    D = delta_T(theta[8:14], c_now, r)
    P_c = (inv_T(he_delta(theta[2:8])) @ T_cb @ D @ T_bo @ np.append(P_obj, 1.0))[:3]
    proj = np.array([K[0, 0] * P_c[0] / P_c[2] + K[0, 2], K[1, 1] * P_c[1] / P_c[2] + K[1, 2]])
    return float(n @ (x_e - proj))


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(5)
    rows, fd = [], []
    for _ in range(20):
        T_bo = make_T(Rotation.random(random_state=rng.integers(1 << 30)).as_matrix(), rng.normal(0, 0.1, 3))
        T_cb0 = make_T(Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix(), [0.0, 0.0, 0.0])
        P_obj = rng.normal(0, 0.04, 3)
        P_b = T_bo[:3, :3] @ P_obj + T_bo[:3, 3]
        T_cb0[:3, 3] = np.array([0.02, -0.01, 0.45]) - T_cb0[:3, :3] @ P_b      # the point ~0.45 m ahead
        w = rng.normal(0, 5e-7, 3)                  # 0.5 m/s
        c, r = rng.normal(0, 0.02, 3), 0.07
        n = rng.normal(size=2)
        n /= np.linalg.norm(n)
        x_e, t_rel = rng.uniform(20, 150, 2), float(rng.uniform(-2e6, 2e6))
        P_c = T_cb0[:3, :3] @ P_b + T_cb0[:3, 3]
        d = EdgeData(np.zeros(1), np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1, bool),
                     np.array([t_rel]), P_b[None], P_c[None], T_cb0[None, :3, :3], w[None], n[None], 1)
        rows.append(jacobian(d, K, (T_bo[:3, :3] @ c + T_bo[:3, 3])[None], np.array([r]))[0])
        col = []
        for j in range(14):
            h = np.zeros(14)
            h[j] = 1.0 if j == 0 else (0.1 if j == 1 else 1e-3)
            col.append((_distance(x_e, n, P_obj, T_bo, c, r, T_cb0, w, t_rel, h)
                        - _distance(x_e, n, P_obj, T_bo, c, r, T_cb0, w, t_rel, -h)) / (2 * h[j]))
        fd.append(col)
    rows, fd = np.array(rows), np.array(fd)
    scale = np.abs(fd).max(axis=0) + 1e-12
    assert np.max(np.abs(rows - fd) / scale) < 1e-3, np.max(np.abs(rows - fd) / scale, axis=0)


def test_kernel_derivatives_and_curvature():
    s = np.linspace(-2, 2, 401)
    outer = np.ones_like(s, dtype=bool)
    for beta in (0.0, 0.6, -0.4):
        k, dk, _ = kernel_derivs(s, outer, 0.5, beta)
        assert np.allclose(dk[1:-1], (k[2:] - k[:-2]) / (s[2] - s[0]), atol=1e-3)
        assert np.allclose(-kernel_curvature(s, outer, 0.5, beta)[1:-1], (dk[2:] - dk[:-2]) / (s[2] - s[0]),
                           atol=1e-2)


def test_layout_columns():
    lay = Layout(3, True, False, True, [True, False, True])
    assert lay.n == 26 and list(lay.cols(2)[8:]) == list(range(20, 26))
    assert lay.free[0] and not lay.free[1] and lay.free[2:8].all()
    assert not lay.free[14:20].any() and lay.free[20:].all()


# ---------------------------------------------------------------------------- rendered scenes
@pytest.fixture(scope="module")
def wrong(tmp_path_factory):
    """Half-resolution DAVIS346, 3 s at 0.5 m/s: a 20 ms clock error and 5 mm / 3 deg on every object."""
    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    out = tmp_path_factory.mktemp("joint") / "wrong"
    generate(out, SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5, duration_s=3.0,
                              offset_us=20_000, pose_error_mm=5.0, pose_error_deg=3.0, seed=11,
                              max_px_per_frame=0.5, camera=half_davis_camera()))
    return out


def _errors(scene, gt, poses):
    out = []
    for n, T in poses.items():
        Tt = np.asarray(gt["objects"][n]["T_base_obj"])
        c = scene.raster_model(n).bbox_center_m
        out.append((np.linalg.norm((T[:3, :3] @ c + T[:3, 3]) - (Tt[:3, :3] @ c + Tt[:3, 3])) * 1e3,
                    float(np.degrees(np.linalg.norm(pose_error(T, Tt)[1])))))
    return np.array(out)


def test_clock_and_poses_together(wrong):
    """Started 1.5 ms from the true clock with every pose 5 mm / 3 deg off: the clock ends within 0.3 ms, the box
    (the best seen object) within 1 mm / 0.5 deg and every object's centre nearer its truth (median < 1.5 mm); the
    separate clock stage (poses taken as right) is biased by the same pose errors. (The thin flat box, seen at a
    grazing angle at half resolution, keeps a few degrees: bench/accuracy.py reports the calibration.)"""
    from evpose.core.align.clock_refine import refine_offset
    from evpose.core.align.refine_result import RefineParams

    gt = load_ground_truth(wrong)
    start = ClockModel(gt["clock"]["offset_us"] + 1500, 0.0, gt["clock"]["t_ref_us"])
    with Scene.open(wrong) as scene:
        res = joint_fit.refine_joint(scene, params=JointParams(n_windows=16, skew="fixed"), clock=start)
        sep = refine_offset(scene, params=RefineParams(n_windows=16), clock=start)
        before = _errors(scene, gt, {n: scene.T_base_obj(n) for n in scene.object_names})
        after = _errors(scene, gt, {n: o.dT_base @ scene.manifest.object(n).T_base_obj
                                    for n, o in res.objects.items()})
    err = res.offset_us - gt["clock"]["offset_us"]
    print(f"joint: clock {err} us ± {res.offset_std_us:.0f}, poses {after.round(2).tolist()}, {res.runtime_s:.1f} s; "
          f"separate clock {sep.offset_us - gt['clock']['offset_us']} us")
    assert res.accepted, res.reason
    assert abs(err) < 300
    assert abs(err) < abs(sep.offset_us - gt["clock"]["offset_us"])        # the joint fit is not biased by poses
    assert len(res.objects) + len(res.held) == 3 and "box" in res.objects
    box = list(res.objects).index("box")
    assert after[box, 0] < 1.0 and after[box, 1] < 0.5
    assert np.all(before[:, 0] > 4.0) and np.all(after[:, 0] < before[:len(after), 0])
    assert np.median(after[:, 0]) < 1.5
    assert res.objective_after > res.objective_before
    assert 0 < res.offset_std_us < np.inf
    assert abs(err) < 4 * res.offset_std_us + 100                          # not overclaiming
    for o in res.objects.values():
        assert 0 < o.std_mm < 3.0 and 0 < o.std_deg
    doc = res.to_json()
    json.dumps(doc)
    assert set(doc["objects"]) == set(res.objects) and doc["hand_eye"] is None


def test_object_out_of_view_is_held(wrong):
    """An object the camera never sees (moved 5 m away) keeps its pose, with the reason, and does not stop the
    fit of the others."""
    from evpose.core.document.corrections import Corrections

    gt = load_ground_truth(wrong)
    with Scene.open(wrong) as scene:
        doc = Corrections()
        doc.object_deltas["cylinder"] = make_T(np.eye(3), [5.0, 0.0, 0.0])
        scene = scene.with_corrections(doc)
        res = joint_fit.refine_joint(scene, params=JointParams(n_windows=12, clock=False, sigmas_px=(1.5, 0.8)),
                                     clock=ClockModel(gt["clock"]["offset_us"], 0.0, gt["clock"]["t_ref_us"]))
    assert "cylinder" in res.held and "evidence" in res.held["cylinder"]
    assert "cylinder" not in res.objects and res.accepted and set(res.objects) <= {"box", "flatbox"}


def test_the_spin_of_a_solid_of_revolution_is_held(wrong):
    """Issue 23: the cylinder's spin about its own axis changes no silhouette, so the fit must not move it (before,
    it ended 3-10 sigma off with a small sigma); its rotation is reported without the spin, and the box, which has
    no continuous symmetry, holds nothing."""
    gt = load_ground_truth(wrong)
    with Scene.open(wrong) as scene:
        res = joint_fit.refine_joint(scene, params=JointParams(n_windows=12, clock=False, sigmas_px=(1.5, 0.8, 0.45)),
                                     clock=ClockModel(gt["clock"]["offset_us"], 0.0, gt["clock"]["t_ref_us"]))
        kind, axis = scene.model("cylinder").symmetry
        T0 = scene.T_base_obj("cylinder")
    assert kind == "radial" and res.accepted
    cyl = res.objects["cylinder"]
    T1 = cyl.dT_base @ scene.manifest.object("cylinder").T_base_obj
    rotvec = Rotation.from_matrix(T1[:3, :3] @ T0[:3, :3].T).as_rotvec()
    spin_deg = np.degrees(abs(rotvec @ (T0[:3, :3] @ axis)))
    assert spin_deg < 0.01, spin_deg                                  # the spin stayed at its start
    assert np.degrees(np.linalg.norm(rotvec)) > 0.05                  # the other rotations were fitted
    assert "symmetry axis" in cyl.held_rotation and "held_rotation" in cyl.to_json()
    assert res.objects["box"].held_rotation == "" and "held_rotation" not in res.objects["box"].to_json()


def test_an_object_coinciding_with_another_is_held(wrong, tmp_path):
    """Issue 23: a duplicated object at the same pose (a twin) has no events of its own; it used to be moved
    21 mm / 12.8 deg with a sigma of 0.28 mm. One of the two is held with the reason; the other is fitted or put
    back by the held-out check, never moved far."""
    shutil.copytree(wrong, tmp_path / "twin")
    toml = tmp_path / "twin" / "scene.toml"
    box = [b for b in toml.read_text().split("[[objects]]") if 'name = "box"' in b][0]
    toml.write_text(toml.read_text().rstrip("\n") + "\n\n[[objects]]" + box.replace('name = "box"', 'name = "box_twin"'))
    gt = load_ground_truth(wrong)
    with Scene.open(tmp_path / "twin") as scene:
        assert scene.object_names[-1] == "box_twin"
        res = joint_fit.refine_joint(scene, params=JointParams(n_windows=12, clock=False, sigmas_px=(1.5, 0.8)),
                                     clock=ClockModel(gt["clock"]["offset_us"], 0.0, gt["clock"]["t_ref_us"]))
    twin = [n for n in ("box", "box_twin") if "coincides with" in res.held.get(n, "")]
    assert len(twin) == 1, res.held                                  # one of the pair held as the twin
    other = ({"box", "box_twin"} - set(twin)).pop()
    # the other is fitted, or put back by the held-out check (the held twin still hides part of its silhouette, so
    # its fit may end worse on the windows it did not use): never held as a twin too, never moved 20 mm
    assert other in res.objects or "did not use fell" in res.held[other], res.held
    if other in res.objects:
        assert res.objects[other].dt_mm < 15.0


def test_the_held_out_check_puts_back_an_object_the_fit_made_worse(wrong):
    """Issue 23: a fit that ends worse than its start on windows it did not use is not kept (before, a 16.7 mm
    move of a box was applied although its alignment score fell from 0.191 to 0.118). Checked on a made-up result:
    the box moved to its true pose is kept, the cylinder moved 12 mm further off is put back with the reason, and a
    result that makes everything worse is not accepted."""
    from evpose.core.align.joint_check import check_held_out
    from evpose.core.align.joint_result import JointResult, ObjectFit

    gt = load_ground_truth(wrong)
    with Scene.open(wrong) as scene:
        clock = ClockModel(gt["clock"]["offset_us"], 0.0, gt["clock"]["t_ref_us"])
        start = {n: scene.T_base_obj(n) for n in scene.object_names}
        man = {n: scene.manifest.object(n).T_base_obj for n in scene.object_names}
        true = {n: np.asarray(gt["objects"][n]["T_base_obj"]) for n in scene.object_names}
        off = make_T(np.eye(3), [0.012, 0.0, 0.0]) @ start["cylinder"]
        windows = [(t - 5000, t + 5000) for t in clock.t_ref_us + np.arange(300_000, 2_700_000, 150_000)]

        def result(poses):
            r = JointResult(JointParams(clock=False), clock.offset_us, 0.0, accepted=True)
            r.objects = {n: ObjectFit(T @ inv_T(man[n]), 1.0, 1.0, 0.1, 0.1) for n, T in poses.items()}
            return r

        r = result({"box": true["box"], "cylinder": off})
        check_held_out(scene, r, windows, clock, start, 10_000)
        assert r.accepted and "box" in r.objects and r.held_out["box"]["score_change"] > 0
        assert "cylinder" not in r.objects and "did not use fell" in r.held["cylinder"]
        r = result({"box": make_T(np.eye(3), [0.0, 0.015, 0.0]) @ start["box"]})
        r.offset_us += 30_000                                      # and a clock 30 ms off
        check_held_out(scene, r, windows, clock, start, 10_000)
        assert "box" in r.held and not r.accepted and "did not use fall" in r.reason


def test_the_second_look_takes_the_start_basin_only_where_it_fits_better(wrong):
    """A first pass that ended an object far from its truth (the box 8 mm off: beyond the fine widths' reach) while
    its start pose is right: the second look (fit again from the start over the fine widths) finds the truth, keeps
    it and says so. Where the first pass is right and the start 15 mm off (the cylinder), the second look's pose
    scores lower and the first pass's stays. The objective never falls."""
    gt = load_ground_truth(wrong)
    with Scene.open(wrong) as scene:
        names = scene.object_names
        clock = ClockModel(gt["clock"]["offset_us"], 0.0, gt["clock"]["t_ref_us"])
        true = [np.asarray(gt["objects"][n]["T_base_obj"], float) for n in names]
        off = make_T(np.eye(3), [0.008, 0.0, 0.0])
        i_box, i_cyl = names.index("box"), names.index("cylinder")
        first = [T.copy() for T in true]
        first[i_box] = off @ true[i_box]
        start = [T.copy() for T in true]
        start[i_cyl] = make_T(np.eye(3), [0.0, 0.015, 0.0]) @ true[i_cyl]
        p = JointParams(n_windows=12, clock=False)
        windows = joint_fit._choose(scene, p, clock, names, None)
        state = joint_fit.JointState(float(clock.offset_us), 0.0, int(clock.t_ref_us), np.eye(4), first)
        fit = joint_fit._Fit(scene, names, windows, state, p)
        lay = joint_fit._layout(len(names), p, names, False)
        sigmas = p.sigmas(float(scene.camera.K[0, 0]))
        result = joint_fit.JointResult(params=p, offset_us=clock.offset_us, skew_ppm=0.0)
        total, totals = np.zeros(lay.n), [np.zeros(lay.n) for _ in sigmas]
        before = joint_second_look.object_values(fit, state, sigmas[-1])[0].sum(axis=0)
        joint_second_look.second_look(fit, sigmas, lay, p, result, total, totals, start, 0.0, None, None)
        after = joint_second_look.object_values(fit, fit.state, sigmas[-1])[0].sum(axis=0)
        err = _errors(scene, gt, {n: fit.state.T_bo[k] for k, n in enumerate(names)})
    print(f"second look: errors (mm, deg) {err.round(2).tolist()}, shares {before.round(4)} -> {after.round(4)}, "
          f"notes {result.notes}")
    assert err[i_box, 0] < 1.0                                   # found from its start: 8 mm -> the truth
    assert err[i_cyl, 0] < 0.5                                   # the first pass's right pose kept
    assert after.sum() > before.sum() and after[i_box] > before[i_box]
    assert len(result.notes) == 1 and result.notes[0].startswith("box: fitted again from its start pose")
    assert np.any(totals[-1][8 + 6 * i_box: 14 + 6 * i_box])     # the width-disagreement term is the second look's


def test_objectives_score_the_truth_above_a_moved_object_and_shares_sum_to_the_objective(wrong):
    """bench/optimum_check.py's measure: :func:`joint_second_look.objectives` gives every state's objective at
    every width, the truth above the same scene with the box 6 mm off at each of the finer widths (the coarsest may blur it);
    each object's share (the second look's measure) sums to the objective the fit uses."""
    gt = load_ground_truth(wrong)
    with Scene.open(wrong) as scene:
        names = scene.object_names
        clock = ClockModel(gt["clock"]["offset_us"], 0.0, gt["clock"]["t_ref_us"])
        true = [np.asarray(gt["objects"][n]["T_base_obj"], float) for n in names]
        moved = [T.copy() for T in true]
        moved[names.index("box")] = make_T(np.eye(3), [0.0, 0.006, 0.0]) @ true[names.index("box")]
        p = JointParams(n_windows=8, clock=False)
        states = [joint_fit.JointState(float(clock.offset_us), 0.0, int(clock.t_ref_us), np.eye(4), T)
                  for T in (true, moved)]
        F = joint_second_look.objectives(scene, states, params=p, clock=clock)
        fit = joint_fit._Fit(scene, names, joint_fit._choose(scene, p, clock, names, None), states[0], p)
        sigma = p.sigmas(float(scene.camera.K[0, 0]))[-1]
        shares, beta = joint_second_look.object_values(fit, states[0], sigma)
        d = fit.data(states[0], fit.look(states[0]), sigma)
        value = fit.value(d, sigma, beta)
    print(f"objectives: truth {F[0].round(4)}, box moved {F[1].round(4)}; shares {shares.sum(axis=0).round(4)}")
    assert F.shape == (2, len(p.sigmas(float(scene.camera.K[0, 0])))) and np.all(np.isfinite(F))
    assert np.all(F[0, 2:] > F[1, 2:])
    assert shares.sum() == pytest.approx(value, rel=1e-9) and np.all(shares.sum(axis=0) > 0)
    assert F[0, -1] == pytest.approx(value, rel=1e-9)               # the same windows, association and kernel


@pytest.fixture(scope="module")
def mounted(tmp_path_factory):
    """Half resolution, 2.5 s, right clock and poses, a 2 mm / 0.5 deg camera mounting (hand-eye) error."""
    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    out = tmp_path_factory.mktemp("joint") / "mounted"
    generate(out, SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5, duration_s=2.5,
                              hand_eye_error_mm=2.0, hand_eye_error_deg=0.5, seed=12, max_px_per_frame=0.5,
                              camera=half_davis_camera()))
    return out


def test_hand_eye_error_is_recovered(mounted):
    gt = load_ground_truth(mounted)
    H_gt = np.asarray(gt["hand_eye"]["dT_cam"])
    assert gt["injected"]["hand_eye_error_mm"] == 2.0
    with Scene.open(mounted) as scene:
        r = joint_fit.refine_joint(scene, params=JointParams(clock=False, objects=(), hand_eye=True, n_windows=16))
    et, er = pose_error(r.hand_eye_dT_cam, H_gt)
    e0t, e0r = pose_error(np.eye(4), H_gt)
    print(f"hand-eye: {np.linalg.norm(e0t) * 1e3:.2f} mm / {np.degrees(np.linalg.norm(e0r)):.3f} deg -> "
          f"{np.linalg.norm(et) * 1e3:.3f} mm / {np.degrees(np.linalg.norm(er)):.4f} deg "
          f"(std {r.hand_eye_std_mm:.3f} mm / {r.hand_eye_std_deg:.4f} deg), {r.runtime_s:.1f} s")
    assert r.accepted, r.reason
    assert np.linalg.norm(e0t) * 1e3 > 1.5
    assert np.linalg.norm(et) * 1e3 < 0.4 and np.degrees(np.linalg.norm(er)) < 0.06
    assert r.hand_eye_std_mm < 0.4 and r.objects == {}


# ---------------------------------------------------------------------------- CLI contract
def test_refine_joint_apply_is_one_undo_step(wrong, tmp_path):
    folder = tmp_path / "scene"
    shutil.copytree(wrong, folder)
    rc, out = _cli(["refine", str(folder), "--joint", "--json", "--apply", "--windows", "12"])   # with the bar
    assert rc == 0
    doc = json.loads(out)
    for key in ("offset_us", "skew_ppm", "offset_std_us", "objects", "held", "hand_eye", "accepted", "applied"):
        assert key in doc
    assert doc["accepted"] and doc["applied"] and doc["objects"]
    with Scene.open(folder) as scene:
        assert scene.clock.offset_us == doc["offset_us"]
        for n, o in doc["objects"].items():
            assert np.allclose(scene.corrections.object_delta(n), np.asarray(o["dT_base"]))
    # the same through the core: one undo step restores the clock and every pose
    from evpose.core.align.apply import apply_joint_result

    with Scene.open(wrong) as scene:
        r = joint_fit.refine_joint(scene, params=JointParams(n_windows=8, sigmas_px=(1.5, 0.8)))
        h = History(scene.corrections)
        off0, poses0 = scene.clock.offset_us, {n: scene.T_base_obj(n) for n in scene.object_names}
        assert apply_joint_result(h, scene, r)
        assert len(h) == 1 and scene.clock.offset_us == r.offset_us
        h.undo()
        assert scene.clock.offset_us == off0
        assert all(np.allclose(scene.T_base_obj(n), T) for n, T in poses0.items())
    assert _cli(["refine", str(folder), "--hand-eye"])[0] == 2            # --hand-eye goes with --joint


def test_sync_edges_json_puts_the_final_estimate_on_top(wrong, tmp_path):
    """``sync --edges --json``: the top level is the final (edge) estimate, each stage under ``stages``;
    ``--apply`` stores that clock (not the rate's) and no pose."""
    folder = tmp_path / "scene"
    shutil.copytree(wrong, folder)
    rc, out = _cli(["sync", str(folder), "--json", "--edges", "--apply", "--windows", "12"])     # with the bar
    assert rc == 0
    data = json.loads(out)
    rate, edges = data["stages"]["rate"], data["stages"]["edges"]
    for key in ("offset_us", "skew_ppm", "offset_std_us", "skew_std_ppm", "confidence", "runtime_s", "method",
                "reliable", "correction", "applied"):
        assert key in data
    assert rate["reliable"] and edges["accepted"], edges["reason"]
    assert data["method"] == "rate+edges" and data["offset_us"] == edges["offset_us"]
    assert data["offset_std_us"] == pytest.approx(edges["offset_std_us"])
    assert data["offset_us"] != rate["offset_us"]
    gt = load_ground_truth(wrong)
    assert abs(data["offset_us"] - gt["clock"]["offset_us"]) < abs(rate["offset_us"] - gt["clock"]["offset_us"])
    assert data["applied"]
    with Scene.open(folder) as scene:
        assert scene.clock.offset_us == data["offset_us"]
        if data["skew_ppm"] is not None:                                # the skew reported is the skew saved
            assert scene.clock.skew_ppm == pytest.approx(data["skew_ppm"])
        assert scene.corrections.skew_ppm == pytest.approx(data["correction"]["skew_ppm"])
        assert scene.corrections.object_deltas == {}                  # sync stores the clock only
    rc, text = _cli(["sync", str(folder), "--edges", "--windows", "8", "-q"])
    assert rc == 0 and "clock and poses fitted together" in text


def test_a_mounting_error_is_not_turned_into_a_clock_error(mounted):
    """Issue 23.5: with a right clock and a 2 mm / 0.5 deg camera-mounting error, the clock-and-poses fit can only
    absorb the mounting into the clock (it moved it 9 ms and was refused); the sync edge stage's mounting check fits
    again with the hand-eye free, says so, proposes the hand-eye, and keeps the clock right within its sigma."""
    from evpose.core.align import sync_run
    from evpose.core.align.estimate import sync_scene

    gt = load_ground_truth(mounted)
    with Scene.open(mounted) as scene:
        rate = sync_scene(scene)
        res = sync_run.edge_stage(scene, rate, 16)
    assert res.accepted and res.params.hand_eye, (res.reason, res.notes)
    assert "camera mounting (hand-eye) looks off" in res.notes[0]
    err_us = res.offset_us - gt["clock"]["offset_us"]
    assert abs(err_us) <= 2 * res.offset_std_us, (err_us, res.offset_std_us)
    # the printed sigma is the data's with the model-error floor in quadrature (issue 23.2)
    from evpose.core.align import uncertainty as U

    assert res.offset_std_us == pytest.approx(np.hypot(res.offset_std_data_us, U.JOINT_OFFSET_FLOOR_US))
    assert res.hand_eye_std_mm >= U.HAND_EYE_FLOOR_MM and res.hand_eye_std_deg >= U.HAND_EYE_FLOOR_DEG
    et, er = pose_error(res.hand_eye_dT_cam, np.asarray(gt["hand_eye"]["dT_cam"]))
    assert np.linalg.norm(et) * 1e3 <= 2 * res.hand_eye_std_mm and np.degrees(er) <= 2 * res.hand_eye_std_deg
    assert np.linalg.norm(et) * 1e3 < 1.0 and np.degrees(er) < 0.15


def _fake_result(accepted=True, he=False, dt_mm=0.0, std_mm=0.2, dR_deg=0.0, std_deg=0.05, data_us=30.0, n_obj=3):
    from evpose.core.align.joint_result import JointResult, ObjectFit

    r = JointResult(JointParams(hand_eye=he), offset_us=0, skew_ppm=0.0, offset_std_us=50.0, accepted=accepted,
                    offset_std_data_us=data_us, reason="" if accepted else "refused")
    r.objects = {f"o{i}": ObjectFit(np.eye(4), 0.1, 0.1, 0.1, 0.1) for i in range(n_obj)}
    if he:
        r.hand_eye_dT_cam, r.hand_eye_dt_mm, r.hand_eye_std_mm = np.eye(4), dt_mm, std_mm
        r.hand_eye_dR_deg, r.hand_eye_std_deg = dR_deg, std_deg
    return r


def test_mounting_check_takes_the_hand_eye_fit_only_when_significant():
    """The decision of the mounting check, on made-up fits: when it runs, and which fit it believes."""
    from evpose.core.align import sync_run

    assert not sync_run.mounting_suspected(_fake_result())                      # windows agree: no second fit
    assert sync_run.mounting_suspected(_fake_result(data_us=sync_run.MOUNTING_TRIGGER_STD_US * 1.5))
    assert sync_run.mounting_suspected(_fake_result(accepted=False))
    implausible = _fake_result()
    implausible.skew_implausible = True
    assert sync_run.mounting_suspected(implausible)
    k = sync_run.MOUNTING_SIGMAS
    first = _fake_result()
    alt = _fake_result(he=True, dt_mm=(k + 0.5) * 0.2)                          # beyond k sigma: believed
    assert sync_run.mounting_check(first, alt) is alt and "looks off" in alt.notes[0]
    first, alt = _fake_result(), _fake_result(he=True, dt_mm=(k - 0.5) * 0.2, dR_deg=(k - 0.5) * 0.05)
    assert sync_run.mounting_check(first, alt) is first and "no camera-mounting error" in first.notes[-1]
    first, alt = _fake_result(), _fake_result(he=True, dR_deg=(k + 1) * 0.05)    # the rotation alone suffices
    assert sync_run.mounting_check(first, alt) is alt
    first, alt = _fake_result(), _fake_result(accepted=False, he=True, dt_mm=10.0)
    assert sync_run.mounting_check(first, alt) is first and "refused" in first.notes[-1]
    # one object: its own pose error and a mounting error look alike, nothing is concluded
    first, alt = _fake_result(n_obj=1), _fake_result(he=True, dt_mm=10.0, n_obj=sync_run.MOUNTING_MIN_OBJECTS - 1)
    assert sync_run.mounting_check(first, alt) is first and "nothing concluded" in first.notes[-1]
    # a camera that does not turn: a mounting shift is every object shifted alike; only its rotation is judged
    first, alt = _fake_result(), _fake_result(he=True, dt_mm=(k + 1) * 0.2)
    assert sync_run.mounting_check(first, alt, turns=False) is first and "does not turn" in first.notes[-1]
    first, alt = _fake_result(), _fake_result(he=True, dt_mm=10.0, dR_deg=(k + 1) * 0.05)
    assert sync_run.mounting_check(first, alt, turns=False) is alt and "does not turn" in alt.notes[-1]
    # judged against the events' own sigma: the object prior's pull widens the stored sigma (how far the start poses
    # may be off), not the evidence for a mounting change
    first, alt = _fake_result(), _fake_result(he=True, dR_deg=(k + 1) * 0.05, std_deg=0.5)
    alt.hand_eye_std_events_mm, alt.hand_eye_std_events_deg = 0.2, 0.05
    assert sync_run.mounting_check(first, alt) is alt and "start poses' own uncertainty" in alt.notes[0]
    first, alt = _fake_result(), _fake_result(he=True, dR_deg=(k + 1) * 0.05, std_deg=0.5)
    assert sync_run.mounting_check(first, alt) is first                          # without it: the stored sigma


def test_a_kept_mounting_carries_the_checks_sigma_into_the_document(wrong):
    """Issue 28.3: when the mounting check keeps the mounting (nothing concluded, or no error seen), how far it may be
    off -- the hand-eye change the check saw and its sigma in quadrature -- is stored as the hand-eye's sigma (the
    label sigma's hand-eye input); a check that took the hand-eye fit stores that fit's own."""
    from evpose.core.align import sync_run
    from evpose.core.align.apply import plan_joint_result, store_changes

    first, alt = _fake_result(n_obj=1), _fake_result(he=True, dt_mm=10.0, std_mm=0.5, dR_deg=0.3, std_deg=0.1,
                                                     n_obj=sync_run.MOUNTING_MIN_OBJECTS - 1)
    kept = sync_run.mounting_check(first, alt)
    assert kept is first and kept.mounting_check == {"dt_mm": 10.0, "dt_std_mm": 0.5, "dR_deg": 0.3, "dR_std_deg": 0.1}
    assert kept.to_json()["mounting_check"]["dt_mm"] == 10.0
    with Scene.open(wrong) as scene:
        kept.objects = {}
        h = History(scene.corrections)
        changes, _ = plan_joint_result(scene, kept, clock=False)
        assert [c.part for c in changes] == ["sigma"] and store_changes(h, changes, "sync")
        assert scene.corrections.sigma("hand_eye") == {"mm": pytest.approx(np.hypot(10.0, 0.5)),
                                                       "deg": pytest.approx(np.hypot(0.3, 0.1))}
        assert np.array_equal(scene.corrections.hand_eye_delta, np.eye(4))        # the mounting itself is kept
        h.undo()
    first, alt = _fake_result(), _fake_result(accepted=False, he=True, dt_mm=10.0)
    assert sync_run.mounting_check(first, alt).mounting_check is None               # a refused check says nothing


def test_how_far_the_camera_turns(mounted, tmp_path):
    """Trajectory B turns the camera to look at the objects; the same recording with every recorded orientation
    replaced by the first one does not turn."""
    import csv

    from evpose.core.align import sync_run

    with Scene.open(mounted) as scene:
        assert sync_run.camera_turn_deg(scene) > sync_run.MOUNTING_MIN_TURN_DEG
    still = tmp_path / "still"
    shutil.copytree(mounted, still)
    rows = list(csv.reader((still / "trajectory.csv").read_text().splitlines()))
    head, body = rows[0], rows[1:]
    q = [i for i, h in enumerate(head) if h.strip() in ("qx", "qy", "qz", "qw")]
    assert len(q) == 4, head
    for r in body:
        for i in q:
            r[i] = body[0][i]
    (still / "trajectory.csv").write_text("\n".join(",".join(r) for r in [head, *body]) + "\n")
    with Scene.open(still) as scene:
        assert sync_run.camera_turn_deg(scene) < 1e-6


def test_window_poses_are_computed_when_indexed_as_for_the_whole_window_at_once():
    """Issue 25.4: a joint window keeps per event only its knot and fraction (set_window_clock); indexing gives the
    poses and rates the whole-window computation gave (the former storage), bit for bit."""
    from types import SimpleNamespace

    from evpose.core.align.joint_model import KnotPoses, set_window_clock

    rng = np.random.default_rng(5)
    k = 40
    T_bc = np.stack([make_T(Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix(), rng.normal(0, 0.5, 3))
                     for _ in range(k)])
    view = SimpleNamespace(T_base_cam=lambda knots, clock: (T_bc[:len(knots)], np.ones(len(knots), bool)))
    t = np.sort(rng.integers(1000, 4000, 5000)).astype(np.int64)
    w = SimpleNamespace(ev_t=t, t0=1000, t1=4000, xy=rng.normal(size=(len(t), 2)))
    set_window_clock(view, w, None, spacing_us=100)
    assert isinstance(w.T_cb, KnotPoses) and w.T_cb.shape == (len(t), 3, 4) and w.ok.all()
    knots = np.arange(900, 4200, 100, dtype=np.int64)
    T_cb = inv_T(T_bc[:len(knots)])[:, :3, :]
    j = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, len(knots) - 2)
    f = ((t - knots[j]) / 100.0)[:, None, None]
    whole = T_cb[j] * (1.0 - f) + T_cb[j + 1] * f
    rate = (T_cb[j + 1] - T_cb[j]) / 100.0
    e = rng.choice(len(t), 700, replace=False)
    assert np.array_equal(w.T_cb[e], whole[e]) and np.array_equal(w.T_cb.rate(e), rate[e])
    assert np.array_equal(w.T_cb[e, :3, :3], whole[e, :3, :3]) and np.array_equal(w.T_cb[e, :3, 3], whole[e, :3, 3])
    assert np.array_equal(w.T_cb[e[3]], whole[e[3]]) and np.array_equal(w.T_cb[e[3]][:3, 3], whole[e[3], :3, 3])
