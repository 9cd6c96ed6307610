"""E-POSE raw recordings: ROS1 bags and ROS2 bags with ``/dvs/events`` and ``/dvs/pose`` (``evpose import epose-bag``).

Topics
------
``/dvs/events``  ``dvs_msgs/EventArray``: ``Header header, uint32 height, uint32 width, Event[] events`` with
                 ``Event = {uint16 x, uint16 y, time ts, bool polarity}``.
``/dvs/pose``    ``geometry_msgs/PoseStamped``: the camera pose in the robot base frame (metres, quaternion
                 x y z w) -> ``trajectory.csv`` with ``frame = "cam"``.
``/dvs/vel``     optional, counted and ignored.

SRC is a ROS1 ``.bag`` file, a ROS2 bag folder (``metadata.yaml`` + sqlite3 ``.db3`` or ``.mcap`` storage) or a
bare ``.db3`` / ``.mcap`` file. Every kind is read with the pure-Python ``rosbags`` reader for any bag
(``rosbags.highlevel.AnyReader``, rosbags >= 0.11 for its ``default_typestore`` and MCAP storage; no ROS install;
sqlite3 files are opened ``immutable``, read-only), which registers the message types from the bag's own
definitions (a ROS2 bag without them falls back to ``dvs_msgs`` registered from its ``.msg`` text). The
payloads are decoded with numpy on the ROS1 byte layout (:mod:`evpose.core.importers.epose_bag_codec`) or
the ROS2 CDR layout (:mod:`evpose.core.importers.epose_bag_cdr`). A connection whose ``EventArray``
definition differs from ``dvs_msgs``' (ROS1: its hash is not ``5e8beee5a6c107e504c2e78903c224b8``; ROS2: its
fields differ) is decoded by rosbags from the bag's own definition (slow path, reported). The same topic,
type and value checks apply to both ROS versions.

Times: an event's ``ts`` (ROS time) -> int64 µs as ``sec * 10**6 + (nsec + 500) // 1000`` (ns rounded half up).
Pose samples take ``header.stamp`` (``--pose-time bag``: the bag record time); a pose topic whose header stamps
are all zero falls back to the record time (reported).

Objects, meshes, calibration and the published clock prior come from the E-POSE assets
(``--assets DIR --scene S --sequence Q``, :mod:`evpose.core.importers.epose_assets`) and/or ``--objects``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from evpose.core.data.camera import CameraModel
from evpose.core.importers.calibration import load_camera
from evpose.core.importers.epose_assets import load_epose_assets
from evpose.core.importers.epose_bag_cdr import dvs_typestore_ros2, parse_event_array_cdr, parse_pose_stamped_cdr
from evpose.core.importers.epose_bag_codec import (
    EVENT_ARRAY_MD5,
    EVENT_ARRAY_TYPE,
    POSE_STAMPED_TYPE,
    MessageError,
    parse_event_array,
    parse_pose_stamped,
)
from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.object_args import collect_objects
from evpose.core.importers.pose_checks import make_trajectory
from evpose.core.importers.report import ImportContext, result_summary
from evpose.core.importers.scene_builder import SceneBuilder
from evpose.core.importers.time_units import ros_time_to_us

POSE_FIELDS = ("header.stamp", "pose.position.x", "pose.position.y", "pose.position.z", "pose.orientation.x",
               "pose.orientation.y", "pose.orientation.z", "pose.orientation.w")


_BAG_KINDS = "a ROS1 .bag file, a ROS2 bag folder (metadata.yaml) or a ROS2 .db3/.mcap file"


def import_epose_bag(sources, out, ctx: ImportContext) -> dict:
    """Import one E-POSE bag (ROS1 ``.bag``, ROS2 folder, ``.db3`` or ``.mcap``) into a scene folder; returns the
    summary (see ``result_summary``)."""
    from rosbags.highlevel import AnyReader

    if len(sources) != 1:
        raise ImportFailure(", ".join(map(str, sources)) or "(none)", "(arguments)", "SRC", f"give exactly one bag: "
                            f"{_BAG_KINDS}")
    bag = _check_bag_path(Path(sources[0]))
    opts = ctx.options
    assets = load_epose_assets(ctx, opts.assets, opts.scene, opts.sequence) if opts.assets else None
    camera = assets.camera if assets else None
    if opts.camera:
        camera = load_camera(opts.camera, ctx, default_size=(camera.width, camera.height) if camera else None)
    elif camera is not None and opts.width and opts.height:
        camera = CameraModel(camera.K, camera.dist, opts.width, opts.height, source=camera.source)

    kind = "ROS1" if bag.is_file() and bag.suffix.lower() == ".bag" else "ROS2"
    with wrap_errors(bag, "(bag header/index)", "-", f"not a readable {kind} bag"):
        reader = AnyReader([bag], default_typestore=dvs_typestore_ros2())
        reader.open()
    try:
        return _import_open_bag(reader, bag, out, ctx, assets, camera)
    finally:
        try:
            reader.close()
        except Exception:  # noqa: BLE001
            pass


def _check_bag_path(bag: Path) -> Path:
    """Refuse a missing path, a special file or a file that is none of the bag kinds (before anything is read)."""
    from evpose.core.data.input_files import InputFileError, check_regular

    if bag.is_dir():
        if not (bag / "metadata.yaml").is_file():
            raise ImportFailure(bag, "(folder)", "metadata.yaml", f"not a ROS2 bag folder (expected {_BAG_KINDS})")
        return bag
    try:
        check_regular(bag)
    except InputFileError as exc:
        raise ImportFailure(bag, "(file)", "-", exc.reason) from None
    if bag.suffix.lower() not in (".bag", ".db3", ".mcap"):
        raise ImportFailure(bag, "(file)", "SRC", f"unknown bag suffix {bag.suffix!r} (expected {_BAG_KINDS})")
    return bag


def _import_open_bag(reader, bag: Path, out, ctx: ImportContext, assets, camera) -> dict:
    """Check the topics, stream the events into the scene, build the trajectory, add the objects, commit."""
    opts, rep = ctx.options, ctx.report
    ev_conns, pose_conns = _topic_connections(reader, bag, opts)
    slow = _slow_connections(reader, ev_conns, ctx)
    n_ev_msgs = _describe_bag(reader, ev_conns, pose_conns, ctx)
    with SceneBuilder(out, ctx) as sb:
        msgs = _BagMessages(ctx, bag, ev_conns, slow, reader, n_ev_msgs, camera)
        msgs.read(reader, ev_conns + pose_conns, sb)
        sb.finish_events(msgs.sink, bag)
        camera = msgs.camera
        _warn_other_sizes(ctx, msgs.sizes, camera)
        sb.set_trajectory(_pose_trajectory(ctx, bag, msgs), "cam")
        rep.assume(f"{opts.pose_topic} is the camera pose in the robot base frame (T_base_cam, metres)")
        for name, (mesh, T, cid, src) in collect_objects(ctx, assets).items():
            sb.add_object(name, mesh, T, class_id=cid, source=src)
        if not sb.objects:
            rep.warn("no objects (give --assets/--scene or --objects name=mesh:T.json)")
        offset = assets.offset_us if assets is not None and assets.offset_us is not None else 0
        ctx.progress(0.99, "writing scene")
        sb.commit(camera, clock_offset_us=offset)
    ctx.progress(1.0, "done")
    return result_summary(ctx, sb.out)


def _topic_connections(reader, bag: Path, opts) -> tuple[list, list]:
    """The connections of the events and pose topics; refuses a missing or empty topic or a wrong type."""
    topics = {c.topic for c in reader.connections}
    ev_conns = [c for c in reader.connections if c.topic == opts.events_topic]
    pose_conns = [c for c in reader.connections if c.topic == opts.pose_topic]
    for topic, conns in ((opts.events_topic, ev_conns), (opts.pose_topic, pose_conns)):
        if not conns:
            raise ImportFailure(bag, "(topics)", topic, f"no such topic (topics in the bag: {', '.join(sorted(topics)) or 'none'})")
        if sum(c.msgcount for c in conns) == 0:
            raise ImportFailure(bag, "(topics)", topic, "the topic has no messages")
    for c in ev_conns:
        if c.msgtype != EVENT_ARRAY_TYPE:
            raise ImportFailure(bag, f"connection {c.id}", opts.events_topic, f"type {c.msgtype}, expected {EVENT_ARRAY_TYPE}")
    for c in pose_conns:
        if c.msgtype != POSE_STAMPED_TYPE:
            raise ImportFailure(bag, f"connection {c.id}", opts.pose_topic, f"type {c.msgtype}, expected {POSE_STAMPED_TYPE}")
    return ev_conns, pose_conns


def _slow_connections(reader, ev_conns, ctx: ImportContext) -> set:
    """Ids of the event connections whose ``EventArray`` definition is not ``dvs_msgs``' (decoded by rosbags)."""
    if reader.is2:
        ours = dvs_typestore_ros2().fielddefs
        theirs = reader.typestore.fielddefs
        same = all(theirs.get(t) == ours[t] for t in (EVENT_ARRAY_TYPE, "dvs_msgs/msg/Event"))
        slow = set() if same else {c.id for c in ev_conns}
    else:
        slow = {c.id for c in ev_conns if c.digest != EVENT_ARRAY_MD5}
    if slow:
        ctx.report.warn(f"{ctx.options.events_topic}: message definition differs from dvs_msgs/EventArray; decoding "
                        "with rosbags from the bag's own definition (slow path)")
    return slow


