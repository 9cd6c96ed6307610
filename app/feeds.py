"""The main window's view feeds: every view's request -> worker -> widget pipeline in one place (issue 25.1).

A frame request goes to two feeds: the event image (cheap, painted at once) and the overlays (rasterised labels, the
expensive part); the space-time view and the kymograph follow once scrubbing pauses (coalesced) and only while in
sight; the timeline's curves are recomputed on a worker when the clock, the hand-eye or a pose changes. All read event
windows through one byte-bounded cache of decoded event blocks, which the events worker fills ahead of the motion when
idle. Each feed is an :class:`~evpose.app.view_feed.ViewFeed`; the computations are ``core/views/``'s. The residual
view has its own feed object with its dock (:mod:`evpose.app.residual_feed`).
"""
from __future__ import annotations

import os
import time

from PySide6 import QtCore

from evpose.app.view_feed import ViewFeed, in_sight
from evpose.core.data.event_cache import EventChunkCache
from evpose.core.views.frame import EventFrame, FrameComputer, FrameData
from evpose.core.views.kymograph import KymographComputer, KymographData, KymographRequest
from evpose.core.views.spacetime import SpaceTimeComputer, SpaceTimeData
from evpose.core.views.timeline import timeline_data

__all__ = ["ViewFeeds", "SPACETIME_DEBOUNCE_MS"]

#: the space-time view and the kymograph follow once scrubbing pauses: they must not slow the frame
SPACETIME_DEBOUNCE_MS = 250
#: decoded event blocks kept by the idle release (the most recently used: the window on screen and its neighbours)
IDLE_EVENT_BYTES = 1 << 20


def _timeline(req):
    """The timeline's curves for ``req``'s scene and the clock key they were computed with (worker thread)."""
    t = time.perf_counter()
    data = timeline_data(req.scene)
    return data, req.clock_key, 1000.0 * (time.perf_counter() - t)


class _TimelineRequest:
    """A session snapshot and the clock key (offset, skew, hand-eye) the timeline's data will be computed with."""

    def __init__(self, req, clock_key):
        self.scene, self.serial, self.clock_key = req.scene, req.serial, clock_key


