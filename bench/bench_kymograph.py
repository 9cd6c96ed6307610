"""How honest the kymograph's reading is (tracker issue 23, part 8): its lag ± σ against the known clock error on
synthetic scenes, and which windows it declares too weak to read.

Usage::

    python bench/bench_kymograph.py [--split tuning|validation|independent|all] [--times 16] [--generate-only]
                                    [--json] [--rows FILE]

Scenes (2-2.5 s each, cached in ``bench/.data/kymograph/``; a minute or a few to generate, once):

* ``evpose synth`` (full DAVIS346, objects box, cylinder and flatbox, 2 s): speeds 0.1 / 0.5 / 1.0 m/s,
  trajectories A and B, a clock offset injected per seed. The *tuning* seeds (1, 2, 3) are the ones the constants
  of :mod:`evpose.core.views.kymograph_lag` and :mod:`~evpose.core.views.kymograph_confidence` were chosen
  on; the *validation* seeds (11, 12, 13) check them. Caveat: the peak's refinement, ``MIN_PROMINENCE`` and the
  default line's cross-check (``AGREE_SIGMAS``) were chosen on the tuning split, but with the other splits'
  results in view, so they are not a strictly blind hold-out.
* *independent*: scenes of the ray-casting generator that shares no rendering, event or motion code with
  ``evpose synth`` (:mod:`evpose.core.sim_validation`: smooth shading, solid textures, level-crossing events with
  threshold spread, noise, robot poses at 100/250 Hz with jitter, clutter), with E-POSE's meshes when present:
  3 objects, 0.5 and 1.0 m/s, no pose or hand-eye error (a pose error moves the tracks in space, which the
  kymograph cannot tell from a lag).

Readings: ``--times`` current times evenly over each recording (keeping the half span and the largest lag from
its ends: pauses between camera moves included, as a user scrubbing would meet them), each read with the
kymograph's default line (picked anew, as the "Default line" button does) at three clocks: the scene's prior
(the clock error is minus the injected offset), the true clock, and 8 ms off it. The truth of a reading is the
clock error in effect (``lag`` = offset in effect - true offset, see :mod:`~evpose.core.views.kymograph_lag`).

Output: one row per reading (scene, speed, true offset, clock error, reading ± σ, |err|/σ, or the reason it is
too weak), then per split the distribution of |err|/σ over the readable ones (share within 2 and 4, the largest,
the RMS: 1 for a σ that is exactly right, below 1 for a cautious one) and the weak reasons. Readings in one
window at its three clocks share most of their evidence, so the windows are counted too. ``--json``: the
summary as one JSON document on stdout (the table goes to stderr); ``--rows FILE``: every reading as JSON lines
(with the peak, the edge's speed and the events near it also where too weak, to study the σ model).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from synth_scenes import DATA, ensure_synth  # noqa: E402  (bench/ is the script's folder)

ROOT = DATA / "kymograph"
#: The clocks read at each time, as the clock error (µs) against the true clock; None: the scene's prior.
CLOCK_ERRORS_US = (None, 0, 8_000)
HEAD_READING, HEAD_Z = "reading \u00b1 \u03c3 (ms)", "|e|/\u03c3"
#: Half the kymograph's span plus its largest lag (µs): the times keep this far from the recording's ends.
MARGIN_US = 190_000


@dataclass(frozen=True)
class BenchScene:
    speed_mps: float
    seed: int
    trajectory: str
    offset_us: int
    split: str
    generator: str = "synth"
    profile: str = "mixed"
    clutter: int = 0

    @property
    def name(self) -> str:
        if self.generator == "raycast":
            return f"rc_v{self.speed_mps:g}_{self.trajectory}_{self.profile}_c{self.clutter}_s{self.seed}"
        return f"v{self.speed_mps:g}_{self.trajectory}_s{self.seed}"


#: seed -> (trajectory, injected clock offset µs, split)
SEEDS = {1: ("B", 15_000, "tuning"), 2: ("A", -25_000, "tuning"), 3: ("A", 22_000, "tuning"),
         11: ("B", -12_000, "validation"), 12: ("A", 30_000, "validation"), 13: ("B", -18_000, "validation")}
SCENES = [BenchScene(v, seed, traj, off, split) for seed, (traj, off, split) in SEEDS.items()
          for v in (0.1, 0.5, 1.0)]
#: The independent generator's scenes: (speed m/s, trajectory, offset µs, profile, clutter, seed).
RAYCAST = [(0.5, "B", 26_505, "mixed", 0, 9101), (1.0, "A", -47_858, "sweep", 0, 9102),
           (0.5, "A", 16_096, "trapezoid", 3, 9103), (1.0, "B", -10_498, "mixed", 3, 9104)]
SCENES += [BenchScene(v, seed, traj, off, "independent", "raycast", prof, clut)
           for v, traj, off, prof, clut, seed in RAYCAST]
SPLITS = ("tuning", "validation", "independent")
RAYCAST_OBJECTS = ("sugar_box", "mustard_bottle", "drill")


def ensure(scene: BenchScene) -> Path:
    if scene.generator == "raycast":
        return ensure_raycast(scene)
    from evpose.core.sim.synth_config import SynthConfig

    cfg = SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory=scene.trajectory, speed_mps=scene.speed_mps,
                      duration_s=2.0, offset_us=scene.offset_us, seed=scene.seed)
    return ensure_synth(ROOT / scene.name, cfg, "about a minute")


def ensure_raycast(scene: BenchScene) -> Path:
    """The independent generator's scene (generated when it has no ``scene.toml`` yet; a few minutes)."""
    from evpose.core.sim_validation.assemble import generate
    from evpose.core.sim_validation.config import ValidationConfig

    folder = ROOT / scene.name
    if (folder / "scene.toml").is_file():
        return folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    print(f"generating {folder} (once; a few minutes)...", file=sys.stderr, flush=True)
    generate(folder, ValidationConfig(objects=RAYCAST_OBJECTS, trajectory=scene.trajectory, speed_mps=scene.speed_mps,
                                      duration_s=2.5, offset_us=scene.offset_us, profile=scene.profile,
                                      clutter=scene.clutter, seed=scene.seed), overwrite=True)
    return folder


