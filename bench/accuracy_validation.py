"""Accuracy and calibration of the automatic estimates on scenes they were not tuned on (tracker issue 23).

Families (``--family``):

* ``validation``: the frozen family of ``bench/validation_family.json`` (the independent ray-casting generator,
  ``core/sim_validation``; frozen before any tuning). Reported, never tuned on.
* ``calibration``: ``bench/calibration_family.json``, the same generator with other seeds and objects: the only
  scenes the model-error floors of the standard errors are set on (``--floors`` prints the floors they need).
* ``tuning``: the same configurations as the calibration family made by ``evpose synth`` (the simulator the
  estimators were developed on), for the comparison the issue asks for.

Per scene, from the scene's (wrong) corrections, as ``evpose sync --edges`` runs: the event-rate stage, then the
joint fit of clock and object poses from edges started at it, with its mounting check (the fit again with the
hand-eye free): on scenes with a hand-eye error it must find it, elsewhere each detection is a false alarm. Printed: clock and skew errors with their sigma and |error| / sigma, each object's pose
error (translation of its centre, rotation; for a solid of revolution the tilt of its axis only, since its spin is
held) with sigma, the hand-eye error, and the run time; then per stage and parameter the share of |error| / sigma
within 2 and 4 (the issue's targets: >= 90 % within 2, all within 4), per speed and object count.

Usage: ``python bench/accuracy_validation.py [--family validation|calibration|tuning] [--scenes NAME ...]
[--json OUT] [--floors]``. Scenes are generated on first use (``bench/validation_scenes.py``; long: see there).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))

import validation_scenes as vs  # noqa: E402

FAMILIES = {"validation": vs.FAMILY, "calibration": vs.CALIBRATION}


# ------------------------------------------------------------------------------------------- scenes
def family_folders(family: str, names=None) -> dict[str, Path]:
    if family in FAMILIES:
        return vs.ensure_family(names, family=FAMILIES[family])
    return _tuning_folders(names)


def _tuning_folders(names=None) -> dict[str, Path]:
    """The calibration family's configurations made by ``evpose synth`` (cached in ``bench/.data/tuning``)."""
    from evpose.core.sim.synth_config import SynthConfig
    from synth_scenes import DATA, MODELS, ensure_synth

    out = {}
    for e in vs.load_family(vs.CALIBRATION)["scenes"]:
        if names and e["name"] not in names:
            continue
        kw = dict(objects=tuple(e["objects"]), trajectory=e["trajectory"], speed_mps=e["speed_mps"],
                  duration_s=e["duration_s"], offset_us=e["offset_us"], skew_ppm=e["skew_ppm"],
                  pose_error_mm=e["pose_error_mm"], pose_error_deg=e["pose_error_deg"],
                  hand_eye_error_mm=e["hand_eye_error_mm"], hand_eye_error_deg=e["hand_eye_error_deg"],
                  seed=e["seed"], pose_rate_hz=e["pose_rate_hz"], max_frame_interval_us=2000)
        if MODELS.is_dir():
            kw["mesh_dir"] = str(MODELS)
        out[e["name"]] = ensure_synth(DATA / "tuning" / e["name"], SynthConfig(**kw), "a few minutes")
    return out


# ------------------------------------------------------------------------------------------- errors
def _ratio(err, std):
    return abs(err) / std if std is not None and math.isfinite(std) and std > 0 else math.inf


def pose_errors(scene, name: str, T_est, T_true) -> tuple[float, float]:
    """(mm, deg): displacement of the object's centre and its rotation error; for a solid of revolution the angle
    between its axes only (its spin is not observable, and held)."""
    from evpose.core.data.geometry import rotation_angle

    model = scene.model(name)
    c = model.bbox_center_m
    mm = float(np.linalg.norm((T_est[:3, :3] @ c + T_est[:3, 3]) - (T_true[:3, :3] @ c + T_true[:3, 3]))) * 1e3
    kind, axis = model.symmetry
    if kind == "radial":
        a, b = T_est[:3, :3] @ axis, T_true[:3, :3] @ axis
        deg = float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))
    elif kind == "spherical":
        deg = 0.0
    else:
        deg = float(np.degrees(rotation_angle(T_est[:3, :3] @ T_true[:3, :3].T)))
    return mm, deg


