"""Reading and saving ``corrections.json`` safely when several programs write it.

:func:`save` is the one save path (the CLI's ``--apply``, the app's Save, :meth:`Corrections.save`):

1. It resolves a symlinked ``corrections.json`` to its target: the target is replaced, the link stays.
2. It takes an exclusive ``flock`` on the target's folder (or, where a folder cannot be locked, on a
   hidden ``.corrections.json.lock`` beside it) **only for the read-compare-write below**. The kernel
   releases an ``flock`` when its holder exits for any reason, ``kill -9`` included, so no stale lock
   can block a later save; a writer that holds it longer than :data:`LOCK_TIMEOUT_S` makes the save
   fail with a message instead of waiting forever.
3. Under the lock it re-reads the file. If the content differs from the document's ``base`` (what the
   file held when the document was loaded or last saved), another program saved meanwhile: the two
   edits are merged field by field (:func:`evpose.core.document.corrections_merge.merge`) or the save is refused with
   :class:`~evpose.core.document.corrections_merge.CorrectionsConflict` naming the field and both values. A file that
   cannot be read is never overwritten.
4. It writes the result with the next revision (one more than the larger of the two) through
   :func:`evpose.core.data.atomic.atomic_path`: temp file in the same folder, ``fsync`` of the temp file, atomic
   rename over the target, ``fsync`` of the folder. A reader sees the old or the new file, never a
   mix; after a crash at any point the old or the new file is on disk.
"""
from __future__ import annotations

import contextlib
import errno
import json
import os
import stat
import time
from dataclasses import dataclass, field
from pathlib import Path

from evpose.core.data.atomic import atomic_path
from evpose.core.document.corrections import CORRECTIONS_FORMAT, Corrections, CorrectionsError

#: Seconds a save waits for another writer's lock before giving up with a message.
LOCK_TIMEOUT_S = 10.0
#: A corrections file larger than this is refused before it is read (a document of a million review
#: marks is about 100 MB).
MAX_BYTES = 256 * 1024 * 1024
_UNSUPPORTED = {errno.EBADF, errno.EINVAL, errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.ENOSYS}


@dataclass
class SaveReport:
    """What :func:`save` did.

    Attributes
    ----------
    path : Path
        The path saved (a symlink stays a symlink).
    target : Path
        The file actually replaced (the symlink's target, or ``path``).
    revision : int
        Revision written.
    written : Corrections
        The document written (the local one, or the merge).
    merged : Corrections or None
        The merge when another program had saved meanwhile (its edits were taken over); None otherwise.
    from_disk : list of str
        Fields taken over from the other program's save.
    signature : tuple or None
        :func:`signature` of the file just written.
    """

    path: Path
    target: Path
    revision: int
    written: Corrections
    merged: Corrections | None = None
    from_disk: list = field(default_factory=list)
    signature: tuple | None = None


def target_of(path) -> Path:
    """The file a save replaces: the final target of a symlink (relative links resolved), else ``path``."""
    path = Path(path)
    if path.is_symlink():
        return Path(os.path.realpath(path))
    return path


