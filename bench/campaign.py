"""Campaign calibration against each scene's own fit (tracker issue 28.2), over many campaigns.

A campaign: three scenes of one placement (the same objects, placed and mis-placed alike: same seed, same pose
error) and one camera mounting (a hand-eye error), recorded at 0.1, 0.5 and 1.0 m/s, each with its own clock. For
every scene: its own joint fit (``evpose refine --joint --hand-eye``: clock, poses, hand-eye) and its share of the
campaign fit (``evpose dataset refine --joint --shared hand-eye,placement``, here in one process:
:class:`~evpose.core.align.campaign_terms.LocalEvaluator`). Errors against the ground truth: the hand-eye (mm of its
translation, degrees of its rotation) and each object's box centre (mm; the spin of a solid of revolution cannot
move it), each divided by the estimate's own sigma.

Two families, reported apart:

* ``synth`` -- the main generator (:mod:`evpose.core.sim`), half-resolution DAVIS346, 3 procedural objects, 2.5 s,
  seeds 31-36 (the tests use seed 21);
* ``raycast`` -- the independent ray-casting generator of the validation family (:mod:`evpose.core.sim_validation`:
  E-POSE's YCB meshes and DAVIS346 calibration when ``../shared`` has them, textured objects, pose jitter, arm
  ringing), full resolution, 3 s, seeds 41-43.

Neither was used to tune anything: the campaign reuses the single fit's model, kernel widths and sigma floors.
Printed: per campaign and scene, own vs campaign error (|err|/sigma); pooled per family: the share of estimates
within 2 sigma, median errors of the slow scene, how often the campaign beats the slow scene's own fit, and the
run time of the campaign against the sum of the three own fits (one process each way, same machine, same run).

Usage: ``python bench/campaign.py [--family synth|raycast|both] [--seeds N] [--json OUT]`` (scenes are cached in
``bench/.data/campaign``).
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
DATA = BENCH / ".data" / "campaign"
SPEEDS = {"slow": 0.1, "mid": 0.5, "fast": 1.0}
SEEDS = {"synth": (31, 32, 33, 34, 35, 36), "raycast": (41, 42, 43)}


def ensure_campaign(family: str, seed: int) -> Path:
    """The three scenes of one campaign (generated on first use)."""
    root = DATA / f"{family}_{seed}"
    for name, speed in SPEEDS.items():
        folder = root / name
        if (folder / "ground_truth.json").is_file():
            continue
        t0 = time.perf_counter()
        if family == "synth":
            from evpose.core.data.camera import CameraModel
            from evpose.core.sim.synth import generate
            from evpose.core.sim.synth_config import SynthConfig

            generate(folder, SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=speed,
                                         duration_s=2.5, seed=seed, pose_error_mm=3.0, pose_error_deg=1.5,
                                         pose_error_seed=seed, hand_eye_error_mm=2.0, hand_eye_error_deg=0.5,
                                         offset_us=int(1000 * (seed % 7)), max_px_per_frame=0.5,
                                         camera=CameraModel.davis346().binned(2).to_dict()), overwrite=True)
        else:
            from evpose.core.sim_validation.assemble import generate
            from evpose.core.sim_validation.config import ValidationConfig

            generate(folder, ValidationConfig(objects=("sugar_box", "mustard_bottle", "potted_meat_can"),
                                              trajectory="B", speed_mps=speed, duration_s=3.0, seed=seed,
                                              pose_error_mm=3.0, pose_error_deg=1.5, hand_eye_error_mm=2.0,
                                              hand_eye_error_deg=0.5, offset_us=int(1000 * (seed % 7))),
                     overwrite=True)
        print(f"  generated {folder} in {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    return root


def _errors(root: Path, name: str, he_total, objects: dict) -> dict:
    """Hand-eye (mm, deg) and each object's centre error (mm) of a scene's estimate against its truth."""
    from evpose.core.data.geometry import pose_error
    from evpose.core.data.scene import Scene
    from evpose.core.sim.synth import load_ground_truth

    gt = load_ground_truth(root / name)
    et, er = pose_error(np.asarray(he_total), np.asarray(gt["hand_eye"]["dT_cam"]))
    out = {"he_mm": float(np.linalg.norm(et) * 1e3), "he_deg": float(np.degrees(np.linalg.norm(er))), "obj_mm": {}}
    with Scene.open(root / name) as scene:
        for n in scene.object_names:
            Tt = np.asarray(gt["objects"][n]["T_base_obj"])
            T = np.asarray(objects.get(n, np.eye(4))) @ scene.manifest.object(n).T_base_obj
            c = scene.raster_model(n).bbox_center_m
            out["obj_mm"][n] = float(np.linalg.norm((T[:3, :3] @ c + T[:3, 3]) - (Tt[:3, :3] @ c + Tt[:3, 3])) * 1e3)
    return out


def _row(root: Path, name: str, r) -> dict:
    """A scene's estimate (a JointResult: its own fit or its share of the campaign) with errors and sigmas."""
    e = _errors(root, name, r.hand_eye_dT_cam, {n: o.dT_base for n, o in r.objects.items()})
    inf = math.inf
    return {"he_mm": e["he_mm"], "he_deg": e["he_deg"],
            "he_sd_mm": r.hand_eye_std_mm if r.hand_eye_std_mm is not None else inf,
            "he_sd_deg": r.hand_eye_std_deg if r.hand_eye_std_deg is not None else inf,
            "objects": {n: {"mm": mm, "sd_mm": r.objects[n].std_mm if n in r.objects else inf,
                            "held": n not in r.objects} for n, mm in e["obj_mm"].items()},
            "accepted": bool(r.accepted)}


