"""Durability of the user's document (issue 11 item 9): the autosave journal cut at every byte
boundary, or with lines or bytes lost in its middle, restores whole or is reported and ignored, never
crashes (it is one JSON document, all or nothing, not a log of lines); the corrections save syncs its
temp file before the rename and the folder after it."""
import json
import os
from pathlib import Path

import pytest

from evpose.core.data.geometry import T_from_rotvec
from evpose.core.document.corrections import Corrections
from evpose.core.document.journal import read_journal
from evpose.core.session.model import Session


def _put(path: Path, data: bytes) -> None:
    """Replace the file with ``data`` (as a new file: truncating one in place makes ext4 flush it, 5 ms each)."""
    path.unlink(missing_ok=True)
    path.write_bytes(data)


def _edited_session(scene_dir) -> Session:
    s = Session.open(scene_dir)
    s.set_offset_correction_us(12_345, mergeable=False)
    s.history.set(("object", "box"), T_from_rotvec([0.01, 0.02, -0.01], [0.001, -0.002, 0.003]))
    s.add_review("verified", note="grün ok")       # non-ASCII text in the journal
    s.step_windows(3)
    s.add_review("rejected", obj="cylinder")
    return s


def test_journal_cut_at_every_byte_restores_whole_or_is_reported(scene_copy):
    s = _edited_session(scene_copy)
    path = s.write_journal()
    full = path.read_bytes()
    expected = s.scene.corrections.canonical()
    reader = Session.open(scene_copy)               # a fresh app session after the crash
    restored = reported = 0
    for k in range(len(full) + 1):
        _put(path, full[:k])
        j = reader.pending_journal()                 # never raises
        if j is None:
            assert reader.journal_problem is not None and str(path) in reader.journal_problem, k
            assert "ignored" in reader.journal_problem
            reported += 1
        else:
            assert reader.journal_problem is None
            assert j.journal.canonical() == expected, k      # all or nothing
            restored += 1
    assert restored == 1 and reported == len(full)
    # the whole journal restores exactly, as one undo step
    reader.restore_journal(reader.pending_journal())
    assert reader.scene.corrections.canonical() == expected
    assert len(reader.history) == 1
    reader.history.undo()
    assert reader.scene.corrections.canonical() == Corrections().canonical()


def _whole_or_reported(path: Path, expected, expected_base, expected_revision, what) -> bool:
    """Read the journal at ``path``: True when reported (ignored, naming the file), False when restored, and
    then it must be the whole journal (document, base and revision): never a part of it."""
    j, problem = read_journal(path)
    if j is None:
        assert problem is not None and str(path) in problem and "ignored" in problem, what
        return True
    assert problem is None, what
    assert (j.canonical(), j.base, j.revision) == (expected, expected_base, expected_revision), what
    return False


def test_journal_cut_in_the_middle_is_reported_not_half_applied(scene_copy):
    """Not only the end of a journal can go missing: lines or bytes lost in the middle (a hole, a
    zero-filled block after a crash) must be reported too, never restored as a smaller document (the JSON
    often still parses: the journal's checksum catches it). Tried: every run of up to 11 whole lines and
    every run up to the closing line, zero-filled blocks and lost byte runs every 5 bytes."""
    s = _edited_session(scene_copy)
    path = s.write_journal()
    full = path.read_bytes()
    whole, _ = read_journal(path)
    exp, exp_base, exp_rev = whole.canonical(), whole.base, whole.revision
    assert exp == s.scene.corrections.canonical()
    # the checksum comes first: a loss that takes it must take "format" too (refused), or only the checksum line
    assert list(json.loads(full))[:2] == ["sha256", "format"]
    lines = full.splitlines(keepends=True)
    assert len(lines) > 20
    restored = reported = 0
    for i in range(1, len(lines) - 1):                       # lines[i:j] lost, the last line kept:
        for j in {*range(i + 1, min(i + 12, len(lines))), len(lines) - 1}:     # up to 11 lines, or all but "}"
            _put(path, b"".join(lines[:i] + lines[j:]))
            if _whole_or_reported(path, exp, exp_base, exp_rev, f"lines {i}..{j - 1} lost"):
                reported += 1
            else:
                restored += 1
    for start in range(1, len(full) - 1, 5):                 # a zero-filled block, or bytes lost, mid-file
        for n in (1, 3, 17, 64):
            if start + n >= len(full):
                continue
            _put(path, full[:start] + b"\0" * n + full[start + n:])
            assert _whole_or_reported(path, exp, exp_base, exp_rev, f"{n} zero bytes at {start}")
            _put(path, full[:start] + full[start + n:])
            _whole_or_reported(path, exp, exp_base, exp_rev, f"{n} bytes lost at {start}")
    assert reported > 500 and restored <= 1                  # only the checksum line (as an earlier version wrote)


