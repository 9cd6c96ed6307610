"""The scenes of a dataset as one sortable table: the triage columns and review progress.

One row per scene, keyed by the scene's name. The app fills a row with :meth:`DatasetTable.set_values`
(a dict of plain numbers, see :data:`COLUMNS`); a missing or ``None`` value shows empty and sorts last
whichever the direction. Numeric columns sort by their numbers, not by their text.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from PySide6 import QtCore, QtGui, QtWidgets

__all__ = ["COLUMNS", "Column", "DatasetTable", "DatasetTableModel", "SORT_ROLE"]

#: The role that holds a cell's raw value (a number, a string or None): the sort key.
SORT_ROLE = QtCore.Qt.UserRole + 1


def _int(v) -> str:
    return f"{int(v):,}".replace(",", "\u2009")          # thin-space thousands: 1 234 567


def _fixed(digits: int, scale: float = 1.0, sign: bool = False) -> Callable:
    return lambda v: f"{v * scale:{'+' if sign else ''}.{digits}f}"


def _estimate(v, values) -> str:
    std = values.get("estimate_std_ms")
    text = f"{v:+.1f}"
    if std is not None and math.isfinite(std):
        text += f" ± {std:.1f}"
    return text if values.get("estimate_reliable", True) else text + " (unreliable)"


@dataclass(frozen=True)
class Column:
    """One column: the value's key in a row's dict, the header, how to show the value, the header's tooltip."""

    key: str
    title: str
    fmt: Callable
    tip: str
    numeric: bool = True
    uses_row: bool = False          # fmt(value, row values) instead of fmt(value)
    derive: Callable | None = None  # the value computed from the row's values (instead of row[key])

    def value(self, row: dict):
        return self.derive(row) if self.derive is not None else row.get(self.key)


def _estimate_minus_clock(row: dict):
    est, clock = row.get("estimate_ms"), row.get("clock_ms")
    return None if est is None or clock is None else est - clock


COLUMNS = (
    Column("name", "scene", str, "the scene's folder name", numeric=False),
    Column("rank", "rank", _int, "the triage's rank of the scene (Triage all: worst first; empty: nothing flagged)"),
    Column("cause", "cause", str, "what to fix first (Triage all): failed, clock, pose, mounting, object scores, …; "
                                  "the reasons and the next command in the tooltip", numeric=False),
    Column("lowest_score", "object scores", lambda v, row: row.get("object_scores") or f"{v:.2f}",
           "each object's median window score (Triage all; 0 = no better than noise), not averaged away; sorts by "
           "the lowest", numeric=False, uses_row=True),
    Column("proposal", "proposed change", str, "what Refine (dry run) would store, each change with its sigma "
                                               "(Apply / Reject below); 'no change' when everything is within sigma",
           numeric=False),
    Column("n_events", "events", _int, "number of events"),
    Column("duration_s", "duration (s)", _fixed(2), "first to last event, seconds"),
    Column("n_objects", "objects", _int, "labelled objects"),
    Column("unlabeled_share", "unlabeled (%)", _fixed(1, 100.0),
           "share of the 10 ms windows whose label time has no pose (trajectory holes, outside the trajectory)"),
    Column("clock_ms", "clock (ms)", _fixed(1, sign=True),
           "clock offset in effect (prior + saved correction), milliseconds"),
    Column("prior_ms", "prior (ms)", _fixed(1, sign=True), "clock offset of scene.toml (the prior), milliseconds"),
    Column("verified_fraction", "verified (%)", _fixed(1, 100.0),
           "review progress: share of the 10 ms windows every object of which is verified (not stale)"),
    Column("mean_score", "mean score", _fixed(3),
           "alignment score averaged over the objects' mean window scores (Score all; 0 = no better than noise)"),
    Column("estimate_ms", "clock estimate (ms)", _estimate,
           "event-rate clock estimate ± its standard error (Sync all, never applied)", uses_row=True),
    Column("estimate_delta_ms", "estimate − clock (ms)", _fixed(1, sign=True),
           "clock estimate minus the clock in effect: how far the labels' clock is off, by the event rate",
           derive=_estimate_minus_clock),
    Column("status", "status", str, "loading, ok, or why the scene failed (in full in the detail pane)",
           numeric=False),
)
#: Causes drawn in red (a label is wrong) and orange (look first).
_CAUSE_RED = ("failed", "clock", "skew", "pose", "mounting")
_CAUSE_ORANGE = ("object", "clock_uncertain", "unlabeled")


