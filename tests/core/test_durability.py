"""Issue 11, item 9: durability is pinned by the order of the system calls, recorded.

A rename is durable only when the renamed file's data reached the disk first (``fsync`` of the file
before ``rename``) and the directory entry after (``fsync`` of the folder after ``rename``). The export
journal may claim a window only when the window's files are on disk: the filesystem is synced
(``syncfs``) after the files are renamed and before the journal lines that name them are written and
fsynced. Each file evpose writes is logged in its ownership log before it appears under its name.
The journal is cut at every byte of its last line and the resume checked.

The recorder wraps ``os.fsync`` / ``os.replace`` / ``os.rename`` / ``os.write`` (resolving descriptors
through ``/proc/self/fd``) and the filesystem sync.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

import evpose.core.data.atomic as atomic
from evpose.core.export import pool
from evpose.core.export.journal import Journal

pytestmark = pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc/self/fd")


def fd_path(fd: int) -> str:
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return f"fd:{fd}"


class Recorder:
    """Ordered record of durability-relevant calls: ("fsync", path), ("replace", src, dst),
    ("syncfs", path, journal_text), ("write", path, data) for ownership logs and journals."""

    def __init__(self, monkeypatch, journal: Path | None = None):
        self.events: list[tuple] = []
        self.journal = journal
        real_fsync, real_replace, real_rename, real_write = os.fsync, os.replace, os.rename, os.write
        real_syncfs = atomic.sync_filesystem

        def fsync(fd):
            p = fd_path(fd)
            self.events.append(("fsync", p, self._journal_text() if p.endswith("journal.jsonl") else None))
            return real_fsync(fd)

        def replace(src, dst, *a, **k):
            self.events.append(("replace", str(src), str(dst)))
            return real_replace(src, dst, *a, **k)

        def rename(src, dst, *a, **k):
            self.events.append(("replace", str(src), str(dst)))
            return real_rename(src, dst, *a, **k)

        def write(fd, data):
            p = fd_path(fd)
            if p.endswith(".log") or p.endswith("journal.jsonl"):
                self.events.append(("write", p, bytes(data)))
            return real_write(fd, data)

        def syncfs(path):
            self.events.append(("syncfs", str(path), self._journal_text()))
            return real_syncfs(path)

        monkeypatch.setattr(os, "fsync", fsync)
        monkeypatch.setattr(os, "replace", replace)
        monkeypatch.setattr(os, "rename", rename)
        monkeypatch.setattr(os, "write", write)
        monkeypatch.setattr(atomic, "sync_filesystem", syncfs)

    def _journal_text(self) -> str | None:
        if self.journal is None or not self.journal.exists():
            return None
        with open(self.journal, "rb") as f:           # what the OS has, whatever the writer buffers
            return f.read().decode()

    def index(self, pred, start: int = 0) -> int:
        for i in range(start, len(self.events)):
            if pred(self.events[i]):
                return i
        raise AssertionError("event not recorded:\n" + "\n".join(map(repr, self.events[-30:])))


def assert_durable_rename(rec: Recorder, final: Path) -> None:
    """fsync(temp) < replace(temp -> final) < fsync(folder of final)."""
    i_rep = rec.index(lambda e: e[0] == "replace" and e[2] == str(final))
    tmp = rec.events[i_rep][1]
    assert any(e[0] == "fsync" and e[1] == tmp for e in rec.events[:i_rep]), f"{final}: no fsync of {tmp} before the rename"
    rec.index(lambda e: e[0] == "fsync" and e[1] == str(final.parent), start=i_rep + 1)


# ------------------------------------------------------------------------------------------- atomic writes
def test_atomic_write_fsyncs_file_then_renames_then_fsyncs_folder(tmp_path, monkeypatch):
    rec = Recorder(monkeypatch)
    target = tmp_path / "corrections.json"
    atomic.atomic_write_text(target, "{}")
    assert_durable_rename(rec, target)
    atomic.atomic_write_text(target, "{\"a\": 1}")       # replacing an existing file: same order
    rec.events.clear()
    atomic.atomic_write_text(target, "{\"a\": 2}")
    assert_durable_rename(rec, target)


def test_atomic_batch_fsyncs_each_file_logs_it_then_renames(tmp_path, monkeypatch):
    from evpose.core.data.owned_log import OwnedLog

    rec = Recorder(monkeypatch)
    log = OwnedLog(tmp_path, "export", "test")
    names = ["0001_event_image.png", "0001_bbox.txt", "0001_data.mat"]
    with atomic.AtomicBatch(True, log) as b:
        for n in names:
            b.add(tmp_path / n, n.encode() * 10)
    for n in names:
        assert_durable_rename(rec, tmp_path / n)
        i_rep = rec.index(lambda e: e[0] == "replace" and e[2] == str(tmp_path / n))
        i_log = rec.index(lambda e: e[0] == "write" and e[1].endswith(".log") and f'"f":"{n}"'.encode() in e[2])
        assert i_log < i_rep, f"{n} renamed before it was logged"
    # the last file added is renamed last (it marks the window complete)
    reps = [e[2] for e in rec.events if e[0] == "replace"]
    assert reps == [str(tmp_path / n) for n in names]


def test_event_writer_close(tmp_path, monkeypatch):
    from evpose.core.data.event_writer import EventWriter
    from evpose.core.data.events import EventArray

    rec = Recorder(monkeypatch)
    target = tmp_path / "events.h5"
    with EventWriter(target) as w:
        w.append(EventArray(np.array([1, 2], np.uint16), np.array([3, 4], np.uint16), np.array([10, 20], np.int64),
                            np.array([0, 1], np.uint8)))
    assert_durable_rename(rec, target)


def test_scene_folder_synced_before_it_is_renamed_into_place(tmp_path, monkeypatch):
    from evpose.core.data.scene_folder import StagingFolder

    rec = Recorder(monkeypatch)
    st = StagingFolder(tmp_path / "scene", "import", "test")
    st.create()
    (st.path / "trajectory.csv").write_text("t_us\n")
    st.commit([], False)
    i_rep = rec.index(lambda e: e[0] == "replace" and e[2] == str(tmp_path / "scene"))
    i_sync = rec.index(lambda e: e[0] == "syncfs" and e[1] == str(st.path))
    assert i_sync < i_rep, "the staging folder's files were not synced before the rename"
    rec.index(lambda e: e[0] == "fsync" and e[1] == str(tmp_path), start=i_rep + 1)
    # and the files were logged before the rename (the log is inside the renamed folder)
    i_log = rec.index(lambda e: e[0] == "write" and b'"f":"trajectory.csv"' in e[2])
    assert i_log < i_rep


# ------------------------------------------------------------------------------------------- every writer
def _write_corrections(scene: Path) -> Path:
    from evpose.core.document.corrections import Corrections

    doc = Corrections()
    doc.set(("offset_us",), 1234)
    return doc.save(scene / "corrections.json")


def _write_manifest(scene: Path) -> Path:
    from evpose.core.data.manifest_reader import load_manifest

    return load_manifest(scene).save()


def _write_trajectory(scene: Path) -> Path:
    from evpose.core.data.trajectory import Trajectory

    return Trajectory.load_csv(scene / "trajectory.csv").save_csv(scene / "trajectory.csv")


def _write_autosave_journal(scene: Path) -> Path:
    from evpose.core.document.corrections import Corrections
    from evpose.core.document.journal import JOURNAL_NAME, write_journal

    doc = Corrections()
    doc.set(("skew_ppm",), 2.5)
    return write_journal(scene / JOURNAL_NAME, doc)


def _write_one_export_file(scene: Path) -> Path:
    return atomic.write_atomic(scene / "export_config.json", b"{}")        # the default is durable


@pytest.mark.parametrize("writer", [_write_corrections, _write_manifest, _write_trajectory, _write_autosave_journal,
                                    _write_one_export_file], ids=lambda f: f.__name__.removeprefix("_write_"))
def test_every_document_writer_fsyncs_before_its_rename(scene_copy, monkeypatch, writer):
    """Each file of a scene the user keeps (and the single files of an export) goes through the one atomic
    stack: temp file fsynced, renamed, folder fsynced. Written twice: a new file and a replaced one."""
    for _ in range(2):
        rec = Recorder(monkeypatch)
        final = writer(scene_copy)
        monkeypatch.undo()
        assert_durable_rename(rec, final)
        assert not [p.name for p in scene_copy.iterdir() if p.name.endswith(".tmp")]


#: Every production module that renames files into place, and the test above that pins its durability.
#: ``event_index`` writes a cache (rebuilt when lost): renamed for atomicity, deliberately not fsynced.
RENAMING_MODULES = {
    "core/data/atomic.py": "test_atomic_write_fsyncs_file_then_renames_then_fsyncs_folder, "
                           "test_atomic_batch_fsyncs_each_file_logs_it_then_renames, "
                           "test_every_document_writer_fsyncs_before_its_rename",
    "core/data/event_writer.py": "test_event_writer_close",
    "core/data/scene_folder.py": "test_scene_folder_synced_before_it_is_renamed_into_place",
    "core/export/h5.py": "test_h5_export_fsyncs_the_partial_before_renaming_it",
    "core/data/event_index.py": "(a cache: not durable by design)",
}


def test_every_module_that_renames_files_into_place_is_pinned_here():
    """A new rename path (a second atomic-write stack) must get a durability test in this file: the set of
    modules calling ``os.replace`` / ``os.rename`` / ``shutil.move`` / ``Path.rename`` is pinned."""
    import ast

    root = Path(__file__).resolve().parents[2]
    found = set()
    for sub in ("core", "app", "widgets"):
        for f in sorted((root / sub).rglob("*.py")):
            for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
                if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)):
                    continue
                owner = node.func.value.id if isinstance(node.func.value, ast.Name) else None
                if ((owner == "os" and node.func.attr in ("replace", "rename", "renames"))
                        or (owner == "shutil" and node.func.attr == "move") or node.func.attr == "rename"):
                    found.add(f.relative_to(root).as_posix())
    assert found == set(RENAMING_MODULES), (
        f"modules renaming files: {sorted(found)}; pin the durability of each new one in this file")


# ------------------------------------------------------------------------------------------- exports
def _last_file(fmt: str, index: int) -> str:
    return f"{index:04d}_data.mat" if fmt == "epose" else f"test/000000/rgb/{index:06d}.png"


@pytest.mark.parametrize("fmt", ["epose", "bop"])
def test_export_batch_mode_syncs_files_before_journaling_them(tiny_scene_dir, tmp_path, monkeypatch, fmt):
    """"batch" durability: every journal line that the OS has (written, or fsynced) names only windows whose
    files were renamed before a syncfs that came before. Checked at every syncfs and every journal fsync,
    on the journal's content as the OS sees it, so a buffered writer that spills early is caught too."""
    from evpose.core.export import export_scene

    out = tmp_path / "ex"
    journal = out / ".evpose" / "journal.jsonl"
    monkeypatch.setattr(pool, "FLUSH_WINDOWS", 16)
    rec = Recorder(monkeypatch, journal)
    s = export_scene(tiny_scene_dir, fmt, out, window_us=5_000)
    assert s.written > 40
    renamed_at = {}
    for i, e in enumerate(rec.events):
        if e[0] == "replace":
            renamed_at[e[2]] = i
    syncs = [i for i, e in enumerate(rec.events) if e[0] == "syncfs"]
    assert len(syncs) >= 3, "expected one syncfs per chunk of windows"

    def check(at: int, text: str | None, covered_by: int | None):
        for line in (text or "").splitlines():
            try:
                idx = json.loads(line)["i"]
            except ValueError:
                continue
            r = renamed_at.get(str(out / _last_file(fmt, idx)))
            assert r is not None and covered_by is not None and r < covered_by, (
                f"window {idx} is in the journal at event {at} but no syncfs after its rename came before")

    for k, i in enumerate(syncs):
        check(i, rec.events[i][2], syncs[k - 1] if k else None)          # nothing new since the last sync
    for i, e in enumerate(rec.events):
        if e[0] == "fsync" and e[1].endswith("journal.jsonl"):
            before = [j for j in syncs if j < i]
            check(i, e[2], before[-1] if before else None)
            assert before, "journal fsynced before any syncfs"
    # every journal write is fsynced before the next chunk's syncfs (or the end): a journaled window stays journaled
    for i, e in enumerate(rec.events):
        if e[0] == "write" and e[1].endswith("journal.jsonl"):
            nxt = [j for j in syncs if j > i]
            j_fsync = rec.index(lambda x: x[0] == "fsync" and x[1].endswith("journal.jsonl"), start=i + 1)
            assert not nxt or j_fsync < nxt[0], f"journal lines written at event {i} not fsynced before the next syncfs"
    n_journal = sum(1 for line in journal.read_text().splitlines() if line.strip())
    assert n_journal == s.written


