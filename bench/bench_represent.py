"""Time per DAVIS346 event frame (core/label/event_frames, represent) for 10^4 .. 10^7 events in one 10 ms window.

Run: ``.venv/bin/python bench/bench_represent.py [--quick] [--json]``. Prints one table, milliseconds per frame
(best of several repeats; inputs prepared outside the timing):

* ``counts``       :func:`polarity_counts` (one ``np.bincount`` over ``p*H*W + y*W + x``), incl. range checks
* ``add.at(p,y,x)`` the common baseline ``np.add.at(img, (p, y, x), 1)`` on a (2, H, W) image; ``ratio`` =
  baseline / counts
* ``bc flat`` / ``add.at flat``  ``np.bincount`` vs ``np.add.at`` on the same precomputed flat keys (key
  building excluded; NumPy >= 1.25 gives ``add.at`` with a flat index a fast path of about bincount speed)
* ``3ch``, ``voxel5``, ``tsurf``  :func:`three_channel`, :func:`voxel_grid` (5 bins), :func:`time_surface` (split)
* ``undist``       :meth:`EventUndistorter.apply` + :func:`polarity_counts` (table built once, time shown above)
* ``rgb``          the whole ``to_rgb("polarity", ...)`` display path
Target: polarity counts of 10^6 events well below 10 ms. ``--json``: one JSON document of the same figures on
stdout, the table on stderr.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from evpose.core.data.camera import CameraModel  # noqa: E402
from evpose.core.data.events import EventArray  # noqa: E402
from evpose.core.label import represent as R  # noqa: E402
from evpose.core.label.event_frames.counts import polarity_counts  # noqa: E402
from evpose.core.label.event_frames.three_channel import three_channel  # noqa: E402
from evpose.core.label.event_frames.time_surface import time_surface  # noqa: E402
from evpose.core.label.event_frames.undistort import clear_undistorter_cache, undistorter_for  # noqa: E402
from evpose.core.label.event_frames.voxel_grid import voxel_grid  # noqa: E402

W, H = 346, 260
T0, T1 = 1_700_000_000_000_000, 1_700_000_000_010_000     # epoch µs, 10 ms window


def best_ms(f, repeats):
    f()
    best = float("inf")
    for _ in range(repeats):
        s = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - s)
    return best * 1e3


def events(n, seed=0):
    rng = np.random.default_rng(seed)
    return EventArray(rng.integers(0, W, n, dtype=np.uint16), rng.integers(0, H, n, dtype=np.uint16),
                      np.sort(rng.integers(T0, T1, n)), rng.integers(0, 2, n, dtype=np.uint8))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="up to 10^6 events")
    ap.add_argument("--json", action="store_true", help="print one JSON document of the figures (table on stderr)")
    args = ap.parse_args(argv)
    out = sys.stderr if args.json else sys.stdout
    sizes = [10**4, 10**5, 10**6] if args.quick else [10**4, 10**5, 10**6, 10**7]
    cam = CameraModel.davis346()
    clear_undistorter_cache()
    s = time.perf_counter()
    und = undistorter_for(cam)
    build_ms = (time.perf_counter() - s) * 1e3
    print(f"numpy {np.__version__}, {os.cpu_count()} cores; DAVIS346 {W}x{H}, 10 ms window, ms per frame (best of n)",
          file=out)
    print(f"undistortion table built once in {build_ms:.1f} ms ({und.n_valid} of {W * H} pixels map into the image)",
          file=out)
    cols = ["events", "counts", "add.at(p,y,x)", "ratio", "bc flat", "add.at flat", "3ch", "voxel5", "tsurf",
            "undist", "rgb"]
    widths = [7, 8, 14, 7, 8, 12, 8, 8, 8, 8, 8]
    print(" ".join(c.rjust(w) for c, w in zip(cols, widths)), file=out)
    results = {}
    for n in sizes:
        ev = events(n)
        reps = 3 if n >= 10**7 else 7
        yi, xi, pi = ev.y.astype(np.intp), ev.x.astype(np.intp), ev.p.astype(np.intp)
        keys = (pi * H + yi) * W + xi

        def add_at_tuple():
            c = np.zeros((2, H, W), np.int64)
            np.add.at(c, (pi, yi, xi), 1)
            return c

        def add_at_flat():
            c = np.zeros(2 * H * W, np.int64)
            np.add.at(c, keys, 1)
            return c

        pos, neg = polarity_counts(ev, W, H)
        ref = add_at_tuple()
        assert np.array_equal(pos, ref[1]) and np.array_equal(neg, ref[0])
        t = {
            "counts": best_ms(lambda: polarity_counts(ev, W, H), reps),
            "add.at(p,y,x)": best_ms(add_at_tuple, reps),
            "bc flat": best_ms(lambda: np.bincount(keys, minlength=2 * H * W), reps),
            "add.at flat": best_ms(add_at_flat, reps),
            "3ch": best_ms(lambda: three_channel(ev, W, H, T0, T1), reps),
            "voxel5": best_ms(lambda: voxel_grid(ev, W, H, T0, T1, bins=5), reps),
            "tsurf": best_ms(lambda: time_surface(ev, W, H, T1, polarity="split"), reps),
            "undist": best_ms(lambda: polarity_counts(und.apply(ev), W, H), reps),
            "rgb": best_ms(lambda: R.to_rgb("polarity", ev, W, H, T0, T1), reps),
        }
        t["ratio"] = t["add.at(p,y,x)"] / t["counts"]
        results[n] = t
        row = [f"{n:.0e}".replace("e+0", "e")]
        for c in cols[1:]:
            row.append(f"{t[c]:.2f}x" if c == "ratio" else f"{t[c]:.2f}")
        print(" ".join(v.rjust(w) for v, w in zip(row, widths)), file=out, flush=True)
    c6 = results[10**6]["counts"]
    print(f"target: polarity counts of 10^6 events {c6:.2f} ms {'<' if c6 < 10 else '>='} 10 ms "
          f"({'met' if c6 < 10 else 'MISSED'})", file=out)
    if args.json:
        print(json.dumps({"benchmark": "represent", "data": f"uniform random events in one 10 ms window, DAVIS346 "
                          f"{W}x{H}; ms per frame, best of several repeats", "numpy": np.__version__,
                          "cores": os.cpu_count(), "undistortion_table_build_ms": round(build_ms, 2),
                          "ms_per_frame": {str(n): {k: round(v, 3) for k, v in t.items()} for n, t in results.items()},
                          "counts_1e6_ms": round(c6, 3), "target_ms": 10.0, "target_met": bool(c6 < 10)}))
    return results


if __name__ == "__main__":
    main()
