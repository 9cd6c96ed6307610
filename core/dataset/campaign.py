"""``evpose dataset refine --joint --shared hand-eye,placement``: the campaign fit of a dataset's groups on Dask.

The driver runs :func:`evpose.core.align.campaign_fit.fit_campaign`; each scene's terms are computed on a worker
(:class:`DaskEvaluator`), which opens the scene once and keeps its windows, edge setup and last association
between the driver's requests (a per-process cache, :data:`MAX_CACHED_SCENES` scenes, keyed by the run's token):
only states and normal equations of a few kB travel, never events. Every scene's requests go to the same worker
(``workers=``, other workers allowed); a worker that replaced a lost one opens the scene again and makes the
association of the state it is asked about (the answers are the same: the windows are chosen from the scene alone).

Then each scene's share of the result (its clock, its groups' hand-eye and placement as corrections) is planned and,
with ``--apply``, stored as one undo step in its ``corrections.json`` by the single-scene code
(:func:`evpose.core.align.refine_run.plan_and_store`), on the workers, and the group fit is recorded in
``campaign_fit.json`` beside ``dataset.toml`` (:func:`record_campaign`).
"""
from __future__ import annotations

import json
import threading
import time
from collections import OrderedDict
from pathlib import Path

from evpose.core.align.campaign_fit import CampaignScene, fit_campaign
from evpose.core.dataset.dataset import SHARED_KINDS, DatasetError

__all__ = ["CAMPAIGN_FILENAME", "CAMPAIGN_FORMAT", "CAMPAIGN_TEXT", "MAX_CACHED_SCENES", "DaskEvaluator",
           "campaign_scenes", "run_campaign", "check_record", "record_campaign", "campaign_info_task",
           "campaign_eval_task", "campaign_scene_task"]

CAMPAIGN_FILENAME = "campaign_fit.json"
CAMPAIGN_FORMAT = "evpose-campaign-fit/1"
#: The undo step's text of an applied campaign fit (the app's Undo names it).
CAMPAIGN_TEXT = "campaign fit (shared hand-eye / placement)"
#: Scenes a worker process keeps open for a campaign (the least recently asked is closed first).
MAX_CACHED_SCENES = 32

_CACHE: OrderedDict = OrderedDict()
_CACHE_LOCK = threading.Lock()


def campaign_scenes(dataset, shared: set) -> list:
    """Each scene of ``dataset`` with its units: its group's for each kind in ``shared`` (``"group:<name>"``),
    its own otherwise (``"scene:<name>"``)."""
    for kind in shared:
        if kind not in SHARED_KINDS:
            raise DatasetError(f"--shared: unknown kind {kind!r} (allowed: {', '.join(SHARED_KINDS)})")
    out = []
    for ref in dataset.scenes:
        units = {}
        for kind in SHARED_KINDS:
            g = dataset.group_of(ref.name, kind) if kind in shared else None
            units[kind] = f"group:{g.name}" if g is not None else f"scene:{ref.name}"
        out.append(CampaignScene(ref.name, units["hand-eye"], units["placement"]))
    return out


# ---------------------------------------------------------------------------------------- worker side
def _work(path: str, defaults, params, token: str):
    """The :class:`~evpose.core.align.campaign_terms.SceneWork` of ``path`` for run ``token`` in this process."""
    from evpose.core.align.campaign_terms import SceneWork
    from evpose.core.data.scene import Scene

    key = (token, path)
    with _CACHE_LOCK:
        if key in _CACHE:
            _CACHE.move_to_end(key)
            return _CACHE[key][1]
    scene = Scene.open(path, defaults=defaults)
    try:
        if not getattr(scene, "has_poses", True):
            scene.require_poses("campaign fit")
        work = SceneWork(scene, params)
    except BaseException:
        scene.close()
        raise
    with _CACHE_LOCK:
        _CACHE[key] = (scene, work)
        while len(_CACHE) > MAX_CACHED_SCENES:
            _, (old, _) = _CACHE.popitem(last=False)
            old.close()
    return work


def forget_campaign(token: str) -> int:
    """Close this process's scenes of run ``token``; returns how many."""
    with _CACHE_LOCK:
        keys = [k for k in _CACHE if k[0] == token]
        for k in keys:
            _CACHE.pop(k)[0].close()
    return len(keys)


def campaign_info_task(path: str, defaults, params, token: str):
    """A scene's :class:`~evpose.core.align.campaign_terms.SceneInfo` (the scene opened and kept for the run)."""
    return _work(path, defaults, params, token).info()


def campaign_eval_task(path: str, defaults, params, token: str, request):
    """A scene's :class:`~evpose.core.align.campaign_terms.SceneTerms` at ``request``."""
    return _work(path, defaults, params, token).evaluate(request)


def campaign_scene_task(path: str, defaults, result, apply: bool, planned_on: str | None = None) -> dict:
    """Scene ``path``'s share of the campaign (``result``: its :class:`~evpose.core.align.joint_result.JointResult`)
    planned and, with ``apply``, stored as one undo step and saved: the ``dataset refine`` document of the scene.
    Refused (:class:`~evpose.core.align.refine_run.ProposalError`, the scene's failure) when its corrections are not
    the ones the fit started from (``planned_on``: another program saved meanwhile), so no edit is overwritten."""
    from evpose.core.align.refine_run import ProposalError, plan_and_store
    from evpose.core.data.json_values import plain
    from evpose.core.data.scene import Scene

    with Scene.open(path, defaults=defaults) as scene:
        if planned_on is not None and scene.corrections.digest() != planned_on:
            raise ProposalError(f"{scene.corrections_path}: planned_on: the corrections changed while the campaign "
                                "was fitted; run it again")
        return plain(plan_and_store(scene, result, apply, CAMPAIGN_TEXT).data)