def test_export_file_mode_fsyncs_every_file(tiny_scene_dir, tmp_path, monkeypatch):
    from evpose.core.export import export_scene

    out = tmp_path / "ex"
    rec = Recorder(monkeypatch)
    export_scene(tiny_scene_dir, "epose", out, window_us=100_000, objects="box", durable="file")
    # the export's files (not the event-index cache, written on a first open, deliberately not fsynced)
    finals = [Path(e[2]) for e in rec.events if e[0] == "replace" and "/.evpose/" not in e[2]
              and Path(e[2]).is_relative_to(out)]
    assert len(finals) > 20
    for f in finals:
        assert_durable_rename(rec, f)


def test_h5_export_fsyncs_the_partial_before_renaming_it(tiny_scene_dir, tmp_path, monkeypatch):
    import h5py

    from evpose.core.export import export_scene

    out = tmp_path / "ex"
    rec = Recorder(monkeypatch)
    real_close = h5py.File.close

    def close(f):
        name = f.filename if f.id.valid else None
        real_close(f)
        rec.events.append(("h5close", name))

    monkeypatch.setattr(h5py.File, "close", close)
    export_scene(tiny_scene_dir, "h5", out, window_us=100_000, objects="box")
    assert_durable_rename(rec, out / "tiny.h5")
    part = str(out / ".tiny.h5.partial")
    i_rep = rec.index(lambda e: e[0] == "replace" and e[2] == str(out / "tiny.h5"))
    src = rec.events[i_rep][1]               # the canonical copy of the partial file (issue 22), beside it
    assert Path(src).parent == out and src != part and Path(src).name.startswith(".tiny.h5.")
    i_part = min(i for i, e in enumerate(rec.events[:i_rep]) if e[0] == "h5close" and e[1] == part)  # the writer's
    i_close = max(i for i, e in enumerate(rec.events[:i_rep]) if e[0] == "h5close" and e[1] == src)
    assert i_part < i_close, "the copy was made before the partial file was complete"
    assert any(e[0] == "fsync" and e[1] == src for e in rec.events[i_close:i_rep]), \
        "the HDF5 file was not fsynced between its close (HDF5's last writes) and the rename"
    i_log = rec.index(lambda e: e[0] == "write" and b'"f":"tiny.h5"' in e[2])
    assert i_log < i_rep, "the HDF5 file appeared before it was logged"
    assert not Path(part).exists() and not Path(src).exists()