def _describe_bag(reader, ev_conns, pose_conns, ctx: ImportContext) -> int:
    """Report the ignored topics and the message counts; returns the number of event messages."""
    opts, rep = ctx.options, ctx.report
    topics = {c.topic for c in reader.connections}
    n_ev_msgs = sum(c.msgcount for c in ev_conns)
    n_other = {t: sum(c.msgcount for c in reader.connections if c.topic == t) for t in topics
               - {opts.events_topic, opts.pose_topic}}
    if n_other:
        rep.assume(f"ignored topics: {', '.join(f'{t} ({n} messages)' for t, n in sorted(n_other.items()))}")
    rep.details["bag"] = {"ros_version": 2 if reader.is2 else 1, "events_messages": n_ev_msgs,
                          "pose_messages": sum(c.msgcount for c in pose_conns), "duration_s": reader.duration * 1e-9}
    return n_ev_msgs


class _BagMessages:
    """The messages of a bag in file order: events streamed into the scene's sink, pose samples kept."""

    def __init__(self, ctx: ImportContext, bag: Path, ev_conns, slow: set, reader, n_ev_msgs: int,
                 camera: CameraModel | None):
        self.ctx, self.bag, self.slow, self.reader, self.n_ev_msgs = ctx, bag, slow, reader, n_ev_msgs
        self.parse_events = parse_event_array_cdr if reader.is2 else parse_event_array
        self.parse_pose = parse_pose_stamped_cdr if reader.is2 else parse_pose_stamped
        self.ids = {c.id for c in ev_conns}
        self.camera = camera
        self.sink = None
        self.sizes: dict[tuple[int, int], int] = {}
        self.pose_t, self.pose_bag_t, self.pose_v, self.pose_rec = [], [], [], []
        self.i_ev = self.i_pose = 0

    def read(self, reader, conns, sb) -> None:
        opts = self.ctx.options
        with wrap_errors(self.bag, "(messages)", "-", "corrupt bag"):
            it = reader.messages(connections=conns)
        while True:
            rec = f"message {self.i_ev} on {opts.events_topic}"
            with wrap_errors(self.bag, f"after {rec}", "-", "corrupt bag"):
                item = next(it, None)
            if item is None:
                break
            conn, t_bag, raw = item
            if conn.id in self.ids:
                self._events(conn, raw, sb)
            else:
                self._pose(t_bag, raw)
            self.ctx.check_cancel()
        if self.sink is None:
            raise ImportFailure(self.bag, "(topics)", opts.events_topic, "no event messages could be read")

    def _events(self, conn, raw, sb) -> None:
        ctx, bag = self.ctx, self.bag
        rec = f"message {self.i_ev} on {ctx.options.events_topic}"
        if conn.id in self.slow:
            d = _slow_event_array(self.reader, raw, conn.msgtype, bag, rec)
        else:
            try:
                d = self.parse_events(raw)
            except MessageError as exc:
                raise ImportFailure(bag, rec, exc.field, str(exc)) from None
        self.sizes[(d["width"], d["height"])] = self.sizes.get((d["width"], d["height"]), 0) + 1
        nsec = d["nsec"]
        if len(nsec) and int(nsec.max()) >= 10**9:
            j = int(np.argmax(nsec >= 10**9))
            raise ImportFailure(bag, f"{rec}, event {j}", "ts.nsec", f"{int(nsec[j])} is not below 10**9")
        t = ros_time_to_us(d["sec"], nsec)
        if self.sink is None:
            if self.camera is None:
                self.camera = _camera_from_message(ctx, bag, d)
            self.sink = sb.event_sink(self.camera.width, self.camera.height)
        self.sink.add(d["x"], d["y"], t, d["p"], file=bag, record=rec)
        self.i_ev += 1
        ctx.progress(0.97 * self.i_ev / max(self.n_ev_msgs, 1), f"{self.i_ev}/{self.n_ev_msgs} event messages")

    def _pose(self, t_bag, raw) -> None:
        rec = f"message {self.i_pose} on {self.ctx.options.pose_topic}"
        try:
            ts_us, v = self.parse_pose(raw)
        except MessageError as exc:
            raise ImportFailure(self.bag, rec, exc.field, str(exc)) from None
        self.pose_t.append(ts_us)
        self.pose_bag_t.append((int(t_bag) + 500) // 1000)
        self.pose_v.append(v)
        self.pose_rec.append(rec)
        self.i_pose += 1


def _warn_other_sizes(ctx: ImportContext, sizes: dict, camera: CameraModel) -> None:
    other = {k: n for k, n in sizes.items() if k != (camera.width, camera.height)}
    if other:
        ctx.report.warn(f"{sum(other.values())} EventArray message(s) declare a sensor size "
                        f"{', '.join(f'{w}x{h}' for w, h in other)} different from the calibration "
                        f"{camera.width}x{camera.height}")


def _pose_trajectory(ctx: ImportContext, bag: Path, msgs: _BagMessages):
    """The camera trajectory from the pose messages (header stamps, or the bag record times)."""
    opts, rep = ctx.options, ctx.report
    if not msgs.pose_v:
        raise ImportFailure(bag, "(topics)", opts.pose_topic, "no pose messages could be read")
    t_hdr = np.asarray(msgs.pose_t, np.int64)
    if opts.pose_time == "bag":
        t_use = np.asarray(msgs.pose_bag_t, np.int64)
        rep.assume("pose times from the bag record time (--pose-time bag)")
    elif not np.any(t_hdr):
        t_use = np.asarray(msgs.pose_bag_t, np.int64)
        rep.warn(f"{opts.pose_topic}: every header.stamp is 0; using the bag record time")
    else:
        t_use = t_hdr
    V = np.asarray(msgs.pose_v)
    return make_trajectory(ctx, bag, t_use, V[:, :3], V[:, 3:], record_of=lambda i: msgs.pose_rec[i],
                           fields=POSE_FIELDS)


def _camera_from_message(ctx: ImportContext, bag: Path, d: dict) -> CameraModel:
    w, h = ctx.options.width or d["width"], ctx.options.height or d["height"]
    if (w, h) == (346, 260):
        ctx.report.assume("no --camera/--assets: DAVIS346 calibration of E-POSE (sensor 346x260 from the messages)")
        return CameraModel.davis346()
    raise ImportFailure(bag, "message 0", "width/height", f"sensor {w}x{h} is not a DAVIS346; give --camera with the "
                        "calibration")


def _slow_event_array(reader, raw, msgtype: str, bag: Path, rec: str) -> dict:
    """rosbags deserialisation (one Python object per event) for unfamiliar EventArray definitions."""
    with wrap_errors(bag, rec, "events", "cannot deserialise"):
        m = reader.deserialize(raw, msgtype)
        ev = m.events
        n = len(ev)
        x = np.fromiter((e.x for e in ev), np.int64, n)
        y = np.fromiter((e.y for e in ev), np.int64, n)
        sec = np.fromiter((e.ts.sec for e in ev), np.int64, n)
        nsec = np.fromiter((e.ts.nanosec for e in ev), np.int64, n)
        p = np.fromiter((bool(e.polarity) for e in ev), np.uint8, n)
        return {"height": int(m.height), "width": int(m.width), "stamp_us": 0, "x": x, "y": y, "sec": sec,
                "nsec": nsec, "p": p}
