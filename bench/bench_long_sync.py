"""Clock sync of long recordings with large skew (tracker issue 23.7b): time, memory and error of ``evpose sync``
(``sync_scene``, rate stage) on 1- and 3-hour recordings at ±1000 ppm, with the right prior skew and with 0.

Usage::

    python bench/bench_long_sync.py [--cases 1h+1000,1h+1000/0,3h-1000,3h-1000/0] [--pose-hz 250] [--json]

A case ``<hours>h<skew>[/<prior skew>]``: a rate-only scene (``write_long_rate_scene`` of
``tests/core/test_long_sync.py``: a camera translating through minimum-jerk moves of 0.3-1 s and stops, an event
stream whose rate follows its speed at each 1 ms bin's true pose time; offset -45 ms) whose prior is the true clock,
or has the skew given after the slash. Scenes are written once into ``bench/.data/long_sync/`` (a 3-hour one at
250 Hz takes a few minutes and ~1 GB).

Each case runs in a child process of its own: it opens the scene and loads trajectory and events (not measured:
their readers are not part of the sync), times ``sync_scene(scene, kind="speed")``, then runs it again under
``tracemalloc`` (which slows it ~3x) for its traced peak. Printed: the sync's wall and CPU time, its traced peak,
the child's RSS before the sync and its peak (loaded data included), the offset and skew errors against the truth
with the reported sigma, and the notes (what the sync did) or the reason (why it gave no estimate). ``--json``: one
JSON document on stdout (the table goes to stderr). BLAS threads on a busy machine can slow the sync many times
over; ``OPENBLAS_NUM_THREADS=1`` gives the single-threaded figures.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / ".data" / "long_sync"
DEFAULT_CASES = "1h+1000,1h+1000/0,3h-1000,3h-1000/0"
OFFSET_US = -45_000

CHILD = textwrap.dedent("""
    import json, resource, sys, time, tracemalloc
    from evpose.core.align.estimate import sync_scene
    from evpose.core.data.scene import Scene
    scene = Scene.open(sys.argv[1])
    scene.trajectory, scene.events.n_events
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t, c = time.perf_counter(), time.process_time()
    res = sync_scene(scene, kind="speed")
    dt, dc = time.perf_counter() - t, time.process_time() - c
    rss_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    tracemalloc.start()
    sync_scene(scene, kind="speed")
    print(json.dumps({"sync_s": dt, "sync_cpu_s": dc, "traced_peak_mb": tracemalloc.get_traced_memory()[1] / 1e6,
                      "rss_before_mb": rss_before, "rss_peak_mb": rss_peak,
                      "t_ref_us": scene.clock.t_ref_us, "result": res.to_json()}))
""")


def log(*a) -> None:
    print(*a, file=sys.stderr, flush=True)


def parse_case(case: str) -> tuple[float, float, float | None]:
    """``"3h-1000/0"`` -> ``(3.0, -1000.0, 0.0)``; no slash: prior skew None (the truth)."""
    hours, rest = case.split("h")
    skew, _, prior = rest.partition("/")
    return float(hours), float(skew), (float(prior) if prior else None)


def scene_for(hours: float, skew_ppm: float, prior_skew_ppm: float | None, pose_hz: float) -> tuple[Path, dict]:
    """The scene of a case (written when missing) and its true clock."""
    sys.path.insert(0, str(ROOT / "tests" / "core"))
    from test_long_sync import write_long_rate_scene

    prior = "truth" if prior_skew_ppm is None else f"{prior_skew_ppm:+g}"
    name = f"{hours:g}h_{skew_ppm:+g}ppm_prior{prior}_{pose_hz:g}hz"
    folder = DATA / name
    truth_file = folder / "truth.json"
    if not truth_file.exists():
        log(f"writing {folder} ...")
        clock = write_long_rate_scene(folder, hours * 3600.0, OFFSET_US, skew_ppm, seed=4, pose_hz=pose_hz,
                                      prior_skew_ppm=prior_skew_ppm)
        truth_file.write_text(json.dumps({"offset_us": clock.offset_us, "skew_ppm": clock.skew_ppm,
                                          "t_ref_us": clock.t_ref_us}))
    return folder, json.loads(truth_file.read_text())


def run_case(case: str, pose_hz: float) -> dict:
    hours, skew, prior = parse_case(case)
    folder, truth = scene_for(hours, skew, prior, pose_hz)
    out = subprocess.run([sys.executable, "-c", CHILD, str(folder)], capture_output=True, text=True,
                         check=True).stdout
    m = json.loads(out.splitlines()[-1])
    res = m.pop("result")
    row = {"case": case, "hours": hours, "true_skew_ppm": skew, "prior_skew_ppm": skew if prior is None else prior,
           **m, "reliable": res["reliable"], "reason": res["reason"], "notes": res["notes"]}
    if res["reliable"]:
        expected = truth["offset_us"] + truth["skew_ppm"] * 1e-6 * (m["t_ref_us"] - truth["t_ref_us"])
        row.update(offset_err_us=res["offset_us"] - expected, offset_std_us=res["offset_std_us"],
                   offset_std_data_us=res.get("offset_std_data_us", res["offset_std_us"]),
                   skew_err_ppm=None if res["skew_ppm"] is None else res["skew_ppm"] - skew)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default=DEFAULT_CASES)
    ap.add_argument("--pose-hz", type=float, default=250.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    log(f"long-recording sync ({os.cpu_count()} cores; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')})")
    rows = []
    for case in args.cases.split(","):
        r = run_case(case.strip(), args.pose_hz)
        rows.append(r)
        head = (f"{r['case']:>12}  prior {r['prior_skew_ppm']:+6.0f} ppm: sync {r['sync_s']:6.1f} s "
                f"({r['sync_cpu_s']:.1f} s CPU), traced peak "
                f"{r['traced_peak_mb']:5.0f} MB, RSS {r['rss_before_mb']:5.0f} -> {r['rss_peak_mb']:5.0f} MB")
        if r["reliable"]:
            skew = "no skew" if r["skew_err_ppm"] is None else f"skew error {r['skew_err_ppm']:+.3f} ppm"
            log(f"{head}; offset error {r['offset_err_us']:+.0f} us (sigma {r['offset_std_us']:.0f}, from the data "
                f"alone {r['offset_std_data_us']:.0f}), {skew}")
        else:
            log(f"{head}; no estimate: {r['reason']}")
        for n in r["notes"]:
            log(f"{'':14}{n}")
    if args.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
