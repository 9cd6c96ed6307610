"""The mouse wheel scrolls panels; it changes a value only in the control that has the keyboard focus.

Qt gives a spin box, a combo box or a slider the wheel whenever the pointer is over it: scrolling a dock past
the pose panel's step combo once changed the nudge step from 1 mm to 10 mm. :class:`WheelGuard`, installed on the
application, makes such controls take focus by click or Tab only (not by wheel) and passes the wheel of an
unfocused one to the scroll area around it (or drops it when there is none).
"""
from __future__ import annotations

from PySide6 import QtCore, QtWidgets

__all__ = ["WheelGuard", "install_wheel_guard"]

_VALUE_CONTROLS = (QtWidgets.QAbstractSpinBox, QtWidgets.QComboBox, QtWidgets.QAbstractSlider)


def _control(obj):
    """The value control ``obj`` is or belongs to (a spin box's line edit), else None."""
    for w in (obj, obj.parent() if isinstance(obj, QtWidgets.QWidget) else None):
        if isinstance(w, _VALUE_CONTROLS) and not isinstance(w, QtWidgets.QScrollBar):
            return w
    return None


class WheelGuard(QtCore.QObject):
    """Application event filter: see the module docstring."""

    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt API)
        kind = event.type()
        if kind == QtCore.QEvent.Polish:
            control = _control(obj)
            if control is obj and control.focusPolicy() == QtCore.Qt.WheelFocus:
                control.setFocusPolicy(QtCore.Qt.StrongFocus)
            return False
        if kind != QtCore.QEvent.Wheel:
            return False
        control = _control(obj)
        if control is None or control.hasFocus():
            return False
        area = control.parent()
        while area is not None and not isinstance(area, QtWidgets.QAbstractScrollArea):
            area = area.parent()
        if area is not None:
            bar = area.horizontalScrollBar() if event.angleDelta().x() and not event.angleDelta().y() \
                else area.verticalScrollBar()
            QtWidgets.QApplication.sendEvent(bar, event)
        return True


def install_wheel_guard(app: QtWidgets.QApplication) -> WheelGuard:
    """Install one :class:`WheelGuard` on ``app`` (again: the same one)."""
    guard = app.findChild(WheelGuard)
    if guard is None:
        guard = WheelGuard(app)
        app.installEventFilter(guard)
    return guard
