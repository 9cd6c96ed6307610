"""Why is an estimate outside its sigma: the solver's (a wrong optimum) or the objective's (a biased model)?

Per scene of a family (``--family``, as ``bench/accuracy_validation.py``), ``evpose sync --edges`` as a user runs it,
then per fitted object whose pose error is beyond 2 sigma (translation of its centre or rotation), the joint
objective (:func:`evpose.core.align.joint_second_look.objectives`: fresh contours and association, the fit's windows) at
the estimate and with that object alone moved to its true pose, at every kernel width:

* the truth scores **higher at the finest width**: the objective knows better, the fit did not get there -- a
  *wrong optimum* (the solver's; "the coarse widths lead away" when the truth scores lower there);
* the truth scores **lower at the finest width**: the objective itself prefers the estimate -- a *model* error
  (something the generator renders that the edge model lacks: shadows, texture, another object's edges), which
  only a model-error floor can cover.

Printed per object: error and sigma, |error| / sigma, the objective's relative change at the coarsest and finest
widths when the object is moved to its truth, and the verdict; then the count per verdict.

``--cost``: instead, the joint fit's run time with and without its second look at the objects
(:func:`evpose.core.align.joint_second_look.second_look`), measured in one run per scene, and the ratio.

Usage: ``python bench/optimum_check.py [--family calibration|validation|tuning] [--scenes NAME ...] [--all]
[--cost]`` (``--all``: also the objects within 2 sigma).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))

from accuracy_validation import _ratio, family_folders, pose_errors  # noqa: E402


def _states(scene, edges, gt):
    """The estimate's :class:`JointState` and, per object, the estimate with that object at its truth."""
    from evpose.core.align.joint_model import JointState

    names = scene.object_names
    clock = scene.clock
    T_end = [edges.objects[n].dT_base @ scene.manifest.object(n).T_base_obj if n in edges.objects
             else scene.T_base_obj(n) for n in names]
    H = np.linalg.inv(scene.corrections.hand_eye_delta) @ np.asarray(edges.hand_eye_dT_cam)
    end = JointState(float(edges.offset_us), float(edges.skew_ppm), int(clock.t_ref_us), H, T_end)
    moved = {}
    for i, n in enumerate(names):
        if n in edges.objects:
            s = end.copy()
            s.T_bo[i] = np.asarray(gt["objects"][n]["T_base_obj"], float).copy()
            moved[n] = s
    return end, moved


def evaluate(folder: Path, everything: bool = False) -> list[dict]:
    from evpose.core.align.joint_second_look import objectives
    from evpose.core.align.joint_result import JointParams
    from evpose.core.align.sync_run import SyncOptions, run_sync
    from evpose.core.data.scene import Scene
    from evpose.core.sim.synth import load_ground_truth

    gt = load_ground_truth(folder)
    rows = []
    with Scene.open(folder) as scene:
        opts = SyncOptions(edges=True)
        run = run_sync(scene, opts)
        edges = run.edges
        if edges is None or not edges.accepted:
            return [{"scene": folder.name, "object": "-", "verdict": "not accepted"}]
        end, moved = _states(scene, edges, gt)
        for n in moved:
            T_true = np.asarray(gt["objects"][n]["T_base_obj"])
            mm, deg = pose_errors(scene, n, end.T_bo[scene.object_names.index(n)], T_true)
            o = edges.objects[n]
            r_mm, r_deg = _ratio(mm, o.std_mm), _ratio(deg, o.std_deg)
            rows.append({"scene": folder.name, "object": n, "mm": mm, "deg": deg, "std_mm": o.std_mm,
                         "std_deg": o.std_deg, "r_mm": r_mm, "r_deg": r_deg})
        outside = [r for r in rows if max(r["r_mm"], r["r_deg"]) > 2]
        todo = rows if everything else outside
        if todo:
            params = JointParams(n_windows=opts.windows, hand_eye=edges.params.hand_eye)
            F = objectives(scene, [end] + [moved[r["object"]] for r in todo], params=params,
                           clock=run.result.clock())
            rel = F[1:] / F[0] - 1.0
            for r, d in zip(todo, rel):
                r["dF_coarse"], r["dF_fine"] = float(d[0]), float(d[-1])
                r["verdict"] = _verdict(r, d)
        for r in rows:
            r.setdefault("verdict", "within 2 sigma")
    return rows


def cost(folder: Path) -> tuple[float, float]:
    """The CPU time (s, this process) of ``evpose sync --edges`` on ``folder``'s scene (the rate stage, then the joint
    fit and its mounting check) without and with the second look."""
    from evpose.core.align import joint_second_look as look
    from evpose.core.align.sync_run import SyncOptions, run_sync
    from evpose.core.data.scene import Scene

    level = look.SECOND_LOOK_FROM_LEVEL
    out = []
    try:
        for lv in (10 ** 6, level):                      # past the last width: no second look
            look.SECOND_LOOK_FROM_LEVEL = lv
            with Scene.open(folder) as scene:
                t0 = time.process_time()
                run_sync(scene, SyncOptions(edges=True))
                out.append(time.process_time() - t0)
    finally:
        look.SECOND_LOOK_FROM_LEVEL = level
    return out[0], out[1]


def _verdict(row, rel) -> str:
    if max(row["r_mm"], row["r_deg"]) <= 2:
        return "within 2 sigma"
    if not np.isfinite(rel[-1]):
        return "no events at the finest width"
    if rel[-1] > 0:
        return "wrong optimum" + (" (the coarse widths lead away)" if rel[0] < 0 else "")
    return "model (the objective prefers the estimate)"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--family", choices=("validation", "calibration", "tuning"), default="calibration")
    ap.add_argument("--scenes", nargs="*")
    ap.add_argument("--all", action="store_true", help="the objective also for objects within 2 sigma")
    ap.add_argument("--cost", action="store_true", help="run time with and without the second look")
    args = ap.parse_args(argv)
    print(f"# bench/optimum_check.py --family {args.family}{' --cost' if args.cost else ''}, "
          f"{time.strftime('%Y-%m-%d %H:%M')}")
    if args.cost:
        ratios = []
        for name, folder in family_folders(args.family, args.scenes or None).items():
            a, b = cost(folder)
            ratios.append(b / a)
            print(f"{name:<34} sync --edges CPU: without the second look {a:6.1f} s, with {b:6.1f} s: {b / a:.2f}x",
                  flush=True)
        print(f"\n  median {np.median(ratios):.2f}x, max {max(ratios):.2f}x over {len(ratios)} scenes")
        return 0
    counts: dict[str, int] = {}
    for name, folder in family_folders(args.family, args.scenes or None).items():
        for r in evaluate(folder, args.all):
            counts[r["verdict"]] = counts.get(r["verdict"], 0) + 1
            if "mm" not in r:
                print(f"{name:<34} {r['verdict']}")
                continue
            obj = (f"{name:<34} {r['object']:<16} {r['mm']:6.2f} mm / {r['std_mm']:.2f} ({r['r_mm']:4.1f})  "
                   f"{r['deg']:6.2f} deg / {r['std_deg']:.2f} ({r['r_deg']:4.1f})")
            if "dF_fine" in r:
                obj += f"  truth: coarsest {r['dF_coarse'] * 100:+.2f} %, finest {r['dF_fine'] * 100:+.2f} %"
            print(f"{obj}  {r['verdict']}", flush=True)
    print("\n" + "\n".join(f"  {v}: {k}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
