"""The scene's objects: visibility, colour, class, correction state and alignment score."""
from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from evpose.core.session.model import Session
from evpose.core.signals import Change, DOCUMENT, OBJECTS
from evpose.widgets.binding import connect_view

COLUMNS = ("show", "", "object", "class", "corrected", "score")


class ObjectList(QtWidgets.QTableWidget):
    """One row per object. Checking "show" hides/shows its overlays; selecting a row selects the
    object for pose corrections. ``set_scores`` fills the score column with the current window's
    :mod:`core.score` alignment score (higher is better: 0 is no better than noise, 1 all events on
    the silhouette)."""

    def __init__(self, session: Session, parent=None):
        super().__init__(len(session.object_names), len(COLUMNS), parent)
        self.session = session
        self._updating = False
        self._scores: dict[str, float | None] = {}
        self.setHorizontalHeaderLabels(COLUMNS)
        self.verticalHeader().setVisible(False)
        self.setSelectionBehavior(QtWidgets.QAbstractItemView.SelectRows)
        self.setSelectionMode(QtWidgets.QAbstractItemView.SingleSelection)
        self.setEditTriggers(QtWidgets.QAbstractItemView.NoEditTriggers)
        self.horizontalHeader().setSectionResizeMode(2, QtWidgets.QHeaderView.Stretch)
        for c in (0, 1, 3, 4, 5):
            self.horizontalHeader().setSectionResizeMode(c, QtWidgets.QHeaderView.ResizeToContents)
        for r, name in enumerate(session.object_names):
            show = QtWidgets.QTableWidgetItem()
            show.setFlags(QtCore.Qt.ItemIsUserCheckable | QtCore.Qt.ItemIsEnabled | QtCore.Qt.ItemIsSelectable)
            show.setCheckState(QtCore.Qt.Checked)
            self.setItem(r, 0, show)
            swatch = QtWidgets.QTableWidgetItem()
            swatch.setBackground(QtGui.QColor(*session.color(name)))
            swatch.setFlags(QtCore.Qt.ItemIsEnabled)     # not selectable: the selected row keeps its colour
            self.setItem(r, 1, swatch)
            self.setItem(r, 2, QtWidgets.QTableWidgetItem(name))
            self.setItem(r, 3, QtWidgets.QTableWidgetItem(str(session.scene.manifest.objects[r].class_id)))
            self.setItem(r, 4, QtWidgets.QTableWidgetItem(""))
            self.setItem(r, 5, QtWidgets.QTableWidgetItem("–"))
        self.itemChanged.connect(self._item_changed)
        self.itemSelectionChanged.connect(self._selection_changed)
        connect_view(self, session.changed, self._on_session, {OBJECTS, DOCUMENT})
        self.refresh()

    def fit_rows(self, max_rows: int = 6) -> None:
        """Exactly as tall as its rows (up to ``max_rows``, then it scrolls): no empty space under them."""
        self.resizeRowsToContents()
        rows = sum(self.rowHeight(r) for r in range(min(self.rowCount(), max_rows)))
        h = self.horizontalHeader().sizeHint().height() + rows + 2 * self.frameWidth()
        if self.rowCount() > max_rows:
            h += self.horizontalScrollBar().sizeHint().height()
        self.setFixedHeight(max(h, 40))

    def _item_changed(self, item: QtWidgets.QTableWidgetItem) -> None:
        if self._updating or item.column() != 0:
            return
        name = self.session.object_names[item.row()]
        self.session.set_object_visible(name, item.checkState() == QtCore.Qt.Checked)

    def _selection_changed(self) -> None:
        if self._updating:
            return
        rows = {i.row() for i in self.selectedItems()}
        if rows:
            self.session.select(self.session.object_names[min(rows)])

    def _on_session(self, change: Change) -> None:
        if change.kind in ("objects", "document"):
            self.refresh()

    def set_scores(self, scores: dict[str, float | None]) -> None:
        """Current alignment score per object (None: undefined, e.g. out of view)."""
        self._scores = dict(scores)
        self.refresh()

    def refresh(self) -> None:
        self._updating = True
        try:
            view = self.session.view
            deltas = self.session.scene.corrections.object_deltas
            for r, name in enumerate(self.session.object_names):
                self.item(r, 0).setCheckState(QtCore.Qt.Unchecked if name in view.hidden else QtCore.Qt.Checked)
                self.item(r, 4).setText("yes" if name in deltas else "")
                s = self._scores.get(name)
                self.item(r, 5).setText("–" if s is None or not np.isfinite(s) else f"{s:+.2f}")
                if name == view.selected and not self.item(r, 2).isSelected():
                    self.selectRow(r)
        finally:
            self._updating = False