class ViewFeeds(QtCore.QObject):
    """The feeds of ``window`` (a :class:`~evpose.app.main_window.MainWindow`): its views are looked up on it when a
    result arrives (None while no session is open: the result is dropped)."""

    def __init__(self, window):
        super().__init__(window)
        self.window = window
        self.event_cache = EventChunkCache()
        failed = window._worker_failed
        events_fc = FrameComputer(self.event_cache)
        self.events = ViewFeed(self, "frame-events-worker", events_fc.events_stages, self._events_ready,
                               idle=events_fc.prefetch, on_failed=failed)
        # the overlays' rasteriser splits the meshes over two threads when there are two cores (the kernels
        # release the GIL): 2.5 -> 1.6 ms for 3 YCB meshes in bench_raster
        overlay_fc = FrameComputer(self.event_cache, raster_threads=min(2, os.cpu_count() or 1))
        self.frame = ViewFeed(self, "frame-worker", overlay_fc.overlay_stages, self._frame_ready,
                              idle=overlay_fc.prefetch_overlays, on_failed=failed)
        spacetime_fc = SpaceTimeComputer(self.event_cache)      # idle: the silhouette slices of the next steps
        self.spacetime = ViewFeed(self, "spacetime-worker", spacetime_fc.spacetime_stages, self._spacetime_ready,
                                  make_request=self._session_request, in_sight=self._spacetime_in_sight,
                                  idle=spacetime_fc.prefetch_spacetime, on_failed=failed,
                                  coalesce_ms=SPACETIME_DEBOUNCE_MS)
        kymograph_kc = KymographComputer(self.event_cache)    # the x-t slice; label maps cached by time and pose
        self.kymograph = ViewFeed(self, "kymograph-worker", kymograph_kc.stages, self._kymograph_ready,
                                  make_request=self._kymograph_request, in_sight=self._kymograph_in_sight,
                                  on_failed=failed, coalesce_ms=SPACETIME_DEBOUNCE_MS)
        self.timeline = ViewFeed(self, "timeline-worker", _timeline, self._timeline_ready,
                                 make_request=self._timeline_request, on_failed=failed)   # the widget debounces
        self.spacetime_dock = None
        #: the computers whose caches the idle release empties (:meth:`idle_release_tasks`), by feed
        self._computers = {"frame": overlay_fc, "spacetime": spacetime_fc, "kymograph": kymograph_kc}

    @property
    def all(self) -> tuple[ViewFeed, ...]:
        return self.events, self.frame, self.spacetime, self.kymograph, self.timeline

    # ------------------------------------------------------------------ memory
    def idle_release_tasks(self) -> list:
        """What the app's idle release (:class:`~evpose.app.memory.IdleReleaser`) empties, as ``(worker, fn)`` pairs
        (``fn`` runs on the worker's thread between requests; worker None: at once): the work done ahead of the user
        (the overlays of the next window; the decoded event blocks, all but the most recently used
        :data:`IDLE_EVENT_BYTES`), and the caches and annotators of the space-time view and the kymograph while they
        are out of sight (a closed dock, a tab behind another, a minimised window). All are made again on
        demand: the worker prefetches again after the next request, a view coming into sight computes what it needs."""
        c = self._computers
        tasks = [(None, lambda: self.event_cache.shrink(IDLE_EVENT_BYTES)),
                 (self.frame.worker, c["frame"].release_prefetched)]
        if not in_sight(self.spacetime_dock):
            tasks.append((self.spacetime.worker, c["spacetime"].release_caches))
        if not in_sight(self.window.kymograph):
            tasks.append((self.kymograph.worker, c["kymograph"].release_caches))
        return tasks

    # ------------------------------------------------------------------ requests
    def _session_request(self):
        s = self.window.session
        return s.request() if s is not None else None

    def request_frame(self) -> None:
        """One request, to the events feed and the overlays feed."""
        req = self._session_request()
        if req is not None:
            self.events.submit(req)
            self.frame.submit(req)

    def _spacetime_in_sight(self) -> bool:
        # a tab behind another still counts (the dock is not hidden): it is in front after one click
        return self.spacetime_dock is not None and not self.spacetime_dock.isHidden()

    def _kymograph_in_sight(self) -> bool:
        return in_sight(self.window.kymograph)

    def _kymograph_request(self):
        s, view = self.window.session, self.window.kymograph
        if s is None or view is None:
            return None
        return KymographRequest(s.request(), view.line, s.view.kymograph_span_us)

    def _timeline_request(self):
        s, tl = self.window.session, self.window.timeline
        if s is None or tl is None:
            return None
        return _TimelineRequest(s.request(), tl.clock_key())

    # ------------------------------------------------------------------ results
    def _events_ready(self, part: EventFrame | None, serial: int) -> None:
        """The event image of a request, painted before its overlays (None: the events on screen are its)."""
        w = self.window
        if w.frame_view is not None and part is not None:
            w.frame_view.set_events(part)

    def _frame_ready(self, data: FrameData, serial: int) -> None:
        """The overlays of a request: shown over the events (dimmed when those are of another window)."""
        w = self.window
        if w.frame_view is None:
            return
        w.memory.poke()
        w.frame = data
        w.frame_view.set_overlays(data)
        if w.objects is not None:
            w.objects.set_scores(data.scores)

    def _spacetime_ready(self, data: SpaceTimeData, serial: int) -> None:
        if self.window.spacetime is not None:
            self.window.memory.poke()
            self.window.spacetime.set_data(data)

    def _kymograph_ready(self, data: KymographData, serial: int) -> None:
        if self.window.kymograph is not None:
            self.window.kymograph.set_data(data)

    def _timeline_ready(self, result, serial: int) -> None:
        if self.window.timeline is not None:
            data, key, ms = result
            self.window.timeline.set_data(data, key, ms)

    # ------------------------------------------------------------------ life
    def up_to_date(self) -> bool:
        """True when the frame view shows the most recently requested state (events and overlays)."""
        return self.window.frame is not None and self.events_up_to_date() and self.frame.up_to_date()

    def events_up_to_date(self) -> bool:
        """True when the frame view shows the events of the most recent request (overlays may follow)."""
        fv = self.window.frame_view
        return fv is not None and fv.events is not None and self.events.shown >= self.events.submitted

    def spacetime_drawn(self) -> bool:
        """True once the space-time view shows data for the current view (or is hidden)."""
        dock = self.spacetime_dock
        return dock is None or dock.isHidden() or self.spacetime.up_to_date()

    def drop_pending(self) -> None:
        """Everything submitted so far belongs to the closing session: drop it when it arrives."""
        for f in self.all:
            f.drop_pending()
        self.spacetime_dock = None
        self.event_cache.clear()

    def stop(self) -> None:
        for f in self.all:
            f.stop()