# ---------------------------------------------------------------------------------------- driver side
class DaskEvaluator:
    """:func:`~evpose.core.align.campaign_fit.fit_campaign`'s evaluator on a Dask client: each scene's requests go
    to one worker (round robin over the workers at the start), which keeps the scene open."""

    def __init__(self, client, dataset, params, token: str):
        self.client, self.params, self.token = client, params, token
        self.defaults = dataset.defaults or None
        self.paths = {ref.name: str(ref.path) for ref in dataset.scenes}
        workers = sorted(client.scheduler_info()["workers"])
        self.home = {name: [workers[k % len(workers)]] if workers else None for k, name in enumerate(self.paths)}
        self.requests = 0

    def _map(self, fn, per_scene: dict) -> dict:
        futures = {name: self.client.submit(fn, self.paths[name], self.defaults, self.params, self.token, *args,
                                            pure=False, workers=self.home[name], allow_other_workers=True)
                   for name, args in per_scene.items()}
        self.requests += len(futures)
        return {name: f.result() for name, f in futures.items()}

    def infos(self) -> dict:
        return self._map(campaign_info_task, {name: () for name in self.paths})

    def evaluate(self, requests: dict) -> dict:
        return self._map(campaign_eval_task, {name: (req,) for name, req in requests.items()})

    def close(self) -> None:
        try:
            self.client.run(forget_campaign, self.token)
        except Exception:  # a worker gone: its cache went with it
            pass


def run_campaign(client, dataset, shared: set, params, *, apply: bool = False, progress=None, cancel=None):
    """The campaign fit of ``dataset``'s scenes in its ``[[groups]]`` for the kinds in ``shared`` (the others are
    left out) on ``client``'s workers, then every scene's share planned and, with ``apply``, stored. Returns
    ``(CampaignResult, BatchResult)``: the fit and each scene's ``dataset refine`` document (failed scenes with
    their one-line error)."""
    import uuid

    from evpose.core.dataset.batch import BatchResult, failure_text

    grouped = [ref.name for ref in dataset.scenes if any(dataset.group_of(ref.name, k) for k in shared)]
    if not grouped:
        raise DatasetError(f"{dataset.root}: no scene is in a [[groups]] entry sharing {', '.join(sorted(shared))}")
    dataset = dataset.only(grouped)       # a scene in no group is refined on its own (dataset refine without --shared)
    bad = [ref for ref in dataset.scenes if ref.error is not None]
    if bad:
        raise DatasetError(f"{bad[0].path}: {bad[0].error} (a campaign fit needs every scene of its groups)")
    t0 = time.perf_counter()
    evaluator = DaskEvaluator(client, dataset, params, uuid.uuid4().hex[:12])
    try:
        result = fit_campaign(evaluator, campaign_scenes(dataset, shared), params, progress=progress, cancel=cancel)
    finally:
        evaluator.close()
    batch = BatchResult(dataset.name)
    defaults = dataset.defaults or None
    futures = {ref.name: client.submit(campaign_scene_task, str(ref.path), defaults, result.per_scene[ref.name],
                                       apply, result.planned_on.get(ref.name), pure=False) for ref in dataset.scenes}
    for name, fut in futures.items():
        try:
            batch.scenes[name] = fut.result()
        except Exception as exc:          # one scene's save refused (e.g. a conflict): the others are stored
            batch.failed[name] = failure_text(exc)
    batch.runtime_s = time.perf_counter() - t0
    return result, batch.ordered([ref.name for ref in dataset.scenes])


def check_record(dataset) -> Path:
    """The path of the dataset's ``campaign_fit.json``, refused (:class:`DatasetError`) when a file there is not one
    evpose recorded -- checked before a campaign is applied, so nothing is stored that could not be recorded."""
    from evpose.core.dataset.campaign_view import CampaignRecordError, read_record

    try:
        read_record(dataset.root)             # a FIFO, a huge file, another program's JSON: refused, never read whole
    except CampaignRecordError as exc:
        raise DatasetError(f"{exc}; it is not a campaign fit evpose recorded: move it away to record the fit") \
            from None
    return Path(dataset.root) / CAMPAIGN_FILENAME


def record_campaign(dataset, result, batch) -> Path:
    """Write the group fit to ``campaign_fit.json`` beside the dataset's ``dataset.toml`` (atomic; a file of that
    name that evpose did not write is refused, never replaced): the groups' shared terms with their standard
    errors, and which scenes stored them (revision of their corrections; ``values``: a value changed, not only the
    sigma of a value the fit confirmed)."""
    from evpose.core.data.atomic import write_atomic

    path = check_record(dataset)
    doc = {"format": CAMPAIGN_FORMAT, "dataset": dataset.name,
           "groups": [{"name": g.name, "shared": list(g.shared), "scenes": list(g.scenes)} for g in dataset.groups],
           "fit": result.to_json(),
           "stored": {name: {"applied": bool(d.get("applied")), "revision": d.get("revision"),
                             "values": bool(d.get("applied")) and any(c.get("part") != "sigma"
                                                                      for c in d.get("changes") or ())}
                      for name, d in batch.scenes.items()},
           "failed": dict(batch.failed)}
    write_atomic(path, (json.dumps(doc, indent=1, sort_keys=True, allow_nan=False) + "\n").encode())
    return path
