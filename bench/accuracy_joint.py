"""Accuracy against run time of the joint refinement (clock, object poses, hand-eye; tracker issue 15), the
section ``JOINT`` of ``bench/accuracy.py`` (``python bench/accuracy.py --sections joint [--quick] [--json]``).

Scenes (rendered once into ``bench/.data/accuracy``, full DAVIS346 346x260 with its distortion, three objects:
E-POSE's sugar box, drill and mustard bottle meshes when ``../shared/assets/epose/models`` exists, else built-in
shapes; trajectory B; every object's pose 5 mm / 3 degrees off and the clock off by an offset of E-POSE's
``time_shifts.csv``):

* ``joint_<variant>_v<speed>``: 8 s at 0.1, 0.5 and 1.0 m/s, for three simulator settings so the method is not
  tuned to one: ``A`` contrast threshold 0.2 (sigma 0.03), background 0.1 Hz, checker texture (the defaults);
  ``B`` threshold 0.35 (sigma 0.06), background 2 Hz, a texture three times finer; ``C`` threshold 0.15
  (sigma 0.02), background 0.5 Hz, no texture (shading only). ``--quick``: ``A`` only.
* ``joint_A_slow40``: 40 s at 0.1 m/s with a +80 ppm skew, where the windows pin the skew.
* ``joint_he`` / ``joint_he_all``: 6 s at 0.5 m/s with a 2 mm / 0.5 degree hand-eye (camera mounting) error,
  alone and together with the clock and pose errors.
* the 5-object, 5 s scene of the performance benchmarks (``bench/synth_scenes.py::ensure_ycb_scene``) for the
  run-time target.

Methods per scene, each from the scene's (wrong) corrections:

* ``rate``: the event-rate estimate alone (the baseline);
* ``separate``: the previous method, one stage at a time: the clock from the edges started at the rate estimate
  (:func:`~evpose.core.align.sync_edges.refine_offset_from_sync`, which takes the poses as right), then each
  object's pose at that clock (:func:`~evpose.core.align.pose_refine.refine_object`);
* ``joint``: the rate estimate, then :func:`~evpose.core.align.joint_fit.refine_joint` (clock and poses together;
  ``evpose sync --edges``, Auto in the app).

Printed: clock error (µs), skew error (ppm, where estimated), pose errors (median and max over objects; the
displacement of the object's centre in mm and the rotation in degrees), the calibration of the reported standard
errors (|error| / sigma, median, and the share within 2 sigma) and the run time (rate + fit).
"""
from __future__ import annotations

import sys
import time

import numpy as np

from evpose.core.data.geometry import pose_error
from evpose.core.sim.evsim import SensorParams
from evpose.core.sim.synth_config import SynthConfig

#: Rendering of the section's scenes: a frame at least every 2 ms and every pixel of image motion (the classic
#: sections' 1 ms / 0.5 px costs 4x the frames on full-resolution scenes, ~15 min per 8 s scene here).
JOINT_RENDER = dict(max_px_per_frame=1.0, max_frame_interval_us=2000)

VARIANTS = {
    "A": dict(sensor=SensorParams(contrast=0.2, contrast_sigma=0.03, noise_rate_hz=0.1), texture="checker"),
    "B": dict(sensor=SensorParams(contrast=0.35, contrast_sigma=0.06, noise_rate_hz=2.0), texture="fine"),
    "C": dict(sensor=SensorParams(contrast=0.15, contrast_sigma=0.02, noise_rate_hz=0.5), texture="plain"),
}
SPEEDS = (0.1, 0.5, 1.0)


def _objects(models_dir) -> dict:
    if models_dir.is_dir():
        return dict(objects=("sugar_box", "drill", "mustard_bottle"), mesh_dir=str(models_dir))
    return dict(objects=("box", "cylinder", "flatbox"))


