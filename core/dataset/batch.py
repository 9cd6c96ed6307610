"""One function over every scene of a dataset, as Dask tasks, and the document that collects the answers.

Every dataset command answers with one :class:`BatchResult`: ``scenes`` (name -> what the single-scene
command would print with ``--json``), ``failed`` (name -> the one-line error) and ``runtime_s``. A
scene that fails is reported and the others go on; a task whose worker died is rerun by Dask.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

from evpose.core.data.events import Cancelled

__all__ = ["BatchResult", "map_scenes", "failure_text"]


@dataclass
class BatchResult:
    """The answer of a dataset command (its ``--json`` document)."""

    dataset: str
    scenes: dict = field(default_factory=dict)       # name -> the single-scene document, in dataset order
    failed: dict = field(default_factory=dict)       # name -> one-line error
    runtime_s: float = 0.0
    #: workers lost and tasks rerun meanwhile (:meth:`ClusterEvents.summary
    #: <evpose.core.dataset.cluster_events.ClusterEvents.summary>`; None: not on a cluster)
    cluster: dict | None = None
    #: more of the command's document (e.g. ``campaign``: the campaign fit of ``dataset refine --shared``)
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        doc = {"dataset": self.dataset, "scenes": self.scenes, "failed": self.failed, "runtime_s": self.runtime_s}
        if self.cluster is not None:
            doc["cluster"] = self.cluster
        return {**doc, **self.extra}

    def ordered(self, names: list[str]) -> "BatchResult":
        """The same result with ``scenes`` and ``failed`` in dataset order."""
        return BatchResult(self.dataset, {n: self.scenes[n] for n in names if n in self.scenes},
                           {n: self.failed[n] for n in names if n in self.failed}, self.runtime_s, self.cluster,
                           self.extra)


def failure_text(exc: BaseException) -> str:
    """One line for a scene's failure: an input error's own message (it names the file and the field),
    otherwise the exception's type and message."""
    from evpose.core.errors import InputError

    text = str(exc).strip().splitlines()[-1] if str(exc).strip() else ""
    if isinstance(exc, (InputError, OSError)) and text:
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def map_scenes(client, dataset, fn: Callable, *args, label: str = "task",
               progress: Callable[[float, str], None] | None = None,
               cancel: Callable[[], bool] | None = None) -> BatchResult:
    """Run ``fn(scene_path, defaults, *args)`` for every scene of ``dataset`` on ``client``'s workers.

    ``fn`` must be importable by the workers (a module-level function of evpose) and return a JSON-able
    document. ``progress(fraction, message)`` follows the futures; ``cancel()`` True (or Ctrl-C) cancels
    the tasks not yet done and raises :class:`~evpose.core.data.events.Cancelled` / ``KeyboardInterrupt``.
    """
    from distributed import as_completed

    from evpose.core.dataset.cluster_events import ClusterEvents

    t0 = time.perf_counter()
    result = BatchResult(dataset.name)
    events = ClusterEvents(client)
    defaults = dataset.defaults or None
    futures = {client.submit(fn, str(ref.path), defaults, *args, pure=False, key=f"{label}-{ref.name}-{_token()}"):
               ref.name for ref in dataset.scenes}
    for fut, name in futures.items():
        events.track(fut.key, name)
    n = len(futures)
    try:
        if progress is not None:
            progress(0.0, f"0/{n} scenes")
        for k, fut in enumerate(as_completed(list(futures)), 1):
            name = futures[fut]
            try:
                result.scenes[name] = fut.result()
            except Exception as exc:        # one scene's failure is reported, the others go on
                result.failed[name] = failure_text(exc)
            if progress is not None:
                events.poll()
                lost = events.text()
                progress(k / n, f"{k}/{n} scenes, {len(result.failed)} failed" + (f", {lost}" if lost else ""))
            if cancel is not None and cancel():
                raise Cancelled(f"{dataset.root}: {label} cancelled after {k} of {n} scenes")
    finally:
        client.cancel([f for f in futures if not f.done()])
    result.runtime_s = time.perf_counter() - t0
    events.poll(force=True)
    result.cluster = events.summary()
    return result.ordered([ref.name for ref in dataset.scenes])


def _token() -> str:
    import uuid

    return uuid.uuid4().hex[:12]