def signature(path) -> tuple | None:
    """``(st_dev, st_ino, st_mtime_ns, st_size)`` of ``path`` (following a symlink); None if missing.
    Every save renames a new file into place, so the inode changes even within one mtime tick."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino, st.st_mtime_ns, st.st_size


def read(path) -> tuple[Corrections | None, tuple | None]:
    """Parse ``path``: ``(document, signature)``, ``(None, None)`` when there is no file.

    Raises :class:`CorrectionsError` naming the file (and the field) for anything unusable: not a
    regular file, too large, not UTF-8, not JSON, invalid content."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return None, None
    except OSError as exc:
        raise CorrectionsError(f"{path}: cannot read ({exc.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise CorrectionsError(f"{path}: not a regular file")
    if st.st_size > MAX_BYTES:
        raise CorrectionsError(f"{path}: {st.st_size} bytes is too large for a corrections file "
                               f"(limit {MAX_BYTES // 2 ** 20} MiB)")
    try:
        with open(path, "rb") as f:
            fst = os.fstat(f.fileno())
            raw = f.read(MAX_BYTES + 1)
    except FileNotFoundError:
        return None, None
    except OSError as exc:
        raise CorrectionsError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CorrectionsError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CorrectionsError(f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None
    except RecursionError:
        raise CorrectionsError(f"{path}: not valid JSON (nested too deeply)") from None
    doc = Corrections.from_json(data, source=str(path))
    return doc, (fst.st_dev, fst.st_ino, fst.st_mtime_ns, fst.st_size)


def lock_path(target) -> Path:
    """The fallback lock file beside ``target`` (used where a folder cannot be ``flock``-ed)."""
    target = Path(target)
    return target.parent / f".{target.name}.lock"


def _acquire(fd: int, what, timeout_s: float) -> None:
    import fcntl

    deadline = time.monotonic() + timeout_s
    delay = 0.002
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
        except BlockingIOError:
            if time.monotonic() >= deadline:
                raise CorrectionsError(f"{what}: another program has been saving the corrections for "
                                       f"{timeout_s:g} s (it holds the lock); nothing saved, try again") from None
            time.sleep(delay)
            delay = min(delay * 2, 0.05)


@contextlib.contextmanager
def locked(target, timeout_s: float = LOCK_TIMEOUT_S):
    """Hold an exclusive ``flock`` for saving ``target`` (see the module docstring)."""
    target = Path(target)
    try:
        import fcntl  # noqa: F401
    except ImportError:  # pragma: no cover - not POSIX: no lock
        yield None
        return
    fd = None
    for opener in (lambda: os.open(target.parent, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0)),
                   lambda: os.open(lock_path(target), os.O_RDWR | os.O_CREAT, 0o644)):
        try:
            fd = opener()
        except OSError:
            continue                   # no such folder / read-only: the write reports it
        try:
            _acquire(fd, target, timeout_s)
            break
        except OSError as exc:
            os.close(fd)
            fd = None
            if exc.errno not in _UNSUPPORTED:
                raise
        except BaseException:
            os.close(fd)
            raise
    try:
        yield fd
    finally:
        if fd is not None:
            os.close(fd)               # closing the last descriptor releases the flock


def save(path, doc: Corrections, *, prefer: str | None = None, lock_timeout_s: float = LOCK_TIMEOUT_S) -> SaveReport:
    """Save ``doc`` to ``path`` with the revision check (see the module docstring).

    ``doc`` is not modified: the caller applies ``report.merged`` (if any) and records the save
    (:meth:`Corrections.mark_saved`). ``prefer`` ("local" / "disk") resolves conflicts instead of
    refusing. Raises :class:`CorrectionsError` (or its subclass ``CorrectionsConflict``) naming the
    file, and ``OSError`` when the write fails (the old file is then intact)."""
    from evpose.core.document.corrections_merge import merge

    path = Path(path)
    target = target_of(path)
    with locked(target, lock_timeout_s):
        disk, _ = read(target)
        to_write, merged, from_disk = doc, None, []
        if disk is not None:
            base_canon = doc.base if doc.base is not None else Corrections().canonical()
            if disk.canonical() != base_canon:
                base = Corrections.from_json({"format": CORRECTIONS_FORMAT, "revision": 0, **base_canon},
                                             source=f"{path} (as loaded)")
                res = merge(base, doc, disk, prefer=prefer, source=str(path))
                to_write, from_disk = res.doc, res.from_disk
                if doc.differing_keys(res.doc):
                    merged = res.doc
        out = to_write.copy()
        out.revision = max(doc.revision, disk.revision if disk is not None else 0) + 1
        out.scene_name = doc.scene_name or (disk.scene_name if disk is not None else None)
        text = json.dumps(out.to_json(), indent=1) + "\n"
        with atomic_path(target) as tmp:
            with open(tmp, "w", encoding="utf-8") as f:
                f.write(text)
        sig = signature(target)
    return SaveReport(path, target, out.revision, out, merged, from_disk, sig)


def disk_changed(path, doc: Corrections) -> bool:
    """Cheap check whether ``path`` may hold something else than ``doc`` last loaded or saved
    (signature comparison, no read)."""
    return signature(target_of(path)) != doc.disk_signature