def joint_scene_jobs(quick: bool, offsets: list, models_dir, render: dict = JOINT_RENDER) -> dict:
    """name -> SynthConfig of the section's rendered scenes."""
    obj = _objects(models_dir)
    jobs = {}
    for vi, (var, kw) in enumerate(VARIANTS.items()):
        if quick and var != "A":
            continue
        for si, sp in enumerate(SPEEDS):
            jobs[f"joint_{var}_v{sp}"] = SynthConfig(trajectory="B", speed_mps=sp, duration_s=8.0,
                                                    offset_us=offsets[(3 * vi + si) % len(offsets)],
                                                    pose_error_mm=5.0, pose_error_deg=3.0, seed=40 + 3 * vi + si,
                                                    **obj, **kw, **render)
    jobs["joint_A_slow40"] = SynthConfig(trajectory="B", speed_mps=0.1, duration_s=40.0, offset_us=offsets[1],
                                         skew_ppm=80.0, pose_error_mm=5.0, pose_error_deg=3.0, seed=60, **obj,
                                         **VARIANTS["A"], **render)
    jobs["joint_he"] = SynthConfig(trajectory="B", speed_mps=0.5, duration_s=6.0, hand_eye_error_mm=2.0,
                                   hand_eye_error_deg=0.5, seed=70, **obj, **VARIANTS["A"], **render)
    jobs["joint_he_all"] = SynthConfig(trajectory="B", speed_mps=0.5, duration_s=6.0, hand_eye_error_mm=2.0,
                                       hand_eye_error_deg=0.5, offset_us=offsets[2], pose_error_mm=5.0,
                                       pose_error_deg=3.0, seed=71, **obj, **VARIANTS["A"], **render)
    return jobs


# ---------------------------------------------------------------------------- errors
def pose_errors(scene, gt, poses: dict) -> list[tuple[float, float]]:
    """(centre displacement mm, rotation deg) per object of ``poses`` (name -> T_base_obj) against the truth."""
    from accuracy import obj_errors       # imported here: accuracy.py imports this module in its joint section

    return [obj_errors(scene, n, T, gt) for n, T in poses.items()]


def _clock_err(offset_us, gt) -> float | None:
    return None if offset_us is None else float(offset_us - gt["clock"]["offset_us"])


def run_rate(scene, gt) -> dict:
    from evpose.core.align.estimate import sync_scene

    t = time.perf_counter()
    r = sync_scene(scene)
    return {"rate": r, "clock_err_us": _clock_err(r.offset_us, gt), "sigma_us": r.offset_std_us,
            "skew_err_ppm": None if r.skew_ppm is None else float(r.skew_ppm - gt["clock"]["skew_ppm"]),
            "poses": pose_errors(scene, gt, {n: scene.T_base_obj(n) for n in scene.object_names}),
            "runtime_s": time.perf_counter() - t}


def run_separate(scene, gt, rate) -> dict:
    """The previous method: clock from edges at the (wrong) poses, then each pose at that clock."""
    from evpose.core.align.pose_refine import refine_object
    from evpose.core.align.refine_result import RefineParams
    from evpose.core.align.sync_edges import refine_offset_from_sync

    t = time.perf_counter()
    e = refine_offset_from_sync(scene, rate, params=RefineParams(n_windows=24))
    clock = scene.clock_with(offset_us=e.offset_us, skew_ppm=e.skew_ppm) if e.accepted else rate.clock()
    poses = {}
    for n in scene.object_names:
        r = refine_object(scene, n, params=RefineParams(n_windows=12), clock=clock, with_scores=False)
        poses[n] = r.dT_base @ scene.manifest.object(n).T_base_obj
    return {"clock_err_us": _clock_err(clock.offset_us, gt), "sigma_us": e.offset_std_us if e.accepted else None,
            "skew_err_ppm": float(e.skew_ppm - gt["clock"]["skew_ppm"]) if e.accepted and e.skew_estimated else None,
            "poses": pose_errors(scene, gt, poses), "runtime_s": time.perf_counter() - t}


def run_joint(scene, gt, rate, params=None) -> dict:
    from evpose.core.align.joint_fit import refine_joint
    from evpose.core.align.joint_result import JointParams

    params = params or JointParams()
    t = time.perf_counter()
    r = refine_joint(scene, params=params, clock=rate.clock() if rate is not None else None)
    dt = time.perf_counter() - t
    poses = {n: (o.dT_base @ scene.manifest.object(n).T_base_obj) for n, o in r.objects.items()}
    poses.update({n: scene.T_base_obj(n) for n in scene.object_names if n not in poses})
    stds = {n: (o.std_mm, o.std_deg) for n, o in r.objects.items()}
    out = {"result": r, "clock_err_us": _clock_err(r.offset_us, gt) if params.clock else None,
           "sigma_us": r.offset_std_us, "skew_err_ppm": float(r.skew_ppm - gt["clock"]["skew_ppm"])
           if r.skew_estimated else None, "poses": pose_errors(scene, gt, poses),
           "pose_sigma": [stds.get(n, (None, None)) for n in poses], "held": dict(r.held),
           "runtime_s": dt}
    if "hand_eye" in gt and params.hand_eye:
        H_gt = np.asarray(gt["hand_eye"]["dT_cam"])
        et, er = pose_error(r.hand_eye_dT_cam, H_gt)
        out["hand_eye_err"] = (float(np.linalg.norm(et) * 1e3), float(np.degrees(np.linalg.norm(er))))
        out["hand_eye_sigma"] = (r.hand_eye_std_mm, r.hand_eye_std_deg)
    return out


