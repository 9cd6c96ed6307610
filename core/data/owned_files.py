"""What ``--force`` may remove: the entries of a folder that evpose can prove it wrote, and the inputs it must keep.

What is provably ours
---------------------
An entry of a folder is evpose's when it is

* a file listed in an ownership log (:mod:`evpose.core.data.owned_log`) of the folder's role
  (``"scene"`` or ``"export"``) whose size **and** modification time (ns) are still those recorded --
  a file the user edited, replaced or copied over since is not ours any more (``cp -p`` /
  ``shutil.copytree`` keep both);
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
folder that holds a source of the same command. :func:`check_out_path` refuses, before anything is
written, an output that would land inside (or on) an input folder, or on an existing entry that is not
what the command writes (a device, a FIFO, a socket: never replaced).
"""
from __future__ import annotations

import contextlib
import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path

from evpose.core.data.input_files import describe_kind
from evpose.core.data.owned_log import LOG_RE, STATE_DIR, read_logs
from evpose.core.data.temp_files import TEMP_RE, is_stale
from evpose.core.errors import NotOursError

__all__ = ["Inventory", "inventory", "remove_owned", "in_the_way", "held_input", "input_paths", "check_out_path",
           "scene_folders_around"]

#: The millisecond index evpose caches beside an event file it wrote.
CACHE_SUFFIX = ".msidx.npz"


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


class _Sorter:
    """Sorts the entries under one folder into ours and foreign (see :func:`inventory`)."""

    def __init__(self, root: Path, role: str, state_files, temps: str):
        self.proof = read_logs(root, role)
        self.inv = Inventory(root)
        self.state_names = set(state_files)
        self.temps = temps

    def is_temp(self, name: str, path: str) -> bool:
        m = TEMP_RE.match(name)
        return m is not None and (self.temps == "all" or is_stale(path, int(m["pid"])))

    def why_not_ours(self, rel: str, st) -> str | None:
        """None when the file ``rel`` is ours, else the reason it is not."""
        proof = self.proof
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

    def entries(self, d: Path) -> list | None:
        """The entries of ``d`` by name; None (and ``d`` foreign) when it cannot be read."""
        try:
            return sorted(os.scandir(d), key=lambda e: e.name)
        except OSError as exc:
            self.inv.foreign.append((d, f"cannot be read: {exc.strerror}"))
            return None

    def walk(self, d: Path, rel_d: str) -> bool:
        """Sort the content of folder ``d`` (``rel_d``: its path relative to the root, with a trailing
        slash); True when all of it is ours."""
        entries = self.entries(d)
        if entries is None:
            return False
        all_ours = True
        for e in entries:
            all_ours &= self.entry(e, f"{rel_d}{e.name}")
        return all_ours

    def entry(self, e, rel: str) -> bool:
        p = Path(e.path)
        try:
            st = e.stat(follow_symlinks=False)
            is_dir = e.is_dir(follow_symlinks=False)
        except OSError as exc:
            self.inv.foreign.append((p, f"cannot be read: {exc.strerror}"))
            return False
        if is_dir:
            return self.folder(p, rel)
        if self.is_temp(e.name, e.path):
            self.inv.files.append(p)
            return True
        why = self.why_not_ours(rel, st)
        if why is not None:
            self.inv.foreign.append((p, why))
            return False
        self.inv.files.append(p)
        return True

    def folder(self, p: Path, rel: str) -> bool:
        if rel == STATE_DIR:
            ok = self.walk_state(p)
        else:
            ok = self.walk(p, rel + "/")
            if rel not in self.proof.dirs:
                if ok:
                    self.inv.foreign.append((p, "folder not made by evpose"))
                ok = False
        if ok:
            self.inv.dirs.append(p)
        return ok

    def walk_state(self, d: Path) -> bool:
        entries = self.entries(d)
        if entries is None:
            return False
        ok = True
        for e in entries:
            p = Path(e.path)
            if e.is_file(follow_symlinks=False) and (LOG_RE.match(e.name) or e.name in self.state_names
                                                      or self.is_temp(e.name, e.path)):
                self.inv.files.append(p)
            else:
                self.inv.foreign.append((p, "not an evpose state file"))
                ok = False
        return ok


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
    sorter = _Sorter(root, role, state_files, temps)
    sorter.walk(root, "")
    return sorter.inv


def in_the_way(inv: Inventory) -> str:
    """The refusal message of ``--force`` over a folder with foreign entries (without the folder)."""
    return (f"--force removes only what evpose wrote; in the way: {inv.describe_foreign()}; move "
            f"{'it' if len(inv.foreign) == 1 else 'them'} away or choose another folder")


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


# ------------------------------------------------------------------------------------------- outputs
def check_out_path(out, kind: str, inputs=(), option: str = "--out", error=NotOursError) -> Path:
    """Refuse ``out`` before anything is written to it; returns it as given.

    ``kind`` is what the command writes there: ``"folder"`` or ``"file"``. Refused (``error``, an
    :class:`~evpose.core.errors.InputError`; one line naming the path and the option): an existing entry of
    another kind -- a device, a FIFO, a socket is never replaced --, a symbolic link that cannot be followed
    (a loop, a missing target), a file without a folder to go into; and a path inside (or equal to) one of
    ``inputs``, ``(folder, what)`` pairs such as ``(scene_dir, "the scene folder")`` (symbolic links
    followed; a folder None is skipped): outputs never land inside inputs.
    """
    out = Path(out).expanduser()

    def refuse(reason: str) -> Exception:
        return error(f"{out}: {option}: {reason}")

    try:
        st = os.stat(out)
    except FileNotFoundError:
        st = None
        if os.path.islink(out):
            raise refuse(f"a symbolic link to {os.readlink(out)}, which does not exist") from None
    except OSError as exc:
        raise refuse(f"cannot be used ({exc.strerror})") from None
    want = "folder" if kind == "folder" else "regular file"
    if st is not None and not (stat.S_ISDIR(st.st_mode) if kind == "folder" else stat.S_ISREG(st.st_mode)):
        is_ = "a regular file" if stat.S_ISREG(st.st_mode) else describe_kind(st.st_mode)
        raise refuse(f"exists and is {is_}, not a {want}; evpose never replaces it: "
                     "choose another path")
    parent = os.path.dirname(os.path.abspath(out))
    if kind == "file" and st is None and not os.path.isdir(parent):
        raise refuse(f"no folder {parent} to write it into")
    for folder, what in inputs:
        if folder is not None and held_input(folder, [out]) is not None:
            where = "is" if os.path.realpath(out) == os.path.realpath(folder) else "inside"
            raise refuse(f"{where} {what} {folder}; evpose never writes into its inputs: choose a path outside it")
    return out


def scene_folders_around(out) -> list[tuple[Path, str]]:
    """``(folder, "a scene folder")`` of every folder holding a ``scene.toml`` that ``out`` is inside of or
    equal to (its path as given and with symbolic links resolved), for :func:`check_out_path`: an output never
    goes into a scene."""
    from evpose.core.data.manifest import SCENE_FILENAME

    a = Path(os.path.abspath(Path(out).expanduser()))
    r = Path(os.path.realpath(a))
    return [(p, "a scene folder") for p in dict.fromkeys([a, *a.parents, r, *r.parents])
            if os.path.lexists(p / SCENE_FILENAME)]