def evaluate(folder: Path) -> dict:
    """One scene's row (see the module docstring)."""
    from evpose.core.align.sync_run import SyncOptions, run_sync
    from evpose.core.data.geometry import pose_error
    from evpose.core.data.scene import Scene
    from evpose.core.sim.synth import load_ground_truth

    gt = load_ground_truth(folder)
    inj = gt.get("injected", {})
    row = {"scene": folder.name, "speed_mps": None, "n_objects": len(gt["objects"]),
           "true_offset_us": gt["clock"]["offset_us"], "true_skew_ppm": gt["clock"]["skew_ppm"]}
    gen = gt.get("generator", {})
    row["speed_mps"] = gen.get("speed_mps", gt.get("config", {}).get("speed_mps"))
    row["duration_s"] = gen.get("duration_s", gt.get("config", {}).get("duration_s"))
    with Scene.open(folder) as scene:
        t0 = time.perf_counter()
        run = run_sync(scene, SyncOptions(edges=True))
        row["runtime_s"] = time.perf_counter() - t0
        rate, edges = run.result, run.edges
        true_o, true_s = gt["clock"]["offset_us"], gt["clock"]["skew_ppm"]
        row["rate"] = _clock_row(rate.offset_us, rate.offset_std_us, rate.skew_ppm,
                                 getattr(rate, "skew_std_ppm", None), true_o, true_s, rate.reliable, rate.reason)
        row["rate"]["std_data_us"] = rate.offset_std_data_us            # before its floor (for --floors)
        if edges is not None:
            row["joint"] = _clock_row(edges.offset_us, edges.offset_std_us,
                                      edges.skew_ppm if edges.skew_estimated else None, edges.skew_std_ppm,
                                      true_o, true_s, edges.accepted, edges.reason)
            if not edges.skew_estimated and edges.skew_std_ppm is not None:     # "not pinned": does its sigma cover
                row["joint"].update(skew_kept_err_ppm=float(edges.skew_ppm - true_s),   # the skew it kept?
                                    skew_unpinned_std_ppm=edges.skew_std_ppm,
                                    r_skew_unpinned=_ratio(edges.skew_ppm - true_s, edges.skew_std_ppm))
            row["joint"]["runtime_s"] = edges.runtime_s
            row["objects"] = {}
            for name in scene.object_names:
                T_true = np.asarray(gt["objects"][name]["T_base_obj"])
                start = pose_errors(scene, name, scene.T_base_obj(name), T_true)
                o = edges.objects.get(name) if edges.accepted else None
                if o is None:
                    row["objects"][name] = {"held": edges.held.get(name, "not accepted"), "start_mm": start[0],
                                            "start_deg": start[1], "mm": start[0], "deg": start[1]}
                    continue
                T_est = o.dT_base @ scene.manifest.object(name).T_base_obj
                mm, deg = pose_errors(scene, name, T_est, T_true)
                row["objects"][name] = {"start_mm": start[0], "start_deg": start[1], "mm": mm, "deg": deg,
                                        "std_mm": o.std_mm, "std_deg": o.std_deg,
                                        "r_mm": _ratio(mm, o.std_mm), "r_deg": _ratio(deg, o.std_deg)}
        # the mounting check of the edge stage: on a scene with a hand-eye error it must find it (the hand-eye row),
        # on the others it must not (a false alarm is counted)
        has_he = bool(inj.get("hand_eye_error_mm", 0) or inj.get("hand_eye_error_deg", 0))
        found = edges is not None and edges.accepted and edges.params.hand_eye and edges.hand_eye_dT_cam is not None
        row["mounting_found"] = bool(found)
        if has_he:
            H_true = np.asarray(gt["hand_eye"]["dT_cam"])
            et, er = pose_error(edges.hand_eye_dT_cam if found else np.eye(4), H_true)
            mm, deg = float(np.linalg.norm(et)) * 1e3, float(np.degrees(np.linalg.norm(er)))
            std_mm, std_deg = (edges.hand_eye_std_mm, edges.hand_eye_std_deg) if found else (None, None)
            row["hand_eye"] = {"found": bool(found), "mm": mm, "deg": deg, "std_mm": std_mm, "std_deg": std_deg,
                               "r_mm": _ratio(mm, std_mm) if found else math.inf,
                               "r_deg": _ratio(deg, std_deg) if found else math.inf}
    return row


