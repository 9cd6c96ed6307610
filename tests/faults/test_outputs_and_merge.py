"""Issue 22, parts 3 and 4: the merged BOP dataset is all or nothing, and outputs never land inside inputs
or on special files; unreadable scenes of a dataset are reported, never skipped.

The CLI cases run the real ``evpose`` command (one local Dask worker where a cluster is needed) and
compare snapshots of every input byte for byte; the assembly's leftovers are set up through the API
(:func:`evpose.core.dataset.bop_dataset.assemble_bop`, the code the command runs).
"""
from __future__ import annotations

import json
import os
import re
import shutil
import socket
import stat
import subprocess
from pathlib import Path

import pytest
from evpose_testing import TINY_SCENE, half_davis_camera
from fault_harness import assert_clean_error, assert_ok, run_cli, snapshot

from evpose.core.dataset.bop_dataset import BopAssemblyError, assemble_bop

NAMES = ["s1", "s2"]
#: Few windows per scene (0.2 s scenes, 50 ms windows) on one worker: the command's paths, quickly.
FAST = ("--window-ms", "50", "--workers", "1", "-q")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """Two tiny scenes with the objects box (class id 1) and cylinder (2); never modify it."""
    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    root = tmp_path_factory.mktemp("outputs") / "ds"
    for name, seed in zip(NAMES, (3, 4)):
        cfg = dict(TINY_SCENE, seed=seed, duration_s=0.2, objects=("box", "cylinder"))
        generate(root / name, SynthConfig(**cfg, camera=half_davis_camera()))
    return root


@pytest.fixture
def ds(dataset, tmp_path) -> Path:
    return Path(shutil.copytree(dataset, tmp_path / "ds", symlinks=True))


@pytest.fixture(scope="module")
def exports(dataset, tmp_path_factory) -> Path:
    """``OUT/<scene>``: each scene's BOP export, as ``dataset export`` leaves them before the merge."""
    from evpose.core.export import export_scene

    out = tmp_path_factory.mktemp("exports") / "out"
    for name in NAMES:
        export_scene(dataset / name, "bop", out / name, window_us=50_000)
    return out


@pytest.fixture
def out(exports, tmp_path) -> Path:
    return Path(shutil.copytree(exports, tmp_path / "out"))


def set_class_ids(scene: Path, box: int, cylinder: int) -> None:
    """The class ids of the scene's two objects (box first, then cylinder, in scene.toml)."""
    ids = iter((box, cylinder))
    toml = scene / "scene.toml"
    toml.write_text(re.sub(r"class_id = \d+", lambda _m: f"class_id = {next(ids)}", toml.read_text()))


def side_folders(out: Path) -> list[str]:
    """What an assembly may leave beside OUT/bop (must be nothing once it ended)."""
    return sorted(p.name for p in out.iterdir() if p.name.startswith(".bop."))


def scene_names(out: Path) -> dict:
    return json.loads((out / "bop" / "scene_names.json").read_text())


# ------------------------------------------------------------------------------------------- 3. merged BOP, CLI
def test_a_refused_merge_leaves_nothing_and_a_failing_scene_keeps_the_merged_dataset(ds, tmp_path):
    out = tmp_path / "out"
    cmd = ("dataset", "export", ds, "--format", "bop", "--out", out, *FAST)
    set_class_ids(ds / "s2", 2, 1)                    # s2 gives the box's id to the cylinder and back
    inputs = snapshot(ds)
    line = assert_clean_error(run_cli(*cmd), f"{ds / 's2' / 'scene.toml'}", "obj_id", "class ids")
    assert "'s1'" in line
    assert not out.exists() and snapshot(ds) == inputs          # refused before anything was written

    set_class_ids(ds / "s2", 1, 2)                    # fixed: the rerun needs no --force
    inputs = snapshot(ds)
    r = run_cli(*cmd)
    assert_ok(r)
    assert snapshot(ds) == inputs
    assert scene_names(out)["scenes"] == {"000000": "s1", "000001": "s2"} and scene_names(out)["missing"] == []
    assert f"{out / 'bop'}: one BOP dataset of 2 scene(s)" in r.stdout

    set_class_ids(ds / "s2", 3, 4)                    # s2's export now differs: refused without --force
    inputs, merged = snapshot(ds), snapshot(out / "bop")
    r = run_cli(*cmd)
    assert r.returncode == 3 and "Traceback" not in r.stderr and snapshot(ds) == inputs, r.stderr
    assert "s2: failed:" in r.stderr and "--force" in r.stderr
    assert f"bop: failed: {out / 'bop'}: kept as it was: it holds scene(s) 's2'" in r.stderr
    assert snapshot(out / "bop") == merged and side_folders(out) == []      # never a silently shorter dataset