def run_campaign(root: Path, **knobs) -> dict:
    from evpose.core.align.campaign_fit import CampaignScene, fit_campaign
    from evpose.core.align.campaign_terms import LocalEvaluator
    from evpose.core.align.joint_fit import refine_joint
    from evpose.core.align.joint_result import JointParams
    from evpose.core.data.scene import Scene

    params = JointParams(hand_eye=True, skew="fixed", n_windows=24, **knobs)
    out = {"own": {}, "campaign": {}, "start": {}}
    t_own = 0.0
    for name in SPEEDS:
        with Scene.open(root / name) as scene:
            t0 = time.perf_counter()
            r = refine_joint(scene, params=params)
            t_own += time.perf_counter() - t0
        out["own"][name] = _row(root, name, r)
        out["start"][name] = _errors(root, name, np.eye(4), {})
    scenes = {n: Scene.open(root / n) for n in SPEEDS}
    try:
        t0 = time.perf_counter()
        camp = fit_campaign(LocalEvaluator(scenes, params),
                            [CampaignScene(n, "group:day", "group:placement") for n in SPEEDS], params)
        t_camp = time.perf_counter() - t0
    finally:
        for s in scenes.values():
            s.close()
    for name in SPEEDS:
        out["campaign"][name] = _row(root, name, camp.per_scene[name])
    out.update(own_s=t_own, campaign_s=t_camp, accepted=bool(camp.accepted), steps=len(camp.trace))
    return out


def _ratios(row: dict) -> list:
    """(|err|/sigma) of a row's hand-eye translation, rotation and every fitted object's centre."""
    r = [row["he_mm"] / row["he_sd_mm"], row["he_deg"] / row["he_sd_deg"]]
    r += [o["mm"] / o["sd_mm"] for o in row["objects"].values() if not o["held"]]
    return r