def _clock_row(offset_us, std_us, skew_ppm, skew_std, true_o, true_s, ok, reason) -> dict:
    d = {"ok": bool(ok), "reason": reason, "offset_us": offset_us,
         "err_us": None if offset_us is None else float(offset_us - true_o), "std_us": std_us}
    d["r"] = _ratio(d["err_us"], std_us) if d["err_us"] is not None else math.inf
    if skew_ppm is not None:
        d.update(skew_err_ppm=float(skew_ppm - true_s), skew_std_ppm=skew_std,
                 r_skew=_ratio(skew_ppm - true_s, skew_std))
    return d


# ------------------------------------------------------------------------------------------- reports
def _cov(ratios) -> str:
    r = np.array([x for x in ratios if x is not None], float)
    if not len(r):
        return "n/a"
    fin = r[np.isfinite(r)]
    return (f"{np.mean(r <= 2) * 100:3.0f} % <= 2, {np.mean(r <= 4) * 100:3.0f} % <= 4, median "
            f"{np.median(fin) if len(fin) else float('nan'):.2f}, n {len(r)}")


def report(rows: list[dict], family: str) -> str:
    out = [f"{family.upper()} family, {len(rows)} scenes ({time.strftime('%Y-%m-%d')})", ""]
    head = f"{'scene':<36} {'m/s':>4} {'obj':>3} {'rate err ms ± sigma':>22} {'joint err us ± sigma':>22} " \
           f"{'skew err ppm ± sigma':>22} {'poses mm / deg (median, max)':>30} {'run s':>6}"
    out.append(head)
    for r in rows:
        ra, jo = r["rate"], r.get("joint") or {}
        rate = "—" if ra["err_us"] is None else f"{ra['err_us'] / 1e3:+.2f} ± {_ms(ra['std_us'])}"
        joint = "—" if not jo or jo.get("err_us") is None else f"{jo['err_us']:+.0f} ± {_num(jo['std_us'])}"
        skew = "—"
        if jo.get("skew_err_ppm") is not None:
            skew = f"{jo['skew_err_ppm']:+.1f} ± {_num(jo['skew_std_ppm'])}"
        elif jo.get("skew_kept_err_ppm") is not None:
            skew = f"(not pinned) {jo['skew_kept_err_ppm']:+.0f} ± {_num(jo['skew_unpinned_std_ppm'])}"
        objs = [o for o in (r.get("objects") or {}).values()]
        poses = "—" if not objs else (f"{np.median([o['mm'] for o in objs]):.2f}/{np.median([o['deg'] for o in objs]):.2f}, "
                                      f"{max(o['mm'] for o in objs):.2f}/{max(o['deg'] for o in objs):.2f}")
        out.append(f"{r['scene']:<36} {r['speed_mps'] or 0:>4g} {r['n_objects']:>3} {rate:>22} {joint:>22} "
                   f"{skew:>22} {poses:>30} {r['runtime_s']:>6.1f}")
    out += ["", "calibration of the reported sigma (|error| / sigma):"]
    out.append(f"  rate offset      {_cov([r['rate']['r'] for r in rows if r['rate']['err_us'] is not None])}")
    out.append(f"  joint offset     {_cov([r['joint']['r'] for r in rows if r.get('joint') and r['joint']['ok']])}")
    out.append(f"  joint skew       {_cov([r['joint']['r_skew'] for r in rows if r.get('joint') and r['joint']['ok'] and 'r_skew' in r['joint']])}")
    out.append("  skew not pinned  " + _cov([r["joint"]["r_skew_unpinned"] for r in rows if r.get("joint")
                                             and r["joint"]["ok"] and "r_skew_unpinned" in r["joint"]]))
    objs = [o for r in rows for o in (r.get("objects") or {}).values() if "r_mm" in o]
    out.append(f"  pose translation {_cov([o['r_mm'] for o in objs])}")
    out.append(f"  pose rotation    {_cov([o['r_deg'] for o in objs])}")
    he = [r["hand_eye"] for r in rows if "hand_eye" in r]
    if he:
        out.append(f"  hand-eye         {_cov([h['r_mm'] for h in he] + [h['r_deg'] for h in he])}")
    false = [r["scene"] for r in rows if r.get("mounting_found") and "hand_eye" not in r]
    out.append(f"  mounting check   found {sum(h['found'] for h in he)} of {len(he)} hand-eye errors; "
               f"{len(false)} false alarm(s) in {len(rows) - len(he)} scenes without one"
               + (f" ({', '.join(false)})" if false else ""))
    out += ["", "per speed: |clock error| median / max (us), rate and joint"]
    for sp in sorted({r["speed_mps"] for r in rows if r["speed_mps"]}):
        sel = [r for r in rows if r["speed_mps"] == sp]
        re_ = [abs(r["rate"]["err_us"]) for r in sel if r["rate"]["err_us"] is not None]
        je = [abs(r["joint"]["err_us"]) for r in sel if r.get("joint") and r["joint"]["ok"]]
        out.append(f"  {sp:g} m/s: rate {_mm(re_)}, joint {_mm(je)} ({len(sel)} scenes)")
    return "\n".join(out)


