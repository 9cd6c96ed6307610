"""The output folder of ``synth`` and ``import``: checked before anything is written, built in a locked
staging folder beside it, and swapped in at the end.

:func:`check_scene_out` refuses a folder that ``--force`` may not replace (one holding an input of the
command, or anything evpose cannot prove it wrote: :mod:`evpose.core.data.owned_files`).
:class:`StagingFolder` builds the scene in ``.<name>.<kind>-<pid>-<tag>``, logs every file
(:func:`evpose.core.data.owned_log.record_tree`), syncs the filesystem, renames it into place and removes
the old scene's files; :func:`clean_stale_staging` deals with what killed runs left beside it.
"""
from __future__ import annotations

import contextlib
import os
import re
import secrets
from pathlib import Path

from evpose.core.data import atomic
from evpose.core.data.owned_files import held_input, in_the_way, inventory, remove_owned, scene_folders_around
from evpose.core.data.owned_log import record_tree
from evpose.core.data.temp_files import is_stale
from evpose.core.errors import NotOursError

__all__ = ["SCENE_ROLE", "NotOurs", "check_scene_out", "clean_stale_staging", "StagingFolder"]

NotOurs = NotOursError
_STAGING_RE = re.compile(r"^\.(?P<name>.+)\.(?P<kind>import|synth|replaced)-(?P<pid>\d+)-(?P<tag>[0-9a-f]+)$")
SCENE_ROLE = "scene"


def check_scene_out(out, inputs, force: bool) -> Path:
    """The absolute scene folder ``out`` of ``synth`` / ``import``, checked before anything is written.

    Refuses (:class:`NotOurs`, whose ``reason`` is the message without the path) a path inside (or equal to)
    a folder among ``inputs`` or inside a scene folder (outputs never land inside inputs); a path that is not
    a folder; a non-empty folder without ``force``; with ``force``, a folder holding an input of the
    command, or holding anything evpose cannot prove it wrote (see :func:`inventory`).
    """
    out = Path(os.path.abspath(Path(out).expanduser()))
    guards = [(Path(p), "an input folder of this command") for p in inputs if os.path.isdir(p)]
    for folder, what in guards + scene_folders_around(out.parent):      # outputs never land inside inputs
        if held_input(folder, [out]) is not None:
            raise _not_ours(out, f"is or is inside {what}, {folder}: evpose never writes into an input or into "
                                 "another scene; choose a folder outside it")
    if not out.exists() and not out.is_symlink():
        return out
    if not out.is_dir():
        raise _not_ours(out, "exists and is not a folder")
    try:
        empty = not any(os.scandir(out))
    except OSError as exc:
        raise _not_ours(out, f"cannot be read ({exc.strerror})") from None
    if empty:
        return out
    if not force:
        raise _not_ours(out, "the folder exists and is not empty (use --force to replace it)")
    inp = held_input(out, inputs)
    if inp is not None:
        raise _not_ours(out, f"holds {inp}, an input of this command: --force never removes a folder that holds an "
                             "input; choose another folder")
    inv = inventory(out, SCENE_ROLE)
    if not inv.clean:
        raise _not_ours(out, in_the_way(inv))
    return out


def _not_ours(path, reason: str) -> NotOurs:
    exc = NotOurs(f"{path}: {reason}")
    exc.path, exc.reason = Path(path), reason
    return exc


def clean_stale_staging(parent) -> list[Path]:
    """Deal with what killed ``synth`` / ``import`` runs left beside their scene folders in ``parent``:
    stale staging folders (``.NAME.import-PID-TAG``, ``.NAME.synth-PID-TAG``: removed) and stale
    ``.NAME.replaced-PID-TAG`` folders (the previous scene: put back when ``NAME`` is missing, else its
    evpose files removed). Folders of live processes are left alone. Returns what was removed or restored."""
    import shutil

    done = []
    try:
        it = list(os.scandir(parent))
    except OSError:
        return done
    for e in it:
        m = _STAGING_RE.match(e.name)
        if m is None or not e.is_dir(follow_symlinks=False) or not is_stale(e.path, int(m["pid"])):
            continue
        p = Path(e.path)
        if m["kind"] in ("import", "synth"):
            shutil.rmtree(p, ignore_errors=True)
            done.append(p)
            continue
        target = Path(parent) / m["name"]
        if not target.exists() and not target.is_symlink():
            with contextlib.suppress(OSError):
                os.rename(p, target)
                done.append(target)
            continue
        inv = inventory(p, SCENE_ROLE)
        remove_owned(inv, keep_root=False)
        done.append(p)
    return done


class StagingFolder:
    """A scene built in a hidden, locked sibling folder and swapped in at the end.

    ``create()`` removes stale leftovers of killed runs beside ``out`` (:func:`clean_stale_staging`),
    then makes ``.<out name>.<kind>-<pid>-<tag>`` and holds a ``flock`` on it until ``commit()`` or
    ``abort()``. ``commit()`` logs every file of the staging folder (:func:`record_tree`), flushes the
    filesystem, checks ``out`` again (as :func:`check_scene_out`), moves an existing ``out`` aside,
    checks that what was moved is still all ours (else it is put back and the commit refused),
    renames the staging folder to ``out``, fsyncs the parent, and removes the old scene's files.
    """

    def __init__(self, out, kind: str, command: str = ""):
        self.out = Path(os.path.abspath(Path(out).expanduser()))
        self.kind = kind
        self.command = command
        self.path = self.out.parent / f".{self.out.name}.{kind}-{os.getpid()}-{secrets.token_hex(4)}"
        self._fd: int | None = None

    def create(self) -> Path:
        import fcntl

        self.out.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_staging(self.out.parent)
        self.path.mkdir()
        self._fd = os.open(self.path, os.O_RDONLY)
        with contextlib.suppress(OSError):
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return self.path

    def _release(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None

    def abort(self) -> None:
        import shutil

        shutil.rmtree(self.path, ignore_errors=True)
        self._release()

    def commit(self, inputs, force: bool) -> Path:
        record_tree(self.path, SCENE_ROLE, self.command)
        atomic.sync_filesystem(self.path)     # every file of the scene on disk before the rename
        check_scene_out(self.out, inputs, force)
        trash = None
        if self.out.exists() or self.out.is_symlink():
            trash = self.out.parent / f".{self.out.name}.replaced-{os.getpid()}-{secrets.token_hex(4)}"
            os.rename(self.out, trash)
            inv = inventory(trash, SCENE_ROLE)
            if not inv.clean:          # something appeared since the check: put everything back
                os.rename(trash, self.out)
                raise _not_ours(self.out, in_the_way(inv))
        try:
            os.rename(self.path, self.out)
        except BaseException:
            if trash is not None:
                os.rename(trash, self.out)
            raise
        self._release()
        atomic.fsync_dir(self.out.parent)
        if trash is not None:
            remove_owned(inv, keep_root=False)
        return self.out
