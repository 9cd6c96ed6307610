"""``dataset import epose-bag``: every bag of a raw folder -> one scene, on a Dask LocalCluster of 2 workers.

Bags are written like the epose-bag importer tests (``write_bag`` of test_importers) with tiny random event
streams; the objects, meshes and published clock priors come from the real E-POSE assets (skipped when absent).
Each imported scene must equal what ``evpose import epose-bag BAG --assets --scene --sequence --out`` writes:
the same files, byte for byte, except ``import_report.json`` whose ``runtime_s`` differs (and the name of the
ownership log, which carries the writer's pid).
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from test_importers import write_bag

from evpose.core.data.events import Cancelled, EventArray
from evpose.core.data.manifest_reader import load_manifest
from evpose.core.data.trajectory import Trajectory
from evpose.core.dataset.dataset import Dataset, DatasetError
from evpose.core.dataset.import_bags import import_dataset, plan_bags

# bag (relative to RAW_DIR) -> its E-POSE scene (scenes.json key) and sequence (as published in time_shifts.csv)
EPOSE = {"potted meat/t_10_ML.bag": ("potted_meat_can", "T_10_ml"), "Mustard_t_10_GL.bag": ("mustard_bottle", "t_10_gl"),
         "Potted_Meat_Can_R_05_LL.bag": ("potted_meat_can", "R_05_ll")}
#: their published clock priors (time_shifts.csv, seconds; potted meat R_05_ll was published as 0: a warning)
SHIFT_S = {"potted_meat_can_T_10_ml": -0.0229971408843994, "mustard_bottle_t_10_gl": -0.0371060371398926,
           "potted_meat_can_R_05_ll": 0.0}
GOOD = {rel: f"{s}_{q}" for rel, (s, q) in EPOSE.items()}       # -> dataset scene name
UNMATCHED = "calibration_run.bag"
BROKEN = "wood_block_R_10_ml.bag"          # matches wood_block / R_10_ml, but the file is cut in half


def tiny_bag(path: Path, seed: int, n: int = 2000) -> Path:
    """A bag of ``n`` random DAVIS346 events over 0.2 s and a static camera pose sampled every 5 ms."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 200_000, n)) + 1_600_000_000_000_000 + seed * 10**6
    ev = EventArray(rng.integers(0, 346, n), rng.integers(0, 260, n), t, rng.integers(0, 2, n))
    t_pose = np.arange(t[0] - 20_000, t[-1] + 20_000, 5000)
    tr = Trajectory(t_pose, np.zeros((len(t_pose), 3)) + [0, -0.5, 0.4] + rng.normal(0, 0.01, 3),
                    np.tile([0, 0, 0, 1.0], (len(t_pose), 1)))
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_bag(path, ev, tr, numpy_encode=True, msg_events=500)


