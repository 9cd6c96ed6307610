"""The residual view's widget: the window's events coloured by their signed distance to the edges the labels predict,
and per object the numbers (:mod:`evpose.core.views.residuals`).

Red events lie outside the drawn outline, blue ones inside (full colour from 1.5 px off, grey on the edge);
green ones are near an inner edge (a fold or a depth step of the object), grey ones near no edge. A right label
shows thin, pale, balanced colour along every edge; a shifted one red on one side and blue on the other; a depth
error one colour all around; a tilt red on the near side and blue on the far one, or the reverse. The table gives
each object's events near its edges, the mean signed distance on its silhouette and the outline's shift that fits
them (px, ± its standard error). The widget only shows what it is given (:meth:`ResidualView.set_data`).
"""
from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

from evpose.core.views.residuals import ResidualData, residual_rgb
from evpose.widgets.sweep_view import SweepView

__all__ = ["ResidualView", "LEGEND"]

LEGEND = ("<span style='color:#dc1e1e'>■</span> outside the drawn outline &nbsp; "
          "<span style='color:#1e46dc'>■</span> inside &nbsp; <span style='color:#28a03c'>■</span> inner edge &nbsp; "
          "<span style='color:#999'>■</span> no edge within {band:g} px")
COLUMNS = ("object", "events", "mean px", "shift x px", "shift y px")


def _pm(v: float, sd: float) -> str:
    return f"{v:+.2f}" + (f"±{sd:.2f}" if math.isfinite(sd) else " (not pinned)")


class ResidualView(QtWidgets.QWidget):
    """Residual image, legend, per-object table and a status line."""

    def __init__(self, parent=None):
        super().__init__(parent)
        self.data: ResidualData | None = None
        self.plot = pg.GraphicsLayoutWidget()
        self.plot.setBackground("w")
        self.plot.setMinimumHeight(110)
        self.viewbox = self.plot.addViewBox(lockAspect=True, invertY=True, enableMenu=False)
        self.image = pg.ImageItem(axisOrder="row-major")
        self.viewbox.addItem(self.image)
        self.legend = QtWidgets.QLabel(LEGEND.format(band=4))
        self.legend.setTextFormat(QtCore.Qt.RichText)
        self.legend.setWordWrap(True)
        self.table = QtWidgets.QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QtWidgets.QAbstractItemView.NoEditTriggers)
        self.table.horizontalHeader().setSectionResizeMode(QtWidgets.QHeaderView.ResizeToContents)
        self.table.horizontalHeader().setStretchLastSection(True)
        self.table.verticalHeader().setDefaultSectionSize(self.table.fontMetrics().height() + 6)
        self.table.setToolTip("mean: signed distance of the silhouette's events (+: outside the drawn outline); "
                              "shift: the outline's image shift that fits them (x right, y down), ± its standard "
                              "error (a jackknife over 8 stretches of the outline)")
        self.status = QtWidgets.QLabel("")
        self.status.setWordWrap(True)
        #: the selected object swept over a span, from the top and the side (widgets/sweep_view.py)
        self.sweep = SweepView()
        # the image and the sweep share what the table leaves, in a splitter (a laptop's dock is ~470 px tall)
        self.splitter = QtWidgets.QSplitter(QtCore.Qt.Vertical)
        self.splitter.setChildrenCollapsible(False)
        self.splitter.addWidget(self.plot)
        self.splitter.addWidget(self.sweep)
        self.splitter.setStretchFactor(0, 1)
        self.splitter.setStretchFactor(1, 1)
        lay = QtWidgets.QVBoxLayout(self)
        lay.setContentsMargins(2, 2, 2, 2)
        lay.addWidget(self.legend)
        lay.addWidget(self.table)
        lay.addWidget(self.status)
        lay.addWidget(self.splitter, 1)

    def set_data(self, data: ResidualData, compute_ms: float | None = None) -> None:
        """Show ``data`` (a :class:`~evpose.core.views.residuals.ResidualData`)."""
        self.data = data
        rgb = residual_rgb(data)
        self.image.setImage(rgb, levels=(0, 255))
        self.viewbox.setRange(xRange=(0, data.size[0]), yRange=(0, data.size[1]), padding=0.01)
        self.legend.setText(LEGEND.format(band=data.band_px))
        rows = list(data.objects.values())
        self.table.setRowCount(len(rows))
        for r, o in enumerate(rows):
            cells = (o.name, str(o.n_events), "–" if o.mean_px is None else f"{o.mean_px:+.2f}",
                     _pm(o.shift_px[0], o.shift_std_px[0]), _pm(o.shift_px[1], o.shift_std_px[1]))
            for c, text in enumerate(cells):
                item = QtWidgets.QTableWidgetItem(text)
                if c:
                    item.setTextAlignment(QtCore.Qt.AlignRight | QtCore.Qt.AlignVCenter)
                self.table.setItem(r, c, item)
        h = self.table.horizontalHeader().sizeHint().height() + sum(self.table.rowHeight(r) for r in range(len(rows)))
        self.table.setFixedHeight(h + 2 * self.table.frameWidth() + 2)
        ms = "" if compute_ms is None else f" ({compute_ms:.0f} ms)"
        self.status.setText(data.reason or f"window {data.t0_us} – {data.t1_us} µs: {len(data.signed_px)} events "
                                           f"near the edges of {len(rows)} object(s){ms}")

    def row_texts(self) -> list[list[str]]:
        """The table's cells (for tests and screenshots)."""
        return [[self.table.item(r, c).text() for c in range(self.table.columnCount())]
                for r in range(self.table.rowCount())]

    def image_array(self) -> np.ndarray | None:
        return None if self.image.image is None else np.asarray(self.image.image)
