"""The recording formats of issue 17, each written by its reference library, imported back and compared.

* AEDAT4 written by iniVation's ``dv-processing`` (``dv.io.MonoCameraWriter``, events + a pose stream);
* ROS2 bags written by ``rosbags.rosbag2.Writer`` in sqlite3 and MCAP storage, ``dvs_msgs`` registered from
  its ``.msg`` text and every message serialised by rosbags (``serialize_cdr``);
* Prophesee EVT 2.0 / EVT 3.0 / DAT written by ``faery``'s encoders (Metavision's SDK is not on PyPI), across
  each format's time-counter wrap.

(The writers are in ``tests/recording_writers.py``, shared with the fault tests of ``tests/faults``.)

Events must come back identical; poses identical to what the file holds (AEDAT4 stores float32). Then the
failure modes: a watchdog on the AEDAT4 reading process (stall, crash), header and size checks, and the
CLI's one error line. Corruption of every new format is fuzzed in ``test_import_fuzz_formats.py``.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from recording_writers import float32_traj, write_aedat4, write_prophesee, write_ros2_bag
from test_importers import (  # noqa: F401
    assert_events_equal,
    assert_traj_equal,
    digest,
    no_leftovers,
    read_scene,
    src,
)

from evpose.core.data.events import EventArray
from evpose.core.data.manifest_reader import load_manifest
from evpose.core.data.trajectory import Trajectory
from evpose.core.importers import ImportFailure, import_scene

OBJECT_NAMES = ["box", "cylinder", "flatbox"]


#: Metavision sensors count µs from the camera start (EVT 3.0 keeps 24 bits of it): the scene moved to start at 1 s.
SENSOR_T0_US = 1_000_000


def shifted(src, t_first_us: int):
    """The source events and trajectory moved in time so that the first event is at ``t_first_us``."""
    d = t_first_us - int(src.ev.t[0])
    ev = EventArray(src.ev.x, src.ev.y, src.ev.t + d, src.ev.p)
    return ev, Trajectory(src.traj.t_us + d, src.traj.positions_m, src.traj.quats_xyzw)


def size_of(src) -> tuple[int, int]:
    return src.cam.width, src.cam.height


def cli_parser():
    import argparse

    from evpose.app.cli.importers import add_import_parser

    p = argparse.ArgumentParser()
    add_import_parser(p.add_subparsers(dest="command", required=True))
    return p


# ================================================================================================ AEDAT4
def test_aedat4_round_trip_with_its_pose_stream(src, tmp_path):
    rec = write_aedat4(tmp_path / "rec.aedat4", src.ev, src.traj, size=size_of(src))
    before = digest([rec, src.cam_json])
    res = import_scene("aedat4", [rec], tmp_path / "scene", camera=str(src.cam_json), objects=src.objects_arg, log=None)
    assert digest([rec, src.cam_json]) == before
    ev, traj, man, rep = read_scene(tmp_path / "scene")
    assert_events_equal(ev, src.ev)
    assert_traj_equal(traj, float32_traj(src.traj), tol=1e-12)
    assert (man.camera.width, man.camera.height) == size_of(src)
    assert [o.name for o in man.objects] == OBJECT_NAMES and res["n_events"] == len(src.ev)
    assert any("pose stream 'poses' is T_base_cam" in a and "base -> cam" in a for a in rep["assumptions"])
    no_leftovers(tmp_path)


def test_aedat4_trajectory_file_wins_and_size_comes_from_the_file(src, tmp_path):
    rec = write_aedat4(tmp_path / "rec.aedat4", src.ev, src.traj, size=size_of(src))
    csv = src.traj.save_csv(tmp_path / "trajectory.csv")
    import_scene("aedat4", [rec, csv, src.cam_json], tmp_path / "scene", log=None)
    ev, traj, man, rep = read_scene(tmp_path / "scene")
    assert_events_equal(ev, src.ev)
    assert_traj_equal(traj, src.traj)                    # the CSV's float64 poses, not the file's float32 ones
    assert any("ignored (TRAJECTORY given)" in a for a in rep["assumptions"])
    # a DAVIS346-sized file without calibration gets E-POSE's, reported; a calibration of another size is refused
    rec346 = write_aedat4(tmp_path / "r346.aedat4", src.ev, size=(346, 260))
    import_scene("aedat4", [rec346, csv], tmp_path / "s346", log=None)
    _, _, man, rep = read_scene(tmp_path / "s346")
    assert (man.camera.width, man.camera.height) == (346, 260) and any("DAVIS346" in a for a in rep["assumptions"])
    with pytest.raises(ImportFailure, match=r"camera.json: \(file\): resolution: the calibration is for 173x130, "
                                            r"the sensor of r346.aedat4 is 346x260"):
        import_scene("aedat4", [rec346, csv, src.cam_json], tmp_path / "s2", log=None)


def test_aedat4_without_poses_is_event_only_and_without_events_is_refused(src, tmp_path):
    rec = write_aedat4(tmp_path / "rec.aedat4", src.ev, size=size_of(src))
    res = import_scene("aedat4", [rec], tmp_path / "events_only", camera=str(src.cam_json), log=None)
    assert res["events_only"] and res["n_poses"] == 0 and res["objects"] == []       # issue 26.4
    assert_events_equal(read_scene(tmp_path / "events_only")[0], src.ev)
    bad = tmp_path / "text.aedat4"
    bad.write_text("not an AEDAT4 file\n" * 50)
    with pytest.raises(ImportFailure, match=r"text.aedat4: \(header\): version: .*not an AEDAT 4.0 file"):
        import_scene("aedat4", [bad], tmp_path / "scene", camera=str(src.cam_json), log=None)
    os.mkfifo(tmp_path / "pipe.aedat4")
    with pytest.raises(ImportFailure, match=r"pipe.aedat4: \(file\): SRC: is a FIFO"):
        import_scene("aedat4", [tmp_path / "pipe.aedat4"], tmp_path / "scene", log=None)
    assert not (tmp_path / "scene").exists()
    no_leftovers(tmp_path)


@pytest.mark.parametrize("how", ["stall", "crash", "stall-before-header"])
def test_aedat4_reader_process_stall_or_crash_is_one_error(src, tmp_path, monkeypatch, how):
    """The watchdog of the reading process: dv-processing spinning on a corrupt packet (stall) or dying."""
    from evpose.core.importers import aedat4_reader

    rec = write_aedat4(tmp_path / "rec.aedat4", src.ev, src.traj, size=size_of(src))
    real = aedat4_reader.child_command(rec, True)
    script = tmp_path / "child.py"
    script.write_text(
        "import os, runpy, signal, sys, time\n"
        f"HOW = {how!r}\n"
        "if HOW == 'stall-before-header':\n    time.sleep(60)\n"
        "import evpose.core.importers.aedat4_child as c\n"
        "def hang(out, rec, stream):\n"
        "    out.f.flush()\n"
        "    if HOW == 'crash':\n        os.kill(os.getpid(), signal.SIGSEGV)\n"
        "    time.sleep(60)\n"
        "c._events = hang\n"
        "c.main(sys.argv[1:])\n")
    monkeypatch.setattr(aedat4_reader, "child_command", lambda p, poses: [sys.executable, str(script), *real[-2:]])
    monkeypatch.setattr(aedat4_reader, "STALL_TIMEOUT_S", 1.0)
    # a short start-up allowance only where the start is what stalls: a loaded machine needs seconds to start the
    # child (interpreter, evpose, dv-processing) before it can stall or crash on a packet
    monkeypatch.setattr(aedat4_reader, "START_TIMEOUT_S", 1.5 if how == "stall-before-header" else 30.0)
    want = {"stall": r"rec.aedat4: \(file\): -: dv-processing produced nothing for 1 s",
            "crash": r"rec.aedat4: \(file\): -: dv-processing crashed \(SIGSEGV\)",
            "stall-before-header": r"rec.aedat4: \(file\): -: dv-processing produced nothing for 1.5 s"}[how]
    with pytest.raises(ImportFailure, match=want):
        import_scene("aedat4", [rec], tmp_path / "scene", camera=str(src.cam_json), log=None)
    assert not (tmp_path / "scene").exists()
    no_leftovers(tmp_path)


# ================================================================================================ ROS2 bags
@pytest.mark.parametrize("storage", ["SQLITE3", "MCAP"])
def test_ros2_bag_round_trip(src, tmp_path, storage):
    bag = write_ros2_bag(tmp_path / "rec", src.ev, src.traj, storage=storage, width=src.cam.width,
                         height=src.cam.height)
    before, names = digest([bag]), sorted(p.name for p in bag.iterdir())
    res = import_scene("epose-bag", [bag], tmp_path / "scene", camera=str(src.cam_json), objects=src.objects_arg,
                       log=None)
    assert digest([bag]) == before and sorted(p.name for p in bag.iterdir()) == names   # read-only, nothing added
    ev, traj, man, rep = read_scene(tmp_path / "scene")
    assert_events_equal(ev, src.ev)
    assert_traj_equal(traj, src.traj)
    assert [o.name for o in man.objects] == OBJECT_NAMES and res["n_events"] == len(src.ev)
    assert rep["bag"]["ros_version"] == 2 and not any("slow path" in w for w in rep["warnings"])
    # the bare storage file reads the same
    store = next(bag.glob("*.db3" if storage == "SQLITE3" else "*.mcap"))
    import_scene("epose-bag", [store], tmp_path / "scene2", camera=str(src.cam_json), log=None)
    assert_events_equal(read_scene(tmp_path / "scene2")[0], src.ev)
    no_leftovers(tmp_path)


def test_cdr_codec_matches_rosbags():
    from evpose.core.importers.epose_bag_cdr import (
        dvs_typestore_ros2,
        encode_event_array_cdr,
        encode_pose_stamped_cdr,
        parse_event_array_cdr,
        parse_pose_stamped_cdr,
    )

    ts = dvs_typestore_ros2()
    T = ts.types
    Tm, H = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    rng = np.random.default_rng(4)
    for n, fid in ((0, ""), (1, "x"), (2, "ab"), (3, "abc"), (999, "davis_left_camera"), (5, "é")):
        x, y = rng.integers(0, 65535, n), rng.integers(0, 65535, n)
        sec, nsec, p = rng.integers(0, 2**31 - 1, n), rng.integers(0, 10**9, n), rng.integers(0, 2, n)
        events = [T["dvs_msgs/msg/Event"](x=int(a), y=int(b), ts=Tm(sec=int(s), nanosec=int(ns)), polarity=bool(c))
                  for a, b, s, ns, c in zip(x, y, sec, nsec, p)]
        m = T["dvs_msgs/msg/EventArray"](header=H(stamp=Tm(sec=12, nanosec=345), frame_id=fid), height=260, width=346,
                                         events=events)
        raw = bytes(ts.serialize_cdr(m, "dvs_msgs/msg/EventArray"))
        d = parse_event_array_cdr(raw)
        back = ts.deserialize_cdr(raw, "dvs_msgs/msg/EventArray")
        assert (d["height"], d["width"], d["stamp_us"]) == (back.height, back.width, 12_000_000)
        for k, v in (("x", x), ("y", y), ("sec", sec), ("nsec", nsec), ("p", p)):
            np.testing.assert_array_equal(d[k], v, err_msg=k)
        assert encode_event_array_cdr(x, y, sec.astype(np.int64) * 10**9 + nsec, p, stamp_ns=12 * 10**9 + 345,
                                      frame_id=fid) == raw
        ps = T["geometry_msgs/msg/PoseStamped"](header=H(stamp=Tm(sec=3, nanosec=4), frame_id=fid), pose=T[
            "geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=1.0, y=-2.0, z=3.5), orientation=T[
                "geometry_msgs/msg/Quaternion"](x=0.0, y=0.6, z=0.0, w=0.8)))
        raw = bytes(ts.serialize_cdr(ps, "geometry_msgs/msg/PoseStamped"))
        assert encode_pose_stamped_cdr(3 * 10**9 + 4, [1, -2, 3.5], [0, 0.6, 0, 0.8], frame_id=fid) == raw
        t, v = parse_pose_stamped_cdr(raw)
        assert t == 3_000_000 and v.tolist() == [1, -2, 3.5, 0, 0.6, 0, 0.8]


def test_ros2_unfamiliar_event_definition_is_decoded_by_rosbags(src, tmp_path):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register({**get_types_from_msg("uint16 x\nuint16 y\nbuiltin_interfaces/Time ts\nbool polarity\nuint8 extra\n",
                                      "dvs_msgs/msg/Event"),
                 **get_types_from_msg("std_msgs/Header header\nuint32 height\nuint32 width\nEvent[] events\n",
                                      "dvs_msgs/msg/EventArray")})
    ev = src.ev[np.arange(5000)]
    bag = write_ros2_bag(tmp_path / "rec", ev, src.traj, storage="MCAP", width=src.cam.width,
                         height=src.cam.height, typestore=ts, msg_events=700)
    import_scene("epose-bag", [bag], tmp_path / "scene", camera=str(src.cam_json), log=None)
    got, traj, _, rep = read_scene(tmp_path / "scene")
    assert_events_equal(got, ev)
    assert any("slow path" in w for w in rep["warnings"])


def test_ros2_bag_gets_the_ros1_validation(src, tmp_path):
    ev = src.ev[np.arange(3000)]
    bag = write_ros2_bag(tmp_path / "rec", ev, src.traj, storage="SQLITE3", width=src.cam.width,
                         height=src.cam.height, numpy_encode=True, msg_events=1000)
    with pytest.raises(ImportFailure, match=r"rec: \(topics\): /dvs/ev: no such topic \(topics in the bag: "
                                            r"/dvs/events, /dvs/pose\)"):
        import_scene("epose-bag", [bag], tmp_path / "s", camera=str(src.cam_json), events_topic="/dvs/ev", log=None)
    with pytest.raises(ImportFailure, match=r"connection \d+: /dvs/events: type dvs_msgs/msg/EventArray, expected "
                                            r"geometry_msgs/msg/PoseStamped"):
        import_scene("epose-bag", [bag], tmp_path / "s", camera=str(src.cam_json), pose_topic="/dvs/events", log=None)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ImportFailure, match=r"empty: \(folder\): metadata.yaml: not a ROS2 bag folder"):
        import_scene("epose-bag", [tmp_path / "empty"], tmp_path / "s", log=None)
    assert not (tmp_path / "s").exists()


# ================================================================================================ Prophesee
@pytest.mark.parametrize("version", ["evt2", "evt3", "dat"])
def test_prophesee_round_trip(src, tmp_path, version):
    ev0, traj0 = shifted(src, SENSOR_T0_US)
    rec = write_prophesee(tmp_path / ("rec.dat" if version == "dat" else "rec.raw"), ev0, version=version,
                          size=size_of(src))
    csv = traj0.save_csv(tmp_path / "trajectory.csv")
    before = digest([rec, csv, src.cam_json])
    res = import_scene("prophesee", [rec, csv, src.cam_json], tmp_path / "scene", objects=src.objects_arg, log=None)
    assert digest([rec, csv, src.cam_json]) == before
    ev, traj, man, rep = read_scene(tmp_path / "scene")
    assert_events_equal(ev, ev0)
    assert_traj_equal(traj, traj0)
    assert [o.name for o in man.objects] == OBJECT_NAMES and res["n_events"] == len(ev0)
    assert rep["prophesee"]["sensor"] == list(size_of(src))
    assert rep["prophesee"]["version"] == {"evt2": "evt2", "evt3": "evt3", "dat": "dat2"}[version]
    no_leftovers(tmp_path)


@pytest.mark.parametrize("version,wrap", [("evt3", 1 << 24), ("evt2", 1 << 34), ("dat", 1 << 32)])
def test_prophesee_time_counter_wraps(src, tmp_path, version, wrap):
    """EVT 3.0 counts 24 bits of µs (16.8 s), EVT 2.0 34 bits (4.77 h), DAT 32 bits (71.6 min): times across
    the wrap come back as written."""
    span = int(src.ev.t[-1] - src.ev.t[0])
    ev, traj = shifted(src, wrap - span // 2)
    assert int(ev.t[0]) < wrap <= int(ev.t[-1])
    rec = write_prophesee(tmp_path / ("w.dat" if version == "dat" else "w.raw"), ev, version=version, size=size_of(src))
    csv = traj.save_csv(tmp_path / "trajectory.csv")
    import_scene("prophesee", [rec, csv, src.cam_json], tmp_path / "scene", log=None)
    got, got_traj, _, _ = read_scene(tmp_path / "scene")
    assert_events_equal(got, ev)
    assert_traj_equal(got_traj, traj)


def test_prophesee_sensor_size_from_the_header(src, tmp_path):
    ev0, traj0 = shifted(src, SENSOR_T0_US)
    rec = write_prophesee(tmp_path / "rec.raw", ev0, version="evt3", size=size_of(src))
    csv = traj0.save_csv(tmp_path / "trajectory.csv")
    # the header's size decides the camera: a calibration for another size is refused
    other = tmp_path / "cam346.json"
    other.write_text(json.dumps({**src.cam.to_dict(), "width": 346, "height": 260}))
    with pytest.raises(ImportFailure, match=r"cam346.json: \(file\): resolution: the calibration is for 346x260, the "
                                            r"sensor of rec.raw is 173x130"):
        import_scene("prophesee", [rec, csv, other], tmp_path / "s", log=None)
    # a header without the size needs --width/--height
    data = rec.read_bytes()
    lines = data.split(b"\n")
    keep = [ln for ln in lines[:3] if ln.startswith(b"% evt")]
    nohdr = tmp_path / "nosize.raw"
    nohdr.write_bytes(b"\n".join(keep) + b"\n" + data[sum(len(ln) + 1 for ln in lines[:3]):])
    with pytest.raises(ImportFailure, match=r"nosize.raw: \(header\): geometry: .*sensor size.*: pass --width and "
                                            r"--height"):
        import_scene("prophesee", [nohdr, csv, src.cam_json], tmp_path / "s", log=None)
    import_scene("prophesee", [nohdr, csv, src.cam_json], tmp_path / "s", width=173, height=130, log=None)
    assert_events_equal(read_scene(tmp_path / "s")[0], ev0)
    # ... unless it names the sensor (2017-2020 Metavision headers): Gen3.1 -> 640 x 480, said in the report
    named = tmp_path / "gen31.raw"
    named.write_bytes(b"\n".join(keep) + b"\n% plugin_name hal_plugin_gen31_fx3\n"
                      + data[sum(len(ln) + 1 for ln in lines[:3]):])
    vga = tmp_path / "cam640.json"
    vga.write_text(json.dumps({**src.cam.to_dict(), "width": 640, "height": 480}))
    res = import_scene("prophesee", [named, csv, vga], tmp_path / "s5", log=None)
    assert any("sensor 640x480 px from the header's '% plugin_name hal_plugin_gen31_fx3'" in a
               for a in res["assumptions"]), res["assumptions"]
    assert_events_equal(read_scene(tmp_path / "s5")[0], ev0)
    # a cut-off last word is a warning; without a trajectory the scene is event-only (issue 26.4)
    cut = tmp_path / "cut.raw"
    cut.write_bytes(data[:-1])
    res = import_scene("prophesee", [cut, csv, src.cam_json], tmp_path / "s3", log=None)
    assert any("not a whole 2-byte EVT3 word" in w for w in res["warnings"])
    res = import_scene("prophesee", [rec], tmp_path / "s4", camera=str(src.cam_json), log=None)
    assert res["events_only"] and not load_manifest(tmp_path / "s4").has_trajectory


def test_evt3_time_low_stepping_back_is_kept_as_written_and_counted(src, tmp_path):
    """Issue 26.1: a TIME_LOW 3 µs below the one before it, within the same TIME_HIGH (as on a real Gen4.1
    recording), gives its event that time (OpenEB's reading; faery clamped it): the event is put in order and the
    report counts the backward step."""
    from evpose.core.importers.prophesee_header import read_text_header

    ev0, traj0 = shifted(src, SENSOR_T0_US)
    rec = write_prophesee(tmp_path / "rec.raw", ev0, version="evt3", size=size_of(src))
    n_head = read_text_header(rec)[0]
    data = rec.read_bytes()
    words = np.frombuffer(data[n_head:], "<u2").copy()
    kind = words >> 12
    # a TIME_LOW whose next word is an ADDR_X, late enough that the low bits can step back 3 µs
    i = next(int(k) for k in np.flatnonzero(kind == 0x6)[len(words) // 4:]
             if kind[k + 1] == 0x2 and (words[k] & 0xFFF) >= 3)
    low = int(words[i] & 0xFFF)
    extra = np.array([0x6000 | (low - 3), words[i + 1], 0x6000 | low], "<u2")    # back 3 us: one more event
    bad = tmp_path / "back.raw"
    bad.write_bytes(data[:n_head] + np.concatenate([words[:i + 2], extra, words[i + 2:]]).tobytes())
    csv = traj0.save_csv(tmp_path / "trajectory.csv")
    res = import_scene("prophesee", [bad, csv, src.cam_json], tmp_path / "s", log=None)
    report = json.loads((tmp_path / "s" / "import_report.json").read_text())
    assert report["counts"]["evt3_time_low_back"] == 1, report["counts"]
    assert any("TIME_LOW word(s) step back" in a for a in report["assumptions"])
    # the added event: the one after the TIME_LOW repeated 3 us earlier, as written
    from evpose.core.importers.evt3_words import Evt3Words

    x, y, t, p = Evt3Words().decode(words[:i + 2])
    got = read_scene(tmp_path / "s")[0]
    assert len(got.t) == len(ev0.t) + 1 and np.all(np.diff(got.t) >= 0)
    at = (got.t == t[-1] - 3) & (got.x == x[-1]) & (got.y == y[-1]) & (got.p == p[-1])
    assert at.sum() == 1 + int(np.count_nonzero((ev0.t == t[-1] - 3) & (ev0.x == x[-1]) & (ev0.y == y[-1])
                                                 & (ev0.p == p[-1])))


def test_cli_new_formats_json_and_one_error_line(src, tmp_path, capsys):
    from evpose.app.cli.importers import FORMAT_NAMES
    from evpose.core.importers import FORMATS

    assert {"aedat4", "prophesee"} <= set(FORMAT_NAMES) and list(FORMAT_NAMES) == list(FORMATS)
    ev0, traj0 = shifted(src, SENSOR_T0_US)
    rec = write_prophesee(tmp_path / "rec.raw", ev0, version="evt3", size=size_of(src))
    csv = traj0.save_csv(tmp_path / "trajectory.csv")
    args = cli_parser().parse_args(["import", "prophesee", str(rec), str(csv), str(src.cam_json), "--out",
                                 str(tmp_path / "scene"), "--json", "-q"])
    assert args.func(args) == 0
    assert json.loads(capsys.readouterr().out)["n_events"] == len(src.ev)
    bad = tmp_path / "bad.raw"
    bad.write_bytes(rec.read_bytes()[:200] + bytes(range(256)) * 8)
    args = cli_parser().parse_args(["import", "prophesee", str(bad), str(csv), str(src.cam_json), "--out",
                                 str(tmp_path / "s2"), "-q"])
    assert args.func(args) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    # random bytes after the header decode to words (EVT 3.0 has no check sum): the first event off the sensor is
    # refused in one line naming the file, the event and the field
    assert len(err) == 1 and "bad.raw: event" in err[0] and "outside the" in err[0] and "Traceback" not in err[0], err
    assert not (tmp_path / "s2").exists()
    shutil.rmtree(tmp_path / "scene")
