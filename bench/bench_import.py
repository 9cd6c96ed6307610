"""Benchmark of the importers: throughput (events/s) and peak memory for an E-POSE-style ROS1 bag, a DSEC file, and
the recording formats of issue 17 (AEDAT4, ROS2 bags in sqlite3 and MCAP storage, Prophesee EVT 2.0 / 3.0 / DAT).

Usage::

    python bench/bench_import.py [--events 50_000_000] [--small 5_000_000] [--baseline-messages 100] [--json]
                                 [--formats bag,dsec,aedat4,ros2-sqlite3,ros2-mcap,evt2,evt3,dat]

Generates once (cached in bench/.data/) synthetic inputs with random events at 2 M ev/s:

* ``bag_<N>.bag``: ``/dvs/events`` (dvs_msgs/EventArray, 346x260, 10k-30k events per message, uncompressed
  chunks) + ``/dvs/pose`` at 100 Hz, written with rosbags' ``rosbag1.Writer``;
* ``dsec_<N>.h5``: DSEC layout (uint32 t + t_offset, ms_to_idx, x/y uint16, p uint8, Blosc-zstd like DSEC's own
  files, 640x480) + a TUM trajectory and a cam_to_cam.yaml;
* ``aedat4_<N>.aedat4``: written by dv-processing (346x260, LZ4 packets of 10k events, a pose stream at 100 Hz);
* ``ros2_sqlite3_<N>/``, ``ros2_mcap_<N>/``: ROS2 bags by rosbags' ``rosbag2.Writer``, the same messages as the
  ROS1 bag in CDR;
* ``evt2_<N>.raw``, ``evt3_<N>.raw``, ``dat_<N>.dat``: written by faery (1280x720, times from 1 s of the sensor clock,
  so 50 M events cross EVT 3.0's 24-bit wrap) + a trajectory CSV and a calibration JSON.

Every measurement runs in its own child process (the parent imports only the standard library, so the children's
``ru_maxrss`` is their own). Rows:

* ``evpose import epose-bag`` vs the baseline **rosbags per-message deserialisation** (``typestore.deserialize_ros1``
  into Python objects, then numpy arrays -- what one writes without a custom parser; timed on the first
  ``--baseline-messages`` messages and extrapolated, no file written);
* ``evpose import dsec`` (copy mode: validate + rewrite with EventWriter) and the validate-only ``link`` mode vs
  the baseline **naive full-array h5py copy** (``ds[:]`` of the four arrays, written to a new file with the same
  Blosc-LZ4 filter, no validation, no ms index);
* ``evpose import aedat4`` vs the **dv-processing decode alone** (``getNextEventBatch`` + ``numpy()``, nothing
  validated or written: the reader's ceiling);
* ``evpose import epose-bag`` on the ROS2 bags vs **rosbags' per-message ``deserialize_cdr``** (as for ROS1);
* ``evpose import prophesee`` vs **faery's decode alone**.

Peak memory is shown for the large and the small file to show that the importers' memory does not depend on the
file size (the naive copy's does). Every measurement runs twice: with glibc's default malloc (speed and ``peak``)
and with ``MALLOC_MMAP_THRESHOLD_=131072`` (``live``: glibc's static default threshold, which switches off the
*dynamic* mmap threshold, so that ru_maxrss measures live memory rather than heap fragmentation -- with the dynamic
threshold the importers' RSS creeps up by ~40 MB over 50 M events while their tracemalloc-traced memory stays flat;
the fixed threshold costs speed, since every large array is then a fresh mmap). Times are wall clock with a warm page cache, 2 cores, from the call to the
renamed scene folder (fsync included), without interpreter start-up and module imports.

``--json`` prints one JSON document of the rows (events/s, peak and live MB, ratios) on stdout; the table goes to
stderr.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from synth_scenes import DATA, run_dir  # bench/ is the script's folder

ROOT = Path(__file__).resolve().parents[1]
RATE = 2_000_000          # events per second of recording
T0_US = 1_600_000_000_000_000


@contextlib.contextmanager
def staged(path: Path):
    """Yield a path to write ``path``'s content to, in a folder this run creates beside it
    (:func:`synth_scenes.run_dir`: a name no one else has, on the same file system); on success it is renamed to
    ``path``, which must not exist. The folder is removed either way: the only files deleted are those this run
    made in it."""
    with run_dir(f".{path.name}", path.parent) as stage:
        tmp = stage / path.name           # the same name: writers that insist on a suffix get it
        yield tmp
        if os.path.lexists(path):
            raise FileExistsError(f"{path}: exists; not replaced")
        os.rename(tmp, path)


def _heavy():
    global np
    sys.path.insert(0, str(ROOT))
    import numpy as np  # noqa: F811


def _event_chunks(n_events, width, height, seed, chunk=1_000_000):
    """Random sorted events at RATE ev/s, yielded as (x, y, t_us, p) chunks."""
    rng = np.random.default_rng(seed)
    t_last = T0_US
    for i0 in range(0, n_events, chunk):
        k = min(chunk, n_events - i0)
        dt = rng.exponential(1e6 / RATE, k)
        t = t_last + np.floor(np.cumsum(dt)).astype(np.int64)
        t_last = int(t[-1])
        yield (rng.integers(0, width, k).astype(np.uint16), rng.integers(0, height, k).astype(np.uint16), t,
               rng.integers(0, 2, k).astype(np.uint8))


def gen_bag(path: Path, n_events: int) -> None:
    from rosbags.rosbag1 import Writer

    from evpose.core.importers.epose_bag_codec import (
        EVENT_ARRAY_TYPE,
        POSE_STAMPED_TYPE,
        dvs_typestore,
        encode_event_array,
        encode_pose_stamped,
    )

    ts = dvs_typestore()
    rng = np.random.default_rng(1)
    with staged(path) as tmp, Writer(tmp) as w:
        ce = w.add_connection("/dvs/events", EVENT_ARRAY_TYPE, typestore=ts)
        cp = w.add_connection("/dvs/pose", POSE_STAMPED_TYPE, typestore=ts)
        carry = None
        seq = 0
        next_pose = T0_US
        for x, y, t, p in _event_chunks(n_events, 346, 260, seed=0):
            if carry is not None:
                x, y, t, p = (np.concatenate([a, b]) for a, b in zip(carry, (x, y, t, p)))
            i = 0
            while len(t) - i >= 30_000:
                m = int(rng.integers(10_000, 30_001))
                sl = slice(i, i + m)
                tn = t[sl] * 1000
                while next_pose <= int(t[sl][-1]):                  # 100 Hz poses, interleaved in time
                    w.write(cp, next_pose * 1000, encode_pose_stamped(next_pose * 1000, [0.1, -0.5, 0.4], [0, 0, 0, 1]))
                    next_pose += 10_000
                w.write(ce, int(tn[-1]), encode_event_array(x[sl], y[sl], tn, p[sl], seq=seq, stamp_ns=int(tn[-1])))
                seq += 1
                i += m
            carry = (x[i:], y[i:], t[i:], p[i:])
        if carry is not None and len(carry[2]):
            tn = carry[2] * 1000
            w.write(ce, int(tn[-1]), encode_event_array(*carry[:2], tn, carry[3], seq=seq, stamp_ns=int(tn[-1])))
        w.write(cp, next_pose * 1000, encode_pose_stamped(next_pose * 1000, [0.1, -0.5, 0.4], [0, 0, 0, 1]))


def gen_dsec(folder: Path, n_events: int) -> None:
    import h5py
    import hdf5plugin

    from evpose.core.data.atomic import atomic_write_text

    folder.mkdir(parents=True, exist_ok=True)
    comp = dict(hdf5plugin.Blosc(cname="zstd", clevel=1, shuffle=hdf5plugin.Blosc.SHUFFLE))
    with staged(folder / "events.h5") as tmp, h5py.File(tmp, "w-") as f:
        ds = {k: f.create_dataset(f"events/{k}", shape=(0,), maxshape=(None,), dtype=dt, chunks=(1 << 16,), **comp)
              for k, dt in (("x", np.uint16), ("y", np.uint16), ("t", np.uint32), ("p", np.uint8))}
        n0, idx, next_ms = 0, [], 0
        for x, y, t, p in _event_chunks(n_events, 640, 480, seed=2):
            rel = t - T0_US
            k_max = int(rel[-1]) // 1000
            if k_max >= next_ms:
                idx.append(n0 + np.searchsorted(rel, 1000 * np.arange(next_ms, k_max + 1)))
                next_ms = k_max + 1
            for k, a in zip("xytp", (x, y, rel.astype(np.uint32), p)):
                ds[k].resize((n0 + len(a),))
                ds[k][n0:] = a
            n0 += len(t)
        f.create_dataset("ms_to_idx", data=np.concatenate(idx).astype(np.uint64))
        f.create_dataset("t_offset", data=np.int64(T0_US))
    dur_us = int(n_events / RATE * 1e6) + 100_000
    lines = [f"{(T0_US + k) // 10**6}.{(T0_US + k) % 10**6:06d} 0.1 -0.5 0.4 0 0 0 1" for k in range(0, dur_us, 10_000)]
    atomic_write_text(folder / "poses.txt", "\n".join(lines) + "\n")
    atomic_write_text(folder / "cam_to_cam.yaml",
        "intrinsics:\n  cam0:\n    camera_matrix: [553.47, 553.40, 346.65, 216.52]\n"
        "    distortion_coeffs: [-0.0949, 0.1497, -0.00084, 0.00030]\n    distortion_model: radtan\n"
        "    resolution: [640, 480]\n")


AEDAT4_T0_US = T0_US
SENSOR_T0_US = 1_000_000              # Prophesee: µs of the sensor clock since the camera started


def gen_aedat4(path: Path, n_events: int) -> None:
    import dv_processing as dv

    cfg = dv.io.MonoCameraWriter.EventOnlyConfig("DAVIS346", (346, 260))
    cfg.addPoseStream("poses")
    with staged(path) as tmp:                              # tmp keeps the .aedat4 suffix dv-processing wants
        w = dv.io.MonoCameraWriter(str(tmp), cfg)
        next_pose = AEDAT4_T0_US
        for x, y, t, p in _event_chunks(n_events, 346, 260, seed=3):
            store = dv.EventStore()
            for a, b, c, d in zip(t.tolist(), x.tolist(), y.tolist(), (p > 0).tolist()):
                store.push_back(a, b, c, d)
            w.writeEvents(store)
            while next_pose <= int(t[-1]) + 10_000:
                w.writePose(dv.Pose(next_pose, (0.1, -0.5, 0.4), (1.0, 0.0, 0.0, 0.0), "base", "cam"))
                next_pose += 10_000
        del w                                              # closes the file


def gen_ros2(folder: Path, n_events: int, storage: str) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer

    from evpose.core.importers.epose_bag_cdr import dvs_typestore_ros2, encode_event_array_cdr, encode_pose_stamped_cdr

    ts = dvs_typestore_ros2()
    rng = np.random.default_rng(1)
    with staged(folder) as tmp, Writer(tmp, version=9, storage_plugin=StoragePlugin[storage]) as w:
        ce = w.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=ts)
        cp = w.add_connection("/dvs/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        next_pose = T0_US
        for x, y, t, p in _event_chunks(n_events, 346, 260, seed=0):
            i = 0
            while i < len(t):
                m = int(rng.integers(10_000, 30_001))
                sl = slice(i, i + m)
                tn = t[sl] * 1000
                while next_pose <= int(t[sl][-1]):
                    tp = next_pose * 1000
                    w.write(cp, tp, encode_pose_stamped_cdr(tp, [0.1, -0.5, 0.4], [0, 0, 0, 1]))
                    next_pose += 10_000
                w.write(ce, int(tn[-1]), encode_event_array_cdr(x[sl], y[sl], tn, p[sl], stamp_ns=int(tn[-1])))
                i += m
        w.write(cp, next_pose * 1000, encode_pose_stamped_cdr(next_pose * 1000, [0.1, -0.5, 0.4], [0, 0, 0, 1]))


def gen_prophesee(path: Path, n_events: int, version: str) -> None:
    import faery
    from faery.extension import dat, evt

    from evpose.core.data.atomic import atomic_write_text

    size = (1280, 720)
    t_last = 0
    with staged(path) as tmp:
        if version == "dat":
            enc = dat.Encoder(path=str(tmp), version="dat2", event_type="cd", zero_t0=False, dimensions=size)
        else:
            enc = evt.Encoder(path=str(tmp), version=version, zero_t0=False, dimensions=size, enforce_monotonic=True)
        with enc as e:
            for x, y, t, p in _event_chunks(n_events, *size, seed=4):
                a = np.zeros(len(t), faery.EVENTS_DTYPE)
                a["t"], a["x"], a["y"], a["on"] = t - T0_US + SENSOR_T0_US, x, y, p > 0
                t_last = int(a["t"][-1])
                if version == "dat":
                    dat_dtype = np.dtype([("t", "=u8"), ("x", "=u2"), ("y", "=u2"), ("payload", "u1")])
                    e.write(a.astype(dat_dtype, casting="unsafe"))
                else:
                    e.write({"events": a})
    lines = ["t_us,x,y,z,qx,qy,qz,qw"] + [f"{k},0.1,-0.5,0.4,0,0,0,1" for k in range(0, t_last + 20_000, 10_000)]
    atomic_write_text(path.with_suffix(".csv"), "\n".join(lines) + "\n")
    atomic_write_text(path.parent / "prophesee_cam.json", json.dumps(
        {"K": [[1700.0, 0, 640.0], [0, 1700.0, 360.0], [0, 0, 1]], "dist": [], "width": 1280, "height": 720}))


#: The recording formats of issue 17: name -> (input path for N events, generator, import task, baseline task,
#: baseline name, what the import row measures).
NEW_FORMATS = {
    "aedat4": (lambda n: DATA / f"aedat4_{n}.aedat4", gen_aedat4, "aedat4", "dv-decode",
               "dv-processing decode only", "evpose import aedat4"),
    "ros2-sqlite3": (lambda n: DATA / f"ros2_sqlite3_{n}", lambda p, n: gen_ros2(p, n, "SQLITE3"), "epose-bag",
                     "rosbags-ros2", "rosbags deserialize_cdr/msg", "evpose import (numpy CDR parser)"),
    "ros2-mcap": (lambda n: DATA / f"ros2_mcap_{n}", lambda p, n: gen_ros2(p, n, "MCAP"), "epose-bag",
                  "rosbags-ros2", "rosbags deserialize_cdr/msg", "evpose import (numpy CDR parser)"),
    "evt2": (lambda n: DATA / f"evt2_{n}.raw", lambda p, n: gen_prophesee(p, n, "evt2"), "prophesee",
             "faery-decode", "faery decode only", "evpose import prophesee"),
    "evt3": (lambda n: DATA / f"evt3_{n}.raw", lambda p, n: gen_prophesee(p, n, "evt3"), "prophesee",
             "faery-decode", "faery decode only", "evpose import prophesee"),
    "dat": (lambda n: DATA / f"dat_{n}.dat", lambda p, n: gen_prophesee(p, n, "dat"), "prophesee",
            "faery-decode", "faery decode only", "evpose import prophesee"),
}


def import_sources(fmt: str, path: Path) -> list:
    """The sources of ``evpose import`` for a generated input of a new format."""
    if fmt == "prophesee":
        return [path, path.with_suffix(".csv"), path.parent / "prophesee_cam.json"]
    return [path]


def decode_only(task: str, arg: str, limit: int) -> int:
    """Events decoded by the reader library alone (the baselines of the new formats)."""
    n = 0
    if task == "dv-decode":
        import dv_processing as dv

        rec = dv.io.MonoCameraRecording(arg)
        while (b := rec.getNextEventBatch()) is not None:
            a = b.numpy()
            n += len(a["timestamp"])
    elif task == "faery-decode":
        from faery.extension import dat, evt

        d = dat.Decoder(arg, None, None) if arg.endswith(".dat") else evt.Decoder(arg, None, None)
        for pk in d:
            n += len(pk if not isinstance(pk, dict) else pk.get("events", ()))
    else:                                   # rosbags-ros2: per-message deserialisation, like the ROS1 baseline
        from rosbags.highlevel import AnyReader

        from evpose.core.importers.epose_bag_cdr import dvs_typestore_ros2

        with AnyReader([Path(arg)], default_typestore=dvs_typestore_ros2()) as rd:
            conns = [c for c in rd.connections if c.topic == "/dvs/events"]
            for k, (c, _, raw) in enumerate(rd.messages(connections=conns)):
                m = rd.deserialize(raw, c.msgtype)
                ev = m.events
                t = np.fromiter((e.ts.sec * 1_000_000 + (e.ts.nanosec + 500) // 1000 for e in ev), np.int64, len(ev))
                x = np.fromiter((e.x for e in ev), np.uint16, len(ev))
                n += len(t) + 0 * len(x)
                if k + 1 >= limit:
                    break
    return n


# ------------------------------------------------------------------------------------------------ children
def child(task: str, arg: str, extra: str) -> dict:
    """Run one task; an import writes into a folder this run creates (:func:`synth_scenes.run_dir`: never a name
    another run or a dead process may hold), removed after the timing."""
    writes = task.startswith("import-new:") or task in ("import-bag", "import-dsec", "link-dsec", "naive-dsec")
    with contextlib.ExitStack() as stack:
        out = stack.enter_context(run_dir(".import")) / "scene" if writes else None
        return _timed_task(task, arg, extra, out)


def _timed_task(task: str, arg: str, extra: str, out: Path | None) -> dict:
    _heavy()
    import resource

    # one-time imports happen before the clock starts: the table measures the work per file
    import h5py  # noqa: F401
    import hdf5plugin  # noqa: F401
    import rosbags.rosbag1  # noqa: F401

    import evpose.core.data.scene  # noqa: F401
    import evpose.core.importers.dsec  # noqa: F401
    import evpose.core.importers.epose_bag  # noqa: F401
    if task.endswith((":aedat4", ":prophesee", ":epose-bag")) or task in ("dv-decode", "faery-decode", "rosbags-ros2"):
        import faery  # noqa: F401

        import evpose.core.importers.aedat4  # noqa: F401
        import evpose.core.importers.prophesee  # noqa: F401
    t0 = time.perf_counter()
    res = {}
    if task.startswith("gen-new:"):
        NEW_FORMATS[task.split(":", 1)[1]][1](Path(arg), int(extra))
    elif task.startswith("import-new:"):
        from evpose.core.importers import import_scene

        fmt = task.split(":", 1)[1]
        t0 = time.perf_counter()
        res["n"] = int(import_scene(fmt, import_sources(fmt, Path(arg)), out, log=None)["n_events"])
    elif task in ("dv-decode", "faery-decode", "rosbags-ros2"):
        res["n"] = decode_only(task, arg, int(extra or 0))
    elif task == "gen-bag":
        gen_bag(Path(arg), int(extra))
    elif task == "gen-dsec":
        gen_dsec(Path(arg), int(extra))
    elif task in ("import-bag", "import-dsec", "link-dsec"):
        from evpose.core.importers import import_scene

        if task == "import-bag":
            r = import_scene("epose-bag", [arg], out)
        else:
            d = Path(arg)
            r = import_scene("dsec", [d / "events.h5", d / "poses.txt", d / "cam_to_cam.yaml"], out,
                             events_mode="copy" if task == "import-dsec" else "link")
        res["n"] = int(r["n_events"])
    elif task == "rosbags-bag":
        from rosbags.rosbag1 import Reader

        from evpose.core.importers.epose_bag_codec import EVENT_ARRAY_TYPE, dvs_typestore

        ts = dvs_typestore()
        n = n_msgs = 0
        limit = int(extra)
        with Reader(arg) as rd:
            conns = [c for c in rd.connections if c.topic == "/dvs/events"]
            for _, _, raw in rd.messages(connections=conns):
                m = ts.deserialize_ros1(raw, EVENT_ARRAY_TYPE)
                ev = m.events
                k = len(ev)
                x = np.fromiter((e.x for e in ev), np.uint16, k)
                y = np.fromiter((e.y for e in ev), np.uint16, k)
                t = np.fromiter((e.ts.sec * 1_000_000 + (e.ts.nanosec + 500) // 1000 for e in ev), np.int64, k)
                p = np.fromiter((e.polarity for e in ev), np.uint8, k)
                n += len(t) + 0 * (len(x) + len(y) + len(p))
                n_msgs += 1
                if n_msgs >= limit:
                    break
        res["n"] = n
    elif task == "naive-dsec":
        import h5py
        import hdf5plugin

        comp = dict(hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=hdf5plugin.Blosc.SHUFFLE))
        out.mkdir(parents=True)
        with h5py.File(Path(arg) / "events.h5", "r") as f, h5py.File(out / "events.h5", "w") as g:
            for k in "xytp":
                a = f[f"events/{k}"][:]
                g.create_dataset(f"events/{k}", data=a, chunks=(1 << 15,), **comp)
                res["n"] = len(a)
            g.create_dataset("t_offset", data=f["t_offset"][()])
    res["seconds"] = time.perf_counter() - t0
    # the AEDAT4 import reads in a child process: its peak counts too (the largest child; none for the others)
    res["maxrss_mb"] = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                        + resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss) / 1024
    return res


MALLOC_ENV = {"MALLOC_MMAP_THRESHOLD_": "131072"}
ALL_FORMATS = ("bag", "dsec", "aedat4", "ros2-sqlite3", "ros2-mcap", "evt2", "evt3", "dat")


def run_child(task: str, arg, extra="", malloc_default=False) -> dict:
    env = dict(os.environ) if malloc_default else {**os.environ, **MALLOC_ENV}
    r = subprocess.run([sys.executable, __file__, "--child", task, str(arg), str(extra)], capture_output=True,
                       text=True, cwd=ROOT, env=env)
    if r.returncode:
        sys.stderr.write(r.stderr)
        raise SystemExit(f"child {task} failed")
    return json.loads(r.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------------------------------ driver
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=50_000_000)
    ap.add_argument("--small", type=int, default=5_000_000)
    ap.add_argument("--baseline-messages", type=int, default=100)
    ap.add_argument("--json", action="store_true", help="print one JSON document of the headline figures "
                    "(the table goes to stderr)")
    ap.add_argument("--formats", default=",".join(ALL_FORMATS),
                    help=f"comma-separated rows to measure (default all: {','.join(ALL_FORMATS)})")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(child(*a.child)))
        return
    formats = [f for f in a.formats.split(",") if f]
    if set(formats) - set(ALL_FORMATS):
        ap.error(f"--formats: unknown {', '.join(sorted(set(formats) - set(ALL_FORMATS)))}")
    DATA.mkdir(parents=True, exist_ok=True)
    sizes = [a.events, a.small]
    for n in sizes:
        bag, dsec = DATA / f"bag_{n}.bag", DATA / f"dsec_{n}"
        if "bag" in formats and not bag.exists():
            print(f"generating {bag.name} ...", file=sys.stderr, flush=True)
            run_child("gen-bag", bag, n)
        if "dsec" in formats and not (dsec / "events.h5").exists():
            print(f"generating {dsec.name} ...", file=sys.stderr, flush=True)
            run_child("gen-dsec", dsec, n)
        for fmt in (f for f in formats if f in NEW_FORMATS):
            path = NEW_FORMATS[fmt][0](n)
            if not path.exists():
                print(f"generating {path.name} ...", file=sys.stderr, flush=True)
                run_child(f"gen-new:{fmt}", path, n)
    rows = []

    def both(task, arg, extra=""):
        """Speed and peak RSS with glibc's default malloc, plus peak RSS with a fixed mmap threshold (live memory)."""
        r = run_child(task, arg, extra, malloc_default=True)
        r["live_mb"] = run_child(task, arg, extra)["maxrss_mb"]
        return r

    for n in sizes:
        bag, dsec = DATA / f"bag_{n}.bag", DATA / f"dsec_{n}"
        if "bag" in formats:
            mb = bag.stat().st_size / 1e6
            ours = both("import-bag", bag)
            base = both("rosbags-bag", bag, a.baseline_messages) if n == a.events else None
            rows.append(("epose-bag", n, f"{mb:.0f} MB", "evpose import (numpy parser)", ours, base,
                         "rosbags deserialize_ros1/msg"))
        if "dsec" in formats:
            mb = (dsec / "events.h5").stat().st_size / 1e6
            ours = both("import-dsec", dsec)
            naive = both("naive-dsec", dsec)
            rows.append(("dsec", n, f"{mb:.0f} MB", "evpose import --events-mode copy", ours, naive,
                         "naive h5py full copy"))
            ours = both("link-dsec", dsec)
            rows.append(("dsec", n, f"{mb:.0f} MB", "evpose import --events-mode link", ours, naive,
                         "naive h5py full copy"))
        for fmt in (f for f in formats if f in NEW_FORMATS):
            path_of, _, imp, base_task, base_name, meth = NEW_FORMATS[fmt]
            path = path_of(n)
            mb = sum(q.stat().st_size for q in (path.rglob("*") if path.is_dir() else [path])) / 1e6
            ours = both(f"import-new:{imp}", path)
            base = both(base_task, path, a.baseline_messages) if n == a.events else None
            rows.append((fmt, n, f"{mb:.0f} MB", meth, ours, base, base_name))
    out = sys.stderr if a.json else sys.stdout
    hdr = (f"{'format':<12} {'events':>10} {'input':>6} | {'method':<32} {'M ev/s':>6} {'peak':>5} {'live':>5} | "
           f"{'baseline':<28} {'M ev/s':>6} {'peak':>5} {'live':>5} | {'speed x':>7} {'live mem x':>10}")
    print(hdr, file=out)
    print("-" * len(hdr), file=out)
    doc_rows = []
    for fmt, n, size, meth, o, b, bname in rows:
        o_rate = o["n"] / o["seconds"] / 1e6
        o_txt = f"{meth:<32} {o_rate:>6.2f} {o['maxrss_mb']:>5.0f} {o['live_mb']:>5.0f}"
        if b:
            b_rate = b["n"] / b["seconds"] / 1e6
            b_txt = f"{bname:<28} {b_rate:>6.2f} {b['maxrss_mb']:>5.0f} {b['live_mb']:>5.0f}"
            mem = "n/a" if bname.startswith("rosbags") else f"{b['live_mb'] / o['live_mb']:.2f}"
            ratio = f"{o_rate / b_rate:>7.1f} {mem:>10}"
        else:
            b_txt, ratio = f"{'(timed on the large file)':<28} {'':>6} {'':>5} {'':>5}", f"{'':>7} {'':>10}"
        print(f"{fmt:<12} {n:>10,} {size:>6} | {o_txt} | {b_txt} | {ratio}", file=out)
        doc_rows.append({"format": fmt, "events": n, "input": size, "method": meth, "m_events_per_s": round(o_rate, 3),
                         "peak_mb": round(o["maxrss_mb"], 1), "live_mb": round(o["live_mb"], 1),
                         "baseline": None if not b else {
                             "method": bname, "m_events_per_s": round(b_rate, 3), "peak_mb": round(b["maxrss_mb"], 1),
                             "live_mb": round(b["live_mb"], 1), "speed_ratio": round(o_rate / b_rate, 2),
                             "live_memory_ratio": None if bname.startswith("rosbags") else
                             round(b["live_mb"] / o["live_mb"], 2)}})
    print(f"\nM ev/s and peak = wall clock and ru_maxrss (MB) with glibc's default malloc; live = ru_maxrss (MB) of a second "
          "run with MALLOC_MMAP_THRESHOLD_=131072, which stops heap fragmentation from inflating RSS. speed x = our "
          "events/s over the baseline's; live mem x = baseline live MB over ours. The rosbags baseline is timed on the "
          f"first {a.baseline_messages} messages (about {a.baseline_messages * 20_000 / 1e6:.0f} M events) and "
          "extrapolated (its memory covers those messages only). Peak and live of the AEDAT4 import add its reading "
          "process's. Targets: >= 1 M ev/s (bag), >= 5 M ev/s (DSEC, AEDAT4, EVT 3.0).", file=out)
    if a.json:
        print(json.dumps({"benchmark": "import", "data": f"synthetic ROS1 bag (dvs_msgs/EventArray, 346x260), "
                          f"DSEC-layout files (640x480), AEDAT4 by dv-processing (346x260), ROS2 bags by rosbags (sqlite3, "
                          f"MCAP), EVT 2.0 / 3.0 / DAT by faery (1280x720); random events at {RATE / 1e6:g} M ev/s, "
                          "cached in bench/.data", "formats": formats,
                          "cores": os.cpu_count(), "baseline_messages": a.baseline_messages, "rows": doc_rows,
                          "targets_m_events_per_s": {"epose-bag": 1.0, "dsec": 5.0, "aedat4": 5.0, "evt3": 5.0}}))


if __name__ == "__main__":
    main()
