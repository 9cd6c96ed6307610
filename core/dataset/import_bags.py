"""``evpose dataset import epose-bag RAW_DIR --assets DIR --out DATASET``: every E-POSE bag -> one scene.

:func:`plan_bags` finds the ``.bag`` files under ``RAW_DIR`` (recursively, in path order) and names the
E-POSE scene and sequence of each, from the assets' ``scenes.json`` and ``time_shifts.csv``, with the
importers' own name matching (:func:`~evpose.core.importers.epose_assets.match_name`, sequences
case-insensitive). Two layouts are accepted::

    RAW_DIR/<scene>/<sequence>.bag        e.g. RAW_DIR/bleach/R_01_ml.bag
    RAW_DIR/.../<scene>_<sequence>.bag    e.g. RAW_DIR/five_obj_clut_r_05_ML.bag

Each bag becomes the scene folder ``DATASET/<scene>_<sequence>`` (the ``scenes.json`` key and the sequence
as published in ``time_shifts.csv``, e.g. ``bleach_cleanser_R_01_ml``), imported on a Dask worker by
:func:`import_task` exactly as ``evpose import epose-bag BAG --assets DIR --scene S --sequence Q --out
DATASET/S_Q`` does: with the published prior time shift as the scene's clock offset. ``DATASET`` is then
a dataset folder (:class:`~evpose.core.dataset.dataset.Dataset`).

A bag that matches no scene/sequence, and a bag whose import fails, are failures of that bag (one line
in ``failed``); the others go on. Two bags naming the same scene stop the run before anything is written.
Each scene is built atomically by the importer (a staging folder renamed into place), so a scene folder
holding ``scene.toml`` and ``import_report.json`` is a finished import: a rerun reports it as skipped
(``"skipped": true``) when its report names the same, unchanged bag. Nothing is ever replaced: a scene
folder that holds anything else is a failure of that bag.
"""
from __future__ import annotations

import json
import re
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from evpose.core.data.json_values import plain
from evpose.core.dataset.batch import BatchResult, failure_text
from evpose.core.dataset.dataset import DatasetError

__all__ = ["BagPlan", "completed_import", "import_dataset", "import_task", "plan_bags"]

FORMAT = "epose-bag"
#: Seconds between two looks at ``cancel()`` while no task finishes.
POLL_S = 0.1


@dataclass(frozen=True)
class BagPlan:
    """One bag of ``RAW_DIR`` and the scene it becomes.

    ``scene`` is the ``scenes.json`` key and ``sequence`` the sequence as published in ``time_shifts.csv``;
    ``name`` is the dataset's scene folder ``<scene>_<sequence>``. A bag that matches nothing has
    ``scene``/``sequence`` None, ``name`` its path relative to ``RAW_DIR`` and ``error`` the one-line reason.
    ``how`` says how the names matched (``"exact"`` or the matcher's words).
    """

    bag: Path
    scene: str | None
    sequence: str | None
    name: str
    how: str = "exact"
    error: str | None = None


class _Names:
    """The E-POSE scenes and time shifts of an assets folder, and the importers' matching of bag names."""

    def __init__(self, assets: Path):
        from evpose.core.importers.epose_assets import read_scenes, read_time_shifts

        self.scenes_file, self.shifts_file = assets / "scenes.json", assets / "time_shifts.csv"
        self.scenes = read_scenes(self.scenes_file)
        self.shifts = read_time_shifts(self.shifts_file)

    def resolve(self, scene: str, sequence: str) -> tuple[str, str, str] | str:
        """``(scenes.json key, sequence as published, how)``, or why the pair names no sequence."""
        from evpose.core.importers.epose_assets import lookup_time_shift, match_name
        from evpose.core.importers.failure import ImportFailure

        try:
            key, how = match_name(scene, self.scenes, file=self.scenes_file, record="scenes", fld="scene")
            _, seq, _, _, _ = lookup_time_shift(self.shifts, self.shifts_file, key, sequence)
        except ImportFailure as exc:
            return exc.reason
        return key, seq, how

    def match(self, rel: Path) -> tuple[str, str, str] | str:
        """The scene of the bag at ``rel`` (relative to RAW_DIR), or the reason it has none."""
        if len(rel.parts) >= 2:                           # RAW_DIR/<scene>/<sequence>.bag
            hit = self.resolve(rel.parent.name, rel.stem)
            if not isinstance(hit, str):
                return hit
        tokens = [t for t in re.split(r"[^A-Za-z0-9]+", rel.stem) if t]
        hits, unsure = {}, []                             # <scene>_<sequence>.bag: every split point
        for k in range(1, len(tokens)):
            hit = self.resolve("_".join(tokens[:k]), "_".join(tokens[k:]))
            if not isinstance(hit, str):
                hits.setdefault(hit[:2], hit)
            elif "ambiguous" in hit:
                unsure.append(f"scene {hit}")
        if len(hits) == 1:
            return next(iter(hits.values()))
        if hits:
            return f"ambiguous: it could be {' or '.join(f'{s}/{q}' for s, q in hits)}"
        return (f"matches no E-POSE scene and sequence of {self.shifts_file} (expected RAW_DIR/<scene>/<sequence>.bag "
                "or <scene>_<sequence>.bag)" + "".join(f"; {u}" for u in unsure))


