"""``--scheduler`` mistakes and meshes of the wrong unit (issue 22, parts 6 and 7), through the real ``evpose``
command: one error line naming the option or the ``scene.toml`` field, no traceback, no hang, no allocation
in proportion to what a peer announces or to a mesh's metric size.

- ``--scheduler``: the address is parsed before anything connects (``tcp://host:port`` or ``host:port``;
  ``inproc://``, ``tls://``, other schemes, a missing port are refused by the parser); then a plain-socket
  probe with bounded waits: a closed port, a peer that accepts and stays silent, one that answers garbage
  or announces a 1 GiB greeting each end in one line within seconds. Every server here binds 127.0.0.1.
- Mesh scale: an object larger than 5 m, smaller than 1 mm, or whose box holds the camera all along is
  refused when the scene opens (``info``, ``export``), naming ``objects[i].mesh_scale`` and the value to try;
  an import writes the scene and warns. ``raster_friendly`` adds a bounded number of triangles whatever the
  mesh's size; the E-POSE meshes and the synthetic objects pass.

The command runs are started together (a thread pool, like ``test_bad_input``): ~35 s on a quiet 2-core machine.
"""
from __future__ import annotations

import json
import os
import shutil
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from fault_harness import assert_clean_error, assert_ok, run_cli, snapshot

#: A refused, silent or garbage peer must end the command within this, start-up included (the probe waits
#: 5 s at most per step; ~7 s alone, up to ~17 s when four commands share two busy cores).
HANG_LIMIT_S = 30
#: How long the probe may keep a silent peer's connection open (measured by the peer: start-up excluded).
SILENT_WAIT_LIMIT_S = 8
TIMEOUT = 60


# ------------------------------------------------------------------------------------------------ fake peers
class FakePeer:
    """A TCP server on 127.0.0.1 that runs ``behave(conn)`` for every connection (in its own thread)."""

    def __init__(self, behave: Callable[[socket.socket], None]):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.port = self.sock.getsockname()[1]
        self.conns: list[socket.socket] = []
        self.held_s: list[float] = []        # per connection: from accept until behave() returned
        self.behave = behave
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            threading.Thread(target=self._run, args=(conn,), daemon=True).start()

    def _run(self, conn):
        t0 = time.monotonic()
        try:
            self.behave(conn)
        except OSError:
            pass
        self.held_s.append(time.monotonic() - t0)

    def close(self):
        self.sock.close()
        for c in self.conns:
            c.close()


def silent(conn):
    """Accept and never answer; return when the client gives up and closes."""
    conn.settimeout(HANG_LIMIT_S)
    while conn.recv(1024):
        pass


def random_bytes(conn):
    """What a non-Dask service may send first: 8 bytes that announce exabytes, then more noise."""
    conn.sendall(b"\xfa\x3c\x91\x07\x55\xe2\x6a\x6e" + os.urandom(120))


def announces_1gib(conn):
    """A plausible-looking length (1 GiB) that Dask would allocate before reading, then a trickle."""
    conn.sendall(struct.pack("Q", 2**30) + b"\0" * 100)
    time.sleep(30)


def not_msgpack(conn):
    """A small, well-framed first message that is not a Dask handshake."""
    body = struct.pack("QQ", 1, 24) + b"HTTP/1.1 400 Bad Request"
    conn.sendall(struct.pack("Q", len(body)) + body)


def hangs_up(conn):
    """Three bytes, then the connection is closed."""
    conn.sendall(b"\x10\0\0")
    conn.shutdown(socket.SHUT_RDWR)


