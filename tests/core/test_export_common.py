"""Machinery shared by all formats: --only-verified, unlabeled windows, atomic files and temp cleanup,
resume after cancel / Ctrl-C, refusal of a different configuration, --jobs 2 == --jobs 1, the CLI."""
import argparse
import hashlib
import json
import shutil
from pathlib import Path

import cv2
import pytest
from scipy.io import loadmat

from evpose.app.cli.export import add_export_parser
from evpose.core.data.events import Cancelled
from evpose.core.data.scene import Scene
from evpose.core.document.corrections import ReviewMark
from evpose.core.export import ExportError, export_scene
from evpose.core.export.windows import UNLABELED_AFTER, UNLABELED_BEFORE, verified_mask
from evpose.core.label.windows import Window


# ----------------------------------------------------------------------------------------- helpers
def tree_hashes(out: Path) -> dict:
    """sha256 of every file of an export except evpose's state folder (the manifest included: it holds nothing
    of the run, so a resumed or parallel export has the same bytes)."""
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file() and ".evpose" not in p.parts}


def no_temp_files(out: Path) -> bool:
    return not [p for p in out.rglob("*") if p.name.startswith(".") and p.name.endswith(".tmp")]


def all_files_complete(out: Path) -> None:
    for p in out.glob("*.png"):
        assert cv2.imread(str(p), cv2.IMREAD_UNCHANGED) is not None, p
    for p in out.glob("*.mat"):
        loadmat(p)


@pytest.fixture
def small_scene(tiny_scene_dir, tmp_path):
    """A scene copy whose reviews restrict --only-verified to windows 20..31 (12 windows)."""
    scene_dir = tmp_path / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    scene = Scene.open(scene_dir)
    t0 = scene.events.t_first_us
    scene.corrections.set(("reviews",), [ReviewMark(t0 + 200_000, t0 + 320_000, "verified")])
    scene.save_corrections()
    scene.close()
    return scene_dir


