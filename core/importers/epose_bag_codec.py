"""ROS1 byte layout of the two E-POSE message types, decoded and encoded with numpy (no Python loop per event).

``dvs_msgs/EventArray`` (little endian, no padding)::

    uint32 seq | uint32 stamp.sec | uint32 stamp.nsec | uint32 len | frame_id bytes
    uint32 height | uint32 width | uint32 n | n x {uint16 x, uint16 y, uint32 sec, uint32 nsec, uint8 polarity}

and ``geometry_msgs/PoseStamped`` (header, then 7 float64: position x y z, orientation x y z w). An
``EventArray`` costs a few vectorised numpy operations instead of one Python object per event (rosbags' own
deserialiser; the test suite checks both agree and that the encoders write rosbags' bytes).
"""
from __future__ import annotations

import numpy as np

from evpose.core.importers.time_units import ros_time_to_us

EVENT_MSG = "uint16 x\nuint16 y\ntime ts\nbool polarity\n"
EVENT_ARRAY_MSG = "Header header\nuint32 height\nuint32 width\nEvent[] events\n"
EVENT_ARRAY_TYPE = "dvs_msgs/msg/EventArray"
EVENT_ARRAY_MD5 = "5e8beee5a6c107e504c2e78903c224b8"
POSE_STAMPED_TYPE = "geometry_msgs/msg/PoseStamped"
#: One ``dvs_msgs/Event`` in ROS1 serialisation (13 bytes, no padding).
EVENT_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<u4"), ("nsec", "<u4"), ("p", "u1")])


class MessageError(ValueError):
    """A malformed message payload; ``field`` names the part of the message at fault."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(message)



def dvs_typestore(store: str = "ROS1_NOETIC", event_msg: str | None = None, array_msg: str | None = None):
    """A rosbags typestore (``store``: a name of ``rosbags.typesys.Stores``; default ROS1 Noetic) with
    ``dvs_msgs/msg/Event`` and ``dvs_msgs/msg/EventArray`` registered from their .msg text (default the ROS1
    definitions)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(getattr(Stores, store))
    types = {}
    types.update(get_types_from_msg(event_msg or EVENT_MSG, "dvs_msgs/msg/Event"))
    types.update(get_types_from_msg(array_msg or EVENT_ARRAY_MSG, EVENT_ARRAY_TYPE))
    ts.register(types)
    return ts


def _header(buf: memoryview, what: str) -> tuple[int, int, int, int]:
    """(seq, sec, nsec, offset after the header) of a ROS1 std_msgs/Header at the start of ``buf``."""
    if len(buf) < 16:
        raise MessageError("header", f"{what}: {len(buf)} bytes, too short for a header")
    seq, sec, nsec, n = np.frombuffer(buf, "<u4", count=4)
    off = 16 + int(n)
    if off > len(buf):
        raise MessageError("header.frame_id", f"{what}: frame_id length {int(n)} runs past the end of the message "
                          f"({len(buf)} bytes)")
    return int(seq), int(sec), int(nsec), off


def parse_event_array(raw) -> dict:
    """Decode one ROS1 ``dvs_msgs/EventArray`` payload without a Python loop per event.

    Returns
    -------
    dict with ``height``, ``width`` (int), ``stamp_us`` (header stamp, µs), and numpy arrays ``x``, ``y``
    (uint16), ``sec``, ``nsec`` (uint32), ``p`` (uint8) -- views into ``raw`` (copy before ``raw`` goes away).
    Raises ``ValueError`` with a ``field`` attribute on a malformed payload.
    """
    buf = memoryview(raw)
    _, hs, hn, off = _header(buf, "EventArray")
    if off + 12 > len(buf):
        raise MessageError("height/width/events", f"message ends after {len(buf)} bytes, inside height/width/count")
    height, width, n = (int(v) for v in np.frombuffer(buf, "<u4", count=3, offset=off))
    off += 12
    need = off + n * EVENT_DTYPE.itemsize
    if need != len(buf):
        raise MessageError("events", f"{n} events need {need} bytes, the message has {len(buf)}")
    ev = np.frombuffer(buf, EVENT_DTYPE, count=n, offset=off)
    return {"height": height, "width": width, "stamp_us": int(ros_time_to_us(hs, hn)),
            "x": ev["x"], "y": ev["y"], "sec": ev["sec"], "nsec": ev["nsec"], "p": ev["p"]}


def encode_event_array(x, y, t_ns, p, *, seq: int = 0, stamp_ns: int = 0, frame_id: str = "", height: int = 260,
                       width: int = 346) -> bytes:
    """ROS1 bytes of a ``dvs_msgs/EventArray`` (for tests, benchmarks and converters); ``t_ns`` int ns."""
    t_ns = np.asarray(t_ns, np.int64)
    n = len(t_ns)
    fid = frame_id.encode()
    head = np.array([seq, stamp_ns // 10**9, stamp_ns % 10**9, len(fid)], "<u4").tobytes() + fid
    rec = np.empty(n, EVENT_DTYPE)
    rec["x"], rec["y"], rec["p"] = x, y, np.asarray(p).astype(np.uint8)
    rec["sec"], rec["nsec"] = t_ns // 10**9, t_ns % 10**9
    return head + np.array([height, width, n], "<u4").tobytes() + rec.tobytes()


def parse_pose_stamped(raw) -> tuple[int, np.ndarray]:
    """Decode ROS1 ``geometry_msgs/PoseStamped`` -> (header stamp µs, [px, py, pz, qx, qy, qz, qw])."""
    buf = memoryview(raw)
    _, hs, hn, off = _header(buf, "PoseStamped")
    if off + 56 != len(buf):
        raise MessageError("pose", f"expected {off + 56} bytes (header + 7 float64), the message has {len(buf)}")
    return int(ros_time_to_us(hs, hn)), np.frombuffer(buf, "<f8", count=7, offset=off).copy()


def encode_pose_stamped(stamp_ns: int, position, quat_xyzw, *, seq: int = 0, frame_id: str = "base") -> bytes:
    fid = frame_id.encode()
    return (np.array([seq, stamp_ns // 10**9, stamp_ns % 10**9, len(fid)], "<u4").tobytes() + fid
            + np.asarray([*position, *quat_xyzw], "<f8").tobytes())