def closed_port() -> socket.socket:
    """A socket bound to 127.0.0.1 but not listening: connections to its port are refused."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    return s


# ------------------------------------------------------------------------------------------------ scenes
def edit_toml(d: Path, old: str, new: str) -> None:
    p = d / "scene.toml"
    text = p.read_text()
    assert old in text, old
    p.write_text(text.replace(old, new, 1))


def box_in_mm(path: Path, extents_mm=(100.0, 60.0, 160.0)) -> Path:
    """A 12-triangle CAD box written in millimetres."""
    import trimesh

    trimesh.creation.box(extents=extents_mm).export(path)
    return path


def use_mesh(d: Path, mesh: str, scale: float | None = None) -> None:
    edit_toml(d, 'mesh = "models/box.ply"\nmesh_scale = 1.0',
              f'mesh = "{mesh}"\nmesh_scale = {1.0 if scale is None else scale}')


def scene_with_box_in_mm(d: Path, tmp: Path) -> None:
    box_in_mm(d / "models" / "box_mm.stl")
    use_mesh(d, "models/box_mm.stl")


def scene_with_cube_in_cm(d: Path, tmp: Path) -> None:
    """A 3 cm cube written in centimetres: 3 m as metres, under 5 m, but the camera is inside it all along."""
    box_in_mm(d / "models" / "cube_cm.stl", (3.0, 3.0, 3.0))
    use_mesh(d, "models/cube_cm.stl")


def scene_with_metre_box_as_mm(d: Path, tmp: Path) -> None:
    use_mesh(d, "models/box.ply", 0.001)


def npz_recording(tmp: Path) -> Path:
    """A small npz recording whose camera stands 0.5 m in front of the base origin."""
    from evpose.core.data.camera import CameraModel

    rng = np.random.default_rng(1)
    n, tp = 20_000, 990_000 + 4000 * np.arange(90)
    cam = CameraModel.davis346()
    src = tmp / "rec.npz"
    np.savez(src, x=rng.integers(0, 346, n), y=rng.integers(0, 260, n),
             t=1_000_000 + np.sort(rng.integers(0, 300_000, n)), p=rng.integers(0, 2, n), t_us=tp, position=np.tile([0.0, 0.0, -0.5], (90, 1)),
             quaternion=np.tile([0, 0, 0, 1.0], (90, 1)), K=cam.K, dist=cam.dist, width=np.int64(346),
             height=np.int64(260))
    (tmp / "T.json").write_text(json.dumps(np.eye(4).tolist()))
    box_in_mm(tmp / "box_mm.stl")
    return src


# ------------------------------------------------------------------------------------------------ cases
@dataclass
class Case:
    id: str
    args: tuple                  # "SCENE", "DS", "OUT", "TMP", "PORT" are substituted
    names: tuple = ()            # words the one error line must contain
    setup: Callable[[Path, Path], None] = lambda d, tmp: None
    peer: Callable | None = None  # a FakePeer behaviour, or closed_port
    limit_s: float | None = None  # the command must end within this


SCHEDULER = ("dataset", "info", "DS", "-q", "--scheduler")
CASES = [
    # ---- refused while parsing the command line (more forms: test_scheduler_addresses_are_parsed_before_connecting)
    Case("no-port", (*SCHEDULER, "notanaddress"), ("--scheduler", "notanaddress", "missing port", "8786")),
    Case("inproc", (*SCHEDULER, "inproc://x"), ("--scheduler", "inproc://", "inside one Python process")),
    Case("tls", (*SCHEDULER, "tls://127.0.0.1:1"), ("--scheduler", "tls://", "certificates", "tcp://")),
    # ---- probed with bounded waits (more peers: test_the_probe_refuses_what_dask_would_allocate_for)
    Case("refused", (*SCHEDULER, "127.0.0.1:PORT"), ("--scheduler 127.0.0.1:", "cannot connect", "Connection refused",
                                                     "attempt(s) over 5 s"), peer=closed_port, limit_s=HANG_LIMIT_S),
    Case("silent", (*SCHEDULER, "tcp://127.0.0.1:PORT"), ("--scheduler tcp://127.0.0.1:", "no Dask greeting",
                                                          "within 5 s"), peer=silent, limit_s=HANG_LIMIT_S),
    Case("garbage", (*SCHEDULER, "127.0.0.1:PORT"), ("--scheduler 127.0.0.1:", "does not speak the Dask protocol"),
         peer=random_bytes, limit_s=HANG_LIMIT_S),
    # ---- meshes of the wrong unit, refused when the scene opens
    Case("mm-box-info", ("info", "SCENE"), ("scene.toml", "objects[0].mesh_scale", "box_mm.stl", "160 m across",
                                            "mesh_scale = 0.001"), scene_with_box_in_mm),
    Case("mm-box-export-h5", ("export", "SCENE", "--format", "h5", "--out", "OUT", "-q"),
         ("scene.toml", "objects[0].mesh_scale", "more than 5 m", "mesh_scale = 0.001"), scene_with_box_in_mm,
         limit_s=HANG_LIMIT_S),
    Case("metre-box-as-mm", ("info", "SCENE"), ("scene.toml", "objects[0].mesh_scale", "box.ply", "less than 1 mm",
                                                "mesh_scale = 1 "), scene_with_metre_box_as_mm),
    Case("cm-cube-camera-inside", ("info", "SCENE"), ("scene.toml", "objects[0].mesh_scale", "cube_cm.stl",
                                                      "camera is inside", "mesh_scale = 0.01 "), scene_with_cube_in_cm),
]


@dataclass
class Prepared:
    case: Case
    scene: Path
    tmp: Path
    before: dict
    args: list
    run: object = None
    elapsed_s: float = 0.0
    resources: list = field(default_factory=list)


def _prepare(case: Case, tiny_scene_dir: Path, root: Path) -> Prepared:
    tmp = root / case.id
    tmp.mkdir()
    d = tmp / "ds" / "scene"
    shutil.copytree(tiny_scene_dir, d)
    case.setup(d, tmp)
    resources, port = [], ""
    if case.peer is closed_port:
        resources.append(closed_port())
        port = str(resources[0].getsockname()[1])
    elif case.peer is not None:
        resources.append(FakePeer(case.peer))
        port = str(resources[0].port)
    subst = {"SCENE": str(d), "DS": str(tmp / "ds"), "OUT": str(tmp / "out"), "PORT": port}
    args = [subst.get(a, a) if a in subst else a.replace("PORT", port) for a in map(str, case.args)]
    return Prepared(case, d, tmp, snapshot(d), args, resources=resources)


@pytest.fixture(scope="module")
def runs(tiny_scene_dir, tmp_path_factory):
    """Every case, run once, four at a time: id -> Prepared with its Run (or run_cli's exception)."""
    from concurrent.futures import ThreadPoolExecutor

    root = tmp_path_factory.mktemp("scheduler_mesh")
    jobs = [_prepare(c, tiny_scene_dir, root) for c in CASES]

    def go(prep: Prepared) -> Prepared:
        t0 = time.monotonic()
        try:
            prep.run = run_cli(*prep.args, timeout=TIMEOUT, env={"XDG_CACHE_HOME": str(prep.tmp / "cache")})
        except BaseException as exc:        # a hang: pytest.fail inside the thread; re-raised by the test
            prep.run = exc
        prep.elapsed_s = time.monotonic() - t0
        return prep

    try:
        with ThreadPoolExecutor(4) as pool:
            yield {p.case.id: p for p in pool.map(go, jobs)}
    finally:
        for p in jobs:
            for r in p.resources:
                r.close()


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_one_line_no_traceback_no_hang(case, runs):
    prep = runs[case.id]
    if isinstance(prep.run, BaseException):
        raise prep.run
    line = assert_clean_error(prep.run, *case.names)
    assert prep.run.returncode == 2, prep.run.stderr
    assert line.startswith(f"evpose {' '.join(case.args[:2]) if case.args[0] == 'dataset' else case.args[0]}: error: ")
    if case.limit_s is not None:
        assert prep.elapsed_s < case.limit_s, f"took {prep.elapsed_s:.1f} s"
    assert snapshot(prep.scene) == prep.before, "an input changed"
    out = prep.tmp / "out"
    assert not out.exists() or not any(p for p in out.iterdir() if p.name != ".evpose"), "output left behind"
    if case.peer is silent:
        held = prep.resources[0].held_s
        assert len(held) == 1 and held[0] < SILENT_WAIT_LIMIT_S, held


# ------------------------------------------------------------------------------------------------ in process
@pytest.mark.parametrize("text, address", [
    ("tcp://head:8786", "tcp://head:8786"), ("head:8786", "tcp://head:8786"), ("TCP://10.0.0.1:1", "tcp://10.0.0.1:1"),
    ("tcp://[::1]:8786", "tcp://[::1]:8786"), (" 127.0.0.1:65535 ", "tcp://127.0.0.1:65535")])
def test_scheduler_addresses_are_parsed_before_connecting(text, address):
    from evpose.core.dataset.cluster import scheduler_address

    assert scheduler_address(text)[0] == address


@pytest.mark.parametrize("text, words", [
    ("ucx://h:1", "unknown address scheme 'ucx://'"), ("ws://h:1", "unknown address scheme 'ws://'"),
    ("tcp://h:0", "from 1 to 65535, got '0'"), ("h:65536", "got '65536'"), ("h:http", "got 'http'"),
    ("::1:8786", "brackets"), ("tcp://[::1]", "[IPv6 address]:port"), (":8786", "the host ''"),
    ("tcp://h:8786/x", "got '8786/x'"), ("tcp://user@h:1", "the host 'user@h'"), ("tcp://h", "missing port")])
def test_bad_scheduler_addresses_are_refused_with_what_is_wrong(text, words):
    from evpose.core.dataset.cluster import ClusterError, scheduler_address

    with pytest.raises(ClusterError) as err:
        scheduler_address(text)
    assert words in str(err.value)


@pytest.mark.parametrize("behave, words", [
    (announces_1gib, "its first message announces 1073741824 bytes"),
    (not_msgpack, "not a Dask handshake"),
    (hangs_up, "closed the connection after 3 of 8 bytes")])
def test_the_probe_refuses_what_dask_would_allocate_for(behave, words):
    """Dask's client allocates the size a peer's first 8 bytes announce and then waits for it: the probe
    reads at most 64 KiB and answers at once."""
    from evpose.core.dataset.cluster import ClusterError, probe_scheduler

    peer = FakePeer(behave)
    try:
        t0 = time.monotonic()
        with pytest.raises(ClusterError) as err:
            probe_scheduler("127.0.0.1", peer.port)
        assert time.monotonic() - t0 < 3
    finally:
        peer.close()
    assert words in str(err.value)


# ------------------------------------------------------------------------------------------------ import
def test_import_of_a_millimetre_mesh_warns_and_the_scene_is_refused_until_fixed(tmp_path):
    """``--objects`` meshes take no scale at import: the scene is written with a warning naming the fix, then
    ``info`` refuses it; with the suggested ``mesh_scale`` it opens."""
    src = npz_recording(tmp_path)
    out = tmp_path / "scene"
    r = run_cli("import", "npz", src, "--out", out, "--objects", f"box={tmp_path / 'box_mm.stl'}:{tmp_path / 'T.json'}",
                "-q", timeout=TIMEOUT)
    assert_ok(r)
    warn = [ln for ln in r.stderr.splitlines() if "mesh_scale" in ln]
    assert len(warn) == 1 and "warning" in warn[0] and "160 m across" in warn[0] and "mesh_scale = 0.001" in warn[0]
    assert "mesh_scale = 0.001" in json.dumps(json.loads((out / "import_report.json").read_text())["warnings"])
    assert_clean_error(run_cli("info", out, timeout=TIMEOUT), "scene.toml", "objects[0].mesh_scale")
    edit_toml(out, "mesh_scale = 1.0", "mesh_scale = 0.001")
    assert_ok(run_cli("info", out, timeout=TIMEOUT))


# ------------------------------------------------------------------------------------------------ core checks
def test_raster_friendly_adds_a_bounded_number_of_triangles_whatever_the_size():
    """Was: a 12-triangle box in mm read as metres split to 2 cm edges, 4.4 GB then ``max_iter exceeded``."""
    import tracemalloc

    import trimesh

    from evpose.core.data.objects import MAX_RASTER_ADDED_FACES, ObjectModel, raster_friendly

    huge = ObjectModel.from_trimesh(trimesh.creation.box(extents=(100.0, 60.0, 160.0)), "box_mm")
    tracemalloc.start()
    t0 = time.perf_counter()
    split = raster_friendly(huge)
    elapsed = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert len(split.faces) - len(huge.faces) <= MAX_RASTER_ADDED_FACES
    assert peak < 200 * 2**20 and elapsed < 10, (peak, elapsed)
    np.testing.assert_array_equal(split.bbox_min_max, huge.bbox_min_max)          # the same surface
    # a right-sized CAD box is split exactly as before: to 2 cm edges
    box = ObjectModel.from_trimesh(trimesh.creation.box(extents=(0.1, 0.06, 0.16)), "box")
    v, f = trimesh.remesh.subdivide_to_size(box.vertices_m, box.faces, max_edge=0.02)
    got = raster_friendly(box)
    np.testing.assert_array_equal(got.vertices_m, v)
    np.testing.assert_array_equal(got.faces, f)


def test_published_meshes_and_synthetic_objects_are_plausible(models_dir):
    from evpose.core.data.objects import mesh_bounds, size_problem
    from evpose.core.sim.synth_objects import BUILTIN_OBJECTS, load_objects

    meshes = sorted(p for p in models_dir.iterdir() if p.suffix in (".obj", ".stl", ".ply"))
    assert len(meshes) == 13
    for p in meshes:
        lo, hi = mesh_bounds(p)
        assert size_problem(hi - lo) is None, p
        assert "mesh_scale = 0.001" in size_problem((hi - lo) * 1000)
        assert "mesh_scale = 1 " in size_problem((hi - lo) * 0.001, 0.001)
    for model in load_objects(BUILTIN_OBJECTS):
        lo, hi = model.bbox_min_max
        assert size_problem(hi - lo) is None, model.name


def test_mesh_bounds_are_cached_by_content_outside_the_scene(tmp_path, monkeypatch):
    """A second scene with the same mesh file (E-POSE imports copy the meshes) costs a hash, not a load."""
    import evpose.core.data.objects as objects

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(objects, "_BOUNDS", {})
    (tmp_path / "a").mkdir()
    a = box_in_mm(tmp_path / "a" / "box.stl")
    lo, hi = objects.mesh_bounds(a)
    np.testing.assert_allclose(hi - lo, [100, 60, 160])
    (tmp_path / "b").mkdir()
    b = Path(shutil.copy(a, tmp_path / "b" / "copy.stl"))
    monkeypatch.setattr(objects, "_BOUNDS", {})                     # a new process: only the disk cache

    def no_load(*args, **kwargs):
        raise AssertionError("the mesh was loaded again")

    monkeypatch.setattr(objects.ObjectModel, "from_file", no_load)
    np.testing.assert_array_equal(objects.mesh_bounds(b)[1], hi)
    assert sorted(os.listdir(tmp_path / "a")) == ["box.stl"] and sorted(os.listdir(tmp_path / "b")) == ["copy.stl"]
    assert len(list((tmp_path / "cache" / "evpose" / "mesh_bounds").glob("*.npz"))) == 1


def test_a_dask_server_is_probed_and_a_scheduler_without_workers_is_not_waited_for_ever(monkeypatch):
    """The probe accepts a real scheduler (it reads and returns its greeting); a scheduler that never gets a
    worker ends in one ``ClusterError`` in bounded time (was: the tasks waited for ever)."""
    from distributed import LocalCluster

    import evpose.core.dataset.cluster as cluster_mod
    from evpose.core.dataset.cluster import ClusterError, ClusterSpec, open_client, probe_scheduler, scheduler_address

    monkeypatch.setattr(cluster_mod, "WORKER_WAIT_S", 1.0)
    with LocalCluster(n_workers=0, processes=False, protocol="tcp://", host="127.0.0.1",
                      dashboard_address="127.0.0.1:0") as lc:
        address, host, port = scheduler_address(lc.scheduler_address)
        assert address == lc.scheduler_address
        assert b"compression" in probe_scheduler(host, port)
        t0 = time.monotonic()
        with pytest.raises(ClusterError, match=r"--scheduler tcp://127\.0\.0\.1:\d+: no worker joined the scheduler "
                                               r"within 1 s; start some with `dask worker tcp://"):
            with open_client(ClusterSpec(scheduler=lc.scheduler_address)):
                pass
        assert time.monotonic() - t0 < HANG_LIMIT_S