@pytest.fixture(scope="module")
def raw_dir(tmp_path_factory) -> Path:
    raw = tmp_path_factory.mktemp("raw")
    for k, rel in enumerate([*GOOD, UNMATCHED, BROKEN]):
        tiny_bag(raw / rel, k)
    data = (raw / BROKEN).read_bytes()
    (raw / BROKEN).write_bytes(data[: len(data) // 2])
    (raw / "notes.txt").write_text("not a bag")
    for p in raw.rglob("*"):
        if p.is_file():
            p.chmod(0o444)               # inputs are read-only: an import that wrote into them would fail
    return raw


@pytest.fixture(scope="module")
def client():
    """The cluster the CLI uses (evpose's settings: SIGINT ignored by workers, no MALLOC_TRIM_THRESHOLD_)."""
    from evpose.core.dataset.cluster import ClusterSpec, open_client

    with open_client(ClusterSpec(workers=2)) as cl:
        yield cl


@pytest.fixture(scope="module")
def first_run(request, raw_dir, tmp_path_factory):
    """The dataset import of ``raw_dir`` (asks for the assets and the cluster only when a test needs it)."""
    assets = request.getfixturevalue("assets_dir")
    client = request.getfixturevalue("client")
    out = tmp_path_factory.mktemp("ds") / "dataset"
    seen = []
    res = import_dataset(client, raw_dir, assets, out, progress=lambda f, m: seen.append((f, m)))
    return res, out, seen


def cli_import(bag: Path, assets: Path, scene: str, sequence: str, out: Path) -> dict:
    """``evpose import epose-bag BAG --assets A --scene S --sequence Q --out OUT --json -q`` in this process."""
    import warnings

    from evpose.app.cli.main import main

    buf, shown = io.StringIO(), warnings.showwarning
    try:
        with contextlib.redirect_stdout(buf):
            rc = main(["import", "epose-bag", str(bag), "--assets", str(assets), "--scene", scene, "--sequence",
                       sequence, "--out", str(out), "--json", "-q"])
    finally:
        warnings.showwarning = shown
    assert rc == 0
    return json.loads(buf.getvalue())


def scene_files(folder: Path) -> dict:
    """relative path -> bytes of every file, the ownership log under one name (its name holds the pid)."""
    files = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            rel = p.relative_to(folder).as_posix()
            files[".evpose/owned.log" if rel.startswith(".evpose/owned-") else rel] = p.read_bytes()
    return files


def logged(log: bytes) -> list:
    """The entries of an ownership log without the times, and without the size of import_report.json (its
    runtime_s differs)."""
    entries = [json.loads(ln) for ln in log.split(b"\n") if ln]
    return [{k: v for k, v in e.items() if k != "mtime_ns" and not (k == "size" and e["f"] == "import_report.json")}
            for e in entries]


def stat_all(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): (p.stat().st_mtime_ns, p.read_bytes()) for p in sorted(folder.rglob("*"))
            if p.is_file()}


# ============================================================================================ planning
def test_plan_matches_both_layouts_case_insensitively(assets_dir, tmp_path):
    names = {"bleach/R_01_ML.bag": "bleach_cleanser_R_01_ml",            # <scene>/<sequence>.bag, short name
             "potted meat/t_10_ML.bag": "potted_meat_can_T_10_ml",        # folder named as in time_shifts.csv
             "Mustard_t_10_GL.bag": "mustard_bottle_t_10_gl",             # <scene>_<sequence>.bag
             "sub/deeper/five_obj_clut-R-05-ml.bag": "five_obj_clut_R_05_ml",
             "three_obj_clut_T_10_ML.bag": "three_obj_clut_T_10_ml",      # not three_obj + "clut_T_10_ML"
             "three_obj_r_01_gl.BAG": "three_obj_r_01_gl",
             "misc/calibration.bag": None, "R_01_ml.bag": None, "five_R_01_ml.bag": None}
    for rel in names:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"")
    (tmp_path / "bleach" / "R_01_ml.txt").write_text("")
    plans = plan_bags(tmp_path, assets_dir)
    assert [p.bag for p in plans] == sorted((tmp_path / r for r in names), key=lambda p: p.relative_to(tmp_path).as_posix())
    for p in plans:
        rel = p.bag.relative_to(tmp_path).as_posix()
        if names[rel] is None:
            assert p.error and p.scene is None and p.name == rel and "\n" not in p.error
            assert p.error.startswith(str(p.bag) + ": ")
        else:
            assert p.error is None and p.name == names[rel] == f"{p.scene}_{p.sequence}", rel
    by = {p.bag.relative_to(tmp_path).as_posix(): p for p in plans}
    assert (by["bleach/R_01_ML.bag"].scene, by["bleach/R_01_ML.bag"].sequence) == ("bleach_cleanser", "R_01_ml")
    assert "time_shifts.csv" in by["misc/calibration.bag"].error
    assert "'five' is ambiguous" in by["five_R_01_ml.bag"].error and "'five_obj_clut'" in by["five_R_01_ml.bag"].error