class DatasetTableModel(QtCore.QAbstractTableModel):
    """Rows of scene values; ``DisplayRole`` is the formatted text, :data:`SORT_ROLE` the raw value."""

    def __init__(self, parent=None):
        super().__init__(parent)
        self._names: list[str] = []
        self._rows: dict[str, dict] = {}

    # --------------------------------------------------------------- contents
    def set_scenes(self, names: list[str]) -> None:
        self.beginResetModel()
        self._names = list(names)
        self._rows = {n: {"name": n, "status": ""} for n in names}
        self.endResetModel()

    def set_values(self, name: str, values: dict) -> None:
        """Update the row of ``name`` with ``values`` (keys of :data:`COLUMNS`; others are kept for tooltips)."""
        row = self._names.index(name)
        self._rows[name].update(values)
        self.dataChanged.emit(self.index(row, 0), self.index(row, len(COLUMNS) - 1))

    def values(self, name: str) -> dict:
        return dict(self._rows[name])

    def names(self) -> list[str]:
        return list(self._names)

    # --------------------------------------------------------------- Qt model
    def rowCount(self, parent=QtCore.QModelIndex()) -> int:
        return 0 if parent.isValid() else len(self._names)

    def columnCount(self, parent=QtCore.QModelIndex()) -> int:
        return 0 if parent.isValid() else len(COLUMNS)

    def headerData(self, section, orientation, role=QtCore.Qt.DisplayRole):
        if orientation != QtCore.Qt.Horizontal:
            return None
        if role == QtCore.Qt.DisplayRole:
            return COLUMNS[section].title
        if role == QtCore.Qt.ToolTipRole:
            return COLUMNS[section].tip
        return None

    def data(self, index, role=QtCore.Qt.DisplayRole):
        if not index.isValid():
            return None
        col = COLUMNS[index.column()]
        row = self._rows[self._names[index.row()]]
        value = col.value(row)
        if role == SORT_ROLE:
            return value
        if role == QtCore.Qt.DisplayRole:
            if value is None:
                return ""
            return col.fmt(value, row) if col.uses_row else col.fmt(value)
        if role == QtCore.Qt.TextAlignmentRole:
            return int((QtCore.Qt.AlignRight if col.numeric else QtCore.Qt.AlignLeft) | QtCore.Qt.AlignVCenter)
        if role == QtCore.Qt.ForegroundRole:
            return _foreground(col.key, row)
        if role == QtCore.Qt.ToolTipRole:
            return _tooltip(col.key, row)
        return None


def _foreground(key: str, row: dict):
    if key == "status" and row.get("failed"):
        return QtGui.QBrush(QtGui.QColor(190, 30, 30))
    if key == "verified_fraction" and row.get("verified_fraction") is not None and row["verified_fraction"] >= 1.0:
        return QtGui.QBrush(QtGui.QColor(20, 130, 50))
    if key in ("estimate_ms", "estimate_delta_ms") and row.get("estimate_reliable") is False:
        return QtGui.QBrush(QtGui.QColor(150, 150, 150))
    if key == "proposal" and row.get("proposal_state") == "proposed":
        return QtGui.QBrush(QtGui.QColor(20, 80, 190))
    if key in ("cause", "rank") and row.get("cause"):
        if row["cause"] in _CAUSE_RED:
            return QtGui.QBrush(QtGui.QColor(190, 30, 30))
        if row["cause"] in _CAUSE_ORANGE:
            return QtGui.QBrush(QtGui.QColor(190, 110, 0))
    return None


def _tooltip(key: str, row: dict):
    if key == "verified_fraction" and row.get("n_windows") is not None:
        marks = ", ".join(f"{k} {v}" for k, v in sorted((row.get("marks") or {}).items())) or "no marks"
        return (f"{row.get('verified_windows')} of {row['n_windows']} windows verified; "
                f"{row.get('touched_not_verified', 0)} marked otherwise; marks: {marks}")
    if key == "status":
        return row.get("status") or None
    if key in ("cause", "rank") and row.get("reasons"):
        return "\n".join(row["reasons"]) + (f"\nnext: {row['next']}" if row.get("next") else "")
    if key == "name":
        return row.get("path")
    return None


