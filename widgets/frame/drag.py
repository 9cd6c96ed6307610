"""Direct manipulation on the frame: click an object to select it, drag it to correct its pose.

A left drag that starts on an object moves it parallel to the image at its depth; with Shift it spins
about the camera's z axis through its centre; with Ctrl it tilts (trackball). The pose follows the cursor
from the start of the drag (:meth:`evpose.core.session.model.Session.drag_object`), and the whole drag is
one undo step. A drag that starts off the objects pans the view as before; the wheel zooms.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore

from evpose.core.session.model import Session

#: The drag mode for the modifiers held when the drag starts.
DRAG_MODIFIERS = (("spin", QtCore.Qt.ShiftModifier), ("tilt", QtCore.Qt.ControlModifier))

#: How to use it, for tooltips and the README.
DRAG_HELP = ("click an object: select it; drag it: move it parallel to the image; Shift+drag: spin it about "
             "the camera's z axis; Ctrl+drag: tilt it (one undo step per drag)")


def drag_mode(modifiers) -> str:
    for mode, mod in DRAG_MODIFIERS:
        if modifiers & mod:
            return mode
    return "move"


def pixel_of(x: float, y: float) -> tuple[int, int]:
    """The pixel (u, v) whose square holds view point (x, y) (pixel centres at integers)."""
    return int(np.floor(x + 0.5)), int(np.floor(y + 0.5))


class FrameViewBox(pg.ViewBox):
    """A pyqtgraph ViewBox whose left clicks and drags on an object select and move it.

    ``pick(u, v)`` names the object drawn at pixel (u, v), or None (then the ViewBox pans as usual).
    ``drag_refused(message)``: a drag started on an object that may not be moved now (a proposal is previewed)."""

    drag_refused = QtCore.Signal(str)

    def __init__(self, session: Session, pick: Callable[[int, int], str | None], **kwargs):
        super().__init__(**kwargs)
        self.session = session
        self.pick = pick
        self._drag: tuple[str, np.ndarray] | None = None    # (mode, start point in view coordinates)

    def _object_at(self, pos) -> str | None:
        p = self.mapToView(pos)
        return self.pick(*pixel_of(p.x(), p.y()))

    def mouseClickEvent(self, ev) -> None:  # noqa: N802 (pyqtgraph API)
        if ev.button() == QtCore.Qt.LeftButton:
            name = self._object_at(ev.pos())
            if name is not None:
                ev.accept()
                self.session.select(name)
                return
        super().mouseClickEvent(ev)

    def mouseDragEvent(self, ev, axis=None) -> None:  # noqa: N802 (pyqtgraph API)
        if ev.button() != QtCore.Qt.LeftButton:
            super().mouseDragEvent(ev, axis)
            return
        if ev.isStart():
            self._drag = None
            name = self._object_at(ev.buttonDownPos())
            if name is not None and self.session.preview is not None:
                self.drag_refused.emit("Accept or reject the proposal shown on the frame before moving objects")
            elif name is not None and self.session.begin_drag(name):
                p = self.mapToView(ev.buttonDownPos())
                self._drag = (drag_mode(ev.modifiers()), np.array([p.x(), p.y()]))
        if self._drag is None:
            super().mouseDragEvent(ev, axis)
            return
        ev.accept()
        mode, start = self._drag
        p = self.mapToView(ev.pos())
        self.session.drag_object(start, (p.x(), p.y()), mode)
        if ev.isFinish():
            self._drag = None
            self.session.end_drag()

    @property
    def dragging(self) -> bool:
        return self._drag is not None