def test_plan_names_a_bag_that_two_splits_match(tmp_path):
    """A name that splits into two published scene/sequence pairs is that bag's failure, naming both."""
    assets = tmp_path / "assets"
    assets.mkdir()
    (assets / "scenes.json").write_text(json.dumps({"scenes": {"cup": {"objects": {}}, "cup_lid": {"objects": {}}}}))
    (assets / "time_shifts.csv").write_text("scene,sequence,shift_s\ncup,lid_r_01,0.1\ncup_lid,r_01,0.2\n")
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "cup_lid_R_01.bag").write_bytes(b"")
    (raw / "cup_lid_R_02.bag").write_bytes(b"")
    (raw / "cup").mkdir()
    (raw / "cup" / "LID_r_01.bag").write_bytes(b"")
    a, b, c = plan_bags(raw, assets)
    assert (a.name, a.sequence) == ("cup_lid_r_01", "lid_r_01")            # the folder form decides first
    assert b.error == f"{raw / 'cup_lid_R_01.bag'}: ambiguous: it could be cup/lid_r_01 or cup_lid/r_01"
    assert c.error.startswith(f"{raw / 'cup_lid_R_02.bag'}: matches no E-POSE scene")


def test_plan_refuses_two_bags_for_one_scene(assets_dir, tmp_path):
    for rel in ("bleach/R_01_ml.bag", "bleach_cleanser_r_01_ML.bag"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"")
    with pytest.raises(DatasetError) as ei:
        plan_bags(tmp_path, assets_dir)
    msg = str(ei.value)
    assert str(tmp_path / "bleach/R_01_ml.bag") in msg and str(tmp_path / "bleach_cleanser_r_01_ML.bag") in msg
    assert "bleach_cleanser_R_01_ml" in msg


def test_plan_refuses_a_raw_dir_without_bags(assets_dir, tmp_path):
    with pytest.raises(DatasetError, match="no .bag files"):
        plan_bags(tmp_path, assets_dir)
    with pytest.raises(DatasetError, match="not a folder"):
        plan_bags(tmp_path / "absent", assets_dir)


# ============================================================================================ importing
def test_each_scene_equals_the_single_scene_import(first_run, raw_dir, assets_dir, tmp_path):
    res, out, _ = first_run
    assert list(res.scenes) == [GOOD[r] for r in sorted(GOOD)]                  # in bag order
    assert [r.name for r in Dataset.open(out).scenes] == sorted(GOOD.values())
    for rel, name in GOOD.items():
        doc = res.scenes[name]
        assert doc["skipped"] is False and doc["bag"] == str(raw_dir / rel)
        scene, sequence = EPOSE[rel]
        single = tmp_path / name
        ref = cli_import(raw_dir / rel, assets_dir, scene, sequence, single)
        got, want = scene_files(out / name), scene_files(single)
        assert set(got) == set(want) and {"events.h5", "trajectory.csv", "scene.toml", "import_report.json"} <= set(got)
        for f in want:
            if f == "import_report.json":
                a, b = json.loads(got[f]), json.loads(want[f])
                assert a.pop("runtime_s") > 0 and b.pop("runtime_s") > 0
                assert a == b, f
                assert a["time_shift"]["sequence"] == sequence and a["epose_scene"] == scene
            elif f == ".evpose/owned.log":     # the same files logged, with their sizes
                assert logged(got[f]) == logged(want[f])
            else:
                assert got[f] == want[f], f
        assert doc["scene"] == str(out / name) and ref["scene"] == str(single)
        assert doc["report"] == str(out / name / "import_report.json") and doc["runtime_s"] > 0
        assert load_manifest(out / name).clock_offset_us == round(SHIFT_S[name] * 1e6)
        assert any("published shift" in w for w in doc["warnings"]) == (SHIFT_S[name] == 0)
        assert {k: v for k, v in doc.items() if k not in ("scene", "report", "runtime_s", "skipped", "bag", "match")} \
            == {k: v for k, v in ref.items() if k not in ("scene", "report", "runtime_s")}


def test_unmatched_and_broken_bags_fail_alone(first_run, raw_dir):
    res, out, seen = first_run
    assert list(res.failed) == [UNMATCHED, "wood_block_R_10_ml"]
    for line in res.failed.values():
        assert "\n" not in line and line.strip() == line
    assert res.failed[UNMATCHED].startswith(f"{raw_dir / UNMATCHED}: matches no E-POSE scene")
    assert res.failed["wood_block_R_10_ml"].startswith(f"{raw_dir / BROKEN}: ")
    assert "ROS1 bag" in res.failed["wood_block_R_10_ml"]
    assert sorted(os.listdir(out)) == sorted(GOOD.values())          # nothing of the failed bags, no staging
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions) and fractions[0] == 0.2 and fractions[-1] == 1.0 and len(fractions) == 5
    assert seen[-1][1] == "5/5 bags, 2 failed"
    assert res.runtime_s > 0


