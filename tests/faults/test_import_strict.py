"""Every input validated on import, every format, and nothing changed without ``--repair`` (issue 22, part 5).

Each case runs the real ``evpose import`` on a tiny input (1200 events on a 346x260 sensor, 0.12 s; a time or a
pixel of one event, a packet header, or one file of a folder broken on purpose) and pins one finding of the
tester: without ``--repair`` one error line naming the file, the record (event index) and the field, and no scene;
with ``--repair`` the change counted in ``import_report.json``. Every case snapshots its inputs and checks they are
byte-identical afterwards. The cases run concurrently (each is its own process), once per module.

Decision pinned here: events and a trajectory that do not overlap in time are imported with a warning (the clock
is what ``sync`` and the corrections fix), with ``time_overlap_us = 0`` in the report.
"""
from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from fault_harness import assert_clean_error, assert_ok, run_cli, snapshot
from recording_writers import write_aedat4, write_prophesee, write_ros2_bag

from evpose.core.data.events import EventArray
from evpose.core.data.trajectory import Trajectory

TIMEOUT = 60
WORKERS = 3
W, H = 346, 260                          # DAVIS346: no calibration needed (E-POSE's is assumed, reported)
N, T0, DT = 1200, 1_000_000, 100         # events, first time (µs), one event every DT µs: times are unique
SECOND = 1_000_000


def base_events() -> EventArray:
    rng = np.random.default_rng(22)
    return EventArray(rng.integers(0, W, N).astype(np.uint16), rng.integers(0, H, N).astype(np.uint16),
                      T0 + DT * np.arange(N, dtype=np.int64), rng.integers(0, 2, N).astype(np.uint8))


def base_trajectory(shift_us: int = 0) -> Trajectory:
    t = T0 - 10_000 + 10_000 * np.arange(16, dtype=np.int64) + shift_us        # covers the events' 0.12 s
    return Trajectory(t, np.tile([0.0, 0.0, 0.5], (16, 1)), np.tile([0.0, 0.0, 0.0, 1.0], (16, 1)))


# ------------------------------------------------------------------------------------------------ byte editors
def payload_offset(path: Path) -> int:
    """Where a Prophesee file's event words start: after its ``%`` lines (and DAT's 2 type/size bytes)."""
    data = path.read_bytes()
    n = 0
    while data.startswith(b"%", n):
        n = data.index(b"\n", n) + 1
    return n + (2 if path.suffix == ".dat" else 0)