def plan_bags(raw_dir, assets) -> list[BagPlan]:
    """Every ``.bag`` under ``raw_dir`` (recursively, in path order) and the scene it becomes.

    Raises :class:`~evpose.core.dataset.dataset.DatasetError` when ``raw_dir`` is not a folder or holds no
    bag, or when two bags name the same scene (the message names both); an unreadable ``scenes.json`` /
    ``time_shifts.csv`` raises the importers' :class:`~evpose.core.importers.failure.ImportFailure`.
    A bag that matches nothing is returned with ``error`` set.
    """
    raw = Path(raw_dir).expanduser().absolute()
    if not raw.is_dir():
        raise DatasetError(f"{raw}: RAW_DIR: not a folder")
    names = _Names(Path(assets).expanduser().absolute())
    bags = sorted((p for p in raw.rglob("*") if p.suffix.lower() == ".bag" and p.is_file()),
                  key=lambda p: p.relative_to(raw).as_posix())
    if not bags:
        raise DatasetError(f"{raw}: RAW_DIR: no .bag files in it")
    plans, seen = [], {}
    for bag in bags:
        rel = bag.relative_to(raw)
        hit = names.match(rel)
        if isinstance(hit, str):
            plans.append(BagPlan(bag, None, None, rel.as_posix(), error=f"{bag}: {hit}"))
            continue
        key, seq, how = hit
        name = f"{key}_{seq}"
        if name in seen:
            raise DatasetError(f"{seen[name]} and {bag}: both are E-POSE {key}/{seq} (scene {name}); "
                               "keep one of them in RAW_DIR")
        seen[name] = bag
        plans.append(BagPlan(bag, key, seq, name, how))
    return plans


def completed_import(out, bag) -> dict | None:
    """The summary of the finished import of ``bag`` at ``out`` (``"skipped": true``), or None when ``out``
    is absent or an empty folder. Raises :class:`DatasetError` when ``out`` holds anything else (another
    bag's scene, the scene of ``bag`` before it changed, or files evpose did not import there)."""
    from evpose.core.data.manifest import SCENE_FILENAME
    from evpose.core.importers import REPORT_FILENAME

    out, bag = Path(out), Path(bag)
    if not out.exists() and not out.is_symlink():
        return None
    if out.is_dir() and not out.is_symlink() and not any(out.iterdir()):
        return None
    report = out / REPORT_FILENAME
    if not (out.is_dir() and (out / SCENE_FILENAME).is_file() and report.is_file()):
        raise DatasetError(f"{out}: exists and is not a scene imported by evpose; it is left alone (move it away "
                           f"to import {bag.name})")
    try:
        rep = json.loads(report.read_text(encoding="utf-8"))
        src = rep["sources"][0] if rep.get("importer") == FORMAT and len(rep["sources"]) == 1 else {}
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        raise DatasetError(f"{report}: not a readable import report; the scene is left alone") from None
    st = bag.stat()
    if src.get("path") != str(bag.resolve()):
        raise DatasetError(f"{out}: holds a scene imported from {src.get('path', 'another source')}, not {bag}; "
                           "it is left alone")
    if (src.get("bytes"), src.get("mtime_ns")) != (st.st_size, st.st_mtime_ns):
        raise DatasetError(f"{out}: imported from {bag} before the bag changed (size or time differs); remove "
                           "the scene folder to import it again")
    return {"scene": str(out.absolute()), "format": FORMAT, "n_events": rep.get("counts", {}).get("events_written"),
            "n_poses": rep.get("trajectory", {}).get("n"), "events_only": bool(rep.get("events_only")),
            "objects": list(rep.get("objects", {})),
            "report": str(out.absolute() / REPORT_FILENAME), "assumptions": rep.get("assumptions", []),
            "repairs": rep.get("repairs", []), "warnings": rep.get("warnings", []),
            "runtime_s": rep.get("runtime_s"), "skipped": True}


