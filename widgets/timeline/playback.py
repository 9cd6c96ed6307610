"""Playback of the timeline: advance the session's time by the elapsed wall time × speed, stop at the
end of the recording. A time set elsewhere while playing (a scrub, a key) is continued from."""
from __future__ import annotations

import time

from PySide6 import QtCore

__all__ = ["Playback", "PLAY_INTERVAL_MS"]

PLAY_INTERVAL_MS = 30            # playback tick


class Playback(QtCore.QObject):
    """Plays a :class:`~evpose.core.session.model.Session` in (a fraction of) real time.

    Parameters
    ----------
    parent : QObject
        Owner of the timer.
    session : Session
        Read: ``time_range``, ``view.t_us``; written: ``set_time``.
    speed : callable() -> float
        Current speed, a fraction of real time.

    Signals
    -------
    changed(bool)
        Playback started (True) / stopped (False).
    """

    changed = QtCore.Signal(bool)

    def __init__(self, parent, session, speed):
        super().__init__(parent)
        self.session = session
        self.speed = speed
        self.clock = time.monotonic          # wall clock (s); replaceable in tests
        self._pos = 0.0                      # fractional event time (µs) reached
        self._last = 0.0                     # wall clock of the last tick
        self._set: int | None = None         # the time the last tick set
        self._timer = QtCore.QTimer(self, interval=PLAY_INTERVAL_MS)
        self._timer.setTimerType(QtCore.Qt.PreciseTimer)
        self._timer.timeout.connect(self.tick)

    @property
    def is_playing(self) -> bool:
        return self._timer.isActive()

    def play(self) -> None:
        """Start from the current time (from the start when at the end)."""
        if self.is_playing:
            return
        t0, t1 = self.session.time_range
        if self.session.view.t_us >= t1:
            self.session.set_time(t0)
        self._pos = float(self.session.view.t_us)
        self._set = int(self.session.view.t_us)
        self._last = self.clock()
        self._timer.start()
        self.changed.emit(True)

    def pause(self) -> None:
        if not self.is_playing:
            return
        self._timer.stop()
        self.changed.emit(False)

    def tick(self) -> None:
        """Advance by the elapsed wall time × speed; stop at the end of the recording."""
        now = self.clock()
        dt, self._last = max(now - self._last, 0.0), now
        cur = int(self.session.view.t_us)
        if cur != self._set:      # the user moved the time meanwhile: continue from there
            self._pos = float(cur)
        self._pos += dt * 1e6 * self.speed()
        t1 = self.session.time_range[1]
        if self._pos >= t1:
            self.session.set_time(t1)
            self.pause()
        else:
            self.session.set_time(int(self._pos))
        self._set = int(self.session.view.t_us)
