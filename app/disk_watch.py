"""Notice when another program saves ``corrections.json`` while the app has the scene open.

A ``QFileSystemWatcher`` watches the file and its folder. Saves replace the file by an atomic
rename, which drops the watch on the old inode, so the watch is re-armed after every notification
(the folder watch sees the rename and a file that appears later). A cheap poll (one ``stat`` every
:data:`POLL_MS`) backs it up where inotify is unavailable (network file systems). Notifications are
debounced into one :attr:`CorrectionsWatcher.changed` signal; the receiver decides whether the
content really changed (:meth:`evpose.core.session.model.Session.check_disk` compares with what the app last
loaded or saved, so the app's own saves are ignored).
"""
from __future__ import annotations

from pathlib import Path

from PySide6 import QtCore

from evpose.core.document.corrections_file import signature, target_of

DEBOUNCE_MS = 150
POLL_MS = 2000


class CorrectionsWatcher(QtCore.QObject):
    """Emits :attr:`changed` (debounced) when ``path`` (or its symlink target) may have changed."""

    changed = QtCore.Signal()

    def __init__(self, path, parent=None):
        super().__init__(parent)
        self.path = Path(path)
        self._watcher = QtCore.QFileSystemWatcher(self)
        self._watcher.fileChanged.connect(self._poke)
        self._watcher.directoryChanged.connect(self._poke)
        self._debounce = QtCore.QTimer(self, singleShot=True, interval=DEBOUNCE_MS)
        self._debounce.timeout.connect(self._fire)
        self._poll = QtCore.QTimer(self, interval=POLL_MS)
        self._poll.timeout.connect(self._poll_tick)
        self._last_sig = signature(target_of(self.path))
        self._arm()
        self._poll.start()

    def _arm(self) -> None:
        """(Re-)watch the file and the folders of the path and of its target."""
        target = target_of(self.path)
        wanted = {str(p) for p in (self.path.parent, target.parent) if p.is_dir()}
        wanted |= {str(p) for p in (self.path, target) if p.exists()}
        have = set(self._watcher.files()) | set(self._watcher.directories())
        missing = sorted(wanted - have)
        if missing:
            self._watcher.addPaths(missing)

    def _poke(self, *_):
        self._arm()
        self._debounce.start()

    def _poll_tick(self) -> None:
        sig = signature(target_of(self.path))
        if sig != self._last_sig:
            self._poke()

    def _fire(self) -> None:
        self._last_sig = signature(target_of(self.path))
        self.changed.emit()

    def stop(self) -> None:
        self._poll.stop()
        self._debounce.stop()
        paths = self._watcher.files() + self._watcher.directories()
        if paths:
            self._watcher.removePaths(paths)