# ------------------------------------------------------------------------------------------- 3. merged BOP, API
def test_a_merge_refused_while_assembling_keeps_the_previous_dataset_or_none(out):
    """The bytes check of the assembly (after the exports): the staging folder goes, OUT/bop stays as it was."""
    assemble_bop(out, NAMES, NAMES)
    before = snapshot(out / "bop")
    model = out / "s2" / "models" / "obj_000001.ply"
    data = model.read_bytes()
    model.unlink()                                     # the merged dataset's hard link keeps the old bytes
    model.write_bytes(data + b"\0")
    with pytest.raises(BopAssemblyError, match="obj_000001.ply: differs"):
        assemble_bop(out, NAMES, NAMES)
    assert snapshot(out / "bop") == before and side_folders(out) == []
    shutil.rmtree(out / "bop")
    with pytest.raises(BopAssemblyError, match="obj_000001.ply: differs"):
        assemble_bop(out, NAMES, NAMES)
    assert not (out / "bop").exists() and side_folders(out) == []


def test_a_scene_that_fails_keeps_the_merged_dataset_or_is_listed_missing(out):
    assemble_bop(out, NAMES, ["s1"])                  # never merged before: left out, its id kept free
    assert scene_names(out)["scenes"] == {"000000": "s1"} and scene_names(out)["missing"] == ["s2"]
    assemble_bop(out, NAMES, NAMES)
    before = snapshot(out / "bop")
    with pytest.raises(BopAssemblyError, match=r"kept as it was: it holds scene\(s\) 's2'"):
        assemble_bop(out, NAMES, ["s1"])
    assert snapshot(out / "bop") == before and side_folders(out) == []


def test_leftovers_of_an_earlier_refused_merge_are_replaced(dataset, out):
    """What evpose before this change left when a merge was refused: models and some scene files as hard
    links of the scene exports, no scene_names.json; the rerun's exports rewrote those files since.
    Recognised as evpose's (by the exports' logs) and replaced; a user's file in it refuses the run and is kept."""
    from evpose.core.export import export_scene

    bop = out / "bop"
    (bop / "models").mkdir(parents=True)
    for p in (out / "s1" / "models").glob("*.ply"):
        os.link(p, bop / "models" / p.name)
    for p in sorted((out / "s1" / "test" / "000000").rglob("*")):
        if p.is_file():
            (bop / "test" / "000000" / p.parent.relative_to(out / "s1" / "test" / "000000")).mkdir(
                parents=True, exist_ok=True)
            os.link(p, bop / "test" / "000000" / p.relative_to(out / "s1" / "test" / "000000"))
    export_scene(dataset / "s1", "bop", out / "s1", window_us=50_000)           # resumed: its models rewritten
    assert os.stat(bop / "models" / "obj_000001.ply").st_nlink == 1
    (bop / "test" / "000000" / "notes.txt").write_text("mine")
    with pytest.raises(BopAssemblyError, match="notes.txt"):
        assemble_bop(out, NAMES, NAMES)
    assert (bop / "test" / "000000" / "notes.txt").read_text() == "mine"
    (bop / "test" / "000000" / "notes.txt").unlink()
    assemble_bop(out, NAMES, NAMES)
    assert scene_names(out)["scenes"] == {"000000": "s1", "000001": "s2"}
    assert (bop / "test" / "000001" / "scene_gt.json").is_file() and side_folders(out) == []


