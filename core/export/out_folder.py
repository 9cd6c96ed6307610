"""The output folder of an export: its lock, its state, and what a run may do with an earlier export in it.

State
-----
``OUT/.evpose/config.json`` holds the configuration fingerprint (:mod:`evpose.core.export.fingerprint`),
``OUT/.evpose/journal.jsonl`` the complete windows (:mod:`evpose.core.export.journal`) and
``OUT/.evpose/owned-*.log`` every file evpose wrote there, logged before it appeared
(:mod:`evpose.core.data.owned_log`; the workers log their own).

Resume, refuse, replace
-----------------------
A run into a folder with the same fingerprint resumes. Otherwise (:func:`prepare_out_dir`) only what
evpose can prove it wrote is ever removed (:func:`evpose.core.data.owned_files.inventory`): anything
else in the folder -- a file the user added, or one of ours changed since -- refuses the run, even with
``force``, naming it; so does a folder holding an input (the scene). An earlier export with results
(journaled windows or a finished export) is replaced only with ``force``; one without (a run that failed
early) is replaced without. evpose's temporary files are removed on start and on interrupt.

Never inside the scene
----------------------
An output folder inside (or equal to) the scene folder or any folder holding a ``scene.toml``, or an
existing ``--out`` that is not a folder (a device, a FIFO, a socket), is refused before anything is written
(:func:`check_export_out`).
"""
from __future__ import annotations

import json
from pathlib import Path

from evpose.core.data.atomic import write_atomic
from evpose.core.data.owned_files import (
    check_out_path,
    held_input,
    in_the_way,
    inventory,
    remove_owned,
    scene_folders_around,
)
from evpose.core.data.owned_log import STATE_DIR
from evpose.core.export.encode import json_text
from evpose.core.export.journal import Journal
from evpose.core.export.options import ExportError

__all__ = ["STATE_DIR", "CONFIG_NAME", "JOURNAL_NAME", "MANIFEST_NAME", "README_NAME", "EXPORT_ROLE",
           "EXPORT_STATE_FILES", "scene_inputs", "check_export_out", "lock_folder", "prepare_out_dir"]

CONFIG_NAME = "config.json"
JOURNAL_NAME = "journal.jsonl"
MANIFEST_NAME = "export_manifest.json"
README_NAME = "README.txt"
#: Role of an export's ownership logs (a scene's logs prove nothing in an export folder).
EXPORT_ROLE = "export"
#: Files of ``.evpose`` that belong to an export besides the ownership logs.
EXPORT_STATE_FILES = (CONFIG_NAME, JOURNAL_NAME)


def scene_inputs(scene) -> list[Path]:
    """Every file an export reads: scene.toml (first), events (a link and its target), trajectory (if any), meshes,
    corrections.json. An output folder that holds one of them is never cleared."""
    m = scene.manifest
    out = [Path(m.path), Path(m.events_path)] + ([] if m.trajectory_path is None else [Path(m.trajectory_path)])
    out += [Path(o.mesh) for o in m.objects]
    cp = getattr(scene, "corrections_path", None)
    if cp is not None:
        out.append(Path(cp))
    return out


def check_export_out(out_dir, scene) -> Path:
    """Refuse, before anything is written, an output folder inside (or equal to) the folder of ``scene`` (a
    scene folder or its scene.toml) or any other scene folder, or one that exists and is not a folder."""
    scene = Path(scene).expanduser()
    folder = scene if scene.is_dir() else scene.parent if scene.is_file() else None     # None: no scene to read
    return check_out_path(out_dir, "folder", [(folder, "the scene folder"), *scene_folders_around(out_dir)],
                          error=ExportError)


def lock_folder(out_dir: Path) -> int:
    """An exclusive ``flock`` on the output folder for the whole run: a second export into the same
    folder (another process or thread) is refused instead of mixing files or deleting live temp files."""
    from evpose.core.data.temp_files import try_lock_folder

    fd = try_lock_folder(out_dir)
    if fd is None:
        raise ExportError(f"{out_dir}: --out: another export is writing into this folder")
    return fd


