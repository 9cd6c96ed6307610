"""What the cluster did behind a dataset command's back: workers lost and the tasks Dask ran again because of it.

Dask reschedules the tasks of a worker that died (a kill, the OOM killer, a lost node) and the export's output is
the same, but a user should know it happened: a worker that keeps dying is a machine or memory problem to fix.
The scheduler logs every removed worker as an event of topic ``"all"`` (action ``"remove-worker"``, with the keys it
was processing and whether the removal was expected, e.g. a cluster closing or scaling down); :class:`ClusterEvents`
reads those since the command started and maps the keys back to scenes through the keys the command submitted.
Nothing runs on the scheduler (works with any ``dask scheduler``, no plugin to install).
"""
from __future__ import annotations

import threading
import time

__all__ = ["ClusterEvents"]

#: The progress line reads the scheduler's events at most this often (one round trip each), s.
POLL_EVERY_S = 2.0


class ClusterEvents:
    """Workers lost and tasks rerun since construction, for the keys registered with :meth:`track`."""

    def __init__(self, client):
        self.client = client
        self.t0 = time.time()
        self._lock = threading.Lock()
        self._scene_of: dict = {}          # task key -> scene name
        self._last_poll = 0.0
        self.lost_workers: list[str] = []
        self.rerun: dict[str, set] = {}    # scene -> keys that were running on a lost worker

    def track(self, key, scene: str) -> None:
        with self._lock:
            self._scene_of[key] = scene

    def poll(self, force: bool = False) -> None:
        """Read the scheduler's remove-worker events (at most every ``POLL_EVERY_S`` unless ``force``)."""
        now = time.monotonic()
        if self.client is None or (not force and now - self._last_poll < POLL_EVERY_S):
            return
        self._last_poll = now
        try:
            events = self.client.get_events("all")
        except Exception:        # a scheduler gone or too old: the export goes on without this report
            return
        lost, rerun = [], {}
        with self._lock:
            for ts, msg in events:
                if ts < self.t0 or not isinstance(msg, dict) or msg.get("action") != "remove-worker" \
                        or msg.get("expected"):
                    continue
                lost.append(str(msg.get("worker", "?")))
                for key in msg.get("processing-tasks", ()) or ():
                    scene = self._scene_of.get(key)
                    if scene is not None:
                        rerun.setdefault(scene, set()).add(key)
            self.lost_workers, self.rerun = lost, rerun

    def summary(self) -> dict:
        """``{"lost_workers": [addresses], "rerun_tasks": {scene: n}}`` (JSON-able)."""
        with self._lock:
            return {"lost_workers": list(self.lost_workers),
                    "rerun_tasks": {s: len(k) for s, k in sorted(self.rerun.items())}}

    def text(self) -> str:
        """For the progress line: "" when nothing happened."""
        with self._lock:
            if not self.lost_workers:
                return ""
            n = sum(len(k) for k in self.rerun.values())
            scenes = ", ".join(sorted(self.rerun))
            return (f"{len(self.lost_workers)} worker(s) lost, {n} task(s) rerun"
                    + (f" ({scenes})" if scenes else ""))
