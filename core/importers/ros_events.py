"""ROS bags of today's event-camera drivers: ``event_camera_msgs/EventPacket`` (``evpose import ros-events
BAG [TRAJECTORY [CALIB]]``; issue 26.2; without a TRAJECTORY an event-only scene, issue 26.4).

The ROS1 and ROS2 drivers of Prophesee and iniVation cameras (``metavision_driver``, ``libcaer_driver``) publish
packets of encoded events::

    std_msgs/Header header   uint32 height   uint32 width   uint64 seq   uint64 time_base
    string encoding          bool is_bigendian              uint8[] events

(``event_camera_msgs``; decoded as ``ros-event-camera/event_camera_codecs`` does). Supported encodings:

* ``evt3``: Prophesee EVT 3.0 words (:class:`~evpose.core.importers.evt3_words.Evt3Words`, one decoder per topic: the
  time words carry over from packet to packet); times are the sensor's µs (``time_base`` is 0);
* ``mono``: 8-byte little-endian words, ``t = time_base + bits 0-31`` (ns), x bits 32-47, y bits 48-62, polarity
  bit 63; times taken to µs (floor).

Any other encoding (e.g. ``libcaer_cmp``, compressed) is refused in one line naming it. The events topic is the one
topic of that type (``--events-topic`` picks one when there are several; the refusal lists them). The sensor size is
the packets' ``width`` x ``height``.

Clock: the events are on the sensor's clock and the trajectory on the robot's (ROS time). The clock prior is the
first packet's ``header.stamp`` minus its first event's time (the driver stamps a packet when it has it, so the prior
is late by the packet's latency, typically a few ms: ``evpose sync`` estimates the rest); ``--offset-us`` overrides.

Bags: a ROS1 ``.bag``, a ROS2 bag folder (sqlite3 or MCAP) read through rosbags. A ROS2 folder whose
``metadata.yaml`` names no storage (``storage_identifier: ""``, as ``event_camera_py``'s test bag; rosbags refuses it
with "Storage plugin '' not supported") is read with the storage its file's suffix names, from a copy of the metadata
in a temporary folder (removed after). A bare ``.mcap`` file is refused: its schemas are IDL text, which rosbags
cannot parse; give the bag folder.
"""
from __future__ import annotations

import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from evpose.core.importers.evt3_words import Evt3Words
from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.object_args import collect_objects
from evpose.core.importers.pose_text import read_pose_text
from evpose.core.importers.recording import build_recording_scene, recording_camera
from evpose.core.importers.report import ImportContext
from evpose.core.importers.scene_builder import events_only

__all__ = ["EVENT_PACKET_TYPE", "EVENT_PACKET_MSG", "import_ros_events", "decode_mono"]

EVENT_PACKET_TYPE = "event_camera_msgs/msg/EventPacket"
#: The message definition (event_camera_msgs, ROS2; the ROS1 one is the same with ``Header``).
EVENT_PACKET_MSG = """std_msgs/Header header
uint32 height
uint32 width
uint64 seq
uint64 time_base
string encoding
bool is_bigendian
uint8[] events
"""
ENCODINGS = ("evt3", "mono")
_STORAGE_BY_SUFFIX = {".mcap": "mcap", ".db3": "sqlite3"}


