"""The frame view's wiring in the main window: its shortcuts (window length, selected object only, outlines
only), their checked state, the key hints in its toolbar, its hover text in the status bar and the keyboard
focus given back to it (:class:`~evpose.app.shortcut_guard.ShortcutGuard` on Esc)."""
from __future__ import annotations

from PySide6 import QtCore

from evpose.app import actions as A

#: Checkable actions that set a boolean display option of the view state (action name = ViewState field).
DISPLAY_TOGGLES = ("selected_only", "outline_only")
#: Actions that scale the window length (its unit kept).
WINDOW_STEPS = (("window_shorter", 0.5), ("window_longer", 2.0))
#: The View menu's entries for them.
MENU = (*DISPLAY_TOGGLES, *(name for name, _ in WINDOW_STEPS))


def connect(window) -> None:
    """Connect the frame actions of ``window`` (a MainWindow with ``actions_by_name``) to its session and view."""
    a = window.actions_by_name
    for name, factor in WINDOW_STEPS:
        a[name].triggered.connect(lambda _=False, f=factor: window.frame_view and window.frame_view.toolbar.scale_window(f))
    for name in DISPLAY_TOGGLES:
        a[name].setCheckable(True)
        a[name].toggled.connect(lambda on, n=name: window.session and window.session.set_view_option(**{n: on}))


def sync(window, view) -> None:
    """Check the display toggles as the view state ``view`` has them (no signal back)."""
    for name in DISPLAY_TOGGLES:
        act = window.actions_by_name[name]
        act.blockSignals(True)
        act.setChecked(getattr(view, name))
        act.blockSignals(False)


def attach(window, frame_view) -> None:
    """A new frame view: its toolbar names the keys, its hover text goes to the status bar."""
    a = window.actions_by_name
    keys = {n: a[k].shortcut().toString() for n, k in A.REPRESENTATION_SHORTCUTS.items()}
    keys.update({n: a[n].shortcut().toString() for n in DISPLAY_TOGGLES})
    frame_view.toolbar.set_key_hints(keys)
    hover = HoverStatus(window.statusBar(), frame_view)
    frame_view.hoverText.connect(hover.show)


class HoverStatus(QtCore.QObject):
    """The frame's hover readout in the status bar for 2 s, cleared at once when the mouse leaves the frame
    (an empty text), unless another message replaced it meanwhile."""

    def __init__(self, bar, parent):
        super().__init__(parent)
        self.bar = bar
        self.shown: str | None = None

    def show(self, text: str) -> None:
        if text:
            self.bar.showMessage(text, 2000)
        elif self.shown is not None and self.bar.currentMessage() == self.shown:
            self.bar.clearMessage()
        self.shown = text or None


def focus_frame(window) -> None:
    """The keyboard focus to the frame view, where the single-key shortcuts work (Esc on a focused button)."""
    target = window.frame_view.glw if window.frame_view is not None else window
    target.setFocus(QtCore.Qt.OtherFocusReason)
