import os

import pytest


@pytest.fixture
def window(qtbot, tmp_path, monkeypatch):
    """A main window with private settings and non-blocking dialogs."""
    from PySide6 import QtCore

    from evpose.app.main_window import MainWindow
    from evpose.app.settings import Settings

    if not os.environ.get("DISPLAY"):
        pytest.skip("the main window embeds an OpenGL view: needs an X display (Xvfb)")
    qs = QtCore.QSettings(str(tmp_path / "settings.ini"), QtCore.QSettings.IniFormat)
    w = MainWindow(Settings(qs))
    w.modal_dialogs = False
    qtbot.addWidget(w)
    w.show()
    yield w
    w.auto_answer["Unsaved corrections"] = 0x00800000  # Discard
    w.close()
