"""Writers of the recording formats of issue 17, each by its reference library, shared by the importer tests
(``tests/core/test_import_formats.py``, ``test_import_fuzz_formats.py``) and the fault tests
(``tests/faults/test_import_strict.py``):

* AEDAT4 by iniVation's ``dv-processing`` (``dv.io.MonoCameraWriter``, events + a pose stream);
* ROS2 bags by ``rosbags.rosbag2.Writer`` in sqlite3 and MCAP storage, ``dvs_msgs`` registered from its ``.msg``
  text and every message serialised by rosbags (``serialize_cdr``);
* Prophesee EVT 2.0 / EVT 3.0 / DAT by ``faery``'s encoders (Metavision's SDK is not on PyPI).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evpose.core.data.trajectory import Trajectory


def write_aedat4(path: Path, ev, traj=None, *, size, frames=("base", "cam"), camera="DAVIS346",
                 packet_events: int | None = None, compressed: bool = True) -> Path:
    """AEDAT4 by dv-processing: the events (one store per ``packet_events`` events, default all in one, packetised
    by the writer) and, with ``traj``, a pose stream; ``compressed=False`` writes the packets uncompressed (their
    bytes can then be edited in place)."""
    dv = pytest.importorskip("dv_processing")
    cfg = dv.io.MonoCameraWriter.EventOnlyConfig(camera, tuple(size))
    if not compressed:
        cfg.compression = dv.CompressionType.NONE
    if traj is not None:
        cfg.addPoseStream("poses")
    w = dv.io.MonoCameraWriter(str(path), cfg)
    step = packet_events or max(len(ev), 1)
    for i in range(0, len(ev), step):
        store = dv.EventStore()
        for t, x, y, p in zip(ev.t[i:i + step].tolist(), ev.x[i:i + step].tolist(), ev.y[i:i + step].tolist(),
                              ev.p[i:i + step].tolist()):
            store.push_back(t, x, y, bool(p))
        w.writeEvents(store)
    if traj is not None:
        for t, pos, q in zip(traj.t_us.tolist(), traj.positions_m.tolist(), traj.quats_xyzw.tolist()):
            w.writePose(dv.Pose(int(t), tuple(pos), (q[3], q[0], q[1], q[2]), *frames))
    del w                                           # closes the file (the writer flushes on a thread)
    return path


def float32_traj(traj: Trajectory) -> Trajectory:
    """The trajectory as AEDAT4 stores it: float32 translation and quaternion."""
    f = lambda a: np.asarray(a, np.float32).astype(np.float64)  # noqa: E731
    return Trajectory(traj.t_us, f(traj.positions_m), f(traj.quats_xyzw))


def write_ros2_bag(path: Path, ev, traj, *, storage: str, width: int, height: int, msg_events=20_000,
                   numpy_encode=False, typestore=None, event_type="dvs_msgs/msg/EventArray") -> Path:
    """A ROS2 bag by rosbags' writer (``storage`` SQLITE3 or MCAP); messages serialised by rosbags."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from evpose.core.importers.epose_bag_cdr import dvs_typestore_ros2, encode_event_array_cdr

    ts = typestore or dvs_typestore_ros2()
    T = ts.types
    Tm, H = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    msgs = []
    with Writer(path, version=9, storage_plugin=StoragePlugin[storage]) as w:
        ce = w.add_connection("/dvs/events", event_type, typestore=ts)
        cp = w.add_connection("/dvs/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        for i in range(0, len(ev), msg_events):
            sl = slice(i, i + msg_events)
            tn = ev.t[sl].astype(np.int64) * 1000
            stamp = Tm(sec=int(tn[-1] // 10**9), nanosec=int(tn[-1] % 10**9))
            if numpy_encode:
                raw = encode_event_array_cdr(ev.x[sl], ev.y[sl], tn, ev.p[sl], stamp_ns=int(tn[-1]), frame_id="davis",
                                             height=height, width=width)
            else:
                objs = [T["dvs_msgs/msg/Event"](x=int(a), y=int(b), ts=Tm(sec=int(t // 10**9), nanosec=int(t % 10**9)),
                                                polarity=bool(c), **({"extra": 7} if typestore else {}))
                        for a, b, t, c in zip(ev.x[sl], ev.y[sl], tn, ev.p[sl])]
                raw = ts.serialize_cdr(T[event_type](header=H(stamp=stamp, frame_id="davis"), height=height,
                                                     width=width, events=objs), event_type)
            msgs.append((int(tn[-1]), ce, bytes(raw)))
        for t, p, q in zip(traj.t_us.tolist(), traj.positions_m.tolist(), traj.quats_xyzw.tolist()):
            tn = int(t) * 1000
            m = T["geometry_msgs/msg/PoseStamped"](
                header=H(stamp=Tm(sec=tn // 10**9, nanosec=tn % 10**9), frame_id="base"),
                pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                                                 orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2],
                                                                                              w=q[3])))
            msgs.append((tn, cp, bytes(ts.serialize_cdr(m, "geometry_msgs/msg/PoseStamped"))))
        for tn, c, raw in sorted(msgs, key=lambda m: m[0]):
            w.write(c, tn, raw)
    return path


def write_prophesee(path: Path, ev, *, version: str, size) -> Path:
    """EVT 2.0 / EVT 3.0 ``.raw`` or DAT by faery's encoders, absolute times (no ``t0`` in the header)."""
    faery = pytest.importorskip("faery")
    from faery.extension import dat, evt

    a = np.zeros(len(ev), faery.EVENTS_DTYPE)
    a["t"], a["x"], a["y"], a["on"] = ev.t, ev.x, ev.y, ev.p.astype(bool)
    if version == "dat":
        with dat.Encoder(path=str(path), version="dat2", event_type="cd", zero_t0=False, dimensions=tuple(size)) as e:
            e.write(a.astype(np.dtype([("t", "=u8"), ("x", "=u2"), ("y", "=u2"), ("payload", "u1")]), casting="unsafe"))
    else:
        with evt.Encoder(path=str(path), version=version, zero_t0=False, dimensions=tuple(size),
                         enforce_monotonic=True) as e:
            for i in range(0, len(a), 50_000):
                e.write({"events": a[i:i + 50_000]})
    return path
