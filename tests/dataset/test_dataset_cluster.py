"""The dataset commands on a Dask LocalCluster of 2 workers (issue 13, "Must show"): the same numbers and
files as the single-scene commands, a worker killed mid-export, an interrupted export resumed, a broken
scene reported while the others complete, and the same export through an external ``dask scheduler`` +
``dask worker`` pair."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from evpose.core.data.events import Cancelled
from evpose.core.dataset.dataset import Dataset
from evpose_testing import describe_file_differences

#: Fields that measure time, not results.
TIMING_KEYS = {"runtime_s", "timings_s", "pool_startup_s", "jobs"}
#: Fields of a manifest that count one run's work (written now / complete before: a resumed run differs).
RUN_KEYS = TIMING_KEYS | {"written", "skipped_complete"}


def without_timings(doc, keys=TIMING_KEYS):
    if isinstance(doc, dict):
        return {k: without_timings(v, keys) for k, v in doc.items() if k not in keys}
    if isinstance(doc, list):
        return [without_timings(v, keys) for v in doc]
    return doc


def tree(root: Path, keys=RUN_KEYS) -> dict[str, bytes]:
    """Every file under ``root`` (but evpose's bookkeeping in .evpose/) with its bytes; JSON manifests
    without the fields ``keys``."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = str(p.relative_to(root))
        if p.is_dir() or rel.startswith(".evpose") or "/.evpose" in rel:
            continue
        data = p.read_bytes()
        if p.name == "export_manifest.json":
            data = json.dumps(without_timings(json.loads(data), keys), sort_keys=True).encode()
        out[rel] = data
    return out


def single_scene_exports(dataset_root: Path, out: Path, fmt: str) -> None:
    from evpose.core.export import export_scene

    for ref in Dataset.open(dataset_root).scenes:
        export_scene(ref.path, fmt, out / ref.name)


@pytest.fixture(scope="module")
def reference_epose(tiny_dataset, tmp_path_factory) -> dict:
    """The epose export of every scene by the single-scene function, one after the other."""
    out = tmp_path_factory.mktemp("reference")
    single_scene_exports(tiny_dataset, out, "epose")
    return {name: tree(out / name) for name in ("scene_a", "scene_b", "scene_c")}


def test_dataset_sync_and_score_equal_the_single_scene_commands(dask_client, tiny_dataset):
    from evpose.core.align.sync_run import SyncOptions
    from evpose.core.dataset.batch import map_scenes
    from evpose.core.dataset.tasks import score_task, sync_task

    ds = Dataset.open(tiny_dataset)
    sync = map_scenes(dask_client, ds, sync_task, SyncOptions(), label="sync")
    score = map_scenes(dask_client, ds, score_task, 10_000, label="score")
    assert sync.failed == {} and score.failed == {}
    assert list(sync.scenes) == ["scene_a", "scene_b", "scene_c"]
    for ref in ds.scenes:
        assert without_timings(sync.scenes[ref.name]) == without_timings(sync_task(str(ref.path), None, SyncOptions()))
        assert without_timings(score.scenes[ref.name]) == without_timings(score_task(str(ref.path), None, 10_000))
    # each answer is its own scene's (the scenes have different clocks)
    offsets = [sync.scenes[n]["offset_us"] for n in ("scene_a", "scene_b", "scene_c")]
    assert len(set(offsets)) == 3


def _contexts_kept() -> int:
    from evpose.core.dataset import dask_windows

    return len(dask_windows._contexts)


def test_dataset_export_equals_the_single_scene_exports(dask_client, tiny_dataset, reference_epose, tmp_path):
    from evpose.core.dataset.export import export_dataset

    res = export_dataset(dask_client, Dataset.open(tiny_dataset), "epose", tmp_path / "out")
    assert res.failed == {} and list(res.scenes) == ["scene_a", "scene_b", "scene_c"]
    for name, ref in reference_epose.items():
        got = tree(tmp_path / "out" / name)
        assert got.keys() == ref.keys(), name
        assert describe_file_differences(got, ref) == [], name
    # every window in one chunk (cut from the measured cost: probes first unless an earlier scene measured it),
    # and no worker keeps a finished scene's context (scene, meshes, rasteriser caches: issue 27.5)
    for doc in res.scenes.values():
        assert sum(doc["chunks"]) == doc["written"], doc["chunks"]
    assert set(dask_client.run(_contexts_kept).values()) == {0}
    # a rerun skips what is complete
    again = export_dataset(dask_client, Dataset.open(tiny_dataset), "epose", tmp_path / "out")
    assert all(s["written"] == 0 and s["skipped_complete"] > 0 for s in again.scenes.values())


def test_h5_dataset_export_is_byte_identical_to_the_single_scene_export(dask_client, tiny_dataset, tmp_path):
    """HDF5 through the cluster (frames come back to the driver in chunks capped in bytes): the same file, byte for
    byte, as the single-scene export in one process."""
    from evpose.core.dataset.export import export_dataset
    from evpose.core.export import export_scene

    ref = Dataset.open(tiny_dataset).scenes[0]
    export_scene(ref.path, "h5", tmp_path / "single")
    res = export_dataset(dask_client, Dataset.open(tiny_dataset), "h5", tmp_path / "out")
    assert res.failed == {}
    got, want = tree(tmp_path / "out" / ref.name), tree(tmp_path / "single")
    assert got.keys() == want.keys() and describe_file_differences(got, want) == []


def test_bop_dataset_export_equals_the_single_scene_exports(dask_client, tiny_dataset, tmp_path):
    """BOP through the cluster: the workers encode each window's scene_gt / scene_gt_info / scene_camera /
    scene_times JSON and journal line, the driver joins them (issue 27.2). Every scene's folder holds the bytes of
    the single-scene export in one process (manifests without the run's timings)."""
    from evpose.core.dataset.export import export_dataset

    single_scene_exports(tiny_dataset, tmp_path / "single", "bop")
    res = export_dataset(dask_client, Dataset.open(tiny_dataset), "bop", tmp_path / "out")
    assert res.failed == {}
    for name in ("scene_a", "scene_b", "scene_c"):
        got, want = tree(tmp_path / "out" / name), tree(tmp_path / "single" / name)
        assert any(k.endswith("scene_gt.json") for k in want) and got.keys() == want.keys(), name
        assert describe_file_differences(got, want) == [], name


def test_bop_shards_through_the_cluster(dask_client, tiny_dataset, tmp_path):
    """``--bop-shards`` on the cluster (issue 27.4): chunks hold whole shards, so each scene's folder holds the bytes
    of its single-scene export (with the dataset's scene id in the keys), and OUT/bop/test_web numbers every scene's
    shards on, with one key_to_shard.json."""
    from evpose.core.dataset.export import export_dataset
    from evpose.core.export import export_scene

    fo = {"shard_windows": 8}
    res = export_dataset(dask_client, Dataset.open(tiny_dataset), "bop", tmp_path / "out", format_options=fo)
    assert res.failed == {}
    n_keys = 0
    for k, ref in enumerate(Dataset.open(tiny_dataset).scenes):
        export_scene(ref.path, "bop", tmp_path / "single" / ref.name, format_options={**fo, "key_scene_id": k})
        got, want = tree(tmp_path / "out" / ref.name), tree(tmp_path / "single" / ref.name)
        assert any(k.endswith(".tar") for k in want) and got.keys() == want.keys(), ref.name
        assert describe_file_differences(got, want) == [], ref.name
        assert sum(res.scenes[ref.name]["chunks"]) == res.scenes[ref.name]["written"]
        n_keys += res.scenes[ref.name]["written"]
    keys = json.loads((tmp_path / "out" / "bop" / "test_web" / "key_to_shard.json").read_text())
    assert len(keys) == n_keys and {key[:6] for key in keys} == {"000000", "000001", "000002"}


def test_label_sigma_through_the_cluster(dask_client, tiny_dataset, tmp_path):
    """--label-sigma on the cluster (issue 28.1): each window's sigma travels with its task, so the E-POSE files hold
    the bytes of the single-scene export with the same option, sigma fields included."""
    import scipy.io

    from evpose.core.dataset.export import export_dataset
    from evpose.core.export import export_scene
    from evpose.core.label.uncertainty import InputSigmas, LabelSigmaOptions

    opts = LabelSigmaOptions(InputSigmas(offset_us=2000, pose_mm=1.0, pose_deg=0.5))
    ds = Dataset.open(tiny_dataset).only(["scene_a"])
    res = export_dataset(dask_client, ds, "epose", tmp_path / "out", label_sigma=opts)
    assert res.failed == {}
    export_scene(ds.scenes[0].path, "epose", tmp_path / "single", label_sigma=opts)
    got, want = tree(tmp_path / "out" / "scene_a"), tree(tmp_path / "single")
    assert got.keys() == want.keys() and describe_file_differences(got, want) == []
    mat = scipy.io.loadmat(next((tmp_path / "out" / "scene_a").rglob("*_data.mat")))
    assert mat["sigma_t_mm"].shape == (1, 3) and (mat["sigma_t_mm"] > 0).all()


def test_bop_export_is_one_dataset(dask_client, tiny_dataset, tmp_path):
    from evpose.core.dataset.export import export_dataset

    out = tmp_path / "out"
    res = export_dataset(dask_client, Dataset.open(tiny_dataset), "bop", out)
    assert res.failed == {}
    bop = out / "bop"
    names = json.loads((bop / "scene_names.json").read_text())
    assert names["scenes"] == {"000000": "scene_a", "000001": "scene_b", "000002": "scene_c"}
    assert names["split"] == "test"                     # the scenes under BOP's split folder, same conventions
    t19, t24 = [], []
    for sid, name in names["scenes"].items():
        for p in (out / name / "test" / "000000").rglob("*"):
            if p.is_file():
                q = bop / "test" / sid / p.relative_to(out / name / "test" / "000000")
                assert q.read_bytes() == p.read_bytes()
        t19 += [{**e, "scene_id": int(sid)} for e in json.loads((out / name / "test_targets_bop19.json").read_text())]
        t24 += [{**e, "scene_id": int(sid)} for e in json.loads((out / name / "test_targets_bop24.json").read_text())]
    assert json.loads((bop / "test_targets_bop19.json").read_text()) == t19 and t19
    assert json.loads((bop / "test_targets_bop24.json").read_text()) == t24
    assert {e["scene_id"] for e in t24} == {0, 1, 2}
    models = sorted(p.name for p in (bop / "models").iterdir())
    assert models == sorted(p.name for p in (out / "scene_a" / "models").iterdir())     # each obj_id once
    info = json.loads((bop / "models" / "models_info.json").read_text())
    assert sorted(info, key=int) == sorted(str(int(m[4:10])) for m in models if m.endswith(".ply"))
    # a rerun rebuilds it from the files it listed; a foreign file in bop/ is refused
    assert export_dataset(dask_client, Dataset.open(tiny_dataset), "bop", out).failed == {}
    (bop / "mine.txt").write_text("user file")
    res = export_dataset(dask_client, Dataset.open(tiny_dataset), "bop", out)
    assert "mine.txt" in res.failed["bop"] and (bop / "mine.txt").read_text() == "user file"


def test_bop_dataset_in_the_chosen_split(dask_client, tiny_dataset, tmp_path):
    """--split train: every scene under OUT/bop/train, with BOP's cam_K (pixel origin at the corner)."""
    from evpose.core.dataset.export import export_dataset

    out = tmp_path / "out"
    res = export_dataset(dask_client, Dataset.open(tiny_dataset), "bop", out, objects="box", window_us=100_000,
                         format_options={"split": "train"})
    assert res.failed == {}
    bop = out / "bop"
    assert sorted(p.name for p in (bop / "train").iterdir()) == ["000000", "000001", "000002"]
    assert not (bop / "test").exists()
    for sid in ("000000", "000001", "000002"):
        side = json.loads((bop / "train" / sid / "evpose_scene.json").read_text())
        cams = json.loads((bop / "train" / sid / "scene_camera.json").read_text())
        K = side["K_opencv"]
        assert all(c["cam_K"][2] == K[0][2] + 0.5 and c["cam_K"][5] == K[1][2] + 0.5 for c in cams.values())


def test_a_killed_worker_gives_the_same_export(dask_client, tiny_dataset, reference_epose, tmp_path):
    from evpose.core.dataset.export import export_dataset

    pids = list(dask_client.run(os.getpid).values())
    killed = threading.Event()

    def progress(fraction, _msg=""):
        if fraction > 0.15 and not killed.is_set():
            killed.set()
            os.kill(pids[0], signal.SIGKILL)        # mid-chunk: Dask reruns its tasks on the other worker

    lines = []
    res = export_dataset(dask_client, Dataset.open(tiny_dataset), "epose", tmp_path / "out",
                         progress=lambda f, msg="": (lines.append(msg), progress(f, msg)))
    assert killed.is_set() and res.failed == {}
    # the user is told (issue 27.6): the lost worker in the summary and the --json document, the chunks it was
    # running counted as rerun under their scenes, and the progress line says so once the scheduler noticed
    lost = res.to_json()["cluster"]
    assert len(lost["lost_workers"]) == 1, lost
    assert sum(lost["rerun_tasks"].values()) >= 1 and set(lost["rerun_tasks"]) <= set(reference_epose), lost
    assert any("1 worker(s) lost" in m for m in lines), lines[-3:]
    for name, ref in reference_epose.items():
        got = tree(tmp_path / "out" / name)
        assert got.keys() == ref.keys(), name
        assert describe_file_differences(got, ref) == [], name
    dask_client.wait_for_workers(2, timeout=60)      # the nanny restarts the worker for the next tests


def test_an_interrupted_export_resumes(dask_client, tiny_dataset, reference_epose, tmp_path):
    from evpose.core.dataset.export import export_dataset

    calls = []

    def cancel():
        calls.append(1)
        return len(calls) > 6

    with pytest.raises(Cancelled):
        export_dataset(dask_client, Dataset.open(tiny_dataset), "epose", tmp_path / "out", cancel=cancel)
    res = export_dataset(dask_client, Dataset.open(tiny_dataset), "epose", tmp_path / "out")
    assert res.failed == {}
    assert sum(s["skipped_complete"] for s in res.scenes.values()) > 0            # it resumed
    for name, ref in reference_epose.items():
        got = tree(tmp_path / "out" / name)
        assert got.keys() == ref.keys() and describe_file_differences(got, ref) == [], name


def test_a_broken_scene_is_reported_and_the_others_complete(dask_client, dataset_copy, tmp_path):
    from evpose.core.dataset.batch import map_scenes
    from evpose.core.dataset.export import export_dataset
    from evpose.core.dataset.tasks import info_task

    events = dataset_copy / "scene_b" / "events.h5"
    events.write_bytes(events.read_bytes()[:5000])          # truncated
    ds = Dataset.open(dataset_copy)
    info = map_scenes(dask_client, ds, info_task, label="info")
    assert list(info.scenes) == ["scene_a", "scene_c"] and list(info.failed) == ["scene_b"]
    assert "events.h5" in info.failed["scene_b"] and "\n" not in info.failed["scene_b"]
    res = export_dataset(dask_client, ds, "epose", tmp_path / "out")
    assert list(res.failed) == ["scene_b"] and "events.h5" in res.failed["scene_b"]
    assert all(res.scenes[n]["written"] > 0 for n in ("scene_a", "scene_c"))
    # BOP scene ids follow the dataset order, failed scenes included: ids stay stable when one scene fails
    res = export_dataset(dask_client, ds, "bop", tmp_path / "bop_out")
    assert list(res.failed) == ["scene_b"]
    names = json.loads((tmp_path / "bop_out" / "bop" / "scene_names.json").read_text())
    assert names["scenes"] == {"000000": "scene_a", "000002": "scene_c"} and names["missing"] == ["scene_b"]
    assert sorted(p.name for p in (tmp_path / "bop_out" / "bop" / "test").iterdir()) == ["000000", "000002"]


def _evpose(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "evpose", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def test_cli_json_contract_and_partial_exit_status(dataset_copy, tmp_path):
    events = dataset_copy / "scene_c" / "events.h5"
    events.write_bytes(b"not hdf5")
    r = _evpose("dataset", "info", dataset_copy, "--workers", "1", "--json", "-q")
    assert r.returncode == 3, r.stderr
    doc = json.loads(r.stdout)
    assert set(doc) >= {"scenes", "failed", "runtime_s"} and list(doc["scenes"]) == ["scene_a", "scene_b"]
    assert "events.h5" in doc["failed"]["scene_c"]
    assert "scene_c: failed:" in r.stderr and "Traceback" not in r.stderr
    report = tmp_path / "report.html"
    r = _evpose("dataset", "report", dataset_copy, "--out", report, "--workers", "2", "--json", "-q")
    assert r.returncode == 3, r.stderr
    doc = json.loads(r.stdout)
    assert list(doc["scenes"]) == ["scene_a", "scene_b"] and list(doc["failed"]) == ["scene_c"]
    assert doc["runtime_s"] > 0 and doc["report"] == str(report) and doc["ranked"][0]["scene"] == "scene_c"
    html = report.read_text()
    assert "scene_a" in html and "scene_c" in html and "events.h5" in html
    r = _evpose("dataset", "sync", tmp_path / "missing", "--workers", "1")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "missing" in r.stderr
    r = _evpose("dataset", "info", dataset_copy, "--workers", "0")
    assert r.returncode == 2 and "--workers" in r.stderr and "Traceback" not in r.stderr


def _dask_cli() -> str:
    exe = Path(sys.executable).with_name("dask")
    if not exe.exists():
        pytest.skip("the dask command is not installed beside this Python")
    return str(exe)


def test_an_external_scheduler_and_workers_give_the_same_export(tiny_dataset, reference_epose, tmp_path):
    """``dask scheduler`` + ``dask worker`` started here on 127.0.0.1 (stopped at the end)."""
    dask = _dask_cli()
    sched_file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sched_file)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while not sched_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        procs.append(subprocess.Popen([dask, "worker", "--scheduler-file", str(sched_file), "--nthreads", "1",
                                       "--nworkers", "2", "--no-dashboard", "--host", "127.0.0.1"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        r = _evpose("dataset", "export", tiny_dataset, "--format", "epose", "--out", tmp_path / "out",
                    "--scheduler", address, "--json", "-q")
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["failed"] == {}
        for name, ref in reference_epose.items():
            got = tree(tmp_path / "out" / name)
            assert got.keys() == ref.keys() and describe_file_differences(got, ref) == [], name
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()


def test_dataset_sync_apply_saves_what_the_single_scene_command_saves(dataset_copy, tmp_path):
    import shutil

    single = tmp_path / "single"
    shutil.copytree(dataset_copy, single)
    r = _evpose("dataset", "sync", dataset_copy, "--apply", "--workers", "2", "--json", "-q")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    for name in ("scene_a", "scene_b", "scene_c"):
        one = _evpose("sync", single / name, "--apply", "--json", "-q")
        assert one.returncode == 0, one.stderr
        alone = json.loads(one.stdout)
        assert doc["scenes"][name]["applied"] == alone["applied"]
        assert without_timings(doc["scenes"][name], TIMING_KEYS | {"saved"}) == without_timings(alone, TIMING_KEYS | {"saved"})
        mine, theirs = dataset_copy / name / "corrections.json", single / name / "corrections.json"
        assert mine.exists() == theirs.exists()          # nothing saved where the estimate was within 2 sigma
        if mine.exists():
            mine, theirs = json.loads(mine.read_text()), json.loads(theirs.read_text())
            assert mine["clock"] == theirs["clock"] and mine.get("revision") == theirs.get("revision")
    assert any(doc["scenes"][n]["applied"] for n in ("scene_a", "scene_b", "scene_c"))


def _same_numbers(a, b, rel=1e-9, path="") -> None:
    """``a == b`` for JSON documents, floats within ``rel`` (a Dask worker's BLAS sums in another order than the
    command's: the last digits of a fitted pose differ)."""
    if isinstance(a, dict) and isinstance(b, dict):
        assert set(a) == set(b), (path, set(a) ^ set(b))
        for k in a:
            _same_numbers(a[k], b[k], rel, f"{path}.{k}")
    elif isinstance(a, list) and isinstance(b, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _same_numbers(x, y, rel, f"{path}[{i}]")
    elif isinstance(a, float) or isinstance(b, float):
        assert a == pytest.approx(b, rel=rel, abs=1e-12), (path, a, b)
    else:
        assert a == b, (path, a, b)


def _snapshot(root: Path) -> dict:
    """Every path under ``root`` (bookkeeping included) with its bytes and modification time."""
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None, p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*"))}


def _apply_proposals(root: Path, docs: dict) -> None:
    """Apply each dry-run document with :func:`apply_proposal` (the dataset view's Apply); a second apply of the same
    proposal is refused (the corrections changed since it was made), and so is an empty one."""
    from evpose.core.align.refine_run import ProposalError, apply_proposal
    from evpose.core.data.scene import Scene

    for name, doc in docs.items():
        scene = Scene.open(root / name)
        try:
            if not doc["changes"]:
                with pytest.raises(ProposalError, match="nothing to apply"):
                    apply_proposal(scene, doc)
                continue
            assert "applied and saved" in apply_proposal(scene, dict(doc))
            with pytest.raises(ProposalError, match="planned_on: the corrections changed"):
                apply_proposal(scene, doc)
        finally:
            scene.close()


def test_dataset_refine_dry_run_touches_nothing_and_apply_equals_the_single_scene_command(dataset_copy, tmp_path):
    """Issue 24.2: ``dataset refine`` is a dry run by default (no file written, not even a lock or a journal; each
    scene's diff printed with its sigma), and ``--apply`` stores, scene by scene, what ``evpose refine --joint
    --apply`` stores: the same changes, the same corrections; a rerun then finds nothing beyond its sigma.

    Two of the three scenes (clocks 20 ms and -15 ms off) for the dataset runs, one for the text dry run and the
    rerun: each joint fit is a few CPU-seconds, and every step here ran on all three before (~10 min under load)."""
    import shutil

    shutil.rmtree(dataset_copy / "scene_c")
    single, proposed, one_scene = tmp_path / "single", tmp_path / "proposed", tmp_path / "one"
    shutil.copytree(dataset_copy, single)
    shutil.copytree(dataset_copy, proposed)
    before = _snapshot(dataset_copy)
    r = _evpose("dataset", "refine", dataset_copy, "--workers", "2", "--windows", "12", "--json", "-q")
    assert r.returncode == 0, r.stderr
    dry = json.loads(r.stdout)["scenes"]
    assert sorted(dry) == ["scene_a", "scene_b"] and _snapshot(dataset_copy) == before
    assert not any(d["applied"] for d in dry.values())
    assert any(c["part"] == "clock" for d in dry.values() for c in d["changes"])    # the clocks are 15-20 ms off
    for d in dry.values():
        for c in d["changes"]:
            assert "+-" in c["text"] and (c.get("offset_std_us") or c.get("std_mm")), c
    shutil.copytree(dataset_copy / "scene_a", one_scene / "scene_a")
    one_before = _snapshot(one_scene)
    text = _evpose("dataset", "refine", one_scene, "--workers", "1", "--windows", "12", "--dry-run", "-q")
    assert text.returncode == 0 and "would apply" in text.stdout and _snapshot(one_scene) == one_before
    _apply_proposals(proposed, dry)
    r = _evpose("dataset", "refine", dataset_copy, "--workers", "2", "--windows", "12", "--apply", "--json", "-q")
    assert r.returncode == 0, r.stderr
    applied = json.loads(r.stdout)["scenes"]
    for name in ("scene_a", "scene_b"):
        one = _evpose("refine", single / name, "--joint", "--windows", "12", "--apply", "--json", "-q")
        assert one.returncode == 0, one.stderr
        alone = json.loads(one.stdout)
        skip = TIMING_KEYS | {"saved", "trace"}
        _same_numbers(without_timings(applied[name], skip), without_timings(alone, skip))
        _same_numbers(without_timings(dry[name], skip | {"applied"}),
                      without_timings(alone, skip | {"applied", "revision", "merged_from_disk"}))
        assert applied[name]["applied"] == bool(applied[name]["changes"])
        mine = json.loads((dataset_copy / name / "corrections.json").read_text())
        theirs = json.loads((single / name / "corrections.json").read_text())
        _same_numbers({k: v for k, v in mine.items() if k != "saved_at"},
                      {k: v for k, v in theirs.items() if k != "saved_at"})
        if dry[name]["changes"]:      # the dataset view's Apply: the dry run's proposal stores the same corrections
            assert json.loads((proposed / name / "corrections.json").read_text()) == mine
    shutil.rmtree(one_scene / "scene_a")
    shutil.copytree(dataset_copy / "scene_a", one_scene / "scene_a")    # the applied scene, run again
    again = json.loads(_evpose("dataset", "refine", one_scene, "--workers", "1", "--windows", "12", "--json",
                               "-q").stdout)["scenes"]
    assert all(not any(c["part"] == "clock" for c in d["changes"]) for d in again.values())


def _terminal_sigint() -> None:
    """In the child before exec: SIGINT as a shell gives it (default action, not blocked), whatever the test
    process's workers and threads did to their own (the disposition SIG_IGN and the signal mask are inherited)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _same_as_reference(out, reference_epose) -> None:
    for name, ref in reference_epose.items():
        got = tree(out / name)
        assert got.keys() == ref.keys() and describe_file_differences(got, ref) == [], name


def test_ctrl_c_stops_the_export_and_its_cluster_and_a_rerun_completes(tiny_dataset, reference_epose, tmp_path):
    """SIGINT to the whole process group, as a terminal sends it: exit 130 with one line, no process of the
    group left, no temp file left; the same command then completes with the same files.

    The signal goes once the first window's files are there (the cluster has started: while it starts, SIGINT is
    ignored so that the workers inherit the ignoring). On a quiet machine the tiny dataset's last windows may be
    written before the signal is handled: such a run (exit 0) must have written the reference files, and the
    scenario is run again (at most three times) until one is interrupted."""
    for attempt in range(3):
        out = tmp_path / f"out{attempt}"
        args = [sys.executable, "-m", "evpose", "dataset", "export", str(tiny_dataset), "--format", "epose",
                "--out", str(out), "--workers", "2"]
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True, preexec_fn=_terminal_sigint)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not any(out.glob("*/*_data.mat")):
            time.sleep(0.01)
        assert any(out.glob("*/*_data.mat")), "the export did not start"
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        if proc.returncode == 0:              # finished before the signal was handled: a complete, right export
            _same_as_reference(out, reference_epose)
            continue
        break
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    time.sleep(1.0)
    ps = subprocess.run(["ps", "-o", "pid=,stat=", "-g", str(proc.pid)], capture_output=True, text=True).stdout
    alive = [ln.split()[0] for ln in ps.splitlines() if ln.split() and not ln.split()[1].startswith("Z")]
    assert alive == [], f"processes of the interrupted run still alive: {alive}"     # (zombies wait for init)
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]
    r = _evpose("dataset", "export", tiny_dataset, "--format", "epose", "--out", out, "--workers", "2", "--json", "-q")
    assert r.returncode == 0, r.stderr
    _same_as_reference(out, reference_epose)


def test_local_workers_keep_the_default_malloc_trimming(dask_client):
    """Dask's MALLOC_TRIM_THRESHOLD_=65536 made the export's windows 1.24x slower (bench_dataset): local workers
    start without it (and the nanny does not put it into this process's environment either)."""
    assert set(dask_client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_")).values()) == {None}
    assert os.environ.get("MALLOC_TRIM_THRESHOLD_") is None


def _worker_periodic_work(dask_worker) -> dict:
    """Run on a worker (``client.run``): its profiler, its event loop's tick and its system monitor as it runs them."""
    pcs = dask_worker.periodic_callbacks
    return {"profile": "profile" in pcs, "tick_ms": pcs["tick"].callback_time,
            "monitor_ms": pcs["monitor"].callback_time if "monitor" in pcs else None}


def test_local_workers_run_without_the_profiler_and_with_a_slow_tick(dask_client):
    """A Dask worker's statistical profiler and 20 ms tick cost an idle worker 4.2-4.6 % of a core and an export
    worker 3-4 % more CPU a window (issue 27.1): evpose's local workers run without the profiler, with a 1 s tick and
    a 5 s system monitor -- also a worker restarted by its nanny (it came back with Dask's defaults at first)."""
    for restart in (False, True):              # also a worker its nanny started again after a kill
        if restart:
            os.kill(next(iter(dask_client.run(os.getpid).values())), signal.SIGKILL)
            time.sleep(0.5)
            dask_client.wait_for_workers(2, timeout=60)
        got = list(dask_client.run(_worker_periodic_work).values())
        assert len(got) == 2 and all(g["profile"] is False for g in got), got
        assert all(g["tick_ms"] == 1000 and g["monitor_ms"] in (None, 5000) for g in got), got


def test_the_workers_env_file_sets_what_local_workers_get():
    """resources/evpose-workers.env (the README's file for workers started by hand or on SLURM) gives, read as Dask
    reads its environment on top of its defaults, exactly the settings evpose's local clusters give their workers.
    (A DASK_..._PRE_SPAWN_ENVIRON__MALLOC_TRIM_THRESHOLD_=None variable, as the README once said, is read as a
    lower-case key and leaves Dask's MALLOC_TRIM_THRESHOLD_=65536 in place.)"""
    import copy

    import dask

    from evpose.core.dataset.cluster import WORKER_CONFIG, WORKER_ENVIRON

    env = {}
    for line in (Path(__file__).parents[2] / "resources" / "evpose-workers.env").read_text().splitlines():
        if line.startswith("export "):
            key, value = line[len("export "):].split("=", 1)
            env[key] = value[1:-1] if value[:1] == value[-1:] == "'" else value
    config = copy.deepcopy(dask.config.config)
    dask.config.update(config, dask.config.collect_env(env))
    for key, value in {**WORKER_ENVIRON, **WORKER_CONFIG}.items():
        assert dask.config.get(key, config=config) == value, key
    assert len(env) == len(WORKER_CONFIG) + 1


def test_the_local_cluster_listens_on_the_loopback_interface_only():
    """A local run's scheduler, workers and dashboard bind 127.0.0.1 (before, the dashboard bound every interface)."""
    from evpose.core.dataset.cluster import ClusterSpec, open_client

    import psutil

    with open_client(ClusterSpec(workers=1)) as client:
        info = client.scheduler_info()
        addresses = [client.scheduler.address] + list(info["workers"])
        me = psutil.Process()
        listening = [c.laddr for p in [me] + me.children(recursive=True)
                     for c in p.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN]
    assert all(a.startswith("tcp://127.0.0.1:") for a in addresses), addresses
    assert listening and all(ip == "127.0.0.1" for ip, _ in listening), listening
