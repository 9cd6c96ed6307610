"""Issue 11, items 3 and 7 (read-only or full output): a full or read-only disk ends in one line naming
the path -- never a traceback or a signal (HDF5 used to segfault) -- leaves no partial file that blocks
the rerun, and the rerun after freeing space completes (resuming where it can).

Each case runs on its own small tmpfs (``small_tmpfs``: skipped unless root). A "ballast" file fills it
to the free space wanted; deleting the ballast is "freeing space".
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from evpose_testing import describe_file_differences
from fault_harness import assert_clean_error, assert_ok, run_cli, snapshot

MB = 1 << 20


def fill(mount: Path, leave_bytes: int) -> Path:
    """Fill ``mount`` with a ballast file so that about ``leave_bytes`` stay free."""
    st = os.statvfs(mount)
    free = st.f_bavail * st.f_frsize
    ballast = mount / "ballast"
    with open(ballast, "wb") as f:
        f.write(b"\0" * max(0, free - leave_bytes))
    return ballast


def free_of(mount: Path) -> int:
    st = os.statvfs(mount)
    return st.f_bavail * st.f_frsize


def no_hidden_leftovers(folder: Path) -> list[str]:
    """Hidden temp files and staging folders evpose makes (a .partial is resume state, listed apart)."""
    return [p.name for p in folder.rglob("*") if re.search(r"\.(tmp|import-.*|synth-.*|replaced-.*)$", p.name)]


def h5_datasets(path: Path) -> dict:
    import h5py
    import hdf5plugin  # noqa: F401

    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda n, o: out.__setitem__(n, o[()]) if isinstance(o, h5py.Dataset) else None)
    return out


def assert_same_h5(a: Path, b: Path) -> None:
    da, db = h5_datasets(a), h5_datasets(b)
    assert sorted(da) == sorted(db)
    for k in da:
        np.testing.assert_array_equal(da[k], db[k], err_msg=k)


@pytest.fixture(scope="module")
def reference_h5(tiny_scene_dir, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ref") / "h5"
    assert_ok(run_cli("export", tiny_scene_dir, "--format", "h5", "--out", out, "-q"))
    return out / "tiny.h5"


# ------------------------------------------------------------------------------------------- HDF5 export
def test_h5_export_on_a_full_disk_fails_cleanly_and_the_rerun_completes(tiny_scene_dir, small_tmpfs, reference_h5):
    """Issue: ``export --format h5`` onto a full disk exited with SIGSEGV and its .partial blocked every rerun."""
    mnt = small_tmpfs("12m")
    out = mnt / "ex"
    scene_before = snapshot(tiny_scene_dir)
    for leave in (64 << 10, 2 * MB):           # full before the file exists; room for the file, not for a window
        ballast = fill(mnt, leave)
        r = run_cli("export", tiny_scene_dir, "--format", "h5", "--out", out, "-q")
        line = assert_clean_error(r, str(out), "No space left on device")
        assert "free some space and rerun" in line
        assert no_hidden_leftovers(out) == []
        ballast.unlink()
    assert_ok(run_cli("export", tiny_scene_dir, "--format", "h5", "--out", out, "-q"))
    assert_same_h5(out / "tiny.h5", reference_h5)
    assert not (out / ".tiny.h5.partial").exists()
    assert snapshot(tiny_scene_dir) == scene_before


def test_h5_export_resumes_after_the_disk_filled_up_midway(tiny_scene_dir, small_tmpfs, reference_h5):
    """Room for the first windows only: the run stops with a clean line before HDF5 meets the full disk, the
    partial file stays whole, and the rerun (after freeing space) resumes from it."""
    mnt = small_tmpfs("16m")
    out = mnt / "ex"
    ballast = fill(mnt, 2 * MB)
    r = run_cli("export", tiny_scene_dir, "--format", "h5", "--out", out, "-q")
    need = float(re.search(r"needs about ([\d.]+) MB for \d+ windows", assert_clean_error(r, str(out))).group(1))
    ballast.unlink()
    ballast = fill(mnt, int((need + 0.12) * MB))
    r = run_cli("export", tiny_scene_dir, "--format", "h5", "--out", out, "-q")
    assert_clean_error(r, str(out / ".tiny.h5.partial"), "No space left on device")
    assert (out / ".tiny.h5.partial").is_file()
    ballast.unlink()
    r = run_cli("export", tiny_scene_dir, "--format", "h5", "--out", out, "-q", "--json")
    assert_ok(r)
    doc = json.loads(r.stdout)
    assert doc["skipped_complete"] >= 32 and doc["written"] > 0          # resumed: the first block was kept
    assert_same_h5(out / "tiny.h5", reference_h5)


_NO_PRECHECK = r"""
import sys
import evpose.core.data.event_writer, evpose.core.export.h5
noop = lambda *a, **k: None
evpose.core.data.event_writer.ensure_free_space = noop          # let HDF5 itself run into the full disk
evpose.core.export.h5.ensure_free_space = noop
from evpose.app.cli.main import main
sys.exit(main(sys.argv[1:]))
"""


def run_without_precheck(*args, timeout=120):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.run([sys.executable, "-c", _NO_PRECHECK, *map(str, args)], capture_output=True, text=True,
                       timeout=timeout, env=env)
    from fault_harness import Run

    return Run(args, p.returncode, p.stdout, p.stderr)


def test_hdf5_meeting_a_full_disk_does_not_crash(tiny_scene_dir, small_tmpfs, reference_h5):
    """When HDF5 itself hits ENOSPC (the free-space check disabled, as when another program fills the disk
    meanwhile): no SIGSEGV, one line, the broken partial file is discarded, and the rerun completes.
    Several amounts of free space, so that the disk fills at different writes."""
    mnt = small_tmpfs("8m")
    out = mnt / "ex"
    for leave in (48 << 10, 160 << 10, 400 << 10):
        ballast = fill(mnt, leave)
        r = run_without_precheck("export", tiny_scene_dir, "--format", "h5", "--out", out, "-q")
        assert_clean_error(r, str(out), "No space left on device")
        assert not (out / ".tiny.h5.partial").exists()
        ballast.unlink()
    assert_ok(run_cli("export", tiny_scene_dir, "--format", "h5", "--out", out, "-q"))
    assert_same_h5(out / "tiny.h5", reference_h5)


@pytest.mark.parametrize("damage", ["cut", "end_of_allocation"])
def test_a_damaged_partial_file_does_not_block_the_rerun(tiny_scene_dir, tmp_path, reference_h5, damage):
    """Issue: a damaged ``.NAME.h5.partial`` made every rerun fail (``addr overflow``), even with --force.
    ``cut``: the file is cut in the middle; ``end_of_allocation``: its superblock records an end of
    allocation below data it points to (what a crash after HDF5 evicted metadata leaves): it opens, and
    used to fail at the first write."""
    import struct

    out = tmp_path / "ex"
    assert_ok(run_cli("export", tiny_scene_dir, "--format", "h5", "--out", out, "-q"))
    part = out / ".tiny.h5.partial"
    (out / "tiny.h5").rename(part)
    (out / "export_manifest.json").unlink()
    data = bytearray(part.read_bytes())
    if damage == "cut":
        data = data[: len(data) // 2]
    else:
        assert data[8] == 0                          # superblock version 0: end of allocation at byte 40
        data[40:48] = struct.pack("<Q", _last_chunk_end(part) - 1)     # the last data chunk ends past it
    part.write_bytes(bytes(data))
    if damage == "end_of_allocation":                # it opens and says every row is done
        import h5py

        with h5py.File(part, "r") as f:
            assert f["_done"][:].all()
    r = run_cli("export", tiny_scene_dir, "--format", "h5", "--out", out, "-q", "--json")
    assert_ok(r)
    assert json.loads(r.stdout)["skipped_complete"] == 0          # started over
    assert_same_h5(out / "tiny.h5", reference_h5)


def _last_chunk_end(path) -> int:
    """The largest end offset (bytes) of a data chunk in the HDF5 file ``path``."""
    import h5py

    end = 0

    def info(ci):
        nonlocal end
        end = max(end, ci.byte_offset + ci.size)

    with h5py.File(path, "r") as f:
        f.visititems(lambda _n, o: o.id.chunk_iter(info) if isinstance(o, h5py.Dataset) and o.chunks else None)
    return end


# ------------------------------------------------------------------------------------------- file formats
def test_epose_export_on_a_full_disk_and_the_resumed_rerun(tiny_scene_dir, small_tmpfs, tmp_path):
    mnt = small_tmpfs("16m")
    out = mnt / "ex"
    args = ("--format", "epose", "-q", "--objects", "box", "--window-ms", "20")
    assert_ok(run_cli("export", tiny_scene_dir, "--out", tmp_path / "ref", *args))
    ballast = fill(mnt, 150 << 10)
    r = run_cli("export", tiny_scene_dir, "--out", out, *args)
    assert_clean_error(r, str(out), "No space left on device")
    assert no_hidden_leftovers(out) == []
    n_done = len(list(out.glob("*_data.mat")))
    ballast.unlink()
    r = run_cli("export", tiny_scene_dir, "--out", out, *args, "--json")
    assert_ok(r)
    assert json.loads(r.stdout)["skipped_complete"] <= n_done
    keep = lambda d: {k: v for k, v in d.items() if not k.startswith(".evpose") and k != "export_manifest.json"}
    got, ref = keep(snapshot(out)), keep(snapshot(tmp_path / "ref"))
    assert got.keys() == ref.keys() and describe_file_differences(got, ref, out, tmp_path / "ref") == []


# ------------------------------------------------------------------------------------------- import and synth
@pytest.fixture(scope="module")
def npz_source(tiny_scene_dir, tmp_path_factory) -> Path:
    from evpose.core.data.event_store import EventStore
    from evpose.core.data.manifest_reader import load_manifest
    from evpose.core.data.trajectory import Trajectory

    with EventStore(tiny_scene_dir / "events.h5") as es:
        ev = es.read(0, es.n_events)
    traj = Trajectory.load_csv(tiny_scene_dir / "trajectory.csv")
    cam = load_manifest(tiny_scene_dir).camera
    p = tmp_path_factory.mktemp("npz") / "rec.npz"
    np.savez(p, x=ev.x, y=ev.y, t=ev.t, p=ev.p, t_us=traj.t_us, position=traj.positions_m,
             quaternion=traj.quats_xyzw, K=cam.K, dist=cam.dist, width=np.int64(cam.width), height=np.int64(cam.height))
    return p


@pytest.mark.parametrize("precheck", [True, False], ids=["checked", "hdf5-hits-enospc"])
def test_import_npz_on_a_full_disk(npz_source, small_tmpfs, precheck):
    """Issue: ``import npz`` onto a full disk segfaulted and left ``.scene.import-*`` folders."""
    mnt = small_tmpfs("8m")
    out = mnt / "scene"
    before = snapshot(npz_source.parent)
    # checked: room to start the event file, not for a block of events; unchecked: HDF5 meets the full disk
    ballast = fill(mnt, 2 * MB if precheck else 300 << 10)
    run = run_cli if precheck else run_without_precheck
    r = run("import", "npz", npz_source, "--out", out, "-q")
    line = assert_clean_error(r, str(out), "--out", "No space left on device")
    if precheck:
        assert "needs about" in line                # refused before HDF5 met the full disk
    assert sorted(p.name for p in mnt.iterdir()) == ["ballast"]            # no scene, no staging folder
    ballast.unlink()
    assert_ok(run_cli("import", "npz", npz_source, "--out", out, "-q"))
    assert (out / "scene.toml").is_file()
    assert snapshot(npz_source.parent) == before


def test_synth_on_a_full_disk(small_tmpfs):
    mnt = small_tmpfs("2m")
    fill(mnt, 100 << 10)
    r = run_cli("synth", mnt / "s", "-q", "--duration", "0.05", "--objects", "box")
    assert_clean_error(r, str(mnt / "s"), "No space left on device")
    assert sorted(p.name for p in mnt.iterdir()) == ["ballast"]


# ------------------------------------------------------------------------------------------- read-only output
def test_read_only_output(tiny_scene_dir, npz_source, small_tmpfs):
    """Item 7: a read-only output gave a traceback; now one line naming the path, for every writer."""
    mnt = small_tmpfs("1m")
    (mnt / "existing").mkdir()
    r = subprocess.run(["mount", "-o", "remount,ro", str(mnt)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot remount read-only: {r.stderr.decode(errors='replace')}")
    for args, path in [
        (("export", tiny_scene_dir, "--format", "h5", "--out", mnt / "ex", "-q"), mnt / "ex"),
        (("export", tiny_scene_dir, "--format", "epose", "--out", mnt / "existing", "-q"), mnt / "existing"),
        (("import", "npz", npz_source, "--out", mnt / "scene", "-q"), mnt / "scene"),
        (("synth", mnt / "s", "-q", "--duration", "0.05", "--objects", "box"), mnt / "s"),
    ]:
        r = run_cli(*args)
        line = assert_clean_error(r, str(path))
        assert "Read-only file system" in line, line


def test_wrap_errors_lets_output_errors_through():
    """Importers turn every failure of parsing an input into an ImportFailure naming the input; a full or
    read-only output is not the input's fault and passes through (to be named as --out)."""
    import errno

    from evpose.core.importers.failure import ImportFailure, wrap_errors

    for code in (errno.ENOSPC, errno.EROFS, errno.EDQUOT):
        with pytest.raises(OSError) as ei:
            with wrap_errors("rec.npz", "array 'x'", "x"):
                raise OSError(code, os.strerror(code))
        assert not isinstance(ei.value, ImportFailure) and ei.value.errno == code
    with pytest.raises(ImportFailure, match=r"rec\.npz: array 'x': x: .*Input/output error"):
        with wrap_errors("rec.npz", "array 'x'", "x"):
            raise OSError(errno.EIO, os.strerror(errno.EIO))