def readings(scene: BenchScene, n_times: int) -> list[dict]:
    """The default line's reading at ``n_times`` times and the three clocks of :data:`CLOCK_ERRORS_US`."""
    from evpose.core.views.kymograph import KymographComputer, KymographRequest
    from evpose.core.session.model import Session

    s = Session.open(ensure(scene))
    kc = KymographComputer()
    rows = []
    try:
        t0, t1 = s.time_range
        for t in np.linspace(t0 + MARGIN_US, t1 - MARGIN_US, n_times).astype(np.int64):
            s.set_time(int(t))
            for error_us in CLOCK_ERRORS_US:
                correction = 0 if error_us is None else scene.offset_us + error_us
                s.set_offset_correction_us(correction)
                start = time.perf_counter()
                d = kc.kymograph(KymographRequest(s.request(), None))
                lag, truth = d.lag, (correction - scene.offset_us) / 1e3
                rows.append(dict(scene=scene.name, split=scene.split, speed_mps=scene.speed_mps,
                                 offset_ms=scene.offset_us / 1e3, t_ms=(int(t) - t0) / 1e3, truth_ms=truth,
                                 lag_ms=lag.lag_ms, sigma_ms=lag.sigma_ms, weak=lag.weak,
                                 z=None if lag.lag_ms is None else abs(lag.lag_ms - truth) / lag.sigma_ms,
                                 objects=[tr.name for tr in d.tracks], lines_tried=d.lines_tried,
                                 window=f"{scene.name}@{int(t)}", peak_ms=lag.peak_ms, speed=lag.speed,
                                 n_near=lag.n_near, n_moving=lag.n_moving,
                                 compute_ms=(time.perf_counter() - start) * 1e3))
    finally:
        s.close()
    return rows