def test_rerun_skips_completed_scenes(first_run, raw_dir, assets_dir, client):
    res, out, _ = first_run
    before = stat_all(out)
    again = import_dataset(client, raw_dir, assets_dir, out)
    assert stat_all(out) == before                                    # nothing rewritten
    assert again.failed == res.failed
    assert list(again.scenes) == list(res.scenes)
    for name, doc in again.scenes.items():
        assert doc["skipped"] is True
        strip = ("skipped", "runtime_s")
        assert {k: v for k, v in doc.items() if k not in strip} == {k: v for k, v in res.scenes[name].items()
                                                                   if k not in strip}


def test_rerun_leaves_what_is_not_this_bags_scene_alone(first_run, raw_dir, assets_dir, client, tmp_path):
    _, out0, _ = first_run
    raw, out = tmp_path / "raw", tmp_path / "dataset"
    shutil.copytree(raw_dir, raw)
    shutil.copytree(out0 / "potted_meat_can_T_10_ml", out / "potted_meat_can_T_10_ml")   # imported from raw_dir's bag
    (out / "mustard_bottle_t_10_gl").mkdir()
    (out / "mustard_bottle_t_10_gl" / "mine.txt").write_text("a user's file")
    before = stat_all(out)
    res = import_dataset(client, raw, assets_dir, out)
    after = stat_all(out)
    assert {k: after.get(k) for k in before} == before                # nothing touched
    assert {k.split("/")[0] for k in set(after) - set(before)} == set(res.scenes) == {"potted_meat_can_R_05_ll"}
    assert "holds a scene imported from" in res.failed["potted_meat_can_T_10_ml"]
    assert "is not a scene imported by evpose; it is left alone" in res.failed["mustard_bottle_t_10_gl"]
    # the same bag, changed after its import, is not replaced either
    shutil.rmtree(out / "mustard_bottle_t_10_gl")
    assert import_dataset(client, raw, assets_dir, out).scenes["mustard_bottle_t_10_gl"]["skipped"] is False
    bag = raw / "Mustard_t_10_GL.bag"
    bag.chmod(0o644)
    bag.write_bytes(bag.read_bytes() + b"\0")
    res = import_dataset(client, raw, assets_dir, out)
    assert "before the bag changed" in res.failed["mustard_bottle_t_10_gl"]


def test_cancel_stops_the_run(raw_dir, assets_dir, client, tmp_path):
    with pytest.raises(Cancelled, match="cancelled after"):
        import_dataset(client, raw_dir, assets_dir, tmp_path / "ds", cancel=lambda: True)


def test_cli_imports_a_dataset_that_the_dataset_commands_open(raw_dir, assets_dir, tmp_path):
    """``evpose dataset import epose-bag RAW --assets A --out DS``: exit 3 (two bags failed, named on stderr,
    no traceback), one JSON document; then ``evpose dataset info DS`` reads the imported scenes."""
    import json
    import subprocess
    import sys

    out = tmp_path / "ds"

    def evpose(*args):
        return subprocess.run([sys.executable, "-m", "evpose", *map(str, args)], capture_output=True, text=True,
                              timeout=600)

    r = evpose("dataset", "import", "epose-bag", raw_dir, "--assets", assets_dir, "--out", out, "--workers", "1",
               "--json", "-q")
    assert r.returncode == 3, r.stderr
    doc = json.loads(r.stdout)
    assert sorted(doc["scenes"]) == sorted(GOOD.values()) and len(doc["failed"]) == 2
    assert "Traceback" not in r.stderr and r.stderr.count("failed:") == 2
    r = evpose("dataset", "info", out, "--workers", "1", "--json", "-q")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert list(info["scenes"]) == sorted(GOOD.values()) and info["failed"] == {}
    assert all(d["n_events"] > 0 for d in info["scenes"].values())