def summarise(family: str, runs: dict) -> list:
    lines = [f"== {family}: {len(runs)} campaigns x 3 scenes (0.1 / 0.5 / 1.0 m/s) =="]
    for seed, run in runs.items():
        for name in SPEEDS:
            o, c, s = run["own"][name], run["campaign"][name], run["start"][name]
            objs = "  ".join(f"{n} {s['obj_mm'][n]:.1f}->{_mm(o['objects'][n])}/{_mm(c['objects'][n])}"
                             for n in o["objects"])
            lines.append(f"{seed:>4} {name:<4}  hand-eye {s['he_mm']:.2f} mm {s['he_deg']:.2f} deg -> own "
                         f"{o['he_mm']:.2f} mm ({_r(o['he_mm'], o['he_sd_mm'])}) {o['he_deg']:.3f} deg "
                         f"({_r(o['he_deg'], o['he_sd_deg'])}) | campaign {c['he_mm']:.2f} mm "
                         f"({_r(c['he_mm'], c['he_sd_mm'])}) {c['he_deg']:.3f} deg ({_r(c['he_deg'], c['he_sd_deg'])})"
                         f";  objects mm start->own/campaign: {objs}")
    for kind in ("own", "campaign"):
        ratios = [x for run in runs.values() for name in SPEEDS for x in _ratios(run[kind][name])]
        fin = [x for x in ratios if math.isfinite(x)]
        within = sum(1 for x in fin if x <= 2) / max(len(ratios), 1)
        lines.append(f"{kind:>8}: {len(ratios)} estimates, {100 * within:.0f} % within 2 sigma "
                     f"({len(ratios) - len(fin)} without a sigma), median |err|/sigma "
                     f"{np.median(fin) if fin else float('nan'):.2f}")
    slow_own = [run["own"]["slow"] for run in runs.values()]
    slow_c = [run["campaign"]["slow"] for run in runs.values()]
    for key, unit in (("he_mm", "mm"), ("he_deg", "deg")):
        lines.append(f"slow scene hand-eye {key}: median own {np.median([r[key] for r in slow_own]):.3f} {unit}, "
                     f"campaign {np.median([r[key] for r in slow_c]):.3f} {unit}; campaign nearer the truth in "
                     f"{sum(c[key] < o[key] for o, c in zip(slow_own, slow_c))} of {len(slow_c)}")
    obj_o = [o["objects"][n]["mm"] for o in slow_own for n in o["objects"]]
    obj_c = [c["objects"][n]["mm"] for c in slow_c for n in c["objects"]]
    lines.append(f"slow scene objects (centre mm, held ones at their start): median own {np.median(obj_o):.2f}, "
                 f"campaign {np.median(obj_c):.2f}; campaign nearer in {sum(c < o for o, c in zip(obj_o, obj_c))} "
                 f"of {len(obj_c)}")
    t_own = sum(r["own_s"] for r in runs.values())
    t_c = sum(r["campaign_s"] for r in runs.values())
    lines.append(f"run time: campaign {t_c:.1f} s vs the three own fits {t_own:.1f} s ({t_c / t_own:.2f}x), "
                 f"{np.mean([r['steps'] for r in runs.values()]):.0f} steps per campaign; accepted "
                 f"{sum(r['accepted'] for r in runs.values())} of {len(runs)}")
    return lines


def _mm(o: dict) -> str:
    return f"{o['mm']:.1f}" + ("(held)" if o["held"] else "")


def _r(err: float, sd: float) -> str:
    return f"{err / sd:.1f}s" if math.isfinite(sd) and sd > 0 else "no sigma"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--family", choices=("synth", "raycast", "both"), default="both")
    ap.add_argument("--seeds", type=int, default=None, help="first N seeds of each family")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--step-min-sigma", type=float, default=None,
                    help="JointParams.step_min_sigma_px (default: the product's)")
    args = ap.parse_args(argv)
    families = ("synth", "raycast") if args.family == "both" else (args.family,)
    doc, lines = {}, []
    for fam in families:
        runs = {}
        for seed in SEEDS[fam][: args.seeds]:
            root = ensure_campaign(fam, seed)
            runs[seed] = run_campaign(root, **({} if args.step_min_sigma is None else
                                               {"step_min_sigma_px": args.step_min_sigma}))
            print(f"  {fam} {seed}: campaign {runs[seed]['campaign_s']:.1f} s", file=sys.stderr, flush=True)
        doc[fam] = runs
        lines += summarise(fam, runs)
    print("\n".join(lines))
    if args.json:
        args.json.write_text(json.dumps(doc, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
