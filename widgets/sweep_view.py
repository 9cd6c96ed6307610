"""The silhouette sweep's widget: the selected object seen from the top (x against t) and from the side (y against
t) over a span, its events as a grey image and the predicted silhouette's extent as two lines in its colour
(:mod:`evpose.core.views.sweep`). With the right pose the lines run along the edges of the event streaks; drawn too
big or too small (a depth error) both lines sit outside or inside them; shifted, both to one side; tilted, one side
more than the other, changing as the camera moves. The widget only shows what it is given (:meth:`SweepView.set_data`).
"""
from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6 import QtWidgets

from evpose.core.views.sweep import SweepData

__all__ = ["SweepView"]


def _grey(counts: np.ndarray) -> np.ndarray:
    """Counts as a white-to-black image (0: white; the 99th percentile of the non-zero counts: black)."""
    c = counts.astype(np.float32)
    nz = c[c > 0]
    top = float(np.percentile(nz, 99)) if len(nz) else 1.0
    return (255 - np.clip(c / max(top, 1.0), 0, 1) * 230).astype(np.uint8)


class SweepView(QtWidgets.QWidget):
    """Top (x-t) and side (y-t) plots of one object's sweep; time runs to the right (ms from the current time)."""

    def __init__(self, parent=None):
        super().__init__(parent)
        self.data: SweepData | None = None
        self.title = QtWidgets.QLabel("")
        self.title.setWordWrap(True)          # a long object name must not widen a narrow dock
        self.glw = pg.GraphicsLayoutWidget()
        self.glw.setBackground("w")
        self.glw.setMinimumHeight(120)
        self.plots, self.images, self.lines = [], [], []
        for row, label in enumerate(("x (px), top view", "y (px), side view")):
            p = self.glw.addPlot(row=0, col=row)      # side by side: a laptop's dock is wider than it is free
            p.setMenuEnabled(False)
            p.invertY(True)
            p.setLabel("left", label)
            p.setLabel("bottom", "t (ms from now)")
            img = pg.ImageItem(axisOrder="row-major")
            p.addItem(img)
            pair = [pg.PlotCurveItem(connect="finite") for _ in range(2)]
            for c in pair:
                p.addItem(c)
            self.plots.append(p)
            self.images.append(img)
            self.lines.append(pair)
        self.plots[1].setXLink(self.plots[0])
        lay = QtWidgets.QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.title)
        lay.addWidget(self.glw, 1)

    def set_data(self, data: SweepData | None, color=(220, 60, 60)) -> None:
        """Show ``data`` (None: nothing to sweep), the extent lines in ``color`` (r, g, b)."""
        self.data = data
        if data is None or data.reason:
            self.title.setText("sweep: " + ("no object shown" if data is None else data.reason))
            for img in self.images:
                img.clear()
            for pair in self.lines:
                for c in pair:
                    c.clear()
            return
        self.title.setText(f"<b>{data.name}</b> swept over {(data.t1_us - data.t0_us) / 1e3:.0f} ms: its events "
                           f"(grey) and its predicted silhouette's extent (lines)")
        span_ms = (data.t1_us - data.t0_us) * 1e-3
        t_lo = data.t_ms[0] - 0.5 * span_ms / len(data.t_ms)
        pen = pg.mkPen(color, width=2)
        for img, pair, counts, cols in zip(self.images, self.lines, (data.top, data.side), ((1, 2), (3, 4))):
            img.setImage(_grey(counts.T), levels=(0, 255))          # rows: pixels, columns: time
            img.setRect(pg.QtCore.QRectF(t_lo, -0.5, span_ms, counts.shape[1]))
            for c, j in zip(pair, cols):
                c.setData(data.extent[:, 0], data.extent[:, j], pen=pen)
        for p, (lo, hi), n in zip(self.plots, ((1, 2), (3, 4)), (data.top.shape[1], data.side.shape[1])):
            seen = np.isfinite(data.extent[:, lo])        # the object's extent and a margin: its edges at a glance
            a, b = (np.nanmin(data.extent[seen, lo]), np.nanmax(data.extent[seen, hi])) if seen.any() else (0, n)
            m = max(10.0, 0.3 * (b - a))
            p.setYRange(max(a - m, 0), min(b + m, n), padding=0.0)
            p.setXRange(t_lo, t_lo + span_ms, padding=0.0)