def test_leftovers_of_a_killed_assembly_are_removed_or_put_back(out):
    """kill -9 in the middle: a staging folder of a dead process is removed; a dataset moved aside for
    the swap is put back when OUT/bop is missing (and so still keeps its scenes)."""
    dead = subprocess.Popen(["true"])
    dead.wait()
    assemble_bop(out, NAMES, NAMES)
    whole = snapshot(out / "bop")
    (out / "bop").rename(out / f".bop.replaced-{dead.pid}-0a1b")
    stage = out / f".bop.assemble-{dead.pid}-0c0d"
    (stage / "models").mkdir(parents=True)
    (stage / "models" / "obj_000001.ply").write_bytes(b"half")
    with pytest.raises(BopAssemblyError, match="kept as it was"):        # put back: s2 cannot be dropped
        assemble_bop(out, NAMES, ["s1"])
    assert snapshot(out / "bop") == whole and side_folders(out) == []
    assemble_bop(out, NAMES, NAMES)
    assert side_folders(out) == [] and scene_names(out)["missing"] == []


def test_the_merged_dataset_is_on_disk_before_it_is_renamed_into_place(out, monkeypatch):
    """Durability of the swap (as ``tests/core/test_durability.py`` pins the scene's staging folder): the staging
    folder's files are synced, logged, then it is renamed to OUT/bop and OUT fsynced; the earlier one goes after."""
    from evpose.core.data import atomic

    assemble_bop(out, NAMES, NAMES)
    events = []
    real_rename, real_fsync, real_sync = os.rename, os.fsync, atomic.sync_filesystem

    def rename(src, dst):
        events.append(("rename", Path(src).name, str(dst)))
        return real_rename(src, dst)

    def fsync(fd):
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        return real_fsync(fd)

    def syncfs(path):
        events.append(("syncfs", Path(path).name))
        return real_sync(path)

    monkeypatch.setattr(os, "rename", rename)
    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(atomic, "sync_filesystem", syncfs)
    assemble_bop(out, NAMES, NAMES)
    monkeypatch.undo()
    i_in = next(i for i, e in enumerate(events) if e[0] == "rename" and e[2] == str(out / "bop"))
    stage = events[i_in][1]
    assert stage.startswith(".bop.assemble-") and ("syncfs", stage) in events[:i_in]
    assert ("fsync", str(out)) in events[i_in + 1:]
    assert [e[0] for e in events[:i_in] if e[0] == "rename"] == ["rename"]          # the earlier one moved aside
    assert (out / "bop" / ".evpose").is_dir() and side_folders(out) == []


# ------------------------------------------------------------------------------------------- 4. special files
def _special(kind: str, path: Path):
    if kind == "fifo":
        os.mkfifo(path)
        return None
    if kind == "socket":
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(path))
        return s
    if os.geteuid() != 0:
        pytest.skip("a device node can only be made as root")
    os.mknod(path, 0o600 | stat.S_IFCHR, os.makedev(1, 3))        # our own null device, in the test's folder
    return None


KIND_TEST = {"fifo": stat.S_ISFIFO, "socket": stat.S_ISSOCK, "device": stat.S_ISCHR}


@pytest.mark.parametrize("kind", list(KIND_TEST))
def test_an_out_that_is_a_special_file_is_refused_never_replaced(ds, tmp_path, kind):
    """The tester's ``dataset report DS --out /dev/full`` replaced the device node, exit 0."""
    target = tmp_path / kind
    keep = _special(kind, target)
    cmds = [("dataset", "report", ds, "--out", target, "--workers", "1", "-q")]
    if kind == "fifo":
        cmds += [("dataset", "export", ds, "--format", "epose", "--out", target, *FAST),
                 ("export", ds / "s1", "--format", "epose", "--out", target, "-q")]
    try:
        inputs = snapshot(ds)
        for cmd in cmds:
            assert_clean_error(run_cli(*cmd, timeout=60), str(target), "--out", "never replaces it")
            assert KIND_TEST[kind](os.lstat(target).st_mode), f"{cmd[:2]} replaced the {kind}"
        assert snapshot(ds) == inputs
    finally:
        if keep is not None:
            keep.close()


def test_every_write_refuses_to_replace_a_special_file(tmp_path):
    """The same rule inside the writers (the report is written long after the command checked --out)."""
    from evpose.core.data.atomic import atomic_write_bytes, write_atomic
    from evpose.core.errors import NotOursError

    fifo = tmp_path / "report.html"
    os.mkfifo(fifo)
    for write in (write_atomic, atomic_write_bytes):
        with pytest.raises(NotOursError, match="FIFO"):
            write(fifo, b"<html>")
        assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and sorted(os.listdir(tmp_path)) == ["report.html"]