def import_task(bag: str, out_scene_dir: str, options: dict) -> dict:
    """Import one bag on a worker: ``evpose import epose-bag BAG --out OUT_SCENE_DIR`` with ``options``
    (:class:`~evpose.core.importers.ImportOptions` fields, e.g. ``assets``, ``scene``, ``sequence``).

    Returns the import's summary (plain JSON values) with ``"skipped": false``, or, when the scene is
    already a finished import of this bag, :func:`completed_import`'s summary. Never replaces anything.
    """
    from evpose.core.importers import ImportOptions, import_scene

    done = completed_import(out_scene_dir, bag)
    if done is not None:
        return plain(done)
    opts = ImportOptions(**options)
    opts.force = False
    summary = import_scene(FORMAT, [bag], out_scene_dir, opts, log=None)
    return plain({**summary, "skipped": False})


def import_dataset(client, raw_dir, assets, out_dir, *, progress: Callable[[float, str], None] | None = None,
                   cancel: Callable[[], bool] | None = None) -> BatchResult:
    """Import every bag of ``raw_dir`` into the dataset folder ``out_dir``, one Dask task per bag.

    Parameters
    ----------
    client : distributed.Client
        Its workers must see ``raw_dir``, ``assets`` and ``out_dir`` under the same paths.
    raw_dir, assets, out_dir : str or Path
        The bags (read-only), the E-POSE assets folder, and the dataset folder (created when absent).
    progress : callable, optional
        ``progress(fraction, message)`` as bags finish.
    cancel : callable, optional
        ``cancel() -> bool``, polled every :data:`POLL_S` s; True cancels the tasks not yet started and
        raises :class:`~evpose.core.data.events.Cancelled` (an import already running completes its scene
        atomically, or leaves nothing).

    Returns
    -------
    BatchResult
        ``scenes``: scene name -> the import summary (``"skipped"`` says whether it was already there,
        ``"bag"`` the source, ``"match"`` how its name matched); ``failed``: scene name (or, for a bag
        that matches nothing, its path relative to ``raw_dir``) -> one line. In bag order.
    """
    from distributed import as_completed

    from evpose.core.data.events import Cancelled

    t0 = time.perf_counter()
    plans = plan_bags(raw_dir, assets)
    out = Path(out_dir).expanduser().absolute()
    if out.exists() and not out.is_dir():
        raise DatasetError(f"{out}: --out: exists and is not a folder")
    assets_abs = str(Path(assets).expanduser().absolute())
    result = BatchResult(out.name)
    result.failed.update({p.name: p.error for p in plans if p.error})
    run = {p.name: p for p in plans if not p.error}
    token = uuid.uuid4().hex[:12]
    futures = {client.submit(import_task, str(p.bag), str(out / p.name),
                             {"assets": assets_abs, "scene": p.scene, "sequence": p.sequence},
                             pure=False, key=f"import-{p.name}-{token}"): p.name for p in run.values()}
    n, k = len(plans), len(result.failed)
    try:
        if progress is not None:
            progress(k / n, f"{k}/{n} bags, {len(result.failed)} failed")
        ac = as_completed(list(futures))
        while not ac.is_empty():
            batch = ac.next_batch(block=False)
            for fut in batch:
                name = futures[fut]
                try:
                    result.scenes[name] = {**fut.result(), "bag": str(run[name].bag), "match": run[name].how}
                except Exception as exc:  # noqa: BLE001 - one bag's failure is reported, the others go on
                    result.failed[name] = failure_text(exc)
                k += 1
                if progress is not None:
                    progress(k / n, f"{k}/{n} bags, {len(result.failed)} failed")
            if cancel is not None and cancel():
                raise Cancelled(f"{Path(raw_dir)}: import cancelled after {k} of {n} bags")
            if not batch:
                time.sleep(POLL_S)
    finally:
        client.cancel([f for f in futures if not f.done()])
    result.runtime_s = time.perf_counter() - t0
    return result.ordered([p.name for p in plans])