class _SortProxy(QtCore.QSortFilterProxyModel):
    """Sorts by the raw values: numbers as numbers, text case-insensitively, empty cells last."""

    def lessThan(self, left, right) -> bool:
        a, b = left.data(SORT_ROLE), right.data(SORT_ROLE)
        if a is None or b is None:
            # empty last in both directions: Qt reverses lessThan for a descending sort
            descending = self.sortOrder() == QtCore.Qt.DescendingOrder
            return (a is not None) != descending if (a is None) != (b is None) else False
        if isinstance(a, str) or isinstance(b, str):
            return str(a).casefold() < str(b).casefold()
        return float(a) < float(b)


class DatasetTable(QtWidgets.QTableView):
    """The dataset's scenes, sortable by any column. Double-clicking (or Enter on) a row emits
    ``sceneActivated(name)``; selecting one ``sceneSelected(name)``."""

    sceneActivated = QtCore.Signal(str)
    sceneSelected = QtCore.Signal(str)

    def __init__(self, parent=None):
        super().__init__(parent)
        self.table_model = DatasetTableModel(self)
        self.proxy = _SortProxy(self)
        self.proxy.setSourceModel(self.table_model)
        self.proxy.setSortRole(SORT_ROLE)
        self.proxy.setDynamicSortFilter(True)
        self.setModel(self.proxy)
        self.setSortingEnabled(True)
        self.sortByColumn(-1, QtCore.Qt.AscendingOrder)      # dataset order until a header is clicked
        self.setSelectionBehavior(QtWidgets.QAbstractItemView.SelectRows)
        self.setSelectionMode(QtWidgets.QAbstractItemView.SingleSelection)
        self.setEditTriggers(QtWidgets.QAbstractItemView.NoEditTriggers)
        self.setAlternatingRowColors(True)
        self.verticalHeader().setVisible(False)
        self.verticalHeader().setDefaultSectionSize(self.fontMetrics().height() + 8)
        header = self.horizontalHeader()
        header.setSectionResizeMode(QtWidgets.QHeaderView.ResizeToContents)
        header.setStretchLastSection(True)
        header.setDefaultAlignment(QtCore.Qt.AlignCenter)
        self.doubleClicked.connect(self._activated)
        self.selectionModel().currentRowChanged.connect(
            lambda cur, _prev: cur.isValid() and self.sceneSelected.emit(self.proxy.index(cur.row(), 0).data(SORT_ROLE)))

    def current_name(self) -> str | None:
        """The selected scene's name (None when no row is current)."""
        cur = self.currentIndex()
        return self.proxy.index(cur.row(), 0).data(SORT_ROLE) if cur.isValid() else None

    def select(self, name: str) -> None:
        """Make scene ``name``'s row the current one."""
        self.setCurrentIndex(self.proxy.index(self.row_of(name), 0))

    def set_scenes(self, names: list[str]) -> None:
        self.table_model.set_scenes(names)

    def set_values(self, name: str, values: dict) -> None:
        self.table_model.set_values(name, values)

    def values(self, name: str) -> dict:
        return self.table_model.values(name)

    def row_of(self, name: str) -> int:
        """The row (as shown, after sorting) of scene ``name``."""
        src = self.table_model.index(self.table_model.names().index(name), 0)
        return self.proxy.mapFromSource(src).row()

    def shown_names(self) -> list[str]:
        """Scene names in the order shown."""
        return [self.proxy.index(r, 0).data(SORT_ROLE) for r in range(self.proxy.rowCount())]

    def column_of(self, key: str) -> int:
        return [c.key for c in COLUMNS].index(key)

    def keyPressEvent(self, event: QtGui.QKeyEvent) -> None:
        if event.key() in (QtCore.Qt.Key_Return, QtCore.Qt.Key_Enter) and self.currentIndex().isValid():
            self._activated(self.currentIndex())
            return
        super().keyPressEvent(event)

    def _activated(self, index) -> None:
        if index.isValid():
            self.sceneActivated.emit(self.proxy.index(index.row(), 0).data(SORT_ROLE))
