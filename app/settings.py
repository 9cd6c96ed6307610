"""Persistent user settings (QSettings): recent scenes, window geometry and dock state."""
from __future__ import annotations

from pathlib import Path

from PySide6 import QtCore

MAX_RECENT = 10


class Settings:
    def __init__(self, settings: QtCore.QSettings | None = None):
        self.qs = settings or QtCore.QSettings("evpose", "evpose")

    def recent_scenes(self) -> list[str]:
        value = self.qs.value("recent_scenes", [])
        if isinstance(value, str):
            value = [value]
        return [v for v in (value or []) if v]

    def add_recent(self, path) -> list[str]:
        p = str(Path(path).resolve())
        items = [p] + [r for r in self.recent_scenes() if r != p]
        self.qs.setValue("recent_scenes", items[:MAX_RECENT])
        return items[:MAX_RECENT]

    def remove_recent(self, path) -> None:
        self.qs.setValue("recent_scenes", [r for r in self.recent_scenes() if r != str(path)])

    def save_window(self, window) -> None:
        self.qs.setValue("window/geometry", window.saveGeometry())
        self.qs.setValue("window/state", window.saveState())

    def restore_window(self, window) -> bool:
        """Restore geometry and dock layout; True if a saved dock layout was applied."""
        geo = self.qs.value("window/geometry")
        if geo is not None:
            window.restoreGeometry(geo)
        state = self.qs.value("window/state")
        return bool(state is not None and window.restoreState(state))

    def last_export_dir(self) -> str:
        return str(self.qs.value("export/last_dir", ""))

    def set_last_export_dir(self, path: str) -> None:
        self.qs.setValue("export/last_dir", path)
