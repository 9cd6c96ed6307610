"""The app icon (issue 12, point 6): ``resources/evpose.svg`` (drawn for evpose: event dots swept by an
edge, an object's box and pose axes) and its 256 px PNG rendering load, ``run_gui`` sets it as the
window icon, and both files are installed with the ``evpose.resources`` package."""
from __future__ import annotations

import sys
from importlib.resources import files

import numpy as np
from PySide6 import QtCore, QtGui, QtSvg

from evpose.app.main import ICON_FILES, app_icon

SIZE_PX = 256


def as_array(img: QtGui.QImage) -> np.ndarray:
    img = img.convertToFormat(QtGui.QImage.Format_RGBA8888)
    return np.frombuffer(img.constBits(), np.uint8).reshape(img.height(), img.width(), 4).copy()


def render_svg(path, size: int = SIZE_PX) -> QtGui.QImage:
    """How ``evpose.png`` is made from the drawing (rerun this and save to update it)."""
    renderer = QtSvg.QSvgRenderer(str(path))
    assert renderer.isValid(), f"{path}: not a valid SVG"
    img = QtGui.QImage(size, size, QtGui.QImage.Format_ARGB32_Premultiplied)
    img.fill(0)
    p = QtGui.QPainter(img)
    p.setRenderHint(QtGui.QPainter.Antialiasing)
    renderer.render(p)
    p.end()
    return img


def test_icon_files_are_package_resources():
    for name in ICON_FILES:
        assert (files("evpose.resources") / name).is_file(), name


def test_svg_draws_an_opaque_icon_with_event_colours(qapp):
    rgba = as_array(render_svg(files("evpose.resources") / "evpose.svg"))
    opaque = rgba[..., 3] == 255
    assert 0.8 < opaque.mean() < 0.95                    # a rounded square, transparent corners
    assert rgba[0, 0, 3] == 0 and rgba[SIZE_PX // 2, SIZE_PX // 2, 3] == 255
    r, g, b = (rgba[..., k].astype(int) for k in range(3))
    assert ((r > 180) & (g < 110) & (b < 110)).sum() > 200     # ON events / x axis: red
    assert ((b > 180) & (r < 110)).sum() > 200                 # OFF events / z axis: blue


def test_png_is_the_rendering_of_the_svg(qapp):
    png = QtGui.QImage(str(files("evpose.resources") / "evpose.png"))
    assert not png.isNull() and png.size() == QtCore.QSize(SIZE_PX, SIZE_PX)
    fresh = as_array(render_svg(files("evpose.resources") / "evpose.svg")).astype(int)
    diff = np.abs(as_array(png).astype(int) - fresh)
    assert diff.max() <= 8, "evpose.png is out of date: render evpose.svg with render_svg() and save it"


def test_app_icon_has_pixels(qapp):
    icon = app_icon()
    assert not icon.isNull()
    pm = icon.pixmap(32, 32)
    assert not pm.isNull() and as_array(pm.toImage())[..., 3].max() == 255


RUN_GUI_WITH_A_FAKE_WINDOW = r"""
import sys
import numpy as np
from PySide6 import QtGui, QtWidgets
import evpose.app.main_window
from evpose.app.main import app_icon, run_gui


class FakeWindow(QtWidgets.QMainWindow):
    # stands in for MainWindow in run_gui: no scene, no GL view, no settings written
    icon_at_creation = None

    def __init__(self):
        super().__init__()
        FakeWindow.icon_at_creation = QtWidgets.QApplication.windowIcon()
        self.modal_dialogs = True
        self.last_error = None
        self.session = None
        self.frame = None

    def spacetime_drawn(self):
        return True


def pixels(icon):
    img = icon.pixmap(48, 48).toImage().convertToFormat(QtGui.QImage.Format_RGBA8888)
    return np.frombuffer(img.constBits(), np.uint8).copy()


evpose.app.main_window.MainWindow = FakeWindow
assert run_gui(None, quit_after=0) == 0
icon = FakeWindow.icon_at_creation
assert icon is not None and not icon.isNull(), "no window icon when the main window was created"
assert np.array_equal(pixels(icon), pixels(app_icon())), "the window icon is not evpose's icon"
print("icon ok")
"""


def test_run_gui_sets_the_window_icon(tmp_path):
    """In a process of its own: ``run_gui`` runs and quits the application's event loop, after which
    Qt starts no further worker threads in that process (it would poison every later GUI test)."""
    import os
    import subprocess

    env = dict(os.environ, QT_QPA_PLATFORM="offscreen", XDG_CONFIG_HOME=str(tmp_path))
    proc = subprocess.run([sys.executable, "-c", RUN_GUI_WITH_A_FAKE_WINDOW], capture_output=True, text=True,
                          env=env, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0 and "icon ok" in proc.stdout, proc.stderr[-2000:]


def test_package_data_installs_the_icon():
    """pyproject's package-data for ``evpose.resources`` matches both icon files (a wheel built with
    ``pip wheel --no-deps .`` lists them under ``evpose/resources/``)."""
    import fnmatch
    from pathlib import Path

    try:
        import tomllib
    except ModuleNotFoundError:                      # Python 3.10
        import tomli as tomllib

    pyproject = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())
    patterns = pyproject["tool"]["setuptools"]["package-data"]["evpose.resources"]
    for name in ICON_FILES:
        assert any(fnmatch.fnmatch(name, p) for p in patterns), (name, patterns)