def W(i, t0, t1):
    return Window(i, t0, t1, (t0 + t1) // 2)


# ----------------------------------------------------------------------------------------- only verified
def test_verified_mask_definition():
    wins = [W(i, 100 * i, 100 * (i + 1)) for i in range(10)]
    names = ["a", "b"]
    reviews = [ReviewMark(100, 450, "verified"),          # covers windows 1, 2, 3 fully, 4 partly
               ReviewMark(450, 700, "verified"),          # adjacent marks: union covers 4, 5, 6
               ReviewMark(599, 600, "rejected"),          # added later, overlaps window 5 by 1 us
               ReviewMark(0, 100, "rejected"),            # window 0 rejected ...
               ReviewMark(0, 100, "verified"),            # ... then verified again: the later mark wins
               ReviewMark(200, 300, "flagged"),           # later flag over window 2 excludes it
               ReviewMark(800, 900, "verified", object="a")]   # only object a
    got = verified_mask(wins, reviews, names)
    assert got.tolist() == [True, True, False, True, True, False, True, False, False, False]
    assert verified_mask(wins, reviews, ["a"])[8]
    assert not verified_mask(wins, [], names).any()
    # an earlier rejection inside a later verified mark does not exclude (most recent mark wins)
    assert verified_mask([W(0, 0, 100)], [ReviewMark(10, 20, "rejected"), ReviewMark(0, 100, "verified")], ["a"])[0]
    # a window reaching 1 us beyond the verified marks is not fully covered
    assert not verified_mask([W(0, 0, 101)], [ReviewMark(0, 100, "verified")], ["a"])[0]
    # the mask agrees with Corrections.review_status at every microsecond
    from evpose.core.document.corrections import Corrections

    c = Corrections(reviews=reviews)
    for w, ok in zip(wins, got):
        statuses = {c.review_status(t, o) for t in range(w.t0_us, w.t1_us) for o in names}
        assert ok == (statuses == {"verified"})


def test_only_verified_export(small_scene, tmp_path):
    s = export_scene(small_scene, "epose", tmp_path / "out", only_verified=True)
    assert s.selected == 12 and s.written == 12 and s.filtered_unverified == s.windows_total - 12
    assert sorted(int(p.name[:4]) for p in (tmp_path / "out").glob("*_data.mat")) == list(range(20, 32))
    man = json.loads((tmp_path / "out" / "export_manifest.json").read_text())
    st = man["windows"]["status"]
    assert st.count("written") == 12 and st.count("filtered_unverified") == s.windows_total - 12
    assert st[19] == "filtered_unverified" and st[20] == "written"


# ----------------------------------------------------------------------------------------- unlabeled
def test_unlabeled_windows_reported(tiny_scene_dir, tmp_path):
    scene = Scene.open(tiny_scene_dir)
    scene.corrections.set(("offset_us",), 10_000_000)   # +10 s: every label time is after the trajectory
    s = export_scene(scene, "epose", tmp_path / "a")
    assert s.written == 0 and s.unlabeled == s.windows_total == 80
    assert s.unlabeled_reasons == {UNLABELED_AFTER: 80}
    assert [u["index"] for u in s.unlabeled_windows] == list(range(80))
    assert not list((tmp_path / "a").glob("*.png"))
    man = json.loads((tmp_path / "a" / "export_manifest.json").read_text())
    assert man["counts"]["unlabeled"] == 80 and man["unlabeled"][0]["reason"] == UNLABELED_AFTER
    assert set(man["windows"]["status"]) == {"unlabeled"}
    scene.corrections.set(("offset_us",), -400_000)     # the first windows precede the trajectory
    s = export_scene(scene, "bop", tmp_path / "b")
    assert s.unlabeled_reasons.get(UNLABELED_BEFORE, 0) > 0 and s.unlabeled < 80
    scene.close()


# ----------------------------------------------------------------------------------------- resume
def test_cancel_resume_identical_no_temp(small_scene, tmp_path):
    ref = tmp_path / "ref"
    export_scene(small_scene, "epose", ref, only_verified=True)
    out = tmp_path / "out"
    n = {"k": 0}

    def cancel():
        n["k"] += 1
        return n["k"] > 5     # first call is before any window

    with pytest.raises(Cancelled):
        export_scene(small_scene, "epose", out, only_verified=True, cancel=cancel)
    assert no_temp_files(out) and not (out / "export_manifest.json").exists()
    assert len(list(out.glob("*_data.mat"))) == 5
    all_files_complete(out)
    # a stray temp file of a killed writer (evpose's naming: .<name>.<pid>-<n>.tmp) is removed on start
    (out / ".0025_event_image.png.4194305-2.tmp").write_bytes(b"partial")
    s = export_scene(small_scene, "epose", out, only_verified=True)
    assert s.skipped_complete == 5 and s.written == 7
    assert no_temp_files(out)
    assert tree_hashes(out) == tree_hashes(ref)
    # a window whose last file is gone is redone
    (out / "0023_data.mat").unlink()
    s = export_scene(small_scene, "epose", out, only_verified=True)
    assert s.skipped_complete == 11 and s.written == 1
    assert tree_hashes(out) == tree_hashes(ref)


def test_keyboard_interrupt_leaves_no_partial_files(small_scene, tmp_path, monkeypatch):
    out = tmp_path / "out"
    from evpose.core.data.atomic import AtomicBatch

    orig = AtomicBatch.commit
    calls = {"n": 0}

    def commit(self):        # Ctrl-C in the middle of a window's renames
        calls["n"] += len(self._pending) > 5     # window batches only (not README / box files)
        if calls["n"] == 4:             # 3 files of the 4th window are in place, then Ctrl-C
            for tmp, path in self._pending[:3]:
                tmp.replace(path)
            self._pending = self._pending[3:]
            raise KeyboardInterrupt
        return orig(self)

    monkeypatch.setattr(AtomicBatch, "commit", commit)
    with pytest.raises(KeyboardInterrupt):
        export_scene(small_scene, "epose", out, only_verified=True)
    monkeypatch.setattr(AtomicBatch, "commit", orig)
    assert no_temp_files(out)
    all_files_complete(out)
    assert len(list(out.glob("*_data.mat"))) == 3      # the 4th window never got its last file
    s = export_scene(small_scene, "epose", out, only_verified=True)
    assert s.skipped_complete == 3 and s.written == 9 and no_temp_files(out)


def test_different_configuration_refused_unless_force(small_scene, tmp_path):
    out = tmp_path / "out"
    export_scene(small_scene, "epose", out, only_verified=True)
    with pytest.raises(ExportError, match="different configuration.*--force") as e:
        export_scene(small_scene, "epose", out, only_verified=True, margin_m=0.002)
    assert "margin_m" in str(e.value)
    scene = Scene.open(small_scene)
    scene.corrections.set(("offset_us",), 1234)
    with pytest.raises(ExportError, match="clock"):
        export_scene(scene, "epose", out, only_verified=True)
    with pytest.raises(ExportError, match="format"):
        export_scene(scene, "bop", out, only_verified=True)
    s = export_scene(scene, "epose", out, only_verified=True, force=True)
    assert s.written == 12 and s.skipped_complete == 0
    assert json.loads((out / "export_manifest.json").read_text())["clock"]["offset_us"] == 1234
    # a non-empty folder that is not an evpose export is never cleared, even with force
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("precious")
    with pytest.raises(ExportError, match="not empty"):
        export_scene(scene, "epose", foreign, only_verified=True, force=True)
    assert (foreign / "thesis.tex").read_text() == "precious"
    scene.close()


def test_jobs2_identical_to_jobs1_and_cancel(small_scene, tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    export_scene(small_scene, "epose", one, only_verified=True, jobs=1)
    n = {"k": 0}

    def cancel():
        n["k"] += 1
        return n["k"] > 2       # after the first chunk came back

    with pytest.raises(Cancelled):
        export_scene(small_scene, "epose", two, only_verified=True, jobs=2, cancel=cancel)
    assert no_temp_files(two)
    all_files_complete(two)
    s = export_scene(small_scene, "epose", two, only_verified=True, jobs=2)
    assert s.jobs == 2 and s.written + s.skipped_complete == 12 and s.skipped_complete > 0
    assert tree_hashes(one) == tree_hashes(two)
    assert s.timings_s["annotate"] > 0


def test_files_are_readable_by_others(small_scene, tmp_path):
    import os
    import stat

    out = tmp_path / "out"
    export_scene(small_scene, "epose", out, only_verified=True, objects=["box"])
    mask = 0o666 & ~int(next(line for line in open("/proc/self/status") if line.startswith("Umask:")).split()[1], 8)
    for p in list(out.glob("0020_*")) + [out / "export_manifest.json"]:
        assert stat.S_IMODE(os.stat(p).st_mode) == mask, p


# ----------------------------------------------------------------------------------------- CLI
def cli(argv):
    p = argparse.ArgumentParser(prog="evpose")
    sub = p.add_subparsers(dest="command")
    add_export_parser(sub)
    args = p.parse_args(["export", *argv])
    return args.func(args)


def test_cli_json_and_progress(small_scene, tmp_path, capsys):
    out = tmp_path / "out"
    rc = cli([str(small_scene), "--format", "epose", "--out", str(out), "--only-verified", "--objects", "box,flatbox",
              "--margin-mm", "1", "--json", "-q"])
    cap = capsys.readouterr()
    assert rc == 0
    doc = json.loads(cap.out)          # exactly one JSON document on stdout
    assert doc["written"] == 12 and doc["format"] == "epose" and "files" not in doc and doc["n_files"] > 12
    assert cap.err == ""
    rc = cli([str(small_scene), "--format", "epose", "--out", str(out), "--only-verified", "--objects", "box,flatbox",
              "--margin-mm", "1"])
    cap = capsys.readouterr()
    assert rc == 0 and "0 windows written, 12 already complete" in cap.out
    assert "export epose" in cap.err and "100%" in cap.err           # the tqdm bar on stderr


def test_cli_errors(small_scene, tmp_path, capsys):
    rc = cli([str(tmp_path / "nope"), "--format", "epose", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "nope" in err and "scene" in err
    rc = cli([str(small_scene), "--format", "bop", "--out", str(tmp_path / "o"), "--objects", "box,teapot", "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "--objects" in err and "teapot" in err
    rc = cli([str(small_scene), "--format", "h5", "--out", str(tmp_path / "o"), "--window-ms", "-5", "-q"])
    assert rc == 2 and "--window-ms" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        cli([str(small_scene), "--format", "h5", "--out", str(tmp_path / "o"), "--window-ms", "5", "--window-events", "9"])
    assert e.value.code == 2
    with pytest.raises(SystemExit):
        cli([str(small_scene), "--format", "png", "--out", str(tmp_path / "o")])
    capsys.readouterr()
    rc = cli([str(small_scene), "--format", "bop", "--out", str(tmp_path / "o"), "--skip", "segmented", "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "--skip: only for --format epose" in err and len(err.strip().splitlines()) == 1
    rc = cli([str(small_scene), "--format", "epose", "--out", str(tmp_path / "o"), "--skip", "segmented,mask", "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "--skip: unknown product 'mask'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
    (small_scene / "corrections.json").write_text("{ not json")
    rc = cli([str(small_scene), "--format", "h5", "--out", str(tmp_path / "o2"), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "corrections.json" in err


def test_cli_window_events(small_scene, tmp_path, capsys):
    scene = Scene.open(small_scene)
    n = scene.events.n_events
    scene.corrections.set(("reviews",), [])
    scene.save_corrections()
    scene.close()
    rc = cli([str(small_scene), "--format", "h5", "--out", str(tmp_path / "o"), "--window-events", str(n // 4 + 1),
              "--label-at", "end", "--json", "-q"])
    doc = json.loads(capsys.readouterr().out)
    assert rc == 0 and doc["windows_total"] == 4
    import h5py

    with h5py.File(next((tmp_path / "o").glob("*.h5")), "r") as f:
        w = f["windows"][()]
        assert w["n_events"].sum() == n and (w["t_label_us"] == w["t1_us"]).all()
        assert f.attrs["window_events"] == n // 4 + 1


def test_concurrent_export_into_same_folder_refused(small_scene, tmp_path):
    import fcntl
    import os

    out = tmp_path / "out"
    out.mkdir()
    fd = os.open(out, os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)       # another export holds the folder
    try:
        with pytest.raises(ExportError, match="another export"):
            export_scene(small_scene, "h5", out, only_verified=True)
    finally:
        os.close(fd)
    assert export_scene(small_scene, "h5", out, only_verified=True).written == 12


def test_an_executor_whose_worker_died_mid_write_leaves_no_temp_file(small_scene, tmp_path):
    """A window executor (e.g. Dask) whose worker was killed mid-write leaves that worker's temporary file; the
    chunk runs again elsewhere and the export completes: the finished folder holds no temporary file."""
    from evpose.core.export.pool import WindowExecutor, run_worker_chunk
    from evpose.core.export.worker import WorkerContext

    class DyingFirstWorker(WindowExecutor):
        def run(self, spec, planner, key):
            wctx = WorkerContext(spec)
            out = Path(spec.out_dir)
            (out / ".0000_event_image.png.999999-dead.tmp").write_bytes(b"half a png")   # the killed worker's
            try:
                while (chunk := planner.next()) is not None:
                    results, timings = run_worker_chunk(wctx, chunk)
                    planner.record(len(results), timings["worker_cpu"])
                    yield results, timings
            finally:
                wctx.scene.close()

    ref, out = tmp_path / "ref", tmp_path / "out"
    export_scene(small_scene, "epose", ref)
    export_scene(small_scene, "epose", out, executor=DyingFirstWorker())
    assert no_temp_files(out)
    names = sorted(p.name for p in out.iterdir() if p.is_file())
    assert names == sorted(p.name for p in ref.iterdir() if p.is_file())



@pytest.mark.parametrize("fmt", ["epose", "bop"])
def test_the_export_driver_rasterises_nothing(small_scene, tmp_path, monkeypatch, fmt):
    """On a cluster the driver interpolates poses and journals; the windows are annotated on the workers. Before
    issue 27.2 the driver built an Annotator just to interpolate poses, which loaded and split every mesh for the
    rasteriser, once per sequence (~0.35 s a 5-object scene, serial under the GIL for 306 sequences). Here the
    executor runs the worker's part with rasterising allowed; everything else the export does may not rasterise,
    and the export equals the single-process one."""
    from evpose.core.export.pool import WindowExecutor, run_worker_chunk
    from evpose.core.export.worker import WorkerContext

    ref, out = tmp_path / "ref", tmp_path / "out"
    export_scene(small_scene, fmt, ref)
    original = Scene.raster_model
    on_worker = [False]

    def guarded(self, name):
        assert on_worker[0], f"the export's driver rasterises {name}"
        return original(self, name)

    class Worker(WindowExecutor):
        def run(self, spec, planner, key):
            while (chunk := planner.next()) is not None:
                on_worker[0] = True
                try:
                    wctx = WorkerContext(spec)            # a worker's own scene, opened from the spec
                    results, timings = run_worker_chunk(wctx, chunk)
                    wctx.scene.close()
                finally:
                    on_worker[0] = False
                planner.record(len(results), timings["worker_cpu"])
                yield results, timings

    monkeypatch.setattr(Scene, "raster_model", guarded)
    export_scene(small_scene, fmt, out, executor=Worker())
    assert tree_hashes(out) == tree_hashes(ref)


def test_chunks_synced_by_their_workers_are_journaled_without_a_second_syncfs(small_scene, tmp_path, monkeypatch):
    """A Dask worker syncs its chunk's files before returning (durable=batch); the driver then journals the chunk's
    windows without a syncfs of its own (its writeback of the workers' files cost the driver ~0.5 ms a window,
    issue 27.2) -- but never journals a window before the sync that covers its files."""
    from evpose.core.data import atomic
    from evpose.core.export.journal import Journal
    from evpose.core.export.pool import WindowExecutor, run_worker_chunk
    from evpose.core.export.worker import WorkerContext

    order: list = []
    real_sync, real_journal_sync = atomic.sync_filesystem, Journal.sync
    done_windows: set = set()

    def syncfs(path):
        order.append(("syncfs", frozenset(done_windows)))
        real_sync(path)

    def journal_sync(self):
        lines = bytes(self._buf).decode().split("\n")
        order.append(("journal", frozenset(json.loads(x)["i"] for x in lines if x.strip())))
        real_journal_sync(self)

    class SyncingWorkers(WindowExecutor):
        syncs_chunks = True

        def run(self, spec, planner, key):
            wctx = WorkerContext(spec)
            try:
                while (chunk := planner.next()) is not None:
                    results, timings = run_worker_chunk(wctx, chunk)
                    done_windows.update(t.window.index for t in chunk)
                    atomic.sync_filesystem(spec.out_dir)           # as dask_windows.run_chunk does
                    planner.record(len(results), timings["worker_cpu"])
                    yield results, timings
            finally:
                wctx.scene.close()

    monkeypatch.setattr(atomic, "sync_filesystem", syncfs)
    monkeypatch.setattr(Journal, "sync", journal_sync)
    s = export_scene(small_scene, "epose", tmp_path / "out", executor=SyncingWorkers())
    synced: set = set()
    journaled = 0
    for kind, windows in order:
        if kind == "syncfs":
            synced |= windows
        else:
            assert windows <= synced, "a window journaled before a sync covered its files"
            journaled += len(windows)
    assert journaled == s.written > 0
    assert sum(k == "syncfs" for k, _ in order) == len(s.chunks), "the driver synced on top of its workers"