def decode_mono(data: np.ndarray, time_base_ns: int):
    """``(x, y, t_us, p)`` of a ``mono`` packet's bytes (uint8, little-endian 8-byte words)."""
    w = np.frombuffer(np.ascontiguousarray(data, np.uint8).tobytes(), "<u8")
    t_ns = np.uint64(time_base_ns) + (w & np.uint64(0xFFFFFFFF))
    return ((w >> np.uint64(32)) & np.uint64(0xFFFF)).astype(np.uint16), \
        ((w >> np.uint64(48)) & np.uint64(0x7FFF)).astype(np.uint16), (t_ns // np.uint64(1000)).astype(np.int64), \
        (w >> np.uint64(63)).astype(np.uint8)


def _check_bag(bag: Path) -> None:
    if bag.suffix.lower() == ".mcap" and bag.is_file():
        raise ImportFailure(bag, "(file)", "SRC", "a bare .mcap file: its schemas are IDL text that rosbags cannot "
                            "parse; give the bag folder (with its metadata.yaml)")
    if not (bag.is_dir() or (bag.is_file() and bag.suffix.lower() == ".bag")):
        raise ImportFailure(bag, "(file)", "SRC", "not a ROS bag (a ROS1 .bag file or a ROS2 bag folder)")


@contextmanager
def _readable_folder(bag: Path):
    """``bag``, or a temporary folder whose ``metadata.yaml`` names the storage its files' suffix implies when the
    bag's names none (see the module docstring); removed on exit."""
    meta = bag / "metadata.yaml" if bag.is_dir() else None
    if meta is None or not meta.is_file():
        yield bag, None
        return
    import yaml

    with wrap_errors(bag, "metadata.yaml", "-", "cannot read"):
        doc = yaml.safe_load(meta.read_text())
    info = (doc or {}).get("rosbag2_bagfile_information") or {}
    if info.get("storage_identifier"):
        yield bag, None
        return
    files = [bag / f for f in info.get("relative_file_paths") or []]
    kinds = {_STORAGE_BY_SUFFIX.get(f.suffix.lower()) for f in files}
    if len(kinds) != 1 or None in kinds:
        raise ImportFailure(meta, "rosbag2_bagfile_information", "storage_identifier", "empty, and the files' "
                            f"suffixes ({', '.join(f.name for f in files) or 'none'}) name no one storage")
    kind = kinds.pop()
    tmp = Path(tempfile.mkdtemp(prefix=".evpose-bag-"))
    try:
        info["storage_identifier"] = kind
        (tmp / "metadata.yaml").write_text(yaml.safe_dump(doc))
        for f in files:
            (tmp / f.name).symlink_to(f.resolve())
        yield tmp, f"{meta.name} names no storage; read as {kind} (its file suffix)"
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _typestore():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(EVENT_PACKET_MSG, EVENT_PACKET_TYPE))
    return ts


def _events_topic(reader, bag: Path, ctx: ImportContext) -> str:
    cands = sorted({c.topic for c in reader.connections if c.msgtype == EVENT_PACKET_TYPE})
    want = getattr(ctx.options, "events_topic", None)
    if want and want != "/dvs/events":                  # (the E-POSE importer's default is not asked for here)
        if want not in cands:
            raise ImportFailure(bag, "(topics)", want, f"no {EVENT_PACKET_TYPE} topic of that name (such topics: "
                                f"{', '.join(cands) or 'none'})")
        return want
    if len(cands) == 1:
        return cands[0]
    listing = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
    if not cands:
        raise ImportFailure(bag, "(topics)", "-", f"no {EVENT_PACKET_TYPE} topic (topics: {listing})")
    raise ImportFailure(bag, "(topics)", "--events-topic", f"several event topics, pick one: {', '.join(cands)}")


