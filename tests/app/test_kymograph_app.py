"""The kymograph in the main window (issue 16, point 1): closed at first (the layout stays as it was), opened by the
space-time view's "Kymograph…" button, computed off the GUI thread for the default line and for a drawn one."""
from PySide6 import QtWidgets


def test_the_kymograph_opens_from_the_space_time_view_and_follows_its_line(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    s.set_time(s.time_range[0] + 300_000)
    dock = window.findChild(QtWidgets.QDockWidget, "dock_kymograph")
    assert dock is not None and dock.isHidden()
    assert dock.toggleViewAction() in window.docks_menu.actions()
    window.spacetime.controls.kymograph_button.click()
    qtbot.waitUntil(lambda: window.kymograph.data is not None, timeout=20_000)
    assert not dock.isHidden() and window.kymograph.data.frame_rgb is not None
    first = window.kymograph.data
    line = (20.0, 40.0, 120.0, 40.0)
    window.kymograph.set_line(line)
    qtbot.waitUntil(lambda: window.kymograph.data is not first and not window.kymograph.data.auto_line,
                    timeout=20_000)
    assert window.kymograph.data.line.as_tuple() == line
    s.set_offset_correction_us(5_000)                 # a clock change recomputes it (debounced)
    shown = window.kymograph.data
    qtbot.waitUntil(lambda: window.kymograph.data is not shown, timeout=20_000)
    assert window.last_error is None
