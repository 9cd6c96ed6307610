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

    def before_close(w):                # pytest-qt closes and deletes it before fixtures' teardown code runs
        w.auto_answer["Unsaved corrections"] = 0x00800000  # Discard

    qtbot.addWidget(w, before_close_func=before_close)
    w.show()
    return w


@pytest.fixture(scope="session")
def demo_scene_dir(tmp_path_factory):
    """``evpose demo``'s scene (35 ms clock error, every pose 5 mm / 3 deg off), built once per test run (about
    1 min) and shared by the run's xdist workers (built under a lock in the run's folder: two test files use it,
    and the workers used to build it once each); never modify it (copy it)."""
    import fcntl

    from evpose.app.cli.synth import ensure_demo_scene

    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent                  # pytest-N/, the parent of every worker's popen-gwK/
    with open(shared / "demo_scene.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)        # the first worker builds it; the other waits, then finds it
        return ensure_demo_scene(shared / "demo_shared" / "demo_scene", quiet=True)


@pytest.fixture
def demo_copy(demo_scene_dir, tmp_path):
    import shutil

    dst = tmp_path / "demo"
    shutil.copytree(demo_scene_dir, dst)
    return dst
