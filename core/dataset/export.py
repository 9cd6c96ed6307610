"""``dataset export``: every scene exported as the single-scene command does, on a Dask cluster.

Layout::

    OUT/<scene name>/     the scene's export, file for file what ``evpose export SCENE --out OUT/<scene name>``
                          writes (resumable and journaled as that command's folder)
    OUT/bop/              (``--format bop``) one BOP dataset: ``camera.json``, ``models/`` once (``obj_id`` from
                          the class ids), the scenes as ``SPLIT/000000``, ``SPLIT/000001``, ... in dataset order,
                          the test targets, and ``scene_names.json`` (scene id -> scene name); its files are hard
                          links to the scenes' own files (no second copy on disk); see
                          :mod:`evpose.core.dataset.bop_dataset`

Each scene is driven from a thread of this process (windows, poses, journal, aggregate files), and its
chunks of windows run as Dask tasks (:class:`~evpose.core.dataset.dask_windows.DaskWindows`), so one long
sequence spreads over all workers and several scenes keep them busy. A scene that fails is reported;
the others go on.

Before anything is written (:func:`check_dataset_export`), ``OUT`` is refused when it is inside (or equal to)
the dataset folder or a scene folder, when an ``OUT/<scene>`` or ``OUT/bop`` would hold one, or when it
exists and is not a folder (a device, a FIFO, a socket: never replaced); for BOP, scenes that give one
``obj_id`` to different models are refused (:func:`~evpose.core.dataset.bop_dataset.check_models`).
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from evpose.core.data.events import Cancelled
from evpose.core.data.owned_files import check_out_path, held_input
from evpose.core.dataset.batch import BatchResult, failure_text
from evpose.core.dataset.bop_dataset import BOP_DIR, assemble_bop, check_models
from evpose.core.dataset.cluster_events import ClusterEvents
from evpose.core.dataset.dask_windows import DaskWindows
from evpose.core.errors import NotOursError

__all__ = ["export_dataset", "check_dataset_export", "SCENE_DRIVERS"]

#: Scenes driven at once (each keeps the workers fed with its chunks; more only holds more files open).
SCENE_DRIVERS = 3


def export_dataset(client, dataset, fmt: str, out_dir, *, progress=None, cancel=None, **options) -> BatchResult:
    """Export every scene of ``dataset`` to ``out_dir/<scene name>`` through
    :func:`evpose.core.export.export_scene` (``options``: its keyword arguments), with the windows run on
    ``client``'s workers; for ``fmt == "bop"`` also assemble ``out_dir/bop``. Returns the
    :class:`~evpose.core.dataset.batch.BatchResult` whose ``scenes`` are the per-scene summaries."""
    from evpose.core.export import export_scene

    t0 = time.perf_counter()
    out_dir = check_dataset_export(dataset, out_dir, fmt, options.get("objects"))
    out_dir.mkdir(parents=True, exist_ok=True)
    result = BatchResult(dataset.name)
    stop = threading.Event()
    fractions = dict.fromkeys((ref.name for ref in dataset.scenes), 0.0)
    lock = threading.Lock()
    events = ClusterEvents(client)
    executor = DaskWindows(client, events=events)

    def report():
        if progress is not None:
            events.poll()
            with lock:
                done = sum(fractions.values()) / max(len(fractions), 1)
                text = f"{sum(1 for f in fractions.values() if f >= 1.0)}/{len(fractions)} scenes, {len(result.failed)} failed"
            lost = events.text()
            progress(done, text + (f", {lost}" if lost else ""))

    started: set = set()
    executor.more_scenes = lambda: len(started) < len(dataset.scenes)

    def one(ref):
        started.add(ref.name)
        if stop.is_set():
            return

        def scene_progress(fraction, _msg=""):
            fractions[ref.name] = fraction
            report()
        try:
            scene = dataset.open_scene(ref)
            try:
                s = export_scene(scene, fmt, out_dir / ref.name, progress=scene_progress, executor=executor,
                                 cancel=lambda: stop.is_set() or (cancel is not None and cancel()),
                                 **_scene_options(options, fmt, dataset.scenes.index(ref)))
            finally:
                scene.close()
            result.scenes[ref.name] = s.to_json(with_files=False)
        except Cancelled:
            stop.set()
        except Exception as exc:          # this scene is reported, the others go on
            result.failed[ref.name] = failure_text(exc)
        fractions[ref.name] = 1.0
        report()

    pool = ThreadPoolExecutor(max_workers=min(SCENE_DRIVERS, max(len(dataset.scenes), 1)),
                              thread_name_prefix="evpose-scene")
    try:
        futures = [pool.submit(one, ref) for ref in dataset.scenes]
        for f in futures:
            while not f.done():             # short waits keep Ctrl-C responsive in this thread
                _wait(f)
        if stop.is_set() or (cancel is not None and cancel()):
            raise Cancelled(f"{out_dir}: dataset export cancelled")
    except BaseException:
        stop.set()                          # drivers stop and leave resumable folders
        executor.cancel_all()               # (their chunks are cancelled: none waits for a dead worker)
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
    if client is not None:
        events.poll(force=True)
        result.cluster = events.summary()
        report()            # the last progress line says what the scheduler noticed after the last scene's report
    if fmt == "bop":
        names = [ref.name for ref in dataset.scenes]
        done = [n for n in names if n in result.scenes]
        try:
            assemble_bop(out_dir, names, done)
        except Exception as exc:
            result.failed["bop"] = failure_text(exc)
    result.runtime_s = time.perf_counter() - t0
    return result.ordered([ref.name for ref in dataset.scenes] + ["bop"])


def _scene_options(options: dict, fmt: str, k: int) -> dict:
    """Scene ``k``'s export options: BOP shards' image keys carry the scene's id in the dataset (``k``, as its
    folder ``OUT/bop/SPLIT/{k:06d}``), so the assembly links the shards as they are."""
    fo = options.get("format_options") or {}
    if fmt != "bop" or not fo.get("shard_windows"):
        return options
    return {**options, "format_options": {**fo, "key_scene_id": k}}


def check_dataset_export(dataset, out_dir, fmt: str, objects=None) -> Path:
    """``out_dir`` of a dataset export of ``objects`` (None: all), refused before anything is written (see
    the module docstring)."""
    inputs = dataset.input_folders(out_dir)
    out_dir = check_out_path(out_dir, "folder", inputs)
    targets = [out_dir / ref.name for ref in dataset.scenes] + ([out_dir / BOP_DIR] if fmt == "bop" else [])
    for target in targets:
        inp = held_input(target, [folder for folder, _ in inputs])
        if inp is not None:
            raise NotOursError(f"{out_dir}: --out: {target} would hold {inp}, an input of this export; evpose never "
                               "writes into its inputs: choose a folder outside the dataset")
    if fmt == "bop":
        check_models(dataset, objects)
    return out_dir


def _wait(future) -> None:
    import concurrent.futures

    try:
        future.result(timeout=0.2)
    except concurrent.futures.TimeoutError:
        pass