def _mm(v) -> str:
    return "n/a" if not v else f"{np.median(v):.0f} / {max(v):.0f}"


def _num(x) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.0f}" if abs(x) >= 10 else f"{x:.1f}"


def _ms(x) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x / 1e3:.2f}"


def floors(rows: list[dict]) -> dict:
    """The smallest model-error floor per estimate that brings |error| / sqrt(sigma^2 + floor^2) within 2 for 90 %
    of the rows (and reports how many stay above 4)."""
    def need(pairs):
        pairs = [(abs(e), s if s is not None and math.isfinite(s) else math.inf) for e, s in pairs if e is not None]
        if not pairs:
            return None
        for f in np.r_[0.0, np.geomspace(1e-3, 1e6, 400)]:
            r = [e / math.sqrt(s * s + f * f) if math.isfinite(s) else 0.0 for e, s in pairs]
            if np.mean(np.array(r) <= 2) >= 0.9:
                return float(f)
        return None

    objs = [o for r in rows for o in (r.get("objects") or {}).values() if "r_mm" in o]
    return {"rate_offset_us": need([(r["rate"]["err_us"], r["rate"].get("std_data_us", r["rate"]["std_us"]))
                                    for r in rows]),
            "joint_offset_us": need([(r["joint"]["err_us"], r["joint"]["std_us"]) for r in rows
                                     if r.get("joint") and r["joint"]["ok"]]),
            "joint_skew_ppm": need([(r["joint"]["skew_err_ppm"], r["joint"]["skew_std_ppm"]) for r in rows
                                    if r.get("joint") and "skew_err_ppm" in r["joint"]]),
            "pose_mm": need([(o["mm"], o["std_mm"]) for o in objs]),
            "pose_deg": need([(o["deg"], o["std_deg"]) for o in objs]),
            "hand_eye_mm": need([(r["hand_eye"]["mm"], r["hand_eye"]["std_mm"]) for r in rows
                                 if r.get("hand_eye", {}).get("found")]),
            "hand_eye_deg": need([(r["hand_eye"]["deg"], r["hand_eye"]["std_deg"]) for r in rows
                                  if r.get("hand_eye", {}).get("found")])}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--family", choices=("validation", "calibration", "tuning"), default="validation")
    ap.add_argument("--scenes", nargs="*", help="only these scenes")
    ap.add_argument("--json", help="write the rows to this file")
    ap.add_argument("--floors", action="store_true", help="print the model-error floors these scenes need")
    args = ap.parse_args(argv)
    if args.floors:             # the floors are set on the data-only standard errors: measure without them
        from evpose.core.align import uncertainty

        # but the rate's: the edge stage's search range is 4 of the rate's sigma (at least 5 ms), so without its
        # floor the hardest scenes' joint fits were refused and left out of the other floors (c03, c08 before
        # 2026-11-29); the rate's own floor is set on its data-only sigma, which every row records
        for k in uncertainty.__all__:
            if k.endswith(("_US", "_PPM", "_MM", "_DEG")) and k != "RATE_OFFSET_FLOOR_US":
                setattr(uncertainty, k, 0.0)
    rows = []
    for name, folder in family_folders(args.family, args.scenes).items():
        print(f"{name} ...", file=sys.stderr, flush=True)
        rows.append(evaluate(folder))
    print(report(rows, args.family))
    if args.floors:
        print("\nfloors needed (90 % within 2 sigma):", json.dumps(floors(rows)))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