def row_text(r: dict) -> str:
    read = (f"{r['lag_ms']:+7.2f} \u00b1 {r['sigma_ms']:4.2f}" if r["lag_ms"] is not None else f"{'':>14}")
    z = f"{r['z']:5.2f}" if r["z"] is not None else f"{'':>5}"
    return (f"{r['scene']:<10} {r['speed_mps']:>4.1f} {r['offset_ms']:+6.1f} {r['t_ms']:6.0f} {r['truth_ms']:+6.1f} "
            f"{read}  {z}  {r['weak'] or ''}")


def summary(rows: list[dict]) -> dict:
    z = np.array([r["z"] for r in rows if r["z"] is not None])
    sigma = [r["sigma_ms"] for r in rows if r["z"] is not None]
    by_speed = {f"{v:g}": sum(1 for r in rows if r["speed_mps"] == v and r["z"] is not None)
                for v in sorted({r["speed_mps"] for r in rows})}
    windows = {r["window"] for r in rows if r["z"] is not None}
    return {"readings": len(rows), "readable": int(len(z)), "windows": len({r["window"] for r in rows}),
            "readable_windows": len(windows), "scenes": len({r["scene"] for r in rows}),
            "within_2_sigma": float(np.mean(z <= 2)) if len(z) else None,
            "within_4_sigma": float(np.mean(z <= 4)) if len(z) else None,
            "max_err_over_sigma": float(z.max()) if len(z) else None,
            "rms_err_over_sigma": float(np.sqrt(np.mean(z ** 2))) if len(z) else None,
            "median_sigma_ms": float(np.median(sigma)) if len(z) else None,
            "readable_by_speed_mps": by_speed,
            "weak": dict(Counter(r["weak"] for r in rows if r["weak"])),
            "median_compute_ms": float(np.median([r["compute_ms"] for r in rows]))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--split", choices=(*SPLITS, "all"), default="all")
    ap.add_argument("--times", type=int, default=16, help="current times per scene")
    ap.add_argument("--generate-only", action="store_true")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--rows", type=Path, help="write every reading here as JSON lines")
    args = ap.parse_args(argv)
    scenes = [s for s in SCENES if args.split in ("all", s.split)]
    for s in scenes:
        ensure(s)
    if args.generate_only:
        return 0
    out = sys.stderr if args.json else sys.stdout
    print(f"{'scene':<10} {'m/s':>4} {'offset':>6} {'t ms':>6} {'error':>6} {HEAD_READING:>16}  {HEAD_Z:>5}  "
          "too weak to read", file=out)
    rows = []
    for s in scenes:
        for r in readings(s, args.times):
            rows.append(r)
            print(row_text(r), file=out, flush=True)
    result = {split: summary([r for r in rows if r["split"] == split])
              for split in SPLITS if any(r["split"] == split for r in rows)}
    if args.rows:
        args.rows.write_text("".join(json.dumps(r) + "\n" for r in rows))
    for split, sm in result.items():
        print(f"\n{split}: {sm['scenes']} scenes, {sm['readings']} readings in {sm['windows']} windows, "
              f"{sm['readable']} readable in {sm['readable_windows']} windows "
              f"(by speed {sm['readable_by_speed_mps']}); |err|/\u03c3 <= 2: {sm['within_2_sigma']}, <= 4: "
              f"{sm['within_4_sigma']}, max {sm['max_err_over_sigma']}, RMS {sm['rms_err_over_sigma']}; "
              f"median \u03c3 {sm['median_sigma_ms']} ms; too weak: {sm['weak']}; "
              f"median {sm['median_compute_ms']:.0f} ms per kymograph", file=out)
    if args.json:
        print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
