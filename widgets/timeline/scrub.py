"""Scrubbing the timeline: a click, a drag or the cursor line moves the time. The cursors follow the mouse
at once; the session follows immediately (a click, a release) or throttled to one update per
:data:`SCRUB_INTERVAL_MS` while dragging (leading and trailing updates)."""
from __future__ import annotations

from PySide6 import QtCore

__all__ = ["Scrubber", "SCRUB_INTERVAL_MS"]

SCRUB_INTERVAL_MS = 33           # at most ~30 session.set_time calls per second while dragging


class Scrubber(QtCore.QObject):
    """Turns the user's scrubs into ``session.set_time`` calls.

    Parameters
    ----------
    timeline : Timeline
        Read: ``session``, ``x_of``, ``t_of``; called: ``show_readout(t_us)``, ``scrubbed.emit(t_us)``.

    Attributes
    ----------
    cursors : tuple of pg.InfiniteLine
        The cursor lines it moves (set once the plots exist).
    pending_t : int or None
        The time (µs) a throttled scrub has not handed to the session yet.
    """

    def __init__(self, timeline):
        super().__init__(timeline)
        self.timeline = timeline
        self.cursors: tuple = ()
        self.pending_t: int | None = None
        self._placing = False
        self._timer = QtCore.QTimer(self, singleShot=True, interval=SCRUB_INTERVAL_MS)
        self._timer.timeout.connect(self._timer_fired)

    def place_cursors(self, x_s: float) -> None:
        """Move the cursor lines to plot x ``x_s`` without taking it as a scrub."""
        self._placing = True
        try:
            for c in self.cursors:
                c.setPos(x_s)
        finally:
            self._placing = False

    def scrub_to(self, x_s: float, final: bool) -> None:
        """A click (``final``) or drag step on a plot at plot x ``x_s``."""
        self.request_time(self.timeline.t_of(x_s), final)

    def request_time(self, t_us: int, immediate: bool = True) -> None:
        """Move to ``t_us`` as a user scrub: the cursor moves at once; the session follows immediately
        (``immediate``) or throttled to one update per :data:`SCRUB_INTERVAL_MS` (leading and trailing)."""
        tl = self.timeline
        t0, t1 = tl.session.time_range
        t_us = int(min(max(int(t_us), t0), t1))
        self.pending_t = t_us
        self.place_cursors(tl.x_of(t_us))
        tl.show_readout(t_us)
        if immediate:
            self._timer.stop()
            self._flush()
        elif not self._timer.isActive():
            self._flush()
            self._timer.start()

    def cursor_dragged(self, line) -> None:
        if not self._placing:
            self.request_time(self.timeline.t_of(line.value()), immediate=False)

    def cursor_released(self, line) -> None:
        if not self._placing:
            self.request_time(self.timeline.t_of(line.value()), immediate=True)

    def stop(self) -> None:
        self._timer.stop()

    def _timer_fired(self) -> None:
        if self.pending_t is not None:   # trailing update; keep the next leading one an interval away
            self._flush()
            self._timer.start()

    def _flush(self) -> None:
        t = self.pending_t
        if t is None:
            return
        self.pending_t = None
        session = self.timeline.session
        session.set_time(t)
        self.timeline.scrubbed.emit(int(session.view.t_us))
