"""Importers: every format written with its real library from the synthetic scene, imported back, compared.

Writers here (also used by test_import_validation.py and test_import_fuzz.py):
rosbags ``rosbag1.Writer`` with dvs_msgs registered (epose-bag), ``scipy.io.savemat`` in the MATLAB layout of
the E-POSE scripts (epose-export), ``h5py`` in the DSEC layout (dsec), plain text (rpg), ``zstandard`` +
BOP JSON (ycbev), ``np.savez`` (npz). Events must come back identical; poses within 1e-9 m / 1e-9 rad.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evpose.core.data.event_store import EventStore
from evpose.core.data.geometry import inv_T, make_T, pose_error
from evpose.core.data.manifest_reader import load_manifest
from evpose.core.data.scene import Scene
from evpose.core.data.trajectory import Trajectory
from evpose.core.importers import REPORT_FILENAME, ImportFailure, import_scene

TOL = 1e-9


# ================================================================================================ source data
class Src:
    """The synthetic scene as the source of truth, plus helper files (camera JSON, T_base_obj JSONs)."""

    def __init__(self, scene_dir: Path, work: Path):
        self.dir = scene_dir
        with EventStore(scene_dir / "events.h5") as es:
            self.ev = es.read(0, es.n_events)
        self.traj = Trajectory.load_csv(scene_dir / "trajectory.csv")
        self.man = load_manifest(scene_dir)
        self.cam = self.man.camera
        self.work = work
        self.cam_json = work / "camera.json"
        self.cam_json.write_text(json.dumps(self.cam.to_dict()))
        self.T_files, specs = {}, []
        for o in self.man.objects:
            p = work / f"T_{o.name}.json"
            p.write_text(json.dumps(np.asarray(o.T_base_obj_raw).tolist()))
            self.T_files[o.name] = p
            specs.append(f"{o.name}={o.mesh}:{p}")
        self.objects_arg = ",".join(specs)
        self.scene = Scene.open(scene_dir)

    def labels(self, t_us) -> np.ndarray:
        """Source T_cam_obj (N, K, 4, 4) at event times (manifest clock prior)."""
        T, valid = self.scene.T_cam_obj(np.asarray(t_us, np.int64))
        assert valid.all()
        return T

    def T_base_cam(self, t_us) -> np.ndarray:
        T, valid = self.scene.T_base_cam(np.asarray(t_us, np.int64))
        assert valid.all()
        return T


@pytest.fixture(scope="session")
def src(tiny_scene_dir, tmp_path_factory) -> Src:
    s = Src(tiny_scene_dir, tmp_path_factory.mktemp("import_src"))
    yield s
    s.scene.close()


def digest(paths) -> dict:
    """sha256 + mtime of every file under ``paths`` (to prove inputs are never modified)."""
    out = {}
    for p in map(Path, paths):
        files = [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file())
        for f in files:
            out[str(f)] = (hashlib.sha256(f.read_bytes()).hexdigest(), f.stat().st_mtime_ns)
    return out


def read_scene(out: Path):
    """``(events, trajectory (None for an event-only scene), manifest, import report)`` of an imported scene."""
    man = load_manifest(out)
    with EventStore(man.events_path) as es:
        ev = es.read(0, es.n_events)
    traj = Trajectory.load_csv(man.trajectory_path) if man.has_trajectory else None
    return ev, traj, man, json.loads((out / REPORT_FILENAME).read_text())


def assert_events_equal(a, b):
    assert len(a) == len(b)
    for f in "xytp":
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


def assert_traj_equal(a: Trajectory, b: Trajectory, tol=TOL):
    np.testing.assert_array_equal(a.t_us, b.t_us)
    dt, dr = pose_error(a.T(), b.T())
    assert dt.max() < tol and dr.max() < tol, (dt.max(), dr.max())


def no_leftovers(parent: Path):
    left = [p.name for p in parent.iterdir() if ".import-" in p.name or ".replaced-" in p.name]
    assert not left, left


# ================================================================================================ writers
def write_bag(path: Path, ev, traj, *, msg_events=20_000, width=None, height=None, events=True, poses=True,
              reorder=None, numpy_encode=False, extra_topic=False, compression=None):
    """ROS1 bag with rosbags' writer; messages serialised by rosbags (per-event objects) unless numpy_encode."""
    from rosbags.rosbag1 import Writer

    from evpose.core.importers.epose_bag_codec import (
        EVENT_ARRAY_TYPE,
        POSE_STAMPED_TYPE,
        dvs_typestore,
        encode_event_array,
        encode_pose_stamped,
    )

    ts = dvs_typestore()
    T = ts.types
    Ev, EA, H, Tm = (T["dvs_msgs/msg/Event"], T[EVENT_ARRAY_TYPE], T["std_msgs/msg/Header"],
                     T["builtin_interfaces/msg/Time"])
    PS, Pose, Pt, Q = (T[POSE_STAMPED_TYPE], T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/Point"],
                       T["geometry_msgs/msg/Quaternion"])
    w_, h_ = width or 346, height or 260
    msgs = []
    if path.exists():
        path.unlink()
    w = Writer(path)
    if compression:
        w.set_compression(getattr(Writer.CompressionFormat, compression))
    with w:
        ce = w.add_connection("/dvs/events", EVENT_ARRAY_TYPE, typestore=ts)
        cp = w.add_connection("/dvs/pose", POSE_STAMPED_TYPE, typestore=ts)
        if extra_topic:
            cv = w.add_connection("/dvs/vel", "geometry_msgs/msg/TwistStamped", typestore=ts)
            msgs.append((int(traj.t_us[0]) * 1000, cv, ts.serialize_ros1(
                T["geometry_msgs/msg/TwistStamped"](header=H(seq=0, stamp=Tm(sec=0, nanosec=0), frame_id=""),
                                                    twist=T["geometry_msgs/msg/Twist"](
                                                        linear=T["geometry_msgs/msg/Vector3"](x=0, y=0, z=0),
                                                        angular=T["geometry_msgs/msg/Vector3"](x=0, y=0, z=0))),
                "geometry_msgs/msg/TwistStamped")))
        if events:
            bounds = reorder if reorder is not None else [(i, min(i + msg_events, len(ev)))
                                                          for i in range(0, len(ev), msg_events)]
            for k, sl in enumerate(bounds):
                idx = sl if isinstance(sl, np.ndarray) else np.arange(*sl)
                tn = ev.t[idx].astype(np.int64) * 1000
                if numpy_encode:
                    raw = encode_event_array(ev.x[idx], ev.y[idx], tn, ev.p[idx], seq=k, stamp_ns=int(tn.max()),
                                             height=h_, width=w_)
                else:
                    objs = [Ev(x=int(a), y=int(b), ts=Tm(sec=int(t // 10**9), nanosec=int(t % 10**9)), polarity=bool(c))
                            for a, b, t, c in zip(ev.x[idx], ev.y[idx], tn, ev.p[idx])]
                    m = EA(header=H(seq=k, stamp=Tm(sec=int(tn.max() // 10**9), nanosec=int(tn.max() % 10**9)),
                                    frame_id="davis"), height=h_, width=w_, events=objs)
                    raw = ts.serialize_ros1(m, EVENT_ARRAY_TYPE)
                msgs.append((int(tn.max()) if len(tn) else 0, ce, raw))
        if poses:
            for j, (t, p, q) in enumerate(zip(traj.t_us, traj.positions_m, traj.quats_xyzw)):
                tn = int(t) * 1000
                if numpy_encode:
                    raw = encode_pose_stamped(tn, p, q, seq=j)
                else:
                    m = PS(header=H(seq=j, stamp=Tm(sec=tn // 10**9, nanosec=tn % 10**9), frame_id="base"),
                           pose=Pose(position=Pt(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                                     orientation=Q(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))))
                    raw = ts.serialize_ros1(m, POSE_STAMPED_TYPE)
                msgs.append((tn, cp, raw))
        for tn, c, raw in sorted(msgs, key=lambda m: m[0]):
            w.write(c, tn, raw)
    return path


def epose_windows(src: Src, window_us=10_000, n_windows=None):
    """Closed windows [t0 + k dt, t0 + (k+1) dt] like the E-POSE scripts; returns [(idx array, t_end_us)]."""
    t = src.ev.t
    t0 = int(t[0])
    out, k = [], 0
    while True:
        a, b = t0 + k * window_us, t0 + (k + 1) * window_us
        if a > int(t[-1]) or (n_windows is not None and k >= n_windows):
            break
        i0, i1 = np.searchsorted(t, a, "left"), np.searchsorted(t, b, "right")
        out.append((np.arange(i0, i1), b))
        k += 1
    return out


def write_epose_export(folder: Path, src: Src, *, window_us=10_000, n_windows=None, matlab_K=True, t_unit="s",
                       events_transposed=False, labels=None, K=None, cls=(1, 2, 3)):
    """NNNN_data.mat files as the E-POSE MATLAB scripts write them (scipy.io.savemat, MATLAB shapes)."""
    import scipy.io

    folder.mkdir(parents=True, exist_ok=True)
    wins = epose_windows(src, window_us, n_windows)
    t_end = np.array([b for _, b in wins], np.int64)
    T = src.labels(t_end) if labels is None else labels
    K = src.cam.K if K is None else K
    scale = {"s": 1e-6, "us": 1.0, "ns": 1e3}[t_unit]
    for k, (idx, b) in enumerate(wins):
        ev = np.stack([src.ev.x[idx].astype(float), src.ev.y[idx].astype(float), src.ev.t[idx] * scale,
                       src.ev.p[idx].astype(float)], axis=1) if len(idx) else np.zeros((0, 0))
        if events_transposed and len(idx):
            ev = ev.T
        pose = np.concatenate(list(T[k]), axis=1)                    # 4 x 4k
        scipy.io.savemat(folder / f"{k + 1:04d}_data.mat", {
            "events": ev, "pose": pose, "time": np.array([[b * scale]]),
            "intrinsicMatrix": K.T if matlab_K else K, "cls_index": np.array([list(cls)], float),
            "cameraPose": np.eye(4), "keypointprojections": np.zeros((8, 5 * len(cls))),
            "centerInfo": np.zeros((1, 3))})
    return wins


def write_dsec(path: Path, ev, *, u32=True, t_offset=None, compression="gzip", ms_index=True):
    import h5py

    t_offset = int(ev.t[0]) if t_offset is None else t_offset
    rel = ev.t - t_offset
    with h5py.File(path, "w") as f:
        kw = {"compression": compression} if compression else {}
        f.create_dataset("events/x", data=ev.x, **kw)
        f.create_dataset("events/y", data=ev.y, **kw)
        f.create_dataset("events/t", data=rel.astype(np.uint32 if u32 else np.int64), **kw)
        f.create_dataset("events/p", data=ev.p, **kw)
        if ms_index:
            f.create_dataset("ms_to_idx", data=np.searchsorted(rel, 1000 * np.arange(rel[-1] // 1000 + 1)).astype(np.uint64))
        f.create_dataset("t_offset", data=np.int64(t_offset))
    return path


def sec_text(t_us) -> str:
    t = int(t_us)
    return f"{t // 10**6}.{t % 10**6:06d}"


def write_tum(path: Path, traj, *, header=None):
    lines = [header] if header else []
    lines += [f"{sec_text(t)} " + " ".join(repr(float(v)) for v in (*p, *q))
              for t, p, q in zip(traj.t_us, traj.positions_m, traj.quats_xyzw)]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_dsec_yaml(path: Path, cam, key="cam0"):
    K, d = cam.K, cam.dist
    path.write_text(f"""# DSEC-style cam_to_cam.yaml
disparity_to_depth:
  cams_03:
  - [1.0, 0.0, 0.0, -335.1]
  - [0.0, 1.0, 0.0, -221.2]
extrinsics:
  T_10:
  - [0.9999, 0.0, 0.0, -0.06]
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
intrinsics:
  camRect0:
    camera_matrix:
    - 1.0
    - 1.0
    - 0.5
    - 0.5
    resolution:
    - 640
    - 480
  {key}:
    camera_matrix:
    - {float(K[0, 0])!r}
    - {float(K[1, 1])!r}
    - {float(K[0, 2])!r}
    - {float(K[1, 2])!r}
    camera_model: pinhole
    distortion_coeffs: [{", ".join(repr(float(v)) for v in d)}]
    distortion_model: radtan
    resolution:
    - {cam.width}
    - {cam.height}
""")
    return path


def write_rpg(folder: Path, ev, traj, cam, *, n=None):
    folder.mkdir(parents=True, exist_ok=True)
    n = len(ev) if n is None else n
    with open(folder / "events.txt", "w") as f:
        for i0 in range(0, n, 100_000):
            i1 = min(i0 + 100_000, n)
            f.write("".join(f"{sec_text(t)} {x} {y} {p}\n" for t, x, y, p in
                            zip(ev.t[i0:i1], ev.x[i0:i1], ev.y[i0:i1], ev.p[i0:i1])))
    write_tum(folder / "groundtruth.txt", traj)
    K, d = cam.K, cam.dist
    (folder / "calib.txt").write_text(" ".join(repr(float(v)) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d)) + "\n")
    return folder


YCB_IDS = {"box": 1, "cylinder": 2, "flatbox": 3}


def write_ycbev(root: Path, src: Src, *, n_frames=20, c2ev=True, seq="seq01"):
    """Published YCB-Ev layout: root/seq01/scene_gt.json, root/seq01_events.int32.zst, calib jsons, models."""
    import trimesh
    import zstandard

    from evpose.core.importers.ycbev_files import pack_events

    seqd = root / seq
    seqd.mkdir(parents=True, exist_ok=True)
    t0 = int(src.ev.t[0])
    raw = pack_events(src.ev.t - t0, src.ev.x, src.ev.y, src.ev.p)
    (root / f"{seq}_events.int32.zst").write_bytes(zstandard.ZstdCompressor(threads=-1).compress(raw))
    ids = np.arange(n_frames)
    t_frames = t0 + (ids + 1) * 33333
    T = src.labels(t_frames)                                       # event camera
    T_ev_rgb = make_T(Rotation.from_rotvec([0.01, -0.05, 0.02]).as_matrix(), [0.0576, 0.0132, -0.0320])
    if c2ev:
        (root / "calib_stereo_c2ev.json").write_text(json.dumps(
            {"R_c2ev": T_ev_rgb[:3, :3].tolist(), "t_c2ev": (T_ev_rgb[:3, 3] * 1e3).tolist()}))
        T = np.einsum("ij,nkjl->nkil", inv_T(T_ev_rgb), T)        # poses in the RGB camera
    gt = {}
    for j in ids:
        gt[str(int(j))] = [{"cam_R_m2c": T[j, k, :3, :3].ravel().tolist(), "cam_t_m2c": (T[j, k, :3, 3] * 1e3).tolist(),
                            "obj_id": YCB_IDS[o.name]} for k, o in enumerate(src.man.objects)]
    (seqd / "scene_gt.json").write_text(json.dumps(gt))
    cam = src.cam
    (root / "calib_prophesee.json").write_text(json.dumps({
        "camera_matrix": cam.K.tolist(), "distortion_coefficients": [cam.dist.tolist()],
        "img_size": [cam.width, cam.height], "avg_reprojection_error": 0.3}))
    mdir = root / "ycbv_models" / "models_eval"
    mdir.mkdir(parents=True, exist_ok=True)
    for o in src.man.objects:
        m = trimesh.load(o.mesh, force="mesh")
        trimesh.Trimesh(m.vertices * 1000.0, m.faces, process=False).export(mdir / f"obj_{YCB_IDS[o.name]:06d}.ply")
    return seqd, t_frames, T_ev_rgb


def write_npz(path: Path, ev, traj, cam=None, *, t=None, T_base_cam=False, compressed=False, **extra):
    d = {"x": ev.x, "y": ev.y, "t": ev.t if t is None else t, "p": ev.p, "t_us": traj.t_us}
    if T_base_cam:
        d["T_base_cam"] = traj.T()
    else:
        d["position"], d["quaternion"] = traj.positions_m, traj.quats_xyzw
    if cam is not None:
        d.update(K=cam.K, dist=cam.dist, width=np.int64(cam.width), height=np.int64(cam.height))
    d.update(extra)
    (np.savez_compressed if compressed else np.savez)(path, **d)
    return path


# ================================================================================================ epose-bag
def test_bag_round_trip(src, tmp_path):
    bag = write_bag(tmp_path / "rec.bag", src.ev, src.traj, width=src.cam.width, height=src.cam.height,
                    extra_topic=True)
    before = digest([bag, src.cam_json])
    res = import_scene("epose-bag", [bag], tmp_path / "scene", camera=str(src.cam_json), objects=src.objects_arg)
    assert digest([bag, src.cam_json]) == before
    ev, traj, man, rep = read_scene(tmp_path / "scene")
    assert_events_equal(ev, src.ev)
    assert_traj_equal(traj, src.traj)
    assert [o.name for o in man.objects] == ["box", "cylinder", "flatbox"]
    for o, so in zip(man.objects, src.man.objects):
        np.testing.assert_array_equal(o.T_base_obj_raw, so.T_base_obj_raw)
    np.testing.assert_array_equal(man.camera.K, src.cam.K)
    assert res["n_events"] == len(src.ev) and rep["counts"]["events_written"] == len(src.ev)
    assert any("/dvs/vel" in a for a in rep["assumptions"])
    no_leftovers(tmp_path)


@pytest.mark.parametrize("compression", ["LZ4", "BZ2"])
def test_bag_compressed_chunks(src, tmp_path, compression):
    ev = src.ev[np.arange(60_000)]
    bag = write_bag(tmp_path / "c.bag", ev, src.traj, numpy_encode=True, compression=compression, msg_events=7000)
    import_scene("epose-bag", [bag], tmp_path / "scene", camera=str(src.cam_json))
    got, traj, _, _ = read_scene(tmp_path / "scene")
    assert_events_equal(got, ev)
    assert_traj_equal(traj, src.traj)


def test_event_array_parser_matches_rosbags(src):
    from evpose.core.importers.epose_bag_codec import (
        EVENT_ARRAY_TYPE,
        dvs_typestore,
        encode_event_array,
        parse_event_array,
    )

    ts = dvs_typestore()
    T = ts.types
    rng = np.random.default_rng(1)
    for n, fid in ((0, ""), (1, "x"), (1000, "davis_left_camera"), (5000, "é")):
        x, y = rng.integers(0, 65535, n), rng.integers(0, 65535, n)
        sec, nsec, p = rng.integers(0, 2**31 - 1, n), rng.integers(0, 10**9, n), rng.integers(0, 2, n)  # rosbags: int32 sec
        m = T[EVENT_ARRAY_TYPE](header=T["std_msgs/msg/Header"](seq=7, stamp=T["builtin_interfaces/msg/Time"](
            sec=12, nanosec=345), frame_id=fid), height=260, width=346, events=[T["dvs_msgs/msg/Event"](
                x=int(a), y=int(b), ts=T["builtin_interfaces/msg/Time"](sec=int(s), nanosec=int(ns)), polarity=bool(c))
                for a, b, s, ns, c in zip(x, y, sec, nsec, p)])
        raw = bytes(ts.serialize_ros1(m, EVENT_ARRAY_TYPE))
        d = parse_event_array(raw)
        back = ts.deserialize_ros1(raw, EVENT_ARRAY_TYPE)
        assert (d["height"], d["width"]) == (back.height, back.width) == (260, 346)
        np.testing.assert_array_equal(d["x"], [e.x for e in back.events])
        np.testing.assert_array_equal(d["y"], [e.y for e in back.events])
        np.testing.assert_array_equal(d["sec"], [e.ts.sec for e in back.events])
        np.testing.assert_array_equal(d["nsec"], [e.ts.nanosec for e in back.events])
        np.testing.assert_array_equal(d["p"], [int(e.polarity) for e in back.events])
        # our numpy encoder writes the same bytes as rosbags' serialiser
        enc = encode_event_array(x, y, sec.astype(np.int64) * 10**9 + nsec, p, seq=7, stamp_ns=12 * 10**9 + 345,
                                 frame_id=fid)
        assert enc == raw


def test_ros_time_rounding():
    from evpose.core.importers.time_units import ros_time_to_us

    np.testing.assert_array_equal(ros_time_to_us([1, 1, 1, 1, 0], [499, 500, 1_499, 999_999_999, 0]),
                                  [1_000_000, 1_000_001, 1_000_001, 2_000_000, 0])


def test_bag_assets_five_obj_clut(src, assets_dir, tmp_path):
    """Real assets: objects, meshes, T_base_obj and the prior offset of five_obj_clut/R_05_ml land in the manifest."""
    rng = np.random.default_rng(0)
    n = 30_000
    from evpose.core.data.events import EventArray

    t = np.sort(rng.integers(0, 300_000, n)) + 1_600_000_000_000_000
    ev = EventArray(rng.integers(0, 346, n), rng.integers(0, 260, n), t, rng.integers(0, 2, n))
    tr = Trajectory(np.arange(t[0] - 50_000, t[-1] + 50_000, 4000), np.zeros((100, 3)) + [0, -0.5, 0.4],
                    np.tile([0, 0, 0, 1.0], (100, 1)))
    bag = write_bag(tmp_path / "R_05_ml.bag", ev, tr, numpy_encode=True)
    res = import_scene("epose-bag", [bag], tmp_path / "scene", assets=str(assets_dir), scene="five_obj_clut",
                       sequence="r_05_ML")
    _, _, man, rep = read_scene(tmp_path / "scene")
    scenes = json.loads((assets_dir / "scenes.json").read_text())["scenes"]["five_obj_clut"]["objects"]
    assert [o.name for o in man.objects] == list(scenes)
    for o in man.objects:
        np.testing.assert_array_equal(o.T_base_obj_raw, scenes[o.name])
        assert o.mesh.is_file() and o.mesh.parent == tmp_path / "scene" / "models"
        assert o.mesh.read_bytes() == (assets_dir / "models" / o.mesh.name).read_bytes()
        if o.mesh.suffix == ".obj":
            assert o.mesh.with_suffix(".mtl").is_file()
    assert man.clock_offset_us == round(0.0160980224609375e6) == 16098
    assert rep["time_shift"]["sequence"] == "R_05_ml" and rep["time_shift"]["scene"] == "five_obj_clut"
    assert man.camera.width == 346 and np.allclose(man.camera.K[0, 0], 292.52)
    assert res["objects"] == list(scenes)
    peg = man.object("nine_hole_peg")            # published rounding, residual 0.145: projected and flagged
    assert peg.repair_rotation and 0.14 < peg.rotation_residual < 0.15
    assert any("nine_hole_peg" in r and "rounded" in r for r in rep["repairs"])
    # the copied OBJ meshes load (geometry only, missing textures are fine)
    assert Scene.open(tmp_path / "scene").model("sugar_box").vertices_m.shape[1] == 3


def test_bag_assets_typo_refused_then_repaired(src, assets_dir, tmp_path):
    rng = np.random.default_rng(0)
    from evpose.core.data.events import EventArray

    t = np.arange(1000, dtype=np.int64) * 100 + 10**15
    ev = EventArray(rng.integers(0, 346, 1000), rng.integers(0, 260, 1000), t, rng.integers(0, 2, 1000))
    tr = Trajectory(np.array([t[0], t[-1]]), np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)))
    bag = write_bag(tmp_path / "b.bag", ev, tr, numpy_encode=True)
    with pytest.raises(ImportFailure) as ei:
        import_scene("epose-bag", [bag], tmp_path / "s1", assets=str(assets_dir), scene="three_obj", sequence="R_05_ml")
    msg = str(ei.value)
    assert "scenes.json" in msg and "three_obj/potted_meat_can" in msg and "T_base_obj" in msg and "0.5058" in msg
    assert not (tmp_path / "s1").exists()
    no_leftovers(tmp_path)
    import_scene("epose-bag", [bag], tmp_path / "s2", assets=str(assets_dir), scene="three_obj", sequence="R_05_ml",
                 repair=True)
    man = load_manifest(tmp_path / "s2")
    pm = man.object("potted_meat_can")
    assert pm.repair_rotation and 0.50 < pm.rotation_residual < 0.51
    rep = json.loads((tmp_path / "s2" / REPORT_FILENAME).read_text())
    assert any("potted_meat_can" in r and "residual" in r for r in rep["repairs"])
    assert man.clock_offset_us == round(-0.010505199432373 * 1e6)


def test_epose_name_matching(assets_dir, tmp_path):
    import csv

    from evpose.core.importers.epose_assets import _time_shift, match_name
    from evpose.core.importers.report import ImportContext

    scenes = json.loads((assets_dir / "scenes.json").read_text())["scenes"]
    assert match_name("bleach", scenes, file="f", record="r", fld="f")[0] == "bleach_cleanser"
    assert match_name("dishwasher", scenes, file="f", record="r", fld="f")[0] == "bleach_cleanser"
    assert match_name("spam", scenes, file="f", record="r", fld="f")[0] == "potted_meat_can"
    assert match_name("Five_Obj_Clut", scenes, file="f", record="r", fld="f")[0] == "five_obj_clut"
    with pytest.raises(ImportFailure, match="ambiguous"):
        match_name("five", scenes, file="f", record="r", fld="f")
    rows = list(csv.reader(open(assets_dir / "time_shifts.csv")))
    shift_scenes = {r[0] for r in rows[1:]}
    expect = {"bleach_cleanser": "bleach", "wood_block": "block", "cracker_box": "cracker", "rubiks_cube": "rubik",
              "potted_meat_can": "potted meat", "nine_hole_peg": "nine hole peg", "mustard_bottle": "mustard",
              "five_obj_clut": "five_obj_clut", "five_obj": "five_obj", "three_obj": "three_obj",
              "sugar_box": "sugar_box"}
    for key, short in expect.items():
        assert match_name(key, shift_scenes, file="f", record="r", fld="f")[0] == short, key
    for key in scenes:       # every scene of scenes.json has a time-shift row, and the lookup says which
        ctx = ImportContext("epose-bag", [], log=None)
        off = _time_shift(ctx, assets_dir / "time_shifts.csv", key, "T_10_ML")
        assert ctx.report.details["time_shift"]["sequence"] == "T_10_ml"
        assert off == round(ctx.report.details["time_shift"]["shift_s"] * 1e6)


# ================================================================================================ epose-export
def test_epose_export_round_trip(src, tmp_path):
    folder = tmp_path / "export"
    wins = write_epose_export(folder, src)
    before = digest([folder])
    import_scene("epose-export", [folder], tmp_path / "scene", objects=src.objects_arg, width=173, height=130)
    assert digest([folder]) == before
    ev, traj, man, rep = read_scene(tmp_path / "scene")
    assert_events_equal(ev, src.ev)
    n_shared = sum(len(np.intersect1d(a, b)) for (a, _), (b, _) in zip(wins, wins[1:]))
    assert n_shared > 0 and rep["counts"]["events_boundary_duplicates"] == n_shared
    t_end = np.array([b for _, b in wins])
    np.testing.assert_array_equal(traj.t_us, t_end)
    dt, dr = pose_error(traj.T(), src.T_base_cam(t_end))
    assert dt.max() < TOL and dr.max() < TOL
    for o, so in zip(man.objects, src.man.objects):
        assert o.name == so.name
        np.testing.assert_array_equal(o.T_base_obj_raw, so.T_base_obj_raw)
    assert any("transposed" in a for a in rep["assumptions"])          # MATLAB K convention detected
    sp = np.load(tmp_path / "scene" / "source_poses.npz")               # the pose blocks as read, kept
    np.testing.assert_array_equal(sp["T_cam_obj"], src.labels(t_end))
    assert sp["names"].tolist() == ["box", "cylinder", "flatbox"]
    assert any("seconds" in a for a in rep["assumptions"])              # time unit guessed from the event rate
    assert man.camera.K.tolist() == src.cam.K.tolist() and (man.camera.width, man.camera.height) == (173, 130)
    assert any("sensor size 173x130" in a for a in rep["assumptions"])


def test_epose_export_without_T_base_obj_keeps_labels(src, tmp_path):
    folder = tmp_path / "export"
    wins = write_epose_export(folder, src, n_windows=30, matlab_K=False, events_transposed=True, t_unit="us")
    meshes = ",".join(f"{o.name}={o.mesh}" for o in src.man.objects)
    import_scene("epose-export", [folder], tmp_path / "scene", objects=meshes, classes="1=box,2=cylinder,3=flatbox")
    scene = Scene.open(tmp_path / "scene")
    t_end = np.array([b for _, b in wins])
    T_new, valid = scene.T_cam_obj(t_end, names=["box", "cylinder", "flatbox"])
    assert valid.all()
    dt, dr = pose_error(T_new, src.labels(t_end))
    assert dt.max() < TOL and dr.max() < TOL
    rep = json.loads((tmp_path / "scene" / REPORT_FILENAME).read_text())
    assert any("base frame is the frame of object" in a for a in rep["assumptions"])
    assert any("(4, N)" in a for a in rep["assumptions"])
    scene.close()


# ================================================================================================ dsec
@pytest.mark.parametrize("mode", ["copy", "link", "reference"])
def test_dsec_round_trip(src, tmp_path, mode):
    h5 = write_dsec(tmp_path / "events.h5", src.ev)
    tum = write_tum(tmp_path / "poses.txt", src.traj, header="# timestamp tx ty tz qx qy qz qw")
    yml = write_dsec_yaml(tmp_path / "cam_to_cam.yaml", src.cam)
    before = digest([h5, tum, yml])
    import_scene("dsec", [h5, tum, yml], tmp_path / "scene", events_mode=mode, objects=src.objects_arg)
    assert digest([h5, tum, yml]) == before
    ev, traj, man, rep = read_scene(tmp_path / "scene")
    assert_events_equal(ev, src.ev)
    assert_traj_equal(traj, src.traj)
    assert man.camera.K.tolist() == src.cam.K.tolist() and man.camera.dist.tolist() == src.cam.dist.tolist()
    assert (man.camera.width, man.camera.height) == (src.cam.width, src.cam.height)
    if mode == "link":
        assert (tmp_path / "scene" / "events.h5").is_symlink()
    if mode == "reference":
        assert man.events_path == h5.resolve()
    assert rep["time_units"]["poses.txt (poses)"]["unit"] == "s"
    assert not list(tmp_path.glob("events.h5.msidx*"))  # nothing written beside the input during the import


def test_dsec_uint32_wrap_and_our_csv(src, tmp_path):
    import h5py

    ev = src.ev[np.arange(0, len(src.ev), 50)]
    half = len(ev) // 2
    t_offset = int(ev.t[half]) - 2**32          # relative time crosses 2**32 µs in the middle
    rel = ev.t - t_offset
    with h5py.File(tmp_path / "e.h5", "w") as f:
        for k, a in (("x", ev.x), ("y", ev.y), ("p", ev.p)):
            f.create_dataset(f"events/{k}", data=a)
        f.create_dataset("events/t", data=(rel % 2**32).astype(np.uint32))
        f.create_dataset("t_offset", data=np.int64(t_offset))
    src.traj.save_csv(tmp_path / "trajectory.csv")
    import_scene("dsec", [tmp_path / "e.h5", tmp_path / "trajectory.csv", src.cam_json], tmp_path / "scene")
    got, traj, _, rep = read_scene(tmp_path / "scene")
    assert_events_equal(got, ev)
    assert any("wraps" in r for r in rep["repairs"])
    assert rep["time_units"]["trajectory.csv"]["unit"] == "us"
    assert_traj_equal(traj, src.traj)


# ================================================================================================ rpg
def test_rpg_round_trip(src, tmp_path):
    folder = write_rpg(tmp_path / "seq", src.ev, src.traj, src.cam)
    before = digest([folder])
    import_scene("rpg", [folder], tmp_path / "scene", width=src.cam.width, height=src.cam.height,
                 objects=src.objects_arg)
    assert digest([folder]) == before
    ev, traj, man, rep = read_scene(tmp_path / "scene")
    assert_events_equal(ev, src.ev)
    assert_traj_equal(traj, src.traj)
    np.testing.assert_allclose(man.camera.K, src.cam.K, rtol=0, atol=0)
    assert rep["time_units"]["events.txt (events)"]["unit"] == "s"


def test_rpg_exact_decimal_seconds(tmp_path):
    from evpose.core.importers.rpg_text import mantissa_to_us, parse_columns

    text = (b"0.0000005 1 2 1\n0.0000015 3 4 0\n1468940293.951234567 5 6 1\n-0.0000005 0 0 0\n"
            b"12 7 8 1\n0.000001 9 9 0\n")
    mant, nd = parse_columns(text, 4, file="f", line0=1, int_cols=(1, 2, 3))
    us = mantissa_to_us(mant[:, 0], nd[:, 0], "s")
    assert us.tolist() == [1, 2, 1468940293951235, 0, 12_000_000, 1]
    assert mant[:, 1].tolist() == [1, 3, 5, 0, 7, 9]
    with pytest.raises(ImportFailure, match=r"line 3: -: expected 4 columns, got 3"):
        parse_columns(b"1 2 3 4\n1 2 3 4\n1 2 3\n", 4, file="f", line0=1)
    with pytest.raises(ImportFailure, match=r"line 12: column 2: expected an integer"):
        parse_columns(b"1 2 3 4\n0.5 2.5 3 4\n", 4, file="f", line0=11, int_cols=(1, 2, 3))
    with pytest.raises(ImportFailure, match=r"line 2: column 1: malformed number"):
        parse_columns(b"1 2 3 4\n1.2.3 2 3 4\n", 4, file="f", line0=1)


# ================================================================================================ ycbev
def test_ycbev_round_trip(src, tmp_path):
    seqd, t_frames, _ = write_ycbev(tmp_path / "ycbev", src)
    before = digest([tmp_path / "ycbev"])
    t0 = int(src.ev.t[0])
    import_scene("ycbev", [seqd], tmp_path / "scene", time_origin_us=t0)
    assert digest([tmp_path / "ycbev"]) == before
    ev, traj, man, rep = read_scene(tmp_path / "scene")
    assert_events_equal(ev, src.ev)
    np.testing.assert_array_equal(traj.t_us, t_frames)
    names = {"box": "master_chef_can", "cylinder": "cracker_box", "flatbox": "sugar_box"}
    scene = Scene.open(tmp_path / "scene")
    T_new, valid = scene.T_cam_obj(t_frames, names=list(names.values()))
    assert valid.all()
    dt, dr = pose_error(T_new, src.labels(t_frames))
    assert dt.max() < TOL and dr.max() < TOL
    assert all(o.mesh_scale == 0.001 for o in man.objects)
    assert [o.class_id for o in man.objects] == [1, 2, 3]
    assert any("calib_stereo_c2ev" in a for a in rep["assumptions"])
    # meshes in mm scaled back to metres match the source meshes
    np.testing.assert_allclose(scene.model("master_chef_can").vertices_m, src.scene.model("box").vertices_m, atol=1e-12)
    scene.close()


def test_ycbev_anchor_object_gives_base_frame(src, tmp_path):
    seqd, t_frames, _ = write_ycbev(tmp_path / "ycbev", src, n_frames=12, c2ev=False)
    box = src.man.object("box")
    import_scene("ycbev", [seqd], tmp_path / "scene", time_origin_us=int(src.ev.t[0]), rgb_to_event="none",
                 objects=f"master_chef_can={box.mesh}:{src.T_files['box']}")
    traj = Trajectory.load_csv(tmp_path / "scene" / "trajectory.csv")
    dt, dr = pose_error(traj.T(), src.T_base_cam(t_frames))
    assert dt.max() < TOL and dr.max() < TOL
    man = load_manifest(tmp_path / "scene")
    dt, dr = pose_error(man.object("sugar_box").T_base_obj, src.man.object("flatbox").T_base_obj)
    assert dt < TOL and dr < TOL


# ================================================================================================ npz
@pytest.mark.parametrize("variant", ["quat", "T_base_cam", "compressed"])
def test_npz_round_trip(src, tmp_path, variant):
    p = write_npz(tmp_path / "rec.npz", src.ev, src.traj, src.cam, T_base_cam=variant == "T_base_cam",
                  compressed=variant == "compressed")
    before = digest([p])
    import_scene("npz", [p], tmp_path / "scene", objects=src.objects_arg)
    assert digest([p]) == before
    ev, traj, man, _ = read_scene(tmp_path / "scene")
    assert_events_equal(ev, src.ev)
    assert_traj_equal(traj, src.traj)
    assert man.camera.K.tolist() == src.cam.K.tolist()


# ================================================================================================ CLI
def _parser():
    import argparse

    from evpose.app.cli.importers import add_import_parser

    p = argparse.ArgumentParser(prog="evpose")
    add_import_parser(p.add_subparsers(dest="command", required=True))
    return p


def test_cli_json_and_errors(src, tmp_path, capsys):
    p = write_npz(tmp_path / "rec.npz", src.ev, src.traj, src.cam)
    args = _parser().parse_args(["import", "npz", str(p), "--out", str(tmp_path / "scene"), "--json", "-q",
                                 "--objects", src.objects_arg])
    assert args.func(args) == 0
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert doc["n_events"] == len(src.ev) and doc["objects"] == ["box", "cylinder", "flatbox"]
    # existing folder without --force: error naming the folder, exit 2, nothing touched
    args = _parser().parse_args(["import", "npz", str(p), "--out", str(tmp_path / "scene"), "-q"])
    assert args.func(args) == 2
    err = capsys.readouterr().err
    assert "scene" in err and "--force" in err
    # bad input: stderr names file, record and field; no scene folder
    bad = tmp_path / "bad.npz"
    np.savez(bad, x=src.ev.x[:10], y=src.ev.y[:10], t=src.ev.t[:10], p=src.ev.p[:10], t_us=src.traj.t_us[:3],
             position=np.full((3, 3), np.nan), quaternion=src.traj.quats_xyzw[:3], K=src.cam.K, dist=src.cam.dist,
             width=173, height=130)
    args = _parser().parse_args(["import", "npz", str(bad), "--out", str(tmp_path / "s2")])
    assert args.func(args) == 2
    err = capsys.readouterr().err
    assert "bad.npz: pose 0: position[0]: not finite" in err
    assert not (tmp_path / "s2").exists()
    no_leftovers(tmp_path)
    # --force replaces the scene atomically
    args = _parser().parse_args(["import", "npz", str(p), "--out", str(tmp_path / "scene"), "--force", "-q"])
    assert args.func(args) == 0
    assert "wrote" in capsys.readouterr().out
    no_leftovers(tmp_path)


def test_cli_registers_every_format():
    p = _parser()
    for fmt in ("epose-bag", "epose-export", "dsec", "rpg", "ycbev", "npz"):
        a = p.parse_args(["import", fmt, "x", "--out", "y"])
        assert a.format == fmt and a.src == ["x"]
    with pytest.raises(SystemExit):
        p.parse_args(["import", "nope", "x", "--out", "y"])


def test_progress_reported(src, tmp_path):
    p = write_npz(tmp_path / "rec.npz", src.ev, src.traj, src.cam)
    seen = []
    import_scene("npz", [p], tmp_path / "scene", progress=lambda f, m: seen.append(f))
    assert seen[-1] == 1.0 and all(0 <= f <= 1 for f in seen) and seen == sorted(seen)



def test_bag_unfamiliar_event_definition_uses_rosbags(src, tmp_path):
    """An EventArray whose definition hash differs (here: an extra field) is decoded from the bag's own definition."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from evpose.core.importers.epose_bag_codec import (
        EVENT_ARRAY_MSG,
        EVENT_ARRAY_TYPE,
        POSE_STAMPED_TYPE,
        encode_pose_stamped,
    )

    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register({**get_types_from_msg("uint16 x\nuint16 y\ntime ts\nbool polarity\nuint8 extra\n", "dvs_msgs/msg/Event"),
                 **get_types_from_msg(EVENT_ARRAY_MSG, EVENT_ARRAY_TYPE)})
    T = ts.types
    ev = src.ev[np.arange(5000)]
    with Writer(tmp_path / "v.bag") as w:
        ce = w.add_connection("/dvs/events", EVENT_ARRAY_TYPE, typestore=ts)
        cp = w.add_connection("/dvs/pose", POSE_STAMPED_TYPE, typestore=ts)
        for i0 in range(0, len(ev), 1000):
            sl = slice(i0, i0 + 1000)
            tn = ev.t[sl] * 1000
            m = T[EVENT_ARRAY_TYPE](header=T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](
                sec=0, nanosec=0), frame_id=""), height=130, width=173, events=[T["dvs_msgs/msg/Event"](
                    x=int(a), y=int(b), ts=T["builtin_interfaces/msg/Time"](sec=int(t // 10**9), nanosec=int(t % 10**9)),
                    polarity=bool(c), extra=7) for a, b, t, c in zip(ev.x[sl], ev.y[sl], tn, ev.p[sl])])
            w.write(ce, int(tn[-1]), ts.serialize_ros1(m, EVENT_ARRAY_TYPE))
        for t, p, q in zip(src.traj.t_us, src.traj.positions_m, src.traj.quats_xyzw):
            w.write(cp, int(t) * 1000, encode_pose_stamped(int(t) * 1000, p, q))
    import_scene("epose-bag", [tmp_path / "v.bag"], tmp_path / "scene", camera=str(src.cam_json))
    got, traj, _, rep = read_scene(tmp_path / "scene")
    assert_events_equal(got, ev)
    assert_traj_equal(traj, src.traj)
    assert any("slow path" in w for w in rep["warnings"])


def test_npz_fractional_seconds_at_a_low_event_rate(src, tmp_path):
    """A quiet recording (~1e4 ev/s) with times as float seconds from the first pose: seconds imply 1e4 ev/s and
    milliseconds 1e7 ev/s, both plausible; the fractions decide for seconds (the fractional-seconds rule of
    ``guess_time_unit``, unit tests in test_time_units.py). Read as ms, the events would land 1000x too early."""
    step = len(src.ev) // 8000
    ev = src.ev[np.arange(0, len(src.ev), step)]
    t0 = int(src.traj.t_us[0])
    rel_traj = Trajectory(src.traj.t_us - t0, src.traj.positions_m, src.traj.quats_xyzw)
    t_s = (ev.t - t0) / 1e6
    rate = (len(t_s) - 1) / (t_s[-1] - t_s[0])
    assert 5e3 < rate < 2e4 and np.any(t_s != np.round(t_s))
    p = write_npz(tmp_path / "quiet.npz", ev, rel_traj, src.cam, t=t_s)
    import_scene("npz", [p], tmp_path / "scene", log=None)
    got, traj, _, rep = read_scene(tmp_path / "scene")
    assert rep["time_units"]["quiet.npz:t (events)"]["unit"] == "s", rep["time_units"]
    np.testing.assert_array_equal(got.t, ev.t - t0)          # exact µs back from the float seconds
    for f in "xyp":
        np.testing.assert_array_equal(getattr(got, f), getattr(ev, f))
    assert_traj_equal(traj, rel_traj)
