"""Property test: truncated and corrupted inputs of every importer end in ImportFailure naming the file -- never
another exception type, a crash, a hang or a partial scene folder. (A corruption that still parses may import:
then the scene must be complete and loadable.)"""
from __future__ import annotations

import shutil
import signal
import tempfile
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_importers import (  # noqa: F401
    src,
    write_bag,
    write_dsec,
    write_dsec_yaml,
    write_epose_export,
    write_npz,
    write_rpg,
    write_tum,
    write_ycbev,
)

from evpose.core.data.event_store import EventStore
from evpose.core.data.manifest_reader import load_manifest
from evpose.core.data.trajectory import Trajectory
from evpose.core.importers import ImportFailure, import_scene

N_EVENTS = 3000


class _Small:
    """The source scene cut down to a few thousand events (small files keep each example fast)."""

    def __init__(self, src):
        self.__dict__.update(src.__dict__)
        self.ev = src.ev[np.arange(N_EVENTS)]
        t_end = int(self.ev.t[-1])
        k = int(np.searchsorted(src.traj.t_us, t_end)) + 3
        tr = src.traj
        self.traj = Trajectory(tr.t_us[:k], tr.positions_m[:k], tr.quats_xyzw[:k])
        self.labels = src.labels


@pytest.fixture(scope="module")
def bases(src, tmp_path_factory):
    """One valid input set per format: (folder, sources relative to it, files to corrupt, options)."""
    s = _Small(src)
    root = tmp_path_factory.mktemp("fuzz_bases")
    out = {}
    d = root / "bag"
    d.mkdir()
    write_bag(d / "rec.bag", s.ev, s.traj, msg_events=500, width=173, height=130)
    out["epose-bag"] = (d, ["rec.bag"], ["rec.bag"], dict(camera=str(src.cam_json), objects=src.objects_arg))
    d = root / "export"
    write_epose_export(d, s, n_windows=3)
    out["epose-export"] = (d, ["."], ["0001_data.mat", "0002_data.mat"],
                           dict(objects=src.objects_arg, width=173, height=130))
    d = root / "dsec"
    d.mkdir()
    write_dsec(d / "events.h5", s.ev, compression=None)
    write_tum(d / "poses.txt", s.traj)
    write_dsec_yaml(d / "cam_to_cam.yaml", src.cam)
    out["dsec"] = (d, ["events.h5", "poses.txt", "cam_to_cam.yaml"], ["events.h5", "poses.txt", "cam_to_cam.yaml"],
                   dict(objects=src.objects_arg))
    d = root / "rpg"
    write_rpg(d, s.ev, s.traj, src.cam)
    out["rpg"] = (d, ["."], ["events.txt", "groundtruth.txt", "calib.txt"], dict(width=173, height=130))
    d = root / "ycbev"
    write_ycbev(d, s, n_frames=4)
    out["ycbev"] = (d, ["seq01"], ["seq01/scene_gt.json", "seq01_events.int32.zst", "calib_prophesee.json",
                                   "calib_stereo_c2ev.json"], dict(time_origin_us=int(s.ev.t[0])))
    d = root / "npz"
    d.mkdir()
    write_npz(d / "rec.npz", s.ev, s.traj, src.cam)
    out["npz"] = (d, ["rec.npz"], ["rec.npz"], dict(objects=src.objects_arg))
    return out


@st.composite
def corruption(draw):
    kind = draw(st.sampled_from(["truncate", "flip", "zero", "garbage", "insert"]))
    frac = draw(st.floats(0.0, 1.0, allow_nan=False))
    n = draw(st.integers(1, 64))
    data = draw(st.binary(min_size=n, max_size=n))
    return kind, frac, data


def corrupt(path: Path, kind: str, frac: float, data: bytes) -> None:
    b = bytearray(path.read_bytes())
    pos = min(int(frac * len(b)), max(len(b) - 1, 0))
    if kind == "truncate":
        b = b[:pos]
    elif kind == "flip":
        for i, v in enumerate(data[:8]):
            j = (pos + i * 997) % max(len(b), 1)
            if b:
                b[j] ^= v or 0xFF
    elif kind == "zero":
        b[pos:pos + len(data) * 16] = bytes(len(b[pos:pos + len(data) * 16]))
    elif kind == "garbage":
        b[pos:pos + len(data)] = data
    else:
        b[pos:pos] = data
    path.write_bytes(bytes(b))


class _Hang(Exception):
    pass


def _alarm(signum, frame):
    raise _Hang("import did not finish within 30 s")


@pytest.mark.parametrize("fmt", ["epose-bag", "epose-export", "dsec", "rpg", "ycbev", "npz"])
@settings(max_examples=30, deadline=timedelta(seconds=20), derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(target=st.integers(0, 10), how=corruption())
def test_corrupted_inputs_fail_cleanly(bases, fmt, target, how):
    base, sources, targets, opts = bases[fmt]
    check_corrupted_import(fmt, base, sources, targets, opts, target, how)


def check_corrupted_import(fmt, base, sources, targets, opts, target, how, one_line=False) -> None:
    """Import a copy of ``base`` whose file ``targets[target]`` is corrupted by ``how``: either one clear error naming
    that file (a single line with ``one_line``) and no scene folder, or a complete, loadable scene; never a hang
    (30 s alarm) or a leftover staging folder."""
    work = Path(tempfile.mkdtemp(prefix="fuzz-"))
    try:
        d = work / "in"
        shutil.copytree(base, d, symlinks=True)
        victim = d / targets[target % len(targets)]
        corrupt(victim, *how)
        out = work / "scene"
        old = signal.signal(signal.SIGALRM, _alarm)
        signal.alarm(30)
        try:
            import_scene(fmt, [d / s for s in sources], out, log=None, **opts)
        except ImportFailure as exc:
            msg = str(exc)
            assert victim.name in msg or str(victim.parent) in msg, (how, msg)
            assert not out.exists()
            assert not one_line or "\n" not in msg, msg
        else:
            man = load_manifest(out)                                   # a complete, loadable scene
            with EventStore(man.events_path) as es:
                assert es.n_events > 0
            assert len(Trajectory.load_csv(man.trajectory_path)) > 0
        finally:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, old)
        assert not [p for p in work.iterdir() if ".import-" in p.name]
    finally:
        shutil.rmtree(work, ignore_errors=True)


def test_fuzz_bases_import(bases):
    """The uncorrupted inputs import (so the property above is not vacuous)."""
    for fmt, (base, sources, _, opts) in bases.items():
        with tempfile.TemporaryDirectory() as t:
            res = import_scene(fmt, [base / s for s in sources], Path(t) / "scene", log=None, **opts)
            assert res["n_events"] > 0, fmt
