"""The kymograph's small frame view: the current window's events and the silhouettes' contours, where the user
click-drags the kymograph's line across an object edge (pyqtgraph).

Left-drag draws the line (it follows the mouse, and the view asks for a kymograph of it while dragging and
again on release); right-drag zooms and the wheel zooms, as in any pyqtgraph view.
"""
from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore

from evpose.widgets.plot_data import polylines_xy

#: The line's look in the frame preview.
LINE_PEN = {"color": (20, 150, 20), "width": 2}
#: Lines shorter than this (px) are ignored (a click, not a drag).
MIN_LINE_PX = 3.0


class LineDrawViewBox(pg.ViewBox):
    """A ViewBox whose left-drag draws a line: ``drawing(u0, v0, u1, v1)`` while the mouse moves, ``drawn(...)``
    on release (image pixel coordinates)."""

    def __init__(self, on_drawing, on_drawn, **kwargs):
        super().__init__(**kwargs)
        self._on_drawing, self._on_drawn = on_drawing, on_drawn

    def mouseDragEvent(self, ev, axis=None):  # noqa: N802 (Qt name)
        if ev.button() != QtCore.Qt.LeftButton:
            super().mouseDragEvent(ev, axis)
            return
        ev.accept()
        p0 = self.mapSceneToView(ev.buttonDownScenePos())
        p1 = self.mapSceneToView(ev.scenePos())
        line = (p0.x(), p0.y(), p1.x(), p1.y())
        if np.hypot(line[2] - line[0], line[3] - line[1]) < MIN_LINE_PX:
            return
        (self._on_drawn if ev.isFinish() else self._on_drawing)(line)


class FramePreview(pg.GraphicsLayoutWidget):
    """The event image (rows down, square pixels), the contours in their objects' colours and the line.

    ``on_line(line, final)`` is called with ``(u0, v0, u1, v1)`` while the user drags (``final`` False) and on
    release (True)."""

    def __init__(self, on_line, parent=None):
        super().__init__(parent)
        self._on_line = on_line
        self.vb = LineDrawViewBox(lambda ln: self._drag(ln, False), lambda ln: self._drag(ln, True),
                                  lockAspect=True, invertY=True, enableMenu=False)
        self.addItem(self.vb)
        self.image_item = pg.ImageItem(axisOrder="row-major")
        self.vb.addItem(self.image_item)
        self.contour_items: dict = {}
        self.line_item = pg.PlotCurveItem(pen=pg.mkPen(**LINE_PEN))
        self.line_item.setZValue(10)
        self.vb.addItem(self.line_item)
        self.ends_item = pg.ScatterPlotItem(size=7, pen=pg.mkPen(LINE_PEN["color"]), brush=pg.mkBrush("w"))
        self.ends_item.setZValue(11)
        self.vb.addItem(self.ends_item)
        self._shape = None
        self.setMinimumSize(120, 90)

    def set_image(self, rgb: np.ndarray | None) -> None:
        """Show ``rgb`` (H, W, 3) uint8; the view is fitted when the image size changes."""
        if rgb is None:
            return
        self.image_item.setImage(rgb, levels=(0, 255), autoLevels=False)
        if rgb.shape != self._shape:
            self._shape = rgb.shape
            self.vb.setRange(xRange=(-0.5, rgb.shape[1] - 0.5), yRange=(-0.5, rgb.shape[0] - 0.5), padding=0.02)

    def set_contours(self, contours) -> None:
        """``[(name, rgb, [polyline (M, 2)])]``: one curve per object, the others' curves cleared."""
        seen = set()
        for name, rgb, polys in contours:
            item = self.contour_items.get(name)
            if item is None:
                item = self.contour_items[name] = pg.PlotCurveItem(connect="finite")
                item.setZValue(5)
                self.vb.addItem(item)
            item.setPen(pg.mkPen(rgb, width=1.5))
            item.setData(*polylines_xy(polys))
            seen.add(name)
        for name, item in self.contour_items.items():
            if name not in seen:
                item.setData([], [])

    def set_line(self, line) -> None:
        """Draw ``(u0, v0, u1, v1)`` (None: no line)."""
        if line is None:
            self.line_item.setData([], [])
            self.ends_item.setData([], [])
            return
        u0, v0, u1, v1 = line
        self.line_item.setData([u0, u1], [v0, v1])
        self.ends_item.setData([u0], [v0])          # the start: position 0 of the kymograph

    def _drag(self, line, final: bool) -> None:
        self.set_line(line)
        self._on_line(line, final)