def edit_words(path: Path, dtype: str, change: Callable[[np.ndarray], None]) -> None:
    """Change the event words of a Prophesee file in place (``change`` edits the writable array)."""
    data = bytearray(path.read_bytes())
    off = payload_offset(path)
    change(np.frombuffer(data, dtype, (len(data) - off) // np.dtype(dtype).itemsize, off))
    path.write_bytes(bytes(data))


def edit_aedat4_event(path: Path, ev: EventArray, i: int, **new) -> None:
    """Change event ``i`` (``t``, ``x`` or ``y``) of an uncompressed AEDAT4 file: its ``(int64 t, int16 x, int16 y)``
    struct is unique in the file."""
    data = path.read_bytes()
    old = struct.pack("<qhh", int(ev.t[i]), int(ev.x[i]), int(ev.y[i]))
    assert data.count(old) == 1
    vals = {"t": int(ev.t[i]), "x": int(ev.x[i]), "y": int(ev.y[i]), **new}
    path.write_bytes(data.replace(old, struct.pack("<qhh", vals["t"], vals["x"], vals["y"])))


def aedat4_packets(data: bytes, n: int) -> list[tuple[int, int]]:
    """``(offset, size)`` of the first ``n`` packets (after the version line and the IOHeader)."""
    pos, out = 18 + struct.unpack_from("<I", data, 14)[0], []
    for _ in range(n):
        size = struct.unpack_from("<ii", data, pos)[1]
        out.append((pos, size))
        pos += 8 + size
    return out


# ------------------------------------------------------------------------------------------------ inputs
def prophesee(d: Path, name: str, ev: EventArray | None = None, traj: Trajectory | None = None) -> list:
    rec = write_prophesee(d / name, ev or base_events(), version="dat" if name.endswith(".dat") else "evt2",
                          size=(W, H))
    return [rec, (traj or base_trajectory()).save_csv(d / "traj.csv")]


def aedat4(d: Path, name: str = "rec.aedat4", **kw) -> list:
    rec = write_aedat4(d / name, base_events(), size=(W, H), packet_events=300, **kw)
    return [rec, base_trajectory().save_csv(d / "traj.csv")]


def ros2(d: Path, storage: str, ev: EventArray | None = None) -> list:
    bag = write_ros2_bag(d / "rec", ev or base_events(), base_trajectory(), storage=storage, width=W, height=H,
                         numpy_encode=True, msg_events=400)
    return [bag, "--width", W, "--height", H]


def dat_stepping_back(d: Path) -> list:
    """From event 600 on, the DAT time is 1 s earlier (faery clamped all of them onto one microsecond)."""
    def change(w):
        w[600:] -= np.uint64(SECOND)                  # the low 32 bits of a DAT word are its time
    srcs = prophesee(d, "back.dat")
    edit_words(srcs[0], "<u8", change)
    return srcs


def evt2_time_high_lowered(steps: int):
    """An EVT 2.0 file whose middle TIME_HIGH word is ``steps`` x 64 µs too early: the events after it (until
    the next TIME_HIGH) are that much out of order."""
    def change(w):
        w[evt2_middle_time_high(w)] -= np.uint32(steps)

    def build(d: Path) -> list:
        srcs = prophesee(d, "back.raw")
        edit_words(srcs[0], "<u4", change)
        return srcs
    return build


def evt2_middle_time_high(words: np.ndarray) -> int:
    """The word index of the middle TIME_HIGH word (type 8) of an EVT 2.0 payload."""
    high = np.flatnonzero(words >> 28 == 8)
    return int(high[len(high) // 2])


def evt2_events_after_middle_time_high(path: Path) -> np.ndarray:
    """Indices of the events (CD words) between the middle TIME_HIGH word and the next one."""
    data = path.read_bytes()
    off = payload_offset(path)
    w = np.frombuffer(data, "<u4", (len(data) - off) // 4, off)
    kind = w >> 28
    j = evt2_middle_time_high(w)
    nxt = j + 1 + int(np.argmax(kind[j + 1:] == 8))
    cd_before = int(np.count_nonzero(kind[:j] <= 1))
    return cd_before + np.arange(int(np.count_nonzero(kind[j:nxt] <= 1)))


def evt2_unknown_words(d: Path) -> list:
    """Three event words turned into words of type 3 (no such type in EVT 2.0)."""
    srcs = prophesee(d, "unknown.raw")

    def change(w):
        cd = np.flatnonzero(w >> 28 <= 1)[[100, 500, 900]]
        w[cd] = (w[cd] & np.uint32(0x0FFFFFFF)) | np.uint32(3 << 28)
    edit_words(srcs[0], "<u4", change)
    return srcs


def aedat4_event(i: int, **new):
    def build(d: Path) -> list:
        srcs = aedat4(d, compressed=False)
        edit_aedat4_event(srcs[0], base_events(), i, **new)
        return srcs
    return build


def aedat4_bytes(edit: Callable[[bytes], bytes]):
    def build(d: Path) -> list:
        srcs = aedat4(d)
        srcs[0].write_bytes(edit(srcs[0].read_bytes()))
        return srcs
    return build


def packet_size_2gib(data: bytes) -> bytes:
    pos = aedat4_packets(data, 1)[0][0]
    return data[:pos + 4] + struct.pack("<i", 2**31 - 1) + data[pos + 8:]


def cut_in_last_packet(data: bytes) -> bytes:
    pos, size = aedat4_packets(data, 4)[3]
    return data[:pos + 8 + size // 2]


def ros2_events(storage: str, change: Callable[[dict], None]):
    """A ROS2 bag (3 messages of 400 events) of the base events with ``change(columns)`` applied."""
    def build(d: Path) -> list:
        ev = base_events()
        cols = {k: getattr(ev, k).copy() for k in "xytp"}
        change(cols)
        return ros2(d, storage, EventArray(cols["x"], cols["y"], cols["t"], cols["p"]))
    return build


def steps_back_1s_from_event_200(cols: dict) -> None:
    cols["t"][200:] -= SECOND


def x_1000_at_event_500(cols: dict) -> None:
    cols["x"][500] = 1000


def ros2_fifo(storage: str):
    def build(d: Path) -> list:
        srcs = ros2(d, storage)
        store = next(p for p in srcs[0].iterdir() if p.suffix in (".db3", ".mcap"))
        store.unlink()
        os.mkfifo(store)
        return srcs
    return build


def bop_random_ply(d: Path) -> list:
    """A BOP scene of three event images whose one model is random bytes."""
    import cv2

    sd = d / "bop" / "test" / "000000"
    (sd / "rgb").mkdir(parents=True)
    (d / "bop" / "models").mkdir()
    (d / "bop" / "models" / "obj_000001.ply").write_bytes(np.random.default_rng(1).bytes(3000))
    gt, cam = {}, {}
    for i in range(3):
        gt[str(i)] = [{"obj_id": 1, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [10.0 * i, 0, 500.0]}]
        cam[str(i)] = {"cam_K": [300.0, 0, 86.5, 0, 300.0, 65.0, 0, 0, 1]}
        img = np.zeros((130, 173, 3), np.uint8)
        img[60:70, 80 + i:90 + i, 2] = 255
        cv2.imwrite(str(sd / "rgb" / f"{i:06d}.png"), img)
    (sd / "scene_gt.json").write_text(json.dumps(gt))
    (sd / "scene_camera.json").write_text(json.dumps(cam))
    return [d / "bop", "--scene", "0"]


def text_ply_object(d: Path) -> list:
    srcs = prophesee(d, "rec.raw")
    (d / "box.ply").write_text("ply? no: a text file someone named box.ply\n")
    (d / "T.json").write_text(json.dumps(np.eye(4).tolist()))
    return [*srcs, "--objects", f"box={d / 'box.ply'}:{d / 'T.json'}"]


def recording_bytes(name: str, content: bytes):
    """A recording file ``name`` holding ``content`` (and a good trajectory)."""
    def build(d: Path) -> list:
        (d / name).write_bytes(content)
        return [d / name, base_trajectory().save_csv(d / "traj.csv")]
    return build


# ------------------------------------------------------------------------------------------------ cases
@dataclass
class Case:
    id: str
    fmt: str
    build: Callable[[Path], list]        # writes the inputs into a folder; returns SRC... and options
    repair: bool = False                 # also run with --repair


CASES = [
    Case("dat-steps-back", "prophesee", dat_stepping_back, repair=True),
    Case("evt2-slightly-out-of-order", "prophesee", evt2_time_high_lowered(2)),
    Case("evt2-steps-back-1s", "prophesee", evt2_time_high_lowered(SECOND // 64)),
    Case("evt2-unknown-words", "prophesee", evt2_unknown_words),
    Case("evt-empty", "prophesee", recording_bytes("empty.raw", b"")),
    Case("dat-random-bytes", "prophesee", recording_bytes("random.dat", np.random.default_rng(3).bytes(4000))),
    Case("aedat4-x-1000", "aedat4", aedat4_event(700, x=1000)),
    Case("aedat4-y-negative", "aedat4", aedat4_event(701, y=-5)),
    Case("aedat4-jumps-back-0.5s", "aedat4", aedat4_event(900, t=T0 + DT * 900 - SECOND // 2), repair=True),
    Case("aedat4-packet-2gib", "aedat4", aedat4_bytes(packet_size_2gib)),
    Case("aedat4-cut-off", "aedat4", aedat4_bytes(cut_in_last_packet)),
    Case("aedat4-cut-in-its-table", "aedat4", aedat4_bytes(lambda b: b[:-10])),
    Case("aedat4-header-size", "aedat4", aedat4_bytes(lambda b: b[:14] + struct.pack("<I", 10**6) + b[18:])),
    Case("aedat4-version-line-only", "aedat4", aedat4_bytes(lambda b: b[:14])),
    Case("ros2-sqlite3-steps-back-1s", "epose-bag", ros2_events("SQLITE3", steps_back_1s_from_event_200)),
    Case("ros2-mcap-x-1000", "epose-bag", ros2_events("MCAP", x_1000_at_event_500)),
    *[Case(f"ros2-{s.lower()}-fifo", "epose-bag", ros2_fifo(s)) for s in ("SQLITE3", "MCAP")],
    Case("bop-random-ply", "bop", bop_random_ply),
    Case("text-ply-object", "prophesee", text_ply_object),
    Case("no-time-overlap", "prophesee", lambda d: prophesee(d, "rec.dat", traj=base_trajectory(10 * SECOND))),
]


@dataclass
class Result:
    folder: Path                         # the case's inputs (snapshotted before, compared after)
    changed: list                        # input files whose bytes changed (or that vanished)
    strict: object                       # the Run without --repair (or run_cli's exception: a hang)
    repaired: object = None              # the Run with --repair

    def out(self, repair: bool = False) -> Path:
        return self.folder.parent / f"out-{self.folder.name}{'-repair' if repair else ''}"

    def report(self, repair: bool = False) -> dict:
        return json.loads((self.out(repair) / "import_report.json").read_text())


def _selected(request) -> set[str]:
    """The case ids of the selected tests of this module (each test is parametrized by ``cid``)."""
    return {item.callspec.params["cid"] for item in request.session.items
            if item.module is request.module and "cid" in getattr(getattr(item, "callspec", None), "params", {})}


@pytest.fixture(scope="module")
def runs(request, tmp_path_factory) -> dict[str, Result]:
    """The selected cases built and run (concurrently, each ``evpose import`` its own process): id -> Result."""
    from concurrent.futures import ThreadPoolExecutor

    root = tmp_path_factory.mktemp("import_strict")
    env = {"XDG_CACHE_HOME": str(root / "cache")}
    wanted = _selected(request)
    results, jobs, before = {}, [], {}
    for c in (c for c in CASES if c.id in wanted):
        results[c.id] = r = Result(root / c.id, [], None)
        r.folder.mkdir()
        args = c.build(r.folder)
        before[c.id] = snapshot(r.folder)
        for repair in (False, True) if c.repair else (False,):
            jobs.append((c.id, repair, ["import", c.fmt, *args, "--out", r.out(repair), "-q",
                                        *(["--repair"] if repair else [])]))

    def go(job):
        cid, repair, args = job
        try:
            return cid, repair, run_cli(*args, timeout=TIMEOUT, env=env)
        except BaseException as exc:        # a hang: pytest.fail inside the thread, re-raised by the test
            return cid, repair, exc

    with ThreadPoolExecutor(WORKERS) as pool:
        for cid, repair, run in pool.map(go, jobs):
            setattr(results[cid], "repaired" if repair else "strict", run)
    for cid, r in results.items():
        after = snapshot(r.folder)
        r.changed = sorted(k for k in set(before[cid]) | set(after) if before[cid].get(k) != after.get(k))
    return results


def result(runs, cid: str) -> Result:
    """The case's result; its inputs are unchanged and no run hung."""
    r = runs[cid]
    for run in (r.strict, r.repaired):
        if isinstance(run, BaseException):
            raise run
    assert not r.changed, f"inputs changed: {r.changed}"
    return r


def refused(runs, cid: str, *names) -> str:
    """The one error line of the case's run without --repair (naming ``names``); no scene was made."""
    r = result(runs, cid)
    line = assert_clean_error(r.strict, *names)
    assert line.startswith("evpose import: error: ") and "Stacktrace" not in r.strict.stderr, line
    assert not r.out().exists()
    return line


def imported(runs, cid: str, repair: bool = False) -> dict:
    """The import report of the case's run (with or without --repair), which must have succeeded."""
    r = result(runs, cid)
    assert_ok(r.repaired if repair else r.strict)
    return r.report(repair)


def written_times(out: Path) -> np.ndarray:
    """The event times (µs) of a scene's ``events.h5``."""
    import h5py
    import hdf5plugin  # noqa: F401  (Blosc)

    with h5py.File(out / "events.h5", "r") as f:
        return f["events/t"][()].astype(np.int64) + int(f["t_offset"][()] if "t_offset" in f else 0)


def case(*ids):
    return pytest.mark.parametrize("cid", ids)


# ------------------------------------------------------------------------------------------------ time order
@case("dat-steps-back")
def test_dat_time_stepping_back_is_refused_never_clamped(runs, cid):
    """Was: exit 0, 0 warnings, and every event after the step on one microsecond (faery clamps)."""
    refused(runs, cid, "back.dat", ": event 600: t: ", "999900 µs older", "--repair")
    rep = imported(runs, cid, repair=True)
    assert rep["counts"]["events_dropped_late"] == 600 and rep["counts"]["events_written"] == 600
    np.testing.assert_array_equal(written_times(runs[cid].out(repair=True)), base_events().t[:600])


@case("evt2-slightly-out-of-order")
def test_evt2_events_slightly_out_of_order_keep_their_times_counted(runs, cid):
    """Was: clamped onto the previous event's time. Now: put in place within the reorder window, times as in the
    file, counted in import_report.json (no --repair needed: nothing is dropped or re-timed)."""
    rep = imported(runs, cid)
    moved = evt2_events_after_middle_time_high(runs[cid].folder / "back.raw")
    t = base_events().t.copy()
    t[moved] -= 128
    late = int(np.count_nonzero(t[1:] < np.maximum.accumulate(t)[:-1]))
    assert len(moved) >= 1 and late >= 1 and rep["counts"]["events_out_of_order"] == late
    np.testing.assert_array_equal(written_times(runs[cid].out()), np.sort(t))


@case("evt2-steps-back-1s")
def test_evt2_time_stepping_back_beyond_the_window_is_refused(runs, cid):
    """A TIME_HIGH falling by 1 s is a step back, not a 2**34 µs wrap (faery added 4.77 h)."""
    first = int(evt2_events_after_middle_time_high(runs[cid].folder / "back.raw")[0])
    refused(runs, cid, "back.raw", f": event {first}: t: ", "reorder window", "--repair")


@case("aedat4-jumps-back-0.5s")
def test_aedat4_event_jumping_back_is_refused_and_never_moves_the_scene_start(runs, cid):
    """Was: sorted to the front, the scene starting 0.49 s earlier."""
    refused(runs, cid, "rec.aedat4", ": event 900: t: ", "499900 µs older")
    rep = imported(runs, cid, repair=True)
    assert rep["counts"]["events_dropped_late"] == 1 and rep["events"]["t_first_us"] == T0


@case("ros2-sqlite3-steps-back-1s")
def test_ros2_time_stepping_back_1s_inside_a_message_is_refused(runs, cid):
    """Was: the message sorted, the import accepted (sqlite3 and MCAP bags alike: one reader)."""
    refused(runs, cid, "rec", "message 0 on /dvs/events, event 200: t: ", "--repair")


# ------------------------------------------------------------------------------------------------ on the sensor
@case("aedat4-x-1000")
def test_aedat4_x_beyond_the_sensor_is_refused(runs, cid):
    """Was: dropped without --repair (one 'repaired' line, exit 0). With --repair: dropped and counted
    (``tests/core/test_import_validation.py``)."""
    refused(runs, cid, "rec.aedat4", ": event 700: x: 1000 is outside the 346x260 sensor", "--repair")


@case("aedat4-y-negative")
def test_aedat4_negative_y_is_refused(runs, cid):
    refused(runs, cid, "rec.aedat4", ": event 701: y: -5 is outside the 346x260 sensor")


@case("ros2-mcap-x-1000")
def test_ros2_x_beyond_the_sensor_is_refused(runs, cid):
    refused(runs, cid, "rec", "message 1 on /dvs/events, event 100: x: 1000 is outside")


# ------------------------------------------------------------------------------------------------ declared sizes
@case("aedat4-packet-2gib")
def test_aedat4_packet_declaring_2gib_is_refused(runs, cid):
    refused(runs, cid, "rec.aedat4", "packet 0 at byte", ": size: declares 2,147,483,647 bytes")


@case("aedat4-cut-off")
def test_aedat4_cut_in_its_last_packet_is_read_up_to_the_cut_and_reported(runs, cid):
    """Was: not importable at all (dv-processing refuses a file whose packet table is gone)."""
    rep = imported(runs, cid)
    assert rep["counts"]["aedat4_packets_read"] == 3 and rep["counts"]["events_written"] == 900
    assert any("cut off" in w and "packet 3" in w for w in rep["warnings"])
    assert "cut off" in runs[cid].strict.stderr
    assert not list((runs[cid].folder.parent / "cache" / "evpose" / "aedat4").glob("*.aedat4")), "copy left"


@case("aedat4-cut-in-its-table")
def test_aedat4_cut_in_its_packet_table_is_read_without_the_table(runs, cid):
    """dv-processing refuses the damaged table; the packets are read again without it, reported."""
    rep = imported(runs, cid)
    assert rep["counts"]["events_written"] == N
    assert any("cannot read its packet table" in w and "4 packet(s) were read without it" in w
               for w in rep["warnings"])


@case("aedat4-header-size", "aedat4-version-line-only")
def test_aedat4_broken_header_is_one_line_without_a_cpp_stack_trace(runs, cid):
    """Was: dv-processing's message with its C++ stack trace ('Stacktrace: 0# 0x... in dv_processing...')."""
    line = refused(runs, cid, "rec.aedat4", "(header): IOHeader size: ")
    assert "0x0" not in line and ".so" not in line


# ------------------------------------------------------------------------------------------------ EVT words
@case("evt2-unknown-words")
def test_evt2_unknown_words_are_counted_and_warned(runs, cid):
    rep = imported(runs, cid)
    assert rep["counts"]["evt2_words_unknown"] == 3 and rep["counts"]["events_written"] == N - 3
    assert any("3 EVT 2.0 word(s) of unknown type" in w for w in rep["warnings"])


@case("evt-empty", "dat-random-bytes")
def test_not_a_prophesee_file_is_said_so_not_told_to_pass_a_size(runs, cid):
    name, what = {"evt-empty": ("empty.raw", "empty file (0 bytes)"),
                  "dat-random-bytes": ("random.dat", "no '%' header line")}[cid]
    line = refused(runs, cid, name, "(header): ", what, "not a Prophesee")
    assert "--width" not in line


# ------------------------------------------------------------------------------------------------ special files
@case("ros2-sqlite3-fifo", "ros2-mcap-fifo")
def test_fifo_inside_a_ros2_bag_folder_is_refused_before_it_is_opened(runs, cid):
    """Was: the import hung forever opening the FIFO."""
    refused(runs, cid, f"rec/rec.{'db3' if 'sqlite3' in cid else 'mcap'}", "in input folder", "file type: a FIFO")


# ------------------------------------------------------------------------------------------------ meshes
@case("bop-random-ply")
def test_bop_model_of_random_bytes_is_refused(runs, cid):
    refused(runs, cid, "models/obj_000001.ply", "obj_000001: mesh: ", "could not read the mesh")


@case("text-ply-object")
def test_text_file_named_ply_is_refused_as_a_mesh(runs, cid):
    refused(runs, cid, "box.ply", "box: mesh: ", "could not read the mesh")


# ------------------------------------------------------------------------------------------------ time overlap
@case("no-time-overlap")
def test_events_and_trajectory_that_never_overlap_are_warned(runs, cid):
    """Was: 0 warnings (an export then writes 0 windows). Decision: a warning, not a refusal."""
    rep = imported(runs, cid)
    warn = [w for w in rep["warnings"] if "do not overlap in time" in w]
    assert len(warn) == 1 and "--offset-us" in warn[0] and rep["time_overlap_us"] == 0
    assert "do not overlap in time" in runs[cid].strict.stderr
