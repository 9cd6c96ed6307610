"""How wrong is a pose interpolated across a gap? The measurement behind ``trajectory_holes.MAX_GAP_STEPS``.

Usage::

    python bench/trajectory_gaps.py [--json]

``--json``: one JSON document of the figures on stdout (the table on stderr).

Synthetic min-jerk moves (``evpose.core.sim.motion.make_motion``, trajectory B) at the E-POSE speeds, recorded at 250 Hz
like the synthetic scenes. For every gap position, the k-1 samples inside a gap of k sampling steps are dropped,
the pose is interpolated (linear / slerp, as ``evpose.core.data.trajectory.Trajectory``) at 1 ms steps in the gap and
compared with the true (4 kHz) motion. Prints the worst position (mm) and rotation (deg) error per speed and k.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from evpose.core.data.trajectory import Trajectory  # noqa: E402
from evpose.core.sim.motion import make_motion  # noqa: E402
from evpose.core.sim.synth_config import SynthConfig  # noqa: E402

GAPS = (1, 2, 3, 4, 5, 10, 25, 50)


def worst_error(rec: Trajectory, true: Trajectory, k: int) -> tuple[float, float]:
    t = rec.t_us
    worst_mm = worst_deg = 0.0
    for i in range(0, len(t) - k, max(1, k // 2)):
        a, b = int(t[i]), int(t[i + k])
        tt = np.arange(a, b, 1000)
        sub = Trajectory(np.array([a, b]), rec.positions_m[[i, i + k]], rec.quats_xyzw[[i, i + k]])
        Ti, _ = sub.interpolate(tt)
        Tt, _ = true.interpolate(tt)
        e = np.linalg.norm(Ti[:, :3, 3] - Tt[:, :3, 3], axis=1).max() * 1e3
        r = np.degrees((Rotation.from_matrix(Ti[:, :3, :3]).inv() * Rotation.from_matrix(Tt[:, :3, :3])).magnitude())
        worst_mm, worst_deg = max(worst_mm, e), max(worst_deg, float(r.max()))
    return worst_mm, worst_deg


def main(argv=None) -> None:
    as_json = "--json" in (sys.argv[1:] if argv is None else argv)
    out = sys.stderr if as_json else sys.stdout
    print("worst interpolation error across a gap of k sampling steps (250 Hz poses, min-jerk moves)", file=out)
    print(f"{'speed':>8} " + "".join(f"{f'k={k} ({4 * k} ms)':>22}" for k in GAPS), file=out)
    doc = {"benchmark": "trajectory_gaps", "data": "min-jerk moves of trajectory B, poses at 250 Hz, gap of k steps",
           "gaps_steps": list(GAPS), "worst_error": {}}
    for speed in (0.1, 0.5, 1.0):
        cfg = SynthConfig(objects=("box",), trajectory="B", speed_mps=speed, duration_s=6.0, seed=1)
        m = make_motion(cfg, np.random.default_rng(1), 0.5)
        cells = [worst_error(m.recorded, m.true, k) for k in GAPS]
        print(f"{speed:6.1f} m/s" + "".join(f"{f'{mm:.3f} mm {deg:.3f} deg':>22}" for mm, deg in cells), file=out)
        doc["worst_error"][f"{speed:g} m/s"] = [{"k": k, "mm": round(mm, 4), "deg": round(deg, 4)}
                                                for k, (mm, deg) in zip(GAPS, cells)]
    if as_json:
        import json

        print(json.dumps(doc))


if __name__ == "__main__":
    main()