# ---------------------------------------------------------------------------- report
def _fmt(x, nd=0):
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.{nd}f}"


def _pose_cell(p):
    if not p:
        return "n/a"
    dt, dr = np.array([a for a, _ in p]), np.array([b for _, b in p])
    return f"{np.median(dt):.2f} / {dt.max():.2f} mm, {np.median(dr):.2f} / {dr.max():.2f} deg"


def _ratio(err, sigma):
    return None if err is None or sigma is None or not np.isfinite(sigma) or sigma <= 0 else abs(err) / sigma


def bench_joint(scenes: dict, table, ycb_scene=None, separate: bool = True) -> dict:
    """Run the methods on every scene of :func:`joint_scene_jobs` (``scenes``: name -> folder) and print the
    tables; returns the JSON-able headline."""
    from evpose.core.align.joint_result import JointParams
    from evpose.core.data.scene import Scene
    from evpose.core.sim.synth import load_ground_truth

    rows, calib, doc = [], {"clock": [], "pose": []}, {"scenes": {}}
    names = [n for n in scenes if n.startswith("joint_") and not n.startswith("joint_he")]
    for n in names:
        scene, gt = Scene.open(scenes[n]), load_ground_truth(scenes[n])
        rate = run_rate(scene, gt)
        res = {"rate": rate}
        if separate:
            res["separate"] = run_separate(scene, gt, rate["rate"])
        res["joint"] = run_joint(scene, gt, rate["rate"])
        res["joint"]["runtime_s"] += rate["runtime_s"]
        scene.close()
        print(f"  [{n}] " + "; ".join(f"{m}: clock {_fmt(r['clock_err_us'])} us, poses {_pose_cell(r['poses'])}, "
                                      f"{r['runtime_s']:.1f} s" for m, r in res.items()), file=sys.stderr, flush=True)
        gen = gt["generator"]
        label = f"{n.split('_')[1]} {gen['speed_mps']:g} m/s {gen['duration_s']:g} s"
        doc["scenes"][n] = {}
        for method, r in res.items():
            rows.append([label, method, _fmt(r["clock_err_us"]), _fmt(r["sigma_us"]), _fmt(r["skew_err_ppm"], 1),
                         _pose_cell(r["poses"]), _fmt(r["runtime_s"], 1)])
            doc["scenes"][n][method] = {k: r[k] for k in ("clock_err_us", "sigma_us", "skew_err_ppm", "poses",
                                                          "runtime_s")}
        j = res["joint"]
        calib["clock"].append(_ratio(j["clock_err_us"], j["sigma_us"]))
        for (dt, dr), (sm, sd) in zip(j["poses"], j["pose_sigma"]):
            calib["pose"].append((_ratio(dt, sm), _ratio(dr, sd)))
        doc["scenes"][n]["joint"]["held"] = j["held"]
    table("JOINT: clock and poses from edges, scenes with a clock error AND 5 mm / 3 deg pose errors on every object "
          "(346x260, 3 objects)", ["scene (variant, speed, length)", "method", "clock err us", "sigma us",
                                   "skew err ppm", "pose err median / max", "runtime s"], rows)
    _summary(doc, table)
    _calibration(calib, table, doc)
    doc["hand_eye"] = _hand_eye(scenes, table)
    if ycb_scene is not None:
        doc["runtime_5obj"] = _runtime_5obj(ycb_scene, table)
    doc["params"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in JointParams().__dict__.items()}
    return doc


def _summary(doc, table):
    """Per speed, over the simulator variants: clock error and pose error spread of each method."""
    rows = []
    for sp in SPEEDS:
        for method in ("rate", "separate", "joint"):
            ce, pt, pr = [], [], []
            for n, per in doc["scenes"].items():
                if f"_v{sp}" not in n or method not in per:
                    continue
                r = per[method]
                if r["clock_err_us"] is not None:
                    ce.append(abs(r["clock_err_us"]))
                pt += [a for a, _ in r["poses"]]
                pr += [b for _, b in r["poses"]]
            if not ce and not pt:
                continue
            rows.append([f"{sp:g} m/s (8 s)", method, f"{len(ce)}",
                         f"{np.median(ce):.0f} / {max(ce):.0f}" if ce else "n/a",
                         f"{np.median(pt):.2f} / {max(pt):.2f}" if pt else "n/a",
                         f"{np.median(pr):.2f} / {max(pr):.2f}" if pr else "n/a"])
    table("JOINT summary over the simulator variants (spread): |clock err| us and pose errors, median / max",
          ["speed", "method", "scenes", "|clock err| us", "pose mm", "pose deg"], rows)
    print("  targets: clock <= 200 us at every speed; poses <= 1 mm / 0.3 deg median; skew within 10 ppm where "
          "estimated; rate + joint <= 10 s for 5 s of a 5-object scene")


