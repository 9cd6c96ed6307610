"""The kymograph in the main window (issue 16, point 1): closed at first (the layout stays as it was), opened by the
space-time view's "Kymograph…" button, computed off the GUI thread for the default line and for a drawn one; its
readout (a reading ± σ, or "too weak to read" and why; issue 23, part 8) is never cut off on a laptop screen."""
from PySide6 import QtWidgets

from evpose.core.views.kymograph_confidence import REASONS
from evpose.core.views.kymograph_lag import MAX_LAG_MS, LagEstimate
from evpose.widgets.kymograph.view import lag_text

#: Room a desktop takes from a 1366x768 screen (a panel and the title bar), as in test_layout.py.
LAPTOP = (1366, 768 - 70)


def readout_lines_that_do_not_fit(readout) -> list[str]:
    """Of every text the readout can show (the widest reading, each reason it is too weak), the lines wider
    than it draws them (it elides those)."""
    texts = [lag_text(LagEstimate(-(MAX_LAG_MS - 0.1), 4.9))] + [lag_text(LagEstimate(None, weak=r)) for r in REASONS]
    room = readout.contentsRect().width() - 6
    fm = readout.fontMetrics()
    return [line for t in texts for line in t.split("\n") if fm.horizontalAdvance(line) > room]


def test_the_kymograph_opens_from_the_space_time_view_and_follows_its_line(qtbot, window, scene_copy):
    window.resize(*LAPTOP)
    s = window.controller.open_scene(scene_copy)
    s.set_time(s.time_range[0] + 300_000)
    dock = window.findChild(QtWidgets.QDockWidget, "dock_kymograph")
    assert dock is not None and dock.isHidden()
    assert dock.toggleViewAction() in window.docks_menu.actions()
    window.spacetime.controls.kymograph_button.click()
    qtbot.waitUntil(lambda: window.kymograph.data is not None, timeout=20_000)
    assert not dock.isHidden() and window.kymograph.data.frame_rgb is not None
    qtbot.wait(100)
    readout = window.kymograph.readout
    assert readout.isVisible() and readout_lines_that_do_not_fit(readout) == [], readout.width()
    assert readout.text() == lag_text(window.kymograph.data.lag)
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
