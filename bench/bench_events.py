"""Benchmark of evpose.core.data.event_store.EventStore against the naive "load everything, then np.searchsorted" baseline.

Usage::

    python bench/bench_events.py [--events 50_000_000] [--small 5_000_000] [--windows 1000] [--json]

Generates once (cached in bench/.data/) DSEC-like files (uint32 t + t_offset, Blosc-LZ4, ms_to_idx) at about
1 M events/s with bursty rate, 640x480 moving-edge x/y and polarity, plus copies without ms_to_idx. Prints one
table: (a) open time -- the first open of a file validates every event in one chunked pass (sorted t, pixels on
the sensor, polarity 0/1) and caches the result with the index, later opens read the cache --, (b) 10 ms window
fetch (mean / p95) and the ratio to the baseline, (c) peak RSS of each method in its own process (ru_maxrss) for
both file sizes. Times are wall clock with a warm OS page cache. The index cache of the children lives in
bench/.data/cache (XDG_CACHE_HOME), never beside the files.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

# The driver imports only the standard library and runs every measurement in a child process: Linux carries a
# parent's peak RSS over fork+exec into the child's ru_maxrss, so the parent must stay small (~10 MB) for the
# children's ru_maxrss to be their own.
ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / ".data"
T_OFFSET = 1_700_000_000_000_000      # epoch-like µs, as in DSEC
WIDTH, HEIGHT, WIN_US = 640, 480, 10_000


def _heavy():
    """Import the numerical stack (children only)."""
    global np, h5py, EventArray, EventStore, write_events_h5, DEFAULT_CHUNK_EVENTS
    sys.path.insert(0, str(ROOT))
    os.environ["XDG_CACHE_HOME"] = str(DATA / "cache")
    import h5py
    import hdf5plugin  # noqa: F401
    import numpy as np

    from evpose.core.data.event_store import EventStore
    from evpose.core.data.event_writer import DEFAULT_CHUNK_EVENTS, write_events_h5
    from evpose.core.data.events import EventArray


# ------------------------------------------------------------------------------------------------ data
def synth_chunks(n_events, rate=1_000_000, seed=0, chunk=1_000_000):
    """Yield EventArray chunks: bursty Poisson rate (log-normal AR(1) per ms), three moving edges + 20 % noise."""
    rng = np.random.default_rng(seed)
    per_ms = rate / 1000
    n_ms = int(n_events / per_ms * 1.3) + 100
    a, e, z = 0.995, rng.normal(0, np.sqrt(1 - 0.995**2), n_ms), np.empty(n_ms)
    acc = 0.0
    for i in range(n_ms):                     # AR(1): slow bursts of activity
        acc = a * acc + e[i]
        z[i] = acc
    lam = np.exp(z)
    counts = rng.poisson(lam * per_ms / lam.mean())
    cum = np.cumsum(counts)
    last = int(np.searchsorted(cum, n_events))
    counts = counts[:last + 1]
    counts[-1] -= int(cum[last]) - n_events
    v, x0 = np.array([40.0, -25.0, 60.0]), np.array([100.0, 400.0, 250.0])     # px/s, px
    step = max(1, int(chunk / per_ms))
    for m0 in range(0, len(counts), step):
        c = counts[m0:m0 + step]
        n = int(c.sum())
        if n == 0:
            continue
        t = np.repeat(T_OFFSET + 1000 * np.arange(m0, m0 + len(c), dtype=np.int64), c) + rng.integers(0, 1000, n)
        t.sort()
        edge = rng.integers(0, 3, n)
        x = np.mod(x0[edge] + v[edge] * ((t - T_OFFSET) * 1e-6), WIDTH) + rng.normal(0, 2.0, n)
        noise = rng.random(n) < 0.2
        x[noise] = rng.uniform(0, WIDTH, noise.sum())
        y = rng.uniform(0, HEIGHT, n)
        p = (v[edge] > 0) ^ (rng.random(n) < 0.2)
        yield EventArray(np.clip(x, 0, WIDTH - 1).astype(np.uint16), y.astype(np.uint16), t, p.astype(np.uint8))


def ensure_files(n_events):
    """Paths of the cached file with ms_to_idx and its copy without; generated on first use."""
    DATA.mkdir(parents=True, exist_ok=True)
    with_idx = DATA / f"events_{n_events}_v1.h5"
    no_idx = DATA / f"events_{n_events}_v1_noindex.h5"
    if not with_idx.exists():
        t = time.perf_counter()
        print(f"generating {with_idx} ...", file=sys.stderr, flush=True)
        write_events_h5(with_idx, synth_chunks(n_events), time_dtype="uint32", t_offset_us=T_OFFSET,
                        expected_events=n_events)
        print(f"  {time.perf_counter() - t:.1f} s", file=sys.stderr, flush=True)
    if not no_idx.exists():
        tmp = no_idx.with_name(no_idx.name + ".tmp")
        with h5py.File(with_idx, "r") as src, h5py.File(tmp, "w") as dst:
            src.copy("events", dst)                      # raw chunk copy, same compression
            dst["t_offset"] = src["t_offset"][()]
        os.replace(tmp, no_idx)
    return with_idx, no_idx


def window_starts(t_first, t_last, n, seed=1):
    return np.random.default_rng(seed).integers(t_first, t_last - WIN_US, n)


# ------------------------------------------------------------------------------------------------ methods
def naive_load(path):
    """The baseline: read the full arrays with h5py, absolute int64 times."""
    with h5py.File(path, "r") as f:
        x, y, p = f["events/x"][()], f["events/y"][()], f["events/p"][()]
        t = f["events/t"][()].astype(np.int64) + int(f["t_offset"][()])
    return x, y, t, p


def naive_window(arrays, t0, t1):
    x, y, t, p = arrays
    i0, i1 = np.searchsorted(t, [t0, t1], side="left")
    return EventArray(x[i0:i1], y[i0:i1], t[i0:i1], p[i0:i1])


def timed(fn, *args):
    t = time.perf_counter_ns()
    out = fn(*args)
    return (time.perf_counter_ns() - t) * 1e-9, out


def stats(a):
    return {"mean": float(np.mean(a)), "p95": float(np.percentile(a, 95))}


def stage_time(n_events, n_windows):
    """(a) open times and (b) window times for one file size; returns a JSON-able dict (seconds)."""
    from evpose.core.data.event_index import index_cache_file

    with_idx, no_idx = ensure_files(n_events)
    r = {"n": n_events, "size_mb": with_idx.stat().st_size / 1e6, "chunk": DEFAULT_CHUNK_EVENTS}

    def open_close(path, first=False):
        if first:                                 # forget the cached index and validation result
            index_cache_file(path).unlink(missing_ok=True)
        dt, s = timed(lambda: EventStore(path, sensor_size=(WIDTH, HEIGHT)))
        s.close()
        return dt
    r["open_index"] = float(np.median([open_close(with_idx, first=True) for _ in range(3)]))
    r["open_build"] = float(np.median([open_close(no_idx, first=True) for _ in range(3)]))
    r["open_cached"] = float(np.median([open_close(no_idx) for _ in range(5)]))
    r["open_index_cached"] = float(np.median([open_close(with_idx) for _ in range(5)]))
    from evpose.core.data.event_index import scan_index
    from evpose.core.data.event_validation import scan_values
    with h5py.File(with_idx, "r") as f:          # the two halves of the first-open pass, alone
        ds = {k: f[f"events/{k}"] for k in "xyp"}
        r["scan_t"] = timed(scan_index, with_idx, f["events/t"], 0)[0]
        r["scan_xyp"] = timed(scan_values, with_idx, ds)[0]

    with EventStore(with_idx) as s:             # a fresh store: cold HDF5 chunk cache
        r["duration_s"] = (s.t_last_us - s.t_first_us) * 1e-6
        starts = window_starts(s.t_first_us, s.t_last_us, n_windows)
        store, counts = [], []
        for t0 in starts:
            dt, ev = timed(s.window, int(t0), int(t0) + WIN_US)
            store.append(dt)
            counts.append(len(ev))
        t0 = s.t_first_us                         # scrubbing: consecutive windows from the start
        seq = [timed(s.window, t0 + k * WIN_US, t0 + (k + 1) * WIN_US)[0]
               for k in range(min(n_windows, int(r["duration_s"] * 1e6) // WIN_US))]
    r["naive_load"], arrays = timed(naive_load, with_idx)
    naive = []
    for t0, n_expect in zip(starts, counts):
        dt, ev = timed(naive_window, arrays, int(t0), int(t0) + WIN_US)
        assert len(ev) == n_expect, "EventStore and the baseline disagree"
        naive.append(dt)
    r.update(store_win=stats(store), store_seq=stats(seq), naive_win=stats(naive), mean_events=float(np.mean(counts)),
             store_first=store[0], naive_first=naive[0])
    return r


def stage_rss(method, path, n_windows):
    """(c) Run one method in this fresh process; its ru_maxrss is the method's peak (plus the ~10 MB driver)."""
    if method == "store":
        with EventStore(path) as s:
            for t0 in window_starts(s.t_first_us, s.t_last_us, n_windows):
                s.window(int(t0), int(t0) + WIN_US)
    elif method == "naive":
        arrays = naive_load(path)
        for t0 in window_starts(int(arrays[2][0]), int(arrays[2][-1]), n_windows):
            naive_window(arrays, int(t0), int(t0) + WIN_US)
    return {"maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def run_child(*args):
    proc = subprocess.run([sys.executable, __file__, "--stage", *map(str, args)], stdout=subprocess.PIPE, text=True)
    if proc.returncode:
        sys.exit(f"bench stage {args} failed")
    return json.loads(proc.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------------------------------ report
def report(cols, n_windows, out=sys.stdout):
    """Print the table on ``out``; returns the targets as (name, passed, value text)."""
    small, big = cols
    for r in cols:
        sw, nw = r["store_win"]["mean"], r["naive_win"]["mean"]
        r["ratio_open"] = r["open_index"] / r["naive_load"]
        r["ratio_win"] = sw / nw
        r["ratio_first"] = (r["open_index"] + r["store_first"]) / (r["naive_load"] + r["naive_first"])
        r["break_even"] = (r["naive_load"] - r["open_index"]) / max(sw - nw, 1e-12)
    ms = lambda s: f"{s * 1e3:10.3f} ms"  # noqa: E731
    two = lambda d: f"{ms(d['mean'])}{ms(d['p95'])}"  # noqa: E731

    def row(label, fmt):
        return f"{label:46}" + "".join(f"{fmt(r):>30}" for r in cols)
    lines = [
        f"evpose.core.data.event_store benchmark ({os.cpu_count()} cores; HDF5 chunk {big['chunk']} events, Blosc-LZ4, "
        "uint32 t + t_offset; warm OS page cache)",
        row("", lambda r: f"{r['n'] / 1e6:.0f} M events"),
        row("file size, duration, mean rate", lambda r: f"{r['size_mb']:.0f} MB {r['duration_s']:.1f} s "
            f"{r['n'] / r['duration_s'] / 1e6:.2f} M/s"),
        "(a) open, median",
        row("  EventStore first open, ms_to_idx in the file", lambda r: ms(r["open_index"])),
        row("  EventStore first open, no index: build it", lambda r: ms(r["open_build"])),
        row("    of which: t pass (order, wraps, index)", lambda r: ms(r["scan_t"])),
        row("    of which: x/y/p pass (pixels, polarity)", lambda r: ms(r["scan_xyp"])),
        row("  EventStore later opens (cached), file index", lambda r: ms(r["open_index_cached"])),
        row("  EventStore later opens (cached), no index", lambda r: ms(r["open_cached"])),
        row("  baseline: load full arrays with h5py", lambda r: ms(r["naive_load"])),
        row("  ratio EventStore / baseline", lambda r: f"{r['ratio_open']:.5f} x"),
        row(f"(b) 10 ms window, {n_windows} random windows", lambda r: f"{'mean':>13}{'p95':>13}"),
        row("  EventStore (fresh store)", lambda r: two(r["store_win"])),
        row("  EventStore (consecutive windows)", lambda r: two(r["store_seq"])),
        row("  baseline: searchsorted on loaded arrays", lambda r: two(r["naive_win"])),
        row("  ratio EventStore / baseline, per window", lambda r: f"{r['ratio_win']:.1f} x"),
        row("  ratio, open + first window", lambda r: f"{r['ratio_first']:.5f} x"),
        row("  baseline pays off after (windows)", lambda r: f"{r['break_even']:.0f}"),
        row("  mean events per window", lambda r: f"{r['mean_events']:.0f}"),
        f"(c) peak RSS (ru_maxrss), open + {n_windows} windows, one process each",
        row("  interpreter + imports only", lambda r: f"{r['rss_imports']:.0f} MB"),
        row("  EventStore", lambda r: f"{r['rss_store']:.0f} MB"),
        row("  baseline", lambda r: f"{r['rss_naive']:.0f} MB"),
        row("  ratio EventStore / baseline", lambda r: f"{r['rss_store'] / r['rss_naive']:.3f} x"),
    ]
    grow_store, grow_naive = big["rss_store"] - small["rss_store"], big["rss_naive"] - small["rss_naive"]
    win = big["store_win"]["mean"]
    first = max(big["open_index"], big["open_build"])
    targets = [("window fetch mean < 1 ms", win < 1e-3, f"{win * 1e3:.3f} ms"),
               ("first open (validating pass) < loading the arrays (baseline)", first < big["naive_load"],
                f"{first:.2f} s vs {big['naive_load']:.2f} s"),
               ("later opens < 50 ms (cached index and validation)", big["open_cached"] < 0.05,
                f"{big['open_cached'] * 1e3:.1f} ms"),
               (f"peak RSS independent of file size ({small['n'] / 1e6:.0f} M -> {big['n'] / 1e6:.0f} M events)",
                abs(grow_store) < 0.1 * big["rss_store"],
                f"EventStore {grow_store:+.0f} MB, baseline {grow_naive:+.0f} MB")]
    lines.append("targets")
    lines += [f"  {name:64}{'PASS' if ok else 'FAIL'}  {value}" for name, ok, value in targets]
    print("\n".join(lines), file=out)
    return targets


def headline(cols, n_windows, targets) -> dict:
    """The figures of :func:`report` as one JSON-able document (times in ms, sizes in MB)."""
    def one(r):
        return {"events": r["n"], "file_mb": round(r["size_mb"], 1), "duration_s": round(r["duration_s"], 2),
                "open_ms": {"first_with_index": r["open_index"] * 1e3, "first_build_index": r["open_build"] * 1e3,
                            "cached": r["open_cached"] * 1e3, "baseline_load_all": r["naive_load"] * 1e3},
                "window_ms": {"mean": r["store_win"]["mean"] * 1e3, "p95": r["store_win"]["p95"] * 1e3,
                              "consecutive_mean": r["store_seq"]["mean"] * 1e3,
                              "baseline_mean": r["naive_win"]["mean"] * 1e3},
                "ratio_window_vs_baseline": r["ratio_win"], "baseline_pays_off_after_windows": r["break_even"],
                "mean_events_per_window": r["mean_events"],
                "peak_rss_mb": {"imports": r["rss_imports"], "event_store": r["rss_store"], "baseline": r["rss_naive"]}}
    return {"benchmark": "events", "data": f"synthetic DSEC-style HDF5 files (uint32 t + t_offset, Blosc-LZ4, "
            f"{WIDTH}x{HEIGHT}, ~1 M events/s bursty), {n_windows} random {WIN_US // 1000} ms windows",
            "cores": os.cpu_count(), "sizes": [one(r) for r in cols],
            "targets": {name: {"pass": bool(ok), "value": value} for name, ok, value in targets}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--events", type=lambda s: int(s.replace("_", "")), default=50_000_000)
    ap.add_argument("--small", type=lambda s: int(s.replace("_", "")), default=5_000_000)
    ap.add_argument("--windows", type=int, default=1000)
    ap.add_argument("--json", action="store_true", help="print one JSON document of the headline figures "
                    "(the table goes to stderr)")
    ap.add_argument("--stage", nargs="+", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.stage:                                   # child process
        _heavy()
        kind, *rest = a.stage
        if kind == "prepare":
            out = {k: str(v) for k, v in zip(("with_idx", "no_idx"), ensure_files(int(rest[0])))}
        elif kind == "time":
            out = stage_time(int(rest[0]), int(rest[1]))
        else:
            out = stage_rss(kind, rest[0], int(rest[1]))
        print(json.dumps(out))
        return
    cols = []
    for n in (a.small, a.events):
        path = run_child("prepare", n)["with_idx"]
        r = run_child("time", n, a.windows)
        for method in ("imports", "store", "naive"):
            r[f"rss_{method}"] = run_child(method, path, a.windows)["maxrss_mb"]
        cols.append(r)
    targets = report(cols, a.windows, out=sys.stderr if a.json else sys.stdout)
    if a.json:
        print(json.dumps(headline(cols, a.windows, targets)))


if __name__ == "__main__":
    main()