@pytest.mark.parametrize("payload", [b"\xff\xfe{", b"[1, 2]", b'"text"', b"123", b'{"format": "evpose-corrections/1", "base": 3}',
                                     b'{"format": "evpose-corrections/1", "reviews": [7]}', b"",
                                     b'{"format": "evpose-corrections/1", "clock": {"offset_us": 1e300}}'])
def test_damaged_journals_are_reported_not_raised(scene_copy, payload):
    s = Session.open(scene_copy)
    s.journal_path.write_bytes(payload)
    assert s.pending_journal() is None
    assert str(s.journal_path) in s.journal_problem
    assert s.journal_path.exists()                    # kept: it is only removed by a save or a discard


def _save_elsewhere(scene_dir, **fields) -> None:
    """Another program (a CLI ``--apply``) saves ``fields`` into the scene's ``corrections.json``."""
    path = scene_dir / "corrections.json"
    other = Corrections.load(path) if path.exists() else Corrections()
    for key, value in fields.items():
        other.set((key,), value)
    other.save(path)


def _age(path: Path, seconds: float) -> None:
    st = path.stat()
    os.utime(path, (st.st_atime - seconds, st.st_mtime - seconds))


def test_restore_merges_and_keeps_what_another_program_saved_unless_told(scene_copy):
    s = _edited_session(scene_copy)                   # unsaved edits ...
    s.write_journal()                                 # ... autosaved, then the app dies
    journal, st = s.journal_path.read_bytes(), s.journal_path.stat()
    _save_elsewhere(scene_copy, skew_ppm=4.25, offset_us=999)   # a CLI saves another field, and one the journal has
    offer = Session.open(scene_copy).pending_journal()
    assert [(c.field, c.local, c.disk) for c in offer.conflicts] == [("clock.offset_us", "12345 us", "999 us")]
    assert offer.file_newer                           # saved after the autosave
    for take, offset in ((False, 999), (True, 12_345)):
        s.journal_path.write_bytes(journal)           # (the undo below removed it: back to the saved content)
        os.utime(s.journal_path, ns=(st.st_atime_ns, st.st_mtime_ns))
        s2 = Session.open(scene_copy)
        assert s2.restore_journal(s2.pending_journal(), take_autosaved=take) == offer.conflicts
        doc = s2.scene.corrections
        assert doc.skew_ppm == 4.25                   # the other program's edit is kept
        assert doc.offset_us == offset                # the saved value unless the autosaved one is asked for
        assert "box" in doc.object_deltas and len(doc.reviews) == 2      # the journal's other edits restored
        s2.history.undo()
        assert doc.canonical() == Corrections.load(scene_copy / "corrections.json").canonical()


def test_a_journal_the_saved_file_already_holds_is_not_offered(scene_copy):
    """A save whose journal removal was lost (a crash between the two), or another program that saved the
    same values: the journal holds nothing newer than the file."""
    s = _edited_session(scene_copy)
    s.write_journal()
    kept = s.journal_path.read_bytes()
    s.save()
    assert not s.journal_path.exists()
    s.journal_path.write_bytes(kept)                  # the removal did not happen
    _age(s.journal_path, 60)
    assert Session.open(scene_copy).pending_journal() is None


