"""ROS2 (CDR, little endian) byte layout of the two E-POSE message types, decoded and encoded with numpy.

A ROS2 bag stores each message as a 4-byte encapsulation header (``00 01 00 00`` = CDR little endian) and the
CDR payload, whose fields are aligned to their size counted from the payload start. ``dvs_msgs/EventArray``::

    int32 stamp.sec | uint32 stamp.nanosec | uint32 len | frame_id bytes (NUL included)
    (align 4) uint32 height | uint32 width | uint32 n
    event 0:      uint16 x | uint16 y | int32 ts.sec | uint32 ts.nanosec | uint8 polarity
    event k >= 1: (1 pad) uint16 x | uint16 y | (2 pad) int32 ts.sec | uint32 ts.nanosec | uint8 polarity

so every event after the first takes 16 bytes and the message ends right after the last polarity byte.
``geometry_msgs/PoseStamped`` is the header, then (align 8) 7 float64: position x y z, orientation x y z w.

Like :mod:`evpose.core.importers.epose_bag_codec` (ROS1), this costs a few vectorised numpy operations per
message instead of one Python object per event (rosbags' own ``deserialize_cdr``); the test suite checks that
both agree and that the encoders write rosbags' bytes. The messages' definitions are the ROS2 ones registered
from their ``.msg`` text (:func:`dvs_typestore_ros2`).
"""
from __future__ import annotations

import numpy as np

from evpose.core.importers.epose_bag_codec import MessageError, dvs_typestore
from evpose.core.importers.time_units import ros_time_to_us

#: ``.msg`` text of the ROS2 port of ``dvs_msgs`` (``time`` is ``builtin_interfaces/Time``).
EVENT_MSG_ROS2 = "uint16 x\nuint16 y\nbuiltin_interfaces/Time ts\nbool polarity\n"
EVENT_ARRAY_MSG_ROS2 = "std_msgs/Header header\nuint32 height\nuint32 width\nEvent[] events\n"
_CDR_LE = b"\x00\x01"
_FIRST = np.dtype({"names": ["x", "y", "sec", "nsec", "p"], "formats": ["<u2", "<u2", "<i4", "<u4", "u1"],
                   "offsets": [0, 2, 4, 8, 12], "itemsize": 13})
#: Events 1..n-1, 16 bytes apart (the last one has no trailing pad, hence itemsize 15 with stride 16).
_REST = np.dtype({"names": ["x", "y", "sec", "nsec", "p"], "formats": ["<u2", "<u2", "<i4", "<u4", "u1"],
                  "offsets": [0, 2, 6, 10, 14], "itemsize": 15})


def dvs_typestore_ros2():
    """A rosbags ROS2 (Humble) typestore with ``dvs_msgs/msg/Event`` and ``EventArray`` registered from .msg text."""
    return dvs_typestore("ROS2_HUMBLE", EVENT_MSG_ROS2, EVENT_ARRAY_MSG_ROS2)


def _align(off: int, n: int) -> int:
    return (off + n - 1) // n * n


def _header(buf: memoryview, what: str) -> tuple[int, int, int]:
    """(stamp sec, stamp nanosec, payload offset after the header) of a CDR std_msgs/Header."""
    if len(buf) < 16:
        raise MessageError("header", f"{what}: {len(buf)} bytes, too short for a CDR header")
    if bytes(buf[:2]) != _CDR_LE:
        raise MessageError("encapsulation", f"{what}: encapsulation {bytes(buf[:4]).hex()} is not CDR little endian")
    sec = int(np.frombuffer(buf, "<i4", count=1, offset=4)[0])
    nsec, n = (int(v) for v in np.frombuffer(buf, "<u4", count=2, offset=8))
    off = 12 + n                                  # payload offset (payload starts at byte 4)
    if n < 1 or 4 + off > len(buf):
        raise MessageError("header.frame_id", f"{what}: frame_id length {n} does not fit the message "
                           f"({len(buf)} bytes)")
    return sec, nsec, off


