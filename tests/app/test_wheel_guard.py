"""The wheel scrolls a panel over its value controls and changes a value only in the control that has the focus
(issue 25: scrolling the right dock changed the nudge step from 1 mm to 10 mm)."""
from __future__ import annotations

from PySide6 import QtCore, QtGui, QtWidgets

from evpose.app.wheel_guard import install_wheel_guard


def _wheel(widget, dy=-120):
    pos = QtCore.QPointF(widget.width() / 2, widget.height() / 2)
    ev = QtGui.QWheelEvent(pos, widget.mapToGlobal(pos), QtCore.QPoint(0, 0), QtCore.QPoint(0, dy),
                           QtCore.Qt.NoButton, QtCore.Qt.NoModifier, QtCore.Qt.NoScrollPhase, False)
    QtWidgets.QApplication.sendEvent(widget, ev)


def test_wheel_scrolls_the_panel_unless_the_control_has_focus(qtbot):
    install_wheel_guard(QtWidgets.QApplication.instance())
    panel = QtWidgets.QWidget()
    lay = QtWidgets.QVBoxLayout(panel)
    combo = QtWidgets.QComboBox()
    combo.addItems(["1 mm", "5 mm", "10 mm"])
    spin = QtWidgets.QDoubleSpinBox()
    slider = QtWidgets.QSlider(QtCore.Qt.Horizontal)
    slider.setRange(0, 100)
    slider.setValue(50)
    for w in (combo, spin, slider):
        lay.addWidget(w)
    lay.addSpacing(2000)                              # taller than the area: it scrolls
    area = QtWidgets.QScrollArea()
    area.setWidget(panel)
    area.resize(300, 200)
    qtbot.addWidget(area)
    area.show()
    qtbot.waitExposed(area)
    other = QtWidgets.QLineEdit(area)
    other.setFocus()
    for control in (combo, spin, spin.findChild(QtWidgets.QLineEdit), slider):
        assert control.focusPolicy() != QtCore.Qt.WheelFocus
        before = area.verticalScrollBar().value()
        _wheel(control)
        assert (combo.currentIndex(), spin.value(), slider.value()) == (0, 0.0, 50)
        assert area.verticalScrollBar().value() > before, "the panel did not scroll"
        assert not combo.hasFocus() and not spin.hasFocus()
    area.activateWindow()
    combo.setFocus()
    qtbot.waitUntil(combo.hasFocus, timeout=5000)
    _wheel(combo)
    assert combo.currentIndex() == 1                  # focused: the wheel is the control's
    spin.setFocus()
    qtbot.waitUntil(spin.hasFocus, timeout=5000)
    _wheel(spin, dy=120)                              # up: one step up
    assert spin.value() == 1.0
