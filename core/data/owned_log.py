"""The log of files evpose wrote into an output folder: written before each file appears, read as proof.

Every command that writes an output folder (``synth``, ``import``, ``export``) records each file
and folder it creates in ``<folder>/.evpose/owned-<pid>-<tag>.log`` **before** the file appears
under its final name (a crash can leave a logged name that does not exist, never an existing file
that is not logged). One JSON object per line::

    {"format": "evpose-owned/1", "role": "export", "command": "export epose"}   first line
    {"f": "0003_data.mat", "size": 81234, "mtime_ns": 1732530000123456789}     a file evpose wrote
    {"f": ".scene.h5.partial", "partial": true}                               written in place (any size)
    {"d": "000000/rgb"}                                                       a folder evpose made

Each line starts with a newline, so a line cut by a full disk or a kill never merges with the next.
:func:`read_logs` gathers the entries of every log of one role; :mod:`evpose.core.data.owned_files`
decides from them what ``--force`` may remove.
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["STATE_DIR", "OWNED_FORMAT", "LOG_RE", "OwnedLog", "record_tree", "Proof", "read_logs"]

#: The state folder of an output folder (ownership logs; an export's config and journal).
STATE_DIR = ".evpose"
OWNED_FORMAT = "evpose-owned/1"
#: Names of the ownership logs in the state folder.
LOG_RE = re.compile(r"^owned-\d+-[0-9a-f]+\.log$")


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
class Proof:
    """What the logs of one role prove: files by (size, mtime_ns), partial files, folders."""

    files: dict = field(default_factory=dict)      # rel -> set of (size, mtime_ns)
    partial: set = field(default_factory=set)
    dirs: set = field(default_factory=set)


def read_logs(root: Path, role: str) -> Proof:
    """The entries of every ownership log of ``role`` in ``root/.evpose`` (cut lines and logs of
    another role are ignored)."""
    proof = Proof()
    state = root / STATE_DIR
    try:
        names = [n for n in os.listdir(state) if LOG_RE.match(n)]
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
