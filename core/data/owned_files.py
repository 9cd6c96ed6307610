"""The manifest of files evpose wrote into an output folder, and the rule of what ``--force`` may remove.

Manifest
--------
Every command that writes an output folder (``synth``, ``import``, ``export``) records each file
and folder it creates in ``<folder>/.evpose/owned-<pid>-<tag>.log`` **before** the file appears
under its final name (a crash can leave a logged name that does not exist, never an existing file
that is not logged). One JSON object per line::

    {"format": "evpose-owned/1", "role": "export", "command": "export epose"}   first line
    {"f": "0003_data.mat", "size": 81234, "mtime_ns": 1732530000123456789}     a file evpose wrote
    {"f": ".scene.h5.partial", "partial": true}                               written in place (any size)
    {"d": "000000/rgb"}                                                       a folder evpose made

Each line starts with a newline, so a line cut by a full disk or a kill never merges with the next.

What is provably ours
---------------------
An entry of a folder is evpose's when it is

* a file listed in a log of the folder's role (``"scene"`` or ``"export"``) whose size **and**
  modification time (ns) are still those recorded -- a file the user edited, replaced or copied over
  since is not ours any more (``cp -p`` / ``shutil.copytree`` keep both);
* a ``partial`` file of such a log (evpose's resumable in-place file, e.g. the HDF5 ``.partial``);
* a folder listed in a log, or the state folder ``.evpose`` itself, with the state files of the
  role (the logs; ``config.json`` and ``journal.jsonl`` of an export);
* a temporary file of evpose (``.<name>.<pid>-<tag>.tmp``) that is stale (its process is dead and
  its lock free), or any such file when the caller holds the folder's lock (``temps="all"``);
* ``<owned file>.msidx.npz``, the millisecond index evpose caches beside an event file.

Everything else is *foreign*. :func:`inventory` sorts a folder into the two;
:func:`remove_owned` removes only the former, files first, then the folders that became empty
(``rmdir``, which never removes content). Symbolic links are removed as links, never followed.

Inputs
------
:func:`held_input` finds an input of the command inside (or equal to) the output folder, comparing
absolute paths and their resolved targets (symbolic links followed), so ``--force`` never removes a
folder that holds a source of the same command.
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
from dataclasses import dataclass, field
from pathlib import Path

from evpose.core.data.fileio import TEMP_RE, is_stale
from evpose.core.errors import NotOursError

__all__ = ["STATE_DIR", "OWNED_FORMAT", "NotOurs", "OwnedLog", "Inventory", "inventory", "remove_owned",
           "record_tree", "held_input", "input_paths", "in_the_way", "check_scene_out",
           "clean_stale_staging", "StagingFolder"]

STATE_DIR = ".evpose"
OWNED_FORMAT = "evpose-owned/1"
_LOG_RE = re.compile(r"^owned-\d+-[0-9a-f]+\.log$")
CACHE_SUFFIX = ".msidx.npz"


NotOurs = NotOursError


# ------------------------------------------------------------------------------------------- the log
class OwnedLog:
    """Append-only record of the files one process writes into one output folder.

    Parameters
    ----------
    root : path
        The output folder; the log goes to ``root/.evpose/owned-<pid>-<tag>.log``.
    role : {"scene", "export"}
        Only logs of the same role count as proof (a scene's log proves nothing in an export).
    command : str
        For people reading the log.

    The file is opened on the first entry (unbuffered ``O_APPEND`` writes: an entry is in the
    kernel before the caller renames the file it names, so a killed process leaves no unlogged file).
    """

    def __init__(self, root, role: str, command: str = ""):
        self.root = Path(root)
        self.role = role
        self.command = command
        self.path = self.root / STATE_DIR / f"owned-{os.getpid()}-{secrets.token_hex(3)}.log"
        self._prefix = str(self.root) + os.sep
        self._fd: int | None = None

    def __getstate__(self):          # a pickled log (a worker's) opens its own file
        d = dict(self.__dict__)
        d["_fd"] = None
        d["path"] = None
        return d

    def __setstate__(self, d):
        self.__dict__.update(d)
        self.path = self.root / STATE_DIR / f"owned-{os.getpid()}-{secrets.token_hex(3)}.log"

    def rel(self, path) -> str:
        s = str(path)
        if s.startswith(self._prefix):
            return s[len(self._prefix):]
        return os.path.relpath(s, self.root)

    def _write(self, lines: list) -> None:
        """Append lines (dicts, or JSON text already) in one ``write``, each after a newline."""
        if not lines:
            return
        if self._fd is None:
            (self.root / STATE_DIR).mkdir(exist_ok=True)
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666)
            if os.fstat(self._fd).st_size == 0:
                lines = [{"format": OWNED_FORMAT, "role": self.role, "command": self.command}] + lines
        data = "".join("\n" + (d if isinstance(d, str) else json.dumps(d, separators=(",", ":"))) for d in lines)
        view = memoryview(data.encode())
        while view:
            view = view[os.write(self._fd, view):]

    def files(self, entries) -> None:
        """Record files: ``entries`` of ``(path, size, mtime_ns)`` (absolute or relative to root)."""
        dumps = json.dumps          # on the export's per-window path: format the line directly
        self._write([f'{{"f":{dumps(self.rel(p))},"size":{int(s)},"mtime_ns":{int(m)}}}' for p, s, m in entries])

    def paths(self, paths) -> None:
        """Record existing files (or symbolic links) by their current size and modification time."""
        out = []
        for p in paths:
            st = os.lstat(p)
            out.append((p, st.st_size, st.st_mtime_ns))
        self.files(out)

    def partial(self, path) -> None:
        """Record a file evpose writes in place (resumable): it is ours whatever its size."""
        self._write([{"f": self.rel(path), "partial": True}])

    def dirs(self, paths) -> None:
        """Record folders evpose made."""
        self._write([{"d": self.rel(p)} for p in paths])

    def sync(self) -> None:
        if self._fd is not None:
            os.fsync(self._fd)

    def close(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None


def record_tree(root, role: str, command: str = "") -> Path:
    """Log every file, link and folder under ``root`` (a staging folder about to be renamed into
    place) in one new log; returns its path."""
    root = Path(root)
    log = OwnedLog(root, role, command)
    (root / STATE_DIR).mkdir(exist_ok=True)
    files, dirs = [], []
    for dirpath, dirnames, filenames in os.walk(root):
        d = Path(dirpath)
        for n in list(dirnames):
            p = d / n
            if p.is_symlink():         # a link to a folder: recorded as a link, never entered
                files.append(p)
                dirnames.remove(n)
            elif p != root / STATE_DIR:
                dirs.append(p)
        files += [d / n for n in filenames]
    log.dirs(dirs)
    log.paths([f for f in files if f != log.path])
    log.close()
    return log.path


# ------------------------------------------------------------------------------------------- reading
@dataclass
class _Proof:
    files: dict = field(default_factory=dict)      # rel -> set of (size, mtime_ns)
    partial: set = field(default_factory=set)
    dirs: set = field(default_factory=set)


def _read_logs(root: Path, role: str) -> _Proof:
    proof = _Proof()
    state = root / STATE_DIR
    try:
        names = [n for n in os.listdir(state) if _LOG_RE.match(n)]
    except OSError:
        return proof
    for n in sorted(names):
        try:
            text = (state / n).read_bytes().decode("utf-8", "replace")
        except OSError:
            continue
        header_ok = False
        for line in text.split("\n"):
            if not line.strip():
                continue
            try:
                d = json.loads(line)
            except ValueError:
                continue          # a line cut by a crash or a full disk
            if not isinstance(d, dict):
                continue
            if "format" in d:
                header_ok = d.get("format") == OWNED_FORMAT and d.get("role") == role
                continue
            if not header_ok:
                break
            if isinstance(d.get("f"), str):
                if d.get("partial") is True:
                    proof.partial.add(d["f"])
                elif isinstance(d.get("size"), int) and isinstance(d.get("mtime_ns"), int):
                    proof.files.setdefault(d["f"], set()).add((d["size"], d["mtime_ns"]))
            elif isinstance(d.get("d"), str):
                proof.dirs.add(d["d"])
    return proof


@dataclass
class Inventory:
    """A folder sorted into what evpose may remove and what it may not."""

    root: Path
    files: list = field(default_factory=list)       # ours: files and links, absolute paths
    dirs: list = field(default_factory=list)        # ours: folders, deepest first
    foreign: list = field(default_factory=list)     # (absolute path, reason)

    @property
    def clean(self) -> bool:
        return not self.foreign

    def describe_foreign(self, limit: int = 3) -> str:
        """``NAME (reason), ...`` of the first ``limit`` foreign entries (relative to the folder, top
        level first), and how many more."""
        if not self.foreign:
            return ""
        items = sorted(self.foreign, key=lambda pr: (len(pr[0].parts), str(pr[0])))
        shown = []
        for p, why in items[:limit]:
            try:
                name = str(p.relative_to(self.root))
            except ValueError:
                name = str(p)
            shown.append(f"{name} ({why})")
        more = len(items) - len(shown)
        return ", ".join(shown) + (f" and {more} more" if more else "")


def inventory(root, role: str, *, state_files=(), temps: str = "stale") -> Inventory:
    """Sort every entry under ``root`` into ours and foreign (see the module docstring).

    Parameters
    ----------
    root : path
        The folder.
    role : {"scene", "export"}
    state_files : iterable of str
        Names inside ``.evpose`` that belong to the role besides the logs (e.g. ``config.json``).
    temps : {"stale", "all"}
        Which evpose temporary files count as ours: the stale ones, or all (the caller holds the
        folder's lock, so no other evpose process writes there).
    """
    root = Path(root)
    proof = _read_logs(root, role)
    inv = Inventory(root)
    state_names = set(state_files)

    def is_temp(name: str, path: str) -> bool:
        m = TEMP_RE.match(name)
        return m is not None and (temps == "all" or is_stale(path, int(m["pid"])))

    def owned_file(rel: str, st) -> str | None:
        """None when ours, else the reason it is not."""
        if rel in proof.partial:
            return None
        seen = proof.files.get(rel)
        if seen is None:
            if rel.endswith(CACHE_SUFFIX) and rel[:-len(CACHE_SUFFIX)] in proof.files:
                return None
            return "not among the files evpose wrote here"
        if (st.st_size, st.st_mtime_ns) not in seen:
            return "changed since evpose wrote it"
        return None

    def walk(d: Path, rel_d: str) -> bool:
        """Sort the content of folder ``d``; True when all of it is ours."""
        all_ours = True
        try:
            entries = sorted(os.scandir(d), key=lambda e: e.name)
        except OSError as exc:
            inv.foreign.append((d, f"cannot be read: {exc.strerror}"))
            return False
        for e in entries:
            rel = f"{rel_d}{e.name}"
            p = Path(e.path)
            try:
                st = e.stat(follow_symlinks=False)
                is_dir = e.is_dir(follow_symlinks=False)
            except OSError as exc:
                inv.foreign.append((p, f"cannot be read: {exc.strerror}"))
                all_ours = False
                continue
            if is_dir:
                in_state = rel == STATE_DIR
                if in_state:
                    ok = walk_state(p)
                else:
                    ok = walk(p, rel + "/")
                    if rel not in proof.dirs:
                        if ok:
                            inv.foreign.append((p, "folder not made by evpose"))
                        ok = False
                if ok:
                    inv.dirs.append(p)
                all_ours &= ok
                continue
            if is_temp(e.name, e.path):
                inv.files.append(p)
                continue
            why = owned_file(rel, st)
            if why is None:
                inv.files.append(p)
            else:
                inv.foreign.append((p, why))
                all_ours = False
        return all_ours

    def walk_state(d: Path) -> bool:
        ok = True
        try:
            entries = sorted(os.scandir(d), key=lambda e: e.name)
        except OSError as exc:
            inv.foreign.append((d, f"cannot be read: {exc.strerror}"))
            return False
        for e in entries:
            p = Path(e.path)
            if e.is_file(follow_symlinks=False) and (_LOG_RE.match(e.name) or e.name in state_names
                                                      or is_temp(e.name, e.path)):
                inv.files.append(p)
            else:
                inv.foreign.append((p, "not an evpose state file"))
                ok = False
        return ok

    walk(root, "")
    return inv


def remove_owned(inv: Inventory, *, keep_root: bool = True) -> None:
    """Remove what :func:`inventory` found to be ours: files (links as links), then the folders
    that are empty (deepest first). Folders with anything left in them stay."""
    for p in inv.files:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(p)
    for d in sorted(inv.dirs, key=lambda q: len(q.parts), reverse=True):
        with contextlib.suppress(OSError):
            os.rmdir(d)
    if not keep_root:
        with contextlib.suppress(OSError):
            os.rmdir(inv.root)


# ------------------------------------------------------------------------------------------- inputs
def _forms(p) -> list[Path]:
    """The absolute path and its resolved form (every symbolic link followed)."""
    p = Path(p).expanduser()
    a = Path(os.path.abspath(p))
    out = [a]
    with contextlib.suppress(OSError, RuntimeError):
        r = a.resolve()
        if r != a:
            out.append(r)
    # a symlink's own target (one level), e.g. a linked events file inside a source folder
    with contextlib.suppress(OSError):
        if a.is_symlink():
            t = Path(os.readlink(a))
            out.append(Path(os.path.abspath(a.parent / t)))
    return out


def held_input(folder, inputs) -> Path | None:
    """The first input inside (or equal to) ``folder``, comparing absolute and resolved paths; None if none."""
    outs = _forms(folder)
    for inp in inputs:
        if inp is None or str(inp) == "":
            continue
        for f in _forms(inp):
            for o in outs:
                if f == o or o in f.parents:
                    return Path(inp)
    return None


def input_paths(*values) -> list[Path]:
    """Paths named by command options: every value, and every ``,``/``=``/``:``-separated piece of a
    string value that exists on disk (e.g. ``--objects name=mesh.obj:T.json``)."""
    out = []
    for v in values:
        if v is None:
            continue
        if isinstance(v, (list, tuple, set)):
            out += input_paths(*v)
            continue
        s = str(v)
        out.append(Path(s))
        if any(c in s for c in ",=:"):
            for piece in re.split(r"[,=:]", s):
                if piece and os.path.exists(os.path.expanduser(piece)):
                    out.append(Path(piece))
    return out


# ------------------------------------------------------------------------------------------- scene folders
_STAGING_RE = re.compile(r"^\.(?P<name>.+)\.(?P<kind>import|synth|replaced)-(?P<pid>\d+)-(?P<tag>[0-9a-f]+)$")
SCENE_ROLE = "scene"


def check_scene_out(out, inputs, force: bool) -> Path:
    """The absolute scene folder ``out`` of ``synth`` / ``import``, checked before anything is written.

    Refuses (:class:`NotOurs`, whose ``reason`` is the message without the path) a path that is not
    a folder; a non-empty folder without ``force``; with ``force``, a folder holding an input of the
    command, or holding anything evpose cannot prove it wrote (see :func:`inventory`).
    """
    out = Path(os.path.abspath(Path(out).expanduser()))
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


def in_the_way(inv: Inventory) -> str:
    """The refusal message of ``--force`` over a folder with foreign entries (without the folder)."""
    return (f"--force removes only what evpose wrote; in the way: {inv.describe_foreign()}; move "
            f"{'it' if len(inv.foreign) == 1 else 'them'} away or choose another folder")


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
        from evpose.core.data.fileio import fsync_dir, sync_filesystem

        record_tree(self.path, SCENE_ROLE, self.command)
        sync_filesystem(self.path)            # every file of the scene on disk before the rename
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
        fsync_dir(self.out.parent)
        if trash is not None:
            remove_owned(inv, keep_root=False)
        return self.out