def import_ros_events(sources, out, ctx: ImportContext) -> dict:
    """Import the event packets of a ROS bag (+ trajectory, calibration); returns the summary."""
    srcs = [Path(s) for s in sources]
    if not 1 <= len(srcs) <= 3:
        raise ImportFailure(", ".join(map(str, srcs)) or "(none)", "(arguments)", "SRC",
                            "ros-events: give BAG [TRAJECTORY [CALIB]] (the drivers' bags hold no poses)")
    bag, traj_file, calib = srcs[0], (srcs[1] if len(srcs) > 1 else None), (srcs[2] if len(srcs) > 2 else None)
    _check_bag(bag)
    objects = collect_objects(ctx, None)
    traj = None
    if traj_file is None:             # the drivers' bags hold no poses: an event-only scene
        events_only(ctx, bag, objects)
    else:
        traj = read_pose_text(traj_file, ctx)
        ctx.report.assume(f"{traj_file.name}: poses are T_base_cam (camera in the base frame, metres)")
    from rosbags.highlevel import AnyReader

    ts = _typestore()
    with _readable_folder(bag) as (path, note), \
            wrap_errors(bag, "(bag)", "-", "cannot read the bag"):
        if note:
            ctx.report.assume(note)
        reader_cls = None
        if path is not bag:
            from rosbags.rosbag2 import Reader as reader_cls
        with (reader_cls(path) if reader_cls else AnyReader([path], default_typestore=ts)) as reader:
            topic = _events_topic(reader, bag, ctx)
            conns = [c for c in reader.connections if c.topic == topic]
            first = _first_packet(reader, conns, ts, reader_cls is None, bag)
            size = (int(first.width), int(first.height))
            camera = recording_camera(ctx, calib, size, bag)
            state = {"prior": None}
            chunks = _chunks(reader, conns, ts, reader_cls is None, bag, topic, ctx, state)
            return build_recording_scene(ctx, out, bag, camera, chunks, lambda: traj, objects,
                                         clock_offset_us=lambda: state["prior"] or 0)


def _deserialize(reader, raw, conn, ts, any_reader: bool):
    return reader.deserialize(raw, conn.msgtype) if any_reader else ts.deserialize_cdr(raw, conn.msgtype)


def _first_packet(reader, conns, ts, any_reader, bag: Path):
    for conn, _, raw in reader.messages(connections=conns):
        return _deserialize(reader, raw, conn, ts, any_reader)
    raise ImportFailure(bag, "(topics)", conns[0].topic, "the topic has no messages")


def _chunks(reader, conns, ts, any_reader, bag: Path, topic: str, ctx: ImportContext, state: dict):
    """``(x, y, t_us, p, record, fraction)`` per packet; sets ``state["prior"]`` (stamp minus first event, µs)."""
    total = max(sum(c.msgcount for c in conns), 1)
    evt3 = Evt3Words()
    for k, (conn, _, raw) in enumerate(reader.messages(connections=conns)):
        rec = f"message {k} on {topic}"
        with wrap_errors(bag, rec, "-", "cannot decode"):
            m = _deserialize(reader, raw, conn, ts, any_reader)
        if m.encoding not in ENCODINGS:
            raise ImportFailure(bag, rec, "encoding", f"{m.encoding!r} is not supported (supported: "
                                f"{', '.join(ENCODINGS)})")
        if m.is_bigendian:
            raise ImportFailure(bag, rec, "is_bigendian", "big-endian packets are not supported")
        data = np.asarray(m.events, np.uint8)
        if m.encoding == "evt3":
            x, y, t, p = evt3.decode(np.frombuffer(data.tobytes()[: len(data) // 2 * 2], "<u2"))
        else:
            x, y, t, p = decode_mono(data[: len(data) // 8 * 8], int(m.time_base))
        if state["prior"] is None and len(t):
            stamp_us = int(m.header.stamp.sec) * 1_000_000 + int(m.header.stamp.nanosec) // 1000
            state["prior"] = stamp_us - int(t[0])
            ctx.report.assume(f"{topic}: clock prior {state['prior']} µs = the first packet's header.stamp minus its "
                              "first event's sensor time (late by the packet's latency; evpose sync estimates it)")
        yield x, y, t, p, rec, (k + 1) / total
    if evt3.n_triggers:
        ctx.report.assume(f"{topic}: {evt3.n_triggers} external trigger event(s) ignored")
    if evt3.n_time_low_back:
        ctx.report.counts["evt3_time_low_back"] = evt3.n_time_low_back
    if evt3.n_unknown:
        ctx.report.warn(f"{topic}: {evt3.n_unknown} EVT 3.0 word(s) of unknown type skipped")