def parse_event_array_cdr(raw) -> dict:
    """Decode one CDR ``dvs_msgs/EventArray`` payload without a Python loop per event.

    Returns
    -------
    dict with ``height``, ``width`` (int), ``stamp_us`` (header stamp, µs), and numpy arrays ``x``, ``y``
    (uint16), ``sec`` (int32), ``nsec`` (uint32), ``p`` (uint8) -- new arrays (not views into ``raw``).
    Raises :class:`MessageError` (with a ``field``) on a malformed payload.
    """
    buf = memoryview(raw)
    hs, hn, off = _header(buf, "EventArray")
    off = _align(off, 4)
    if 4 + off + 12 > len(buf):
        raise MessageError("height/width/events", f"message ends after {len(buf)} bytes, inside height/width/count")
    height, width, n = (int(v) for v in np.frombuffer(buf, "<u4", count=3, offset=4 + off))
    a = 4 + off + 12
    need = a if n == 0 else a + 16 * n - 3
    if need != len(buf):
        raise MessageError("events", f"{n} events need {need} bytes, the message has {len(buf)}")
    out = {"height": height, "width": width, "stamp_us": int(ros_time_to_us(hs, hn))}
    if n == 0:
        return {**out, **{k: np.empty(0, _FIRST[k]) for k in ("x", "y", "sec", "nsec", "p")}}
    first = np.frombuffer(buf, _FIRST, count=1, offset=a)
    rest = np.ndarray((n - 1,), _REST, buffer=buf, offset=a + 14, strides=(16,)) if n > 1 else None
    for k in ("x", "y", "sec", "nsec", "p"):
        col = np.empty(n, _FIRST[k])
        col[0] = first[k][0]
        if rest is not None:
            col[1:] = rest[k]
        out[k] = col
    return out


def encode_event_array_cdr(x, y, t_ns, p, *, stamp_ns: int = 0, frame_id: str = "", height: int = 260,
                           width: int = 346) -> bytes:
    """CDR bytes of a ``dvs_msgs/EventArray`` (for tests and benchmarks); ``t_ns`` int ns (>= 0)."""
    t_ns = np.asarray(t_ns, np.int64)
    n = len(t_ns)
    fid = frame_id.encode() + b"\x00"
    head = _CDR_LE + b"\x00\x00" + np.array([stamp_ns // 10**9], "<i4").tobytes() + np.array(
        [stamp_ns % 10**9, len(fid)], "<u4").tobytes() + fid
    head += bytes(_align(len(head) - 4, 4) - (len(head) - 4))
    head += np.array([height, width, n], "<u4").tobytes()
    if n == 0:
        return head
    rec = np.zeros(n, np.dtype({"names": _REST.names, "formats": [_REST[k] for k in _REST.names],
                                "offsets": [0, 2, 6, 10, 14], "itemsize": 16}))
    rec["x"], rec["y"], rec["p"] = x, y, np.asarray(p).astype(np.uint8)
    rec["sec"], rec["nsec"] = t_ns // 10**9, t_ns % 10**9
    body = rec.tobytes()        # 16-byte records laid out like events 1..n-1; event 0 lacks the 2 pad bytes after y
    return head + body[:4] + body[6:-1]


def parse_pose_stamped_cdr(raw) -> tuple[int, np.ndarray]:
    """Decode CDR ``geometry_msgs/PoseStamped`` -> (header stamp µs, [px, py, pz, qx, qy, qz, qw])."""
    buf = memoryview(raw)
    hs, hn, off = _header(buf, "PoseStamped")
    off = _align(off, 8)
    if 4 + off + 56 != len(buf):
        raise MessageError("pose", f"expected {4 + off + 56} bytes (header + 7 float64), the message has {len(buf)}")
    return int(ros_time_to_us(hs, hn)), np.frombuffer(buf, "<f8", count=7, offset=4 + off).copy()


def encode_pose_stamped_cdr(stamp_ns: int, position, quat_xyzw, *, frame_id: str = "base") -> bytes:
    fid = frame_id.encode() + b"\x00"
    head = _CDR_LE + b"\x00\x00" + np.array([stamp_ns // 10**9], "<i4").tobytes() + np.array(
        [stamp_ns % 10**9, len(fid)], "<u4").tobytes() + fid
    head += bytes(_align(len(head) - 4, 8) - (len(head) - 4))
    return head + np.asarray([*position, *quat_xyzw], "<f8").tobytes()