def test_a_journal_older_than_the_file_is_offered_only_for_what_the_file_lacks(scene_copy):
    s = Session.open(scene_copy)
    s.set_offset_correction_us(5_000, mergeable=False)          # an intermediate state, autosaved
    s.write_journal()
    _age(s.journal_path, 60)
    _save_elsewhere(scene_copy, offset_us=7_000)      # the file settled the offset later
    assert Session.open(scene_copy).pending_journal() is None  # the journal's only edit is older than the file's
    # the same journal written after the file was saved: the autosaved edit may be the newer one -- asked
    _age(scene_copy / "corrections.json", 120)
    offer = Session.open(scene_copy).pending_journal()
    assert offer is not None and not offer.file_newer and [c.field for c in offer.conflicts] == ["clock.offset_us"]
    assert offer.keep_saved.offset_us == 7_000 and offer.take_autosaved.offset_us == 5_000
    # a journal edit the file does not have is offered whatever the times, without touching the file's
    s.set_skew_correction_ppm(3.0, mergeable=False)
    s.write_journal()
    _age(s.journal_path, 600)
    offer = Session.open(scene_copy).pending_journal()
    assert offer.keep_saved.skew_ppm == 3.0 and offer.keep_saved.offset_us == 7_000 and offer.file_newer


# ---------------------------------------------------------------------------- fsync / rename order
def _record_io(monkeypatch, calls):
    real_fsync, real_replace, real_rename = os.fsync, os.replace, os.rename

    def fsync(fd):
        target = os.readlink(f"/proc/self/fd/{fd}")
        size = os.fstat(fd).st_size
        calls.append(("fsync", target, size))
        return real_fsync(fd)

    def replace(a, b, *args, **kw):
        calls.append(("replace", str(a), str(b)))
        return real_replace(a, b, *args, **kw)

    def rename(a, b, *args, **kw):
        calls.append(("rename", str(a), str(b)))
        return real_rename(a, b, *args, **kw)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    monkeypatch.setattr(os, "rename", rename)


@pytest.mark.parametrize("through_link", [False, True])
def test_corrections_save_syncs_temp_then_renames_then_syncs_folder(scene_copy, tmp_path, monkeypatch, through_link):
    s = _edited_session(scene_copy)
    target = scene_copy / "corrections.json"
    if through_link:
        store = tmp_path / "store"
        store.mkdir()
        target = store / "real.json"
        (scene_copy / "corrections.json").symlink_to(target)
    calls = []
    _record_io(monkeypatch, calls)
    s.save()
    monkeypatch.undo()
    final = target.read_bytes()
    renames = [c for c in calls if c[0] in ("replace", "rename")]
    assert len(renames) == 1, calls
    _, tmp, dst = renames[0]
    assert Path(dst) == target and Path(tmp).parent == target.parent and not Path(tmp).exists()
    i_ren = calls.index(renames[0])
    # the temp file was synced, complete, before the rename ...
    synced_tmp = [i for i, c in enumerate(calls) if c[0] == "fsync" and c[1] == tmp]
    assert synced_tmp and synced_tmp[-1] < i_ren, calls
    assert calls[synced_tmp[-1]][2] == len(final)
    # ... and the folder after it
    synced_dir = [i for i, c in enumerate(calls) if c[0] == "fsync" and c[1] == str(target.parent)]
    assert synced_dir and synced_dir[-1] > i_ren, calls
    assert json.loads(final)["clock"]["offset_us"] == 12_345


def test_journal_write_is_atomic_and_synced(scene_copy, monkeypatch):
    s = _edited_session(scene_copy)
    calls = []
    _record_io(monkeypatch, calls)
    p = s.write_journal()
    monkeypatch.undo()
    ren = [c for c in calls if c[0] in ("replace", "rename")]
    assert len(ren) == 1 and ren[0][2] == str(p)
    i = calls.index(ren[0])
    assert any(c[0] == "fsync" and c[1] == ren[0][1] for c in calls[:i])
    assert any(c[0] == "fsync" and c[1] == str(p.parent) for c in calls[i:])
