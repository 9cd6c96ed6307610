"""Typed keys go where the user types, not to the single-key shortcuts.

The window's shortcuts include single printable keys (``R`` rejects the window, ``D`` moves the object,
``Space`` plays). Qt lets a text field keep such keys (it accepts their ``ShortcutOverride``), but not a
button, a drop-down box or a slider: after a click on "Refine", typing "blurred edges" made two rejected
marks, a 9.8 mm nudge and started playback (issue 16). While one of those has the keyboard focus in the main
window, :class:`ShortcutGuard` keeps the single-key shortcuts from firing (``Ctrl+…``, ``F…`` and the arrows
still work), swallows ``Space`` on a button or box that got the focus from a mouse click (it would click it
again or open the box), swallows typed keys on a drop-down box (its keyboard search would change its value:
"5" made the nudge step 5 mm), says in the status bar how to get the shortcuts back, and gives the focus back to
the frame on ``Esc``.

The filter sits on the focused widget only (moved along by ``QApplication.focusChanged``), not on the whole
application: it sees a handful of events, not every paint and mouse move.
"""
from __future__ import annotations

from typing import Callable

from PySide6 import QtCore, QtWidgets

#: Widgets that do not take typed text, so Qt would hand typed keys to the shortcuts.
GUARDED = (QtWidgets.QAbstractButton, QtWidgets.QComboBox, QtWidgets.QAbstractSlider)

_COMMAND_MODIFIERS = QtCore.Qt.ControlModifier | QtCore.Qt.AltModifier | QtCore.Qt.MetaModifier


def is_typed_key(event) -> bool:
    """A key that types a character (or Space), without Ctrl, Alt or Meta."""
    if event.modifiers() & _COMMAND_MODIFIERS:
        return False
    text = event.text()
    return event.key() == QtCore.Qt.Key_Space or (len(text) == 1 and text.isprintable())


def guarded(widget) -> bool:
    """Would a typed key reach the shortcuts while ``widget`` has the focus (a button, box or slider)?"""
    if isinstance(widget, QtWidgets.QComboBox) and widget.isEditable():
        return False
    return isinstance(widget, GUARDED)


def _describe(widget) -> str:
    text = widget.text() if isinstance(widget, QtWidgets.QAbstractButton) else ""
    if not text and isinstance(widget, QtWidgets.QComboBox):
        text = widget.currentText()
    return f"“{text.replace('&', '')}”" if text else "a control"


class ShortcutGuard(QtCore.QObject):
    """Guards the single-key shortcuts of ``window`` (see the module docstring).

    Parameters
    ----------
    window : QMainWindow
    home : callable
        Gives the keyboard focus back to the main view (on ``Esc``).
    notify : callable(str)
        Shows a hint (the status bar) when a typed key was kept from a shortcut.
    """

    def __init__(self, window: QtWidgets.QWidget, home: Callable[[], None], notify: Callable[[str], None]):
        super().__init__(window)
        self.window = window
        self.home = home
        self.notify = notify
        self.watched: QtWidgets.QWidget | None = None
        self.focus_by_mouse = False
        #: Typed keys kept from the shortcuts so far (for tests and the status bar).
        self.blocked: list[str] = []
        QtWidgets.QApplication.instance().focusChanged.connect(self._focus_changed)

    def _focus_changed(self, old, new) -> None:
        if self.watched is not None:
            try:
                self.watched.removeEventFilter(self)
            except RuntimeError:          # deleted meanwhile
                pass
            self.watched = None
        if new is not None and guarded(new) and new.window() is self.window:
            self.watched = new
            self.focus_by_mouse = QtWidgets.QApplication.mouseButtons() != QtCore.Qt.NoButton
            new.installEventFilter(self)

    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt API)
        if obj is not self.watched:
            return False
        t = event.type()
        if t == QtCore.QEvent.ShortcutOverride and is_typed_key(event):
            event.accept()                # not a shortcut: the key goes to the widget (a box's is dropped below)
            key = "Space" if event.key() == QtCore.Qt.Key_Space else event.text()
            self.blocked.append(key)
            self.notify(f"“{key}” typed while {_describe(obj)} has the keyboard focus: not used as a shortcut "
                        "(Esc or a click on the frame gives the shortcuts back)")
            return True
        if t in (QtCore.QEvent.KeyPress, QtCore.QEvent.KeyRelease):
            if event.key() == QtCore.Qt.Key_Escape and event.modifiers() == QtCore.Qt.NoModifier:
                if t == QtCore.QEvent.KeyPress:
                    self.home()
                return True
            if event.key() == QtCore.Qt.Key_Space and self.focus_by_mouse and \
                    isinstance(obj, (QtWidgets.QAbstractButton, QtWidgets.QComboBox)):
                return True                # no second click of the button just clicked, no popup of the box
            if isinstance(obj, QtWidgets.QComboBox) and is_typed_key(event) and event.key() != QtCore.Qt.Key_Space:
                return True                # a drop-down's keyboard search would pick the item the key starts
        return False
