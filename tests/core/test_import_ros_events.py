"""ROS bags of event_camera_msgs/EventPacket (evpose import ros-events, issue 26.2): ROS2 sqlite3 and MCAP bags
written here with ``evt3`` packets (hand-built words: the events known exactly, the time words split across packets)
and ``mono`` packets; a metadata.yaml without a storage name; the topic picked or asked for in one line; an
unsupported encoding and a bare .mcap refused in one line; the clock prior from the first stamp. With
``EVPOSE_EVENT_CAMERA_PY_TESTS`` pointing at ``ros-event-camera/event_camera_py``'s ``tests`` folder, its real bags
(a Prophesee camera, ROS1 and ROS2) give exactly the counts and the time sum its own test expects from the C++ codec."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from evpose.core.importers import import_scene
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.ros_events import EVENT_PACKET_MSG, EVENT_PACKET_TYPE

pytest.importorskip("rosbags")

STAMP0_NS = 1_700_000_000_000_000_000        # the first packet's header.stamp (ROS time)


def _typestore():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(EVENT_PACKET_MSG, EVENT_PACKET_TYPE))
    return ts


def _evt3_packets():
    """Packets of EVT 3.0 words and their events (x, y, t_us, p): a row of events every 100 µs for 0.5 s, the time
    words at each 4096 µs boundary in their own packet now and then (the decoder's state carries over)."""
    words, events = [], []
    high = -1
    for k in range(5000):
        t = 1_000_000 + 100 * k
        if t >> 12 != high:
            high = t >> 12
            words.append(0x8000 | (high & 0xFFF))
        words += [0x6000 | (t & 0xFFF), 0x0000 | (k % 100)]
        x = (7 * k) % 320
        words.append(0x2000 | ((k % 2) << 11) | x)
        events.append((x, k % 100, t, k % 2))
    cuts = list(range(0, len(words), 37)) + [len(words)]
    packets = [np.array(words[a:b], "<u2").tobytes() for a, b in zip(cuts[:-1], cuts[1:])]
    return packets, np.array(events, np.int64)


def _mono_packets(events, per=500):
    """``mono`` packets of ``events`` (x, y, t_us, p): time_base (ns) the first event's, words ``t - base`` ns."""
    out = []
    for i in range(0, len(events), per):
        e = events[i:i + per]
        base = int(e[0, 2]) * 1000
        w = ((e[:, 2] * 1000 - base).astype(np.uint64) | (e[:, 0].astype(np.uint64) << np.uint64(32))
             | (e[:, 1].astype(np.uint64) << np.uint64(48)) | (e[:, 3].astype(np.uint64) << np.uint64(63)))
        out.append((base, w.astype("<u8").tobytes()))
    return out


def _write_bag(path: Path, packets, *, encoding: str, storage: str = "SQLITE3", topic="/event_camera/events",
               extra_topic=None):
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = _typestore()
    T = ts.types
    with Writer(path, version=9, storage_plugin=StoragePlugin[storage]) as w:
        conns = [w.add_connection(t, EVENT_PACKET_TYPE, typestore=ts) for t in [topic] + ([extra_topic] if extra_topic
                                                                                          else [])]
        for k, pk in enumerate(packets):
            base, data = pk if isinstance(pk, tuple) else (0, pk)
            tn = STAMP0_NS + 1_000_000 * k
            m = T[EVENT_PACKET_TYPE](header=T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](sec=tn // 10**9, nanosec=tn % 10**9), frame_id="cam"),
                height=480, width=640, seq=k, time_base=base, encoding=encoding, is_bigendian=False,
                events=np.frombuffer(data, np.uint8))
            for c in conns:
                w.write(c, tn, bytes(ts.serialize_cdr(m, EVENT_PACKET_TYPE)))
    return path


@pytest.fixture
def traj_and_cam(tmp_path):
    """A static camera pose at 100 Hz over the packets' ROS time, and a 640x480 calibration."""
    t0 = STAMP0_NS // 1000 - 2_000_000
    lines = ["t_us,x,y,z,qx,qy,qz,qw"] + [f"{t0 + 10_000 * k},0,0,0.5,0,0,0,1" for k in range(600)]
    (tmp_path / "traj.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "cam.json").write_text(json.dumps({"width": 640, "height": 480, "K": [[500, 0, 320], [0, 500, 240],
                                                                                        [0, 0, 1]], "dist": [0] * 5}))
    return tmp_path / "traj.csv", tmp_path / "cam.json"


def _events(scene: Path) -> np.ndarray:
    from evpose.core.data.scene import Scene

    s = Scene.open(scene)
    try:
        ev = s.events.read(0, s.events.n_events)
        return np.stack([ev.x, ev.y, ev.t, ev.p], axis=1).astype(np.int64)
    finally:
        s.close()


@pytest.mark.parametrize("storage", ["SQLITE3", "MCAP"])
def test_evt3_packets_import_exactly_with_the_clock_prior_from_the_first_stamp(tmp_path, traj_and_cam, storage):
    traj, cam = traj_and_cam
    packets, want = _evt3_packets()
    bag = _write_bag(tmp_path / "bag", packets, encoding="evt3", storage=storage)
    import_scene("ros-events", [bag, traj, cam], tmp_path / "s", log=None)
    np.testing.assert_array_equal(_events(tmp_path / "s"), want)
    manifest = (tmp_path / "s" / "scene.toml").read_text()
    assert f"offset_us = {STAMP0_NS // 1000 - int(want[0, 2])}" in manifest
    report = json.loads((tmp_path / "s" / "import_report.json").read_text())
    assert any("clock prior" in a and "header.stamp" in a for a in report["assumptions"])


