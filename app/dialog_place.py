"""Dialogs beside the frame view, not over it.

Qt centres a dialog over its parent window, which is where the frame view is: a progress or result box then
hides the frame the user is checking. :class:`DialogPlacer` watches the main window for dialogs it parents
(progress, message, option and export boxes, from any module) and moves each, as it is shown, to the place
where it covers the least of the frame view: right of it (over the corrections), left of it, or below it (over
the timeline), inside the screen. Only the main window and its new dialogs are watched, never every event of
the application."""
from __future__ import annotations

from PySide6 import QtCore, QtWidgets

GAP = 8


def frame_rect(window) -> QtCore.QRect | None:
    """The frame view's rectangle in global coordinates (None when the window shows no scene)."""
    view = getattr(window, "frame_view", None)
    if view is None or not view.isVisible():
        return None
    return QtCore.QRect(view.mapToGlobal(QtCore.QPoint(0, 0)), view.size())


def best_position(size: QtCore.QSize, frame: QtCore.QRect, screen: QtCore.QRect) -> QtCore.QPoint:
    """Top-left corner for a dialog of ``size`` that covers the least of ``frame`` inside ``screen`` (right of
    the frame first, then left, then below, then above)."""
    w, h = size.width(), size.height()
    cy = frame.top() + GAP
    cx = frame.center().x() - w // 2
    candidates = [QtCore.QPoint(frame.right() + GAP, cy), QtCore.QPoint(frame.left() - w - GAP, cy),
                  QtCore.QPoint(cx, frame.bottom() + GAP), QtCore.QPoint(cx, frame.top() - h - GAP)]
    best, best_cover = None, None
    for p in candidates:
        x = min(max(p.x(), screen.left()), screen.right() + 1 - w)
        y = min(max(p.y(), screen.top()), screen.bottom() + 1 - h)
        r = QtCore.QRect(x, y, w, h).intersected(frame)
        cover = r.width() * r.height() if r.isValid() else 0
        if best_cover is None or cover < best_cover:
            best, best_cover = QtCore.QPoint(x, y), cover
    return best


def place_beside_frame(dialog: QtWidgets.QWidget, window) -> bool:
    """Move ``dialog`` off ``window``'s frame view (as far as the screen allows); False when there is no frame."""
    frame = frame_rect(window)
    if frame is None:
        return False
    screen = (window.screen() or QtWidgets.QApplication.primaryScreen()).availableGeometry()
    size = dialog.size().expandedTo(dialog.sizeHint()) if not dialog.isVisible() else dialog.frameGeometry().size()
    dialog.move(best_position(size, frame, screen))
    return True


class DialogPlacer(QtCore.QObject):
    """Places every dialog parented to ``window`` beside its frame view when the dialog is shown."""

    def __init__(self, window: QtWidgets.QWidget):
        super().__init__(window)
        self.window = window
        #: dialogs placed so far (tests read it)
        self.placed = 0
        window.installEventFilter(self)

    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt API)
        kind = event.type()
        if obj is self.window:
            # polished (fully built, about to be shown): a dialog's own Show event then comes through here
            if kind == QtCore.QEvent.ChildPolished and isinstance(event.child(), QtWidgets.QDialog):
                event.child().installEventFilter(self)
        elif kind == QtCore.QEvent.Show and isinstance(obj, QtWidgets.QDialog) and obj.isWindow() \
                and not isinstance(obj, QtWidgets.QFileDialog):
            if place_beside_frame(obj, self.window):
                self.placed += 1
                # a message box sizes itself in its own showEvent: place it again once it has its size
                QtCore.QTimer.singleShot(0, obj, lambda d=obj: d.isVisible() and place_beside_frame(d, self.window))
        return False