# ------------------------------------------------------------------------------------------- journal cut
def test_journal_cut_at_every_byte_of_its_last_line(tiny_scene_dir, tmp_path):
    """The export journal cut at each byte boundary of its last line (a crash while appending): the resume
    redoes that window unless the line is whole JSON, leaves a journal that parses entirely, and the
    folder ends byte-identical to an uninterrupted export."""
    from evpose.core.data.scene import Scene
    from evpose.core.export import export_scene

    out = tmp_path / "ex"
    kw = dict(window_us=200_000, objects="box")
    scene = Scene.open(tiny_scene_dir)
    try:
        export_scene(scene, "epose", out, **kw)
        files = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file() and ".evpose" not in p.parts}
        journal = out / ".evpose" / "journal.jsonl"
        lines = journal.read_bytes().splitlines(keepends=True)
        n = len(lines)
        head, last = b"".join(lines[:-1]), lines[-1]
        last_idx = json.loads(last)["i"]
        mat = out / f"{last_idx:04d}_data.mat"
        assert len(last) > 20
        for k in range(len(last) + 1):
            cut = last[:k]
            journal.write_bytes(head + cut)
            whole = k >= len(last) - 1            # '{...}' with or without its newline is a complete record
            if not whole:                         # mark the window's files: a redo must rewrite them
                mat.write_bytes(b"\0" * len(files[mat.relative_to(out)]))
            s = export_scene(scene, "epose", out, **kw)
            assert (s.skipped_complete, s.written) == ((n, 0) if whole else (n - 1, 1)), k
            got = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file() and ".evpose" not in p.parts}
            got.pop(Path("export_manifest.json"))
            ref = dict(files)
            ref.pop(Path("export_manifest.json"))
            assert got == ref, k
            recs = Journal(journal).load()
            assert sorted(recs) == sorted(json.loads(x)["i"] for x in lines), k
            for x in journal.read_bytes().splitlines():      # the cut stays alone on its line: never merged
                if x != cut.rstrip(b"\n"):
                    json.loads(x)
    finally:
        scene.close()