# ------------------------------------------------------------------------------------------- 4. outputs into inputs
def test_outputs_inside_the_inputs_are_refused(ds, tmp_path):
    """The tester's ``dataset export --out DS/s1`` wrote 3,669 files into the scene, exit 0."""
    link = tmp_path / "link"
    link.symlink_to(ds / "s1")
    inputs = snapshot(ds)
    cases = [("dataset", "export", ds, "--format", "epose", "--out", ds / "s1", "--workers", "1"),
             ("dataset", "report", ds, "--out", ds / "s2" / "report.html", "--workers", "1"),
             ("export", ds / "s1", "--format", "epose", "--out", ds / "s1" / "export"),
             ("export", ds / "s2" / "scene.toml", "--format", "bop", "--out", link / "x"),  # another scene, linked
             ("dataset", "import", "epose-bag", ds, "--assets", tmp_path / "assets", "--out", ds / "imported",
              "--workers", "1")]
    for cmd in cases:
        r = run_cli(*cmd, "-q", timeout=60)
        assert_clean_error(r, str(cmd[cmd.index("--out") + 1]), "--out", "never writes into its inputs")
        assert snapshot(ds) == inputs, cmd
    assert not (ds / "s1" / "export").exists() and not (ds / "imported").exists()


def test_a_dataset_export_never_writes_over_its_inputs(ds, tmp_path):
    """The same check, in the process: inside (or equal to) the dataset folder, and an OUT/<scene> that would
    be a scene folder (a dataset.toml listing scenes elsewhere)."""
    from evpose.core.dataset.dataset import Dataset
    from evpose.core.dataset.export import check_dataset_export
    from evpose.core.errors import InputError

    dataset = Dataset.open(ds)
    for out, fmt, says in ((ds / "exports", "bop", "inside the dataset folder"), (ds, "h5", "is the dataset folder"),
                           (ds / "s2", "epose", "is the scene folder")):
        with pytest.raises(InputError, match=says):
            check_dataset_export(dataset, out, fmt)
    (tmp_path / "list").mkdir()
    (tmp_path / "list" / "dataset.toml").write_text(f'format = "evpose-dataset/1"\nscenes = ["{ds / "s1"}"]\n')
    with pytest.raises(InputError, match=f"{ds / 's1'} would hold {ds / 's1'}"):
        check_dataset_export(Dataset.open(tmp_path / "list"), ds, "epose")
    check_dataset_export(dataset, tmp_path / "elsewhere", "bop")


# ------------------------------------------------------------------------------------------- 4. unreadable scenes
def test_unreadable_scenes_are_reported_failed_never_skipped(ds, tmp_path):
    (ds / "s3").symlink_to("s3")                          # a scene folder that is a symbolic link loop
    (ds / "s4").mkdir()
    (ds / "s4" / "scene.toml").symlink_to("scene.toml")   # a scene.toml that is one
    (ds / "s5").mkdir()
    os.mkfifo(ds / "s5" / "scene.toml")
    inputs = snapshot(ds)
    r = run_cli("dataset", "info", ds, "--workers", "1", "--json", "-q")
    assert snapshot(ds) == inputs
    assert r.returncode == 3, r.stderr
    doc = json.loads(r.stdout)
    assert list(doc["scenes"]) == ["s1", "s2"] and list(doc["failed"]) == ["s3", "s4", "s5"]
    assert "symbolic links" in doc["failed"]["s3"] and "symbolic links" in doc["failed"]["s4"]
    assert "s5/scene.toml: is a FIFO" in doc["failed"]["s5"]
    assert all(f"{name}: failed:" in r.stderr for name in ("s3", "s4", "s5"))

    from evpose.core.dataset.dataset import Dataset
    from evpose.core.dataset.export import export_dataset

    for name in NAMES:                                    # the export sees them too (no cluster needed for them)
        shutil.rmtree(ds / name)
    res = export_dataset(None, Dataset.open(ds), "epose", tmp_path / "out")
    assert list(res.failed) == ["s3", "s4", "s5"] and res.scenes == {}

    os.mkfifo(ds / "dataset.toml")                        # refused, not passed over for the subfolders
    assert_clean_error(run_cli("dataset", "info", ds, "--workers", "1", timeout=60), str(ds / "dataset.toml"), "FIFO")