def test_a_bag_alone_makes_an_event_only_scene_with_the_clock_prior(tmp_path, traj_and_cam):
    """Issue 26.4: the drivers' bags hold no poses; without a TRAJECTORY the scene is event-only (calibration by
    --camera), its events exact and its clock prior already there for the trajectory added later."""
    _, cam = traj_and_cam
    packets, want = _evt3_packets()
    bag = _write_bag(tmp_path / "bag", packets, encoding="evt3")
    res = import_scene("ros-events", [bag], tmp_path / "s", camera=str(cam), log=None)
    assert res["events_only"] and res["n_poses"] == 0
    np.testing.assert_array_equal(_events(tmp_path / "s"), want)
    manifest = (tmp_path / "s" / "scene.toml").read_text()
    assert "[trajectory]" not in manifest and f"offset_us = {STAMP0_NS // 1000 - int(want[0, 2])}" in manifest


def test_mono_packets_and_a_metadata_without_storage(tmp_path, traj_and_cam):
    """``mono`` packets (libcaer_driver); the bag's metadata.yaml names no storage (as event_camera_py's MCAP test
    bag: rosbags refused it with "Storage plugin '' not supported"): read by the file suffix, nothing left behind."""
    import tempfile

    traj, cam = traj_and_cam
    _, want = _evt3_packets()
    bag = _write_bag(tmp_path / "bag", _mono_packets(want), encoding="mono", storage="MCAP")
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("storage_identifier: mcap", 'storage_identifier: ""'))
    before = set(Path(tempfile.gettempdir()).glob(".evpose-bag-*"))
    inputs = {p: p.read_bytes() for p in bag.iterdir()}
    import_scene("ros-events", [bag, traj, cam], tmp_path / "s", log=None)
    # the temporary folder held links to the bag's files: removing it left every input as it was
    assert {p: p.read_bytes() for p in bag.iterdir()} == inputs
    np.testing.assert_array_equal(_events(tmp_path / "s"), want)
    assert set(Path(tempfile.gettempdir()).glob(".evpose-bag-*")) == before
    report = json.loads((tmp_path / "s" / "import_report.json").read_text())
    assert any("names no storage; read as mcap" in a for a in report["assumptions"])


def test_refusals_are_one_line(tmp_path, traj_and_cam):
    traj, cam = traj_and_cam
    packets, _ = _evt3_packets()
    two = _write_bag(tmp_path / "two", packets[:5], encoding="evt3", extra_topic="/other/events")
    with pytest.raises(ImportFailure, match=r"--events-topic: several event topics, pick one: /event_camera/events, "
                                            r"/other/events"):
        import_scene("ros-events", [two, traj, cam], tmp_path / "s1", log=None)
    import_scene("ros-events", [two, traj, cam], tmp_path / "s2", events_topic="/other/events", log=None)
    cmp_bag = _write_bag(tmp_path / "cmp", packets[:5], encoding="libcaer_cmp")
    with pytest.raises(ImportFailure, match=r"message 0 on /event_camera/events: encoding: 'libcaer_cmp' is not "
                                            r"supported \(supported: evt3, mono\)"):
        import_scene("ros-events", [cmp_bag, traj, cam], tmp_path / "s3", log=None)
    mcap = tmp_path / "bare.mcap"
    mcap.write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(ImportFailure, match=r"bare.mcap: \(file\): SRC: a bare .mcap file"):
        import_scene("ros-events", [mcap, traj, cam], tmp_path / "s4", log=None)
    with pytest.raises(ImportFailure, match=r"give BAG \[TRAJECTORY \[CALIB\]\]"):
        import_scene("ros-events", [two, traj, cam, cam], tmp_path / "s5", log=None)
    assert not any((tmp_path / f"s{k}").exists() for k in (1, 3, 4, 5))


SAMPLES = os.environ.get("EVPOSE_EVENT_CAMERA_PY_TESTS")


@pytest.mark.skipif(not SAMPLES, reason="EVPOSE_EVENT_CAMERA_PY_TESTS (event_camera_py's tests folder) not set")
@pytest.mark.parametrize("bag", ["test_events_1.bag", "test_events_1"], ids=["ros1", "ros2-sqlite3"])
def test_real_driver_bags_match_the_codecs_counts(tmp_path, bag):
    """event_camera_py's test (C++ event_camera_codecs): 218 291 OFF and 125 183 ON events. Its expected time sum,
    2 885 601 049 874, includes the 4 157 trigger events the scene leaves out; with their times (33 999 437 880 µs,
    summed once from the same words) it is met exactly, so the CD times are pinned at the difference."""
    src = Path(SAMPLES) / bag
    lines = ["t_us,x,y,z,qx,qy,qz,qw"] + [f"{1675956545_000_000 + 10_000 * k},0,0,0.5,0,0,0,1" for k in range(2000)]
    (tmp_path / "traj.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "cam.json").write_text(json.dumps({"width": 640, "height": 480, "K": [[500, 0, 320], [0, 500, 240],
                                                                                        [0, 0, 1]], "dist": [0] * 5}))
    import_scene("ros-events", [src, tmp_path / "traj.csv", tmp_path / "cam.json"], tmp_path / "s", log=None)
    ev = _events(tmp_path / "s")
    assert (int(np.count_nonzero(ev[:, 3] == 0)), int(np.count_nonzero(ev[:, 3] == 1))) == (218_291, 125_183)
    assert int(ev[:, 2].sum()) == 2_885_601_049_874 - 33_999_437_880