def _calibration(calib, table, doc):
    def stats(v):
        v = [x for x in v if x is not None]
        return (f"{np.median(v):.2f}", f"{100 * np.mean(np.array(v) <= 2):.0f} %", len(v)) if v else ("n/a", "n/a", 0)

    rows = [["clock offset", *stats(calib["clock"])],
            ["pose translation (centre)", *stats([a for a, _ in calib["pose"]])],
            ["pose rotation", *stats([b for _, b in calib["pose"]])]]
    table("JOINT standard errors: |error| / sigma of the joint fit (cluster-robust sandwich over windows)",
          ["parameter", "|err|/sigma median", "within 2 sigma", "n"], rows)
    doc["calibration"] = {r[0]: {"median_ratio": r[1], "within_2_sigma": r[2], "n": r[3]} for r in rows}


def _hand_eye(scenes, table) -> dict:
    from evpose.core.align.joint_result import JointParams
    from evpose.core.data.scene import Scene
    from evpose.core.sim.synth import load_ground_truth

    rows, out = [], {}
    cases = [("joint_he", "hand-eye only (clock and poses right)", JointParams(clock=False, objects=(), hand_eye=True)),
             ("joint_he", "hand-eye + clock + poses (all free)", JointParams(hand_eye=True)),
             ("joint_he", "clock + poses, no hand-eye (it leaks into the poses)", JointParams()),
             ("joint_he_all", "hand-eye + clock + poses, all wrong", JointParams(hand_eye=True))]
    for name, label, p in cases:
        if name not in scenes:
            continue
        scene, gt = Scene.open(scenes[name]), load_ground_truth(scenes[name])
        rate = run_rate(scene, gt)["rate"] if p.clock else None
        r = run_joint(scene, gt, rate, p)
        scene.close()
        he = r.get("hand_eye_err")
        sig = r.get("hand_eye_sigma")
        rows.append([name, label, "n/a" if he is None else f"{he[0]:.3f} mm, {he[1]:.4f} deg",
                     "n/a" if sig is None else f"{_fmt(sig[0], 3)} mm, {_fmt(sig[1], 4)} deg",
                     _fmt(r["clock_err_us"]), _pose_cell(r["poses"]), _fmt(r["runtime_s"], 1)])
        out[label] = {"hand_eye_err": he, "hand_eye_sigma": sig, "clock_err_us": r["clock_err_us"],
                      "poses": r["poses"], "runtime_s": r["runtime_s"]}
    table("HAND-EYE: a 2 mm / 0.5 deg camera mounting error (3 objects, 6 s, 0.5 m/s, 346x260); target <= 0.3 mm / "
          "0.05 deg", ["scene", "fit", "hand-eye err", "sigma", "clock err us", "pose err median / max",
                       "runtime s"], rows)
    return out


def _runtime_5obj(folder, table) -> dict:
    from evpose.core.data.scene import Scene
    from evpose.core.sim.synth import load_ground_truth

    scene, gt = Scene.open(folder), load_ground_truth(folder)
    rate = run_rate(scene, gt)
    j = run_joint(scene, gt, rate["rate"])
    scene.close()
    total = rate["runtime_s"] + j["runtime_s"]
    table("RUN TIME of the automatic path on the 5-object, 5 s scene (346x260, real YCB meshes, 20 ms clock error, "
          "5 mm / 3 deg pose errors)", ["stage", "runtime s", "clock err us", "pose err median / max"],
          [["rate", _fmt(rate["runtime_s"], 2), _fmt(rate["clock_err_us"]), _pose_cell(rate["poses"])],
           ["joint edges", _fmt(j["runtime_s"], 2), _fmt(j["clock_err_us"]), _pose_cell(j["poses"])],
           ["total", _fmt(total, 2), "", f"held: {', '.join(j['held']) or 'none'}"]])
    return {"rate_s": rate["runtime_s"], "joint_s": j["runtime_s"], "total_s": total,
            "clock_err_us": j["clock_err_us"], "poses": j["poses"], "held": j["held"]}
