"""What every view computes from: a :class:`FrameRequest` (a snapshot of the session), the staged-computation
protocol the app's workers run (:func:`run_stages`), and :class:`WindowReader`, the event reading that the
frame and space-time computers share (through the app's decoded-block cache, with the motion noted for
prefetching)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evpose.core.data.events import EventArray
from evpose.core.data.scene import Scene
from evpose.core.session.view_state import ViewState

__all__ = ["FrameRequest", "run_stages", "WindowReader"]


@dataclass(frozen=True)
class FrameRequest:
    """What to compute: a snapshot of the session (see :meth:`Session.request`); ``serial`` orders
    the requests so a late result of an older one is dropped."""

    scene: Scene       # a snapshot: shares data, owns a copy of the corrections
    view: ViewState
    serial: int = 0


def run_stages(gen):
    """Run a staged computation (a generator of checkpoints / partial results) to its end; its return value."""
    try:
        while True:
            next(gen)
    except StopIteration as stop:
        return stop.value


class WindowReader:
    """Reads event windows for a view's computer, through ``cache`` (an
    :class:`~evpose.core.data.event_cache.EventChunkCache` shared between computers, thread-safe) when given, and
    notes the motion of the requests (for :meth:`prefetch`)."""

    def __init__(self, cache=None):
        self.cache = cache
        self._motion = None        # (store, t_us, direction, window_us) of the last request, for prefetch

    def _window_events(self, scene: Scene, t0_us: int, t1_us: int) -> EventArray:
        if self.cache is not None:
            return self.cache.window(scene.events, t0_us, t1_us)
        return scene.events.window(t0_us, t1_us)

    def _note_motion(self, scene: Scene, t_us: int, window_us: int) -> None:
        prev = self._motion
        direction = 0
        if prev is not None and prev[0] is scene.events:
            direction = int(np.sign(t_us - prev[1])) or prev[2]
        self._motion = (scene.events, int(t_us), direction, int(window_us))

    def prefetch(self, should_stop=None) -> int:
        """Decode the event blocks ahead of the last request in its direction of motion (both ways before
        any motion) into the cache: four windows and a block. Returns the blocks read (0 without a
        cache). For a worker's idle time: ``should_stop()`` is checked between blocks."""
        if self.cache is None or self._motion is None:
            return 0
        store, t_us, direction, window_us = self._motion
        ahead_us = 4 * window_us + self.cache.block_us
        return self.cache.prefetch(store, t_us, direction, ahead_us, should_stop)
