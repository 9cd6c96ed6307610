"""Review marks: verified / rejected / flagged over the current window or a time range.

Marks cover grid windows (the current window is a cell of the export grid) and replace older marks of
their scope on the overlap (:mod:`evpose.core.document.review`). A mark made before a later change of the clock or of
its object's pose is *stale*: the list shows it greyed and italic with the reason ("verified at
offset X us (now Y us)"); ``--only-verified`` exports leave stale marks out by default."""
from __future__ import annotations

from PySide6 import QtCore, QtGui, QtWidgets

from evpose.core.document.corrections import REVIEW_STATUSES
from evpose.core.session.model import Session
from evpose.core.signals import Change, DOCUMENT
from evpose.widgets.binding import connect_view

STATUS_COLORS = {"verified": (40, 160, 60), "rejected": (200, 40, 40), "flagged": (230, 140, 0)}
STATUS_KEYS = {"verified": "V", "rejected": "R", "flagged": "F"}
STALE_COLOR = (130, 130, 130)


class ReviewPanel(QtWidgets.QWidget):
    """Mark the current window (or a range started with "Range start") and navigate marks."""

    def __init__(self, session: Session, parent=None):
        super().__init__(parent)
        self.session = session
        self._range_start: int | None = None
        lay = QtWidgets.QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        row = QtWidgets.QHBoxLayout()
        self.buttons = {}
        for status in REVIEW_STATUSES:
            b = QtWidgets.QPushButton(f"{status.capitalize()} ({STATUS_KEYS[status]})")
            b.setStyleSheet(f"color: rgb{STATUS_COLORS[status]}; font-weight: bold")
            b.clicked.connect(lambda _=False, s=status: self.mark(s))
            self.buttons[status] = b
            row.addWidget(b)
        lay.addLayout(row)
        row = QtWidgets.QHBoxLayout()
        self.note = QtWidgets.QLineEdit(placeholderText="note (optional)")
        self.scope = QtWidgets.QComboBox()
        self.scope.addItem("all objects", None)
        for n in session.object_names:
            self.scope.addItem(n, n)
        row.addWidget(self.note, 2)
        row.addWidget(self.scope, 1)
        lay.addLayout(row)
        row = QtWidgets.QHBoxLayout()
        self.range_button = QtWidgets.QPushButton("Range start")
        self.range_button.setCheckable(True)
        self.range_button.setToolTip("Start a range at the current window; the next mark covers everything up to "
                                     "the current window")
        self.range_button.toggled.connect(self._range_toggled)
        self.next_unreviewed = QtWidgets.QPushButton("Next unreviewed (N)")
        self.next_flagged = QtWidgets.QPushButton("Next flagged (Shift+N)")
        self.next_unreviewed.clicked.connect(lambda: self.goto_next(lambda s: s is None))
        self.next_flagged.clicked.connect(lambda: self.goto_next(lambda s: s == "flagged"))
        remove = QtWidgets.QPushButton("Remove mark")
        remove.setToolTip("remove the mark selected in the list")
        remove.clicked.connect(self.remove_selected)
        row.addWidget(self.range_button)        # two buttons a row: the panel fits a narrow column
        row.addWidget(remove)
        lay.addLayout(row)
        row = QtWidgets.QHBoxLayout()
        row.addWidget(self.next_unreviewed)
        row.addWidget(self.next_flagged)
        lay.addLayout(row)
        self.list = QtWidgets.QListWidget()
        self.list.setWordWrap(True)                     # a stale mark's reason wraps instead of being cut
        self.list.setHorizontalScrollBarPolicy(QtCore.Qt.ScrollBarAlwaysOff)
        self.list.setResizeMode(QtWidgets.QListView.Adjust)
        self.list.itemDoubleClicked.connect(self._jump)
        lay.addWidget(self.list, 1)
        self.status = QtWidgets.QLabel()
        self.status.setSizePolicy(QtWidgets.QSizePolicy.Ignored, QtWidgets.QSizePolicy.Preferred)  # text-proof
        lay.addWidget(self.status)
        connect_view(self, session.changed, self._on_session, {DOCUMENT})
        self.refresh()

    def _range_toggled(self, on: bool) -> None:
        self._range_start = self.session.view.window().t0_us if on else None

    def mark(self, status: str) -> None:
        """Mark the current window, or the range from "Range start" to the current window. Not while a proposal is
        previewed on the frame (the mark would record the document, not what is on screen): the panel says so."""
        if self.session.preview is not None:
            self.status.setText("Accept or reject the proposal shown on the frame first")
            return
        w = self.session.view.window()
        t0, t1 = w.t0_us, w.t1_us
        if self._range_start is not None:
            t0, t1 = min(self._range_start, t0), max(self._range_start, w.t0_us) + (w.t1_us - w.t0_us)
            self.range_button.setChecked(False)
        self.session.add_review(status, t0, t1, self.note.text().strip(), self.scope.currentData())
        self.note.clear()

    def goto_next(self, predicate) -> bool:
        """Go to the next window whose review status satisfies ``predicate``; after the last one, wrap around to
        the first from the start of the recording (N / Shift+N cycle through all of them)."""
        t = self.session.next_window_where(predicate)
        wrapped = t is None
        if wrapped:
            t = self.first_window_where(predicate)
        if t is None:
            self.status.setText("none found")
            return False
        self.session.set_time(t)
        self.status.setText(self.summary + ("  (wrapped around to the start)" if wrapped else ""))
        return True

    def first_window_where(self, predicate) -> int | None:
        """Centre time of the first window, from the start of the recording up to the current one (on the current
        window's grid), whose review status satisfies ``predicate``; None if there is none."""
        t0 = self.session.time_range[0]
        w = max(int(self.session.view.window_us), 1)
        now = int(self.session.view.t_us)
        status = self.session.scene.corrections.review_status
        for t in range(t0 + (now - t0) % w, now + 1, w):
            if predicate(status(t)):
                return t
        return None

    def _jump(self, item: QtWidgets.QListWidgetItem) -> None:
        mark = item.data(QtCore.Qt.UserRole)
        self.session.set_time((mark.t0_us + mark.t1_us) // 2)

    def remove_selected(self) -> None:
        """Remove the mark selected in the list (nothing when none is)."""
        item = self.list.currentItem()
        if item is not None:
            self.session.remove_review(item.data(QtCore.Qt.UserRole))

    def _on_session(self, change: Change) -> None:
        if change.kind == "document":           # marks, or the clock / poses that make them stale
            self.refresh()

    def refresh(self) -> None:
        self.list.clear()
        t_ref = self.session.time_range[0]
        now = self.session.mark_state()
        self.stale = {}
        for m in sorted(self.session.scene.corrections.reviews, key=lambda m: m.t0_us):
            text = f"{m.status:9s} {(m.t0_us - t_ref) / 1e6:8.3f}–{(m.t1_us - t_ref) / 1e6:.3f} s"
            if m.object:
                text += f"  [{m.object}]"
            if m.note:
                text += f"  {m.note}"
            reasons = self.session.stale_reasons(m, now=now)
            item = QtWidgets.QListWidgetItem()
            if reasons:
                self.stale[m] = reasons
                text += "  STALE: " + "; ".join(reasons)
                item.setForeground(QtGui.QColor(*STALE_COLOR))
                font = item.font()
                font.setItalic(True)
                item.setFont(font)
                item.setToolTip("This mark was made on other labels: " + "; ".join(reasons)
                                + ".\nMark the window again to verify the current labels.")
            else:
                item.setForeground(QtGui.QColor(*STATUS_COLORS[m.status]))
            item.setText(text)
            item.setData(QtCore.Qt.UserRole, m)
            self.list.addItem(item)
        n = self.list.count()
        self.summary = f"{n} mark{'s' * (n != 1)}" + (f", {len(self.stale)} stale" if self.stale else "")
        self.status.setText(self.summary)