def _read_config(cfg: Path) -> dict | None:
    """The earlier export's ``config.json``: None when absent, ``{}`` when unreadable."""
    if not cfg.is_file():
        return None
    try:
        old = json.loads(cfg.read_text())
    except (OSError, ValueError):
        return {}
    return old if isinstance(old, dict) else {}


def _has_results(out_dir: Path) -> bool:
    """Whether an earlier export left anything worth keeping: a journaled window or a finished export."""
    return (out_dir / MANIFEST_NAME).exists() or bool(Journal(out_dir / STATE_DIR / JOURNAL_NAME).load())


def prepare_out_dir(out_dir: Path, sha: str, doc: dict, force: bool, inputs=()) -> None:
    """Make ``out_dir`` ready for an export with fingerprint ``sha`` (the caller holds its lock).

    * empty or new: used;
    * an earlier export with the same fingerprint: resumed (nothing removed);
    * otherwise every entry is sorted by :func:`evpose.core.data.owned_files.inventory`: anything evpose did not
      write (or that changed since) is never removed and refuses the run, naming it; a folder holding
      an input of this export (the scene) is refused; an earlier export with results (journaled
      windows or a finished export) is replaced only with ``force``; one without results -- a failed
      run, or only ``.evpose`` state -- is replaced without ``force``. Only evpose's own files are
      removed.
    """
    state = out_dir / STATE_DIR
    cfg = state / CONFIG_NAME
    if out_dir.exists() and not out_dir.is_dir():
        raise ExportError(f"{out_dir}: --out: exists and is not a folder")
    if inputs:
        check_export_out(out_dir, inputs[0])          # the scene.toml: never an output inside its folder
    entries = list(out_dir.iterdir()) if out_dir.is_dir() else []
    if entries:
        inp = held_input(out_dir, inputs)
        if inp is not None:
            raise ExportError(f"{out_dir}: --out: holds {inp}, an input of this export; evpose never clears a "
                              "folder that holds an input: choose another folder")
        old = _read_config(cfg)
        if old is None or old.get("sha256") != sha:
            _clear(out_dir, old, doc, force)
    out_dir.mkdir(parents=True, exist_ok=True)
    state.mkdir(exist_ok=True)
    old = _read_config(cfg)
    if old is None or old.get("sha256") != sha:
        write_atomic(cfg, json_text({"sha256": sha, "fingerprint": doc}).encode())


def _clear(out_dir: Path, old: dict | None, doc: dict, force: bool) -> None:
    """Remove an earlier run's files (its config is ``old``, None when there is none) for a new
    configuration ``doc``, or refuse (see :func:`prepare_out_dir`)."""
    inv = inventory(out_dir, EXPORT_ROLE, state_files=EXPORT_STATE_FILES, temps="all")
    if old is None and not inv.clean:
        raise ExportError(f"{out_dir}: --out: the folder is not empty and holds no evpose export "
                          f"({inv.describe_foreign()}); choose an empty or new folder "
                          "(--force only replaces an earlier evpose export)")
    if old is not None and not force and _has_results(out_dir):
        diff = _describe_difference(old.get("fingerprint", {}), doc)
        note = "" if inv.clean else f" (--force would still keep {inv.describe_foreign()}, not evpose's)"
        raise ExportError(f"{out_dir}: --out: holds an export with a different configuration "
                          f"({diff}); use --force to replace it, or another folder{note}")
    if not inv.clean:
        raise ExportError(f"{out_dir}: --out: {in_the_way(inv)}")
    remove_owned(inv)


def _describe_difference(old: dict, new: dict, prefix: str = "") -> str:
    """The first few keys whose values differ (for the refusal message)."""
    diffs = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k), new.get(k)
        if a == b:
            continue
        if isinstance(a, dict) and isinstance(b, dict):
            sub = _describe_difference(a, b, f"{prefix}{k}.")
            diffs.append(sub)
        else:
            diffs.append(f"{prefix}{k}")
    return ", ".join(d for d in diffs if d)[:300] or "unknown"
