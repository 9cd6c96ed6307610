"""The space-time view floated out of the window and docked again (issue 25.5): it keeps drawing. Its vispy canvas is
a QOpenGLWidget, which gets a new GL context in another top-level window; the app shares GL resources between
contexts (``app/qt_compat.py::share_gl_contexts``), without which the floated view drew nothing but OpenGL errors."""
from __future__ import annotations

import numpy as np
import pytest
from PySide6 import QtCore

pytestmark = pytest.mark.gl


def _coloured_pixels(window) -> int:
    img = window.spacetime.render_image()[..., :3].astype(np.int16)
    return int(((img.max(axis=-1) - img.min(axis=-1)) > 60).sum())     # events and tubes are coloured, the rest grey


def test_the_space_time_view_draws_floated_and_docked_again(qtbot, window, scene_copy):
    assert QtCore.QCoreApplication.testAttribute(QtCore.Qt.AA_ShareOpenGLContexts)
    s = window.controller.open_scene(scene_copy)
    s.set_time(s.busiest_time())
    dock = window.feeds.spacetime_dock
    dock.show()
    dock.raise_()
    window.request_spacetime()
    qtbot.waitUntil(window.spacetime_drawn, timeout=60_000)
    qtbot.wait(200)
    docked = _coloured_pixels(window)
    assert docked > 200
    dock.setFloating(True)
    dock.resize(500, 450)
    qtbot.wait(300)
    s.step_windows(1)
    window.request_spacetime()
    qtbot.waitUntil(window.spacetime_drawn, timeout=60_000)
    qtbot.wait(300)
    assert _coloured_pixels(window) > 200, "the floated space-time view draws nothing"
    dock.setFloating(False)
    qtbot.wait(300)
    assert _coloured_pixels(window) > 200, "docked again, the space-time view draws nothing"
