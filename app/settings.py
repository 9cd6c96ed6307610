"""Persistent user settings (QSettings): recent scenes, window geometry and dock state, the export options."""
from __future__ import annotations

import json
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

    def save_window(self, window, version: int = 0) -> None:
        """Save the window's geometry and dock layout (``version``: of the layout, see :meth:`restore_state`)."""
        self.qs.setValue("window/geometry", window.saveGeometry())
        self.qs.setValue("window/state", window.saveState(version))
        self.qs.setValue("window/state_size", [window.width(), window.height()])    # the size the layout is for

    def restore_geometry(self, window) -> bool:
        """Restore the saved window geometry (the caller clamps it to the screen); True if there was one."""
        geo = self.qs.value("window/geometry")
        return bool(geo is not None and window.restoreGeometry(geo))

    def restore_state(self, window, version: int = 0, fits=None) -> bool:
        """Restore the saved dock layout if it was saved with the same ``version`` and, given ``fits(width, height)``,
        at a window size it accepts (a layout made for another size can collapse a view); True if it was applied."""
        state = self.qs.value("window/state")
        if state is None:
            return False
        if fits is not None:
            try:
                w, h = (int(v) for v in self.qs.value("window/state_size"))
            except (TypeError, ValueError):
                return False                # saved before the size was: made for an unknown size
            if not fits(w, h):
                return False
        return bool(window.restoreState(state, version))

    def export_options(self) -> dict:
        """The export dialog's last format and options (empty: defaults)."""
        value = self.qs.value("export/options", "")
        try:
            out = json.loads(value) if isinstance(value, str) and value else {}
        except ValueError:
            return {}
        return out if isinstance(out, dict) else {}

    def set_export_options(self, options: dict) -> None:
        self.qs.setValue("export/options", json.dumps(options))
