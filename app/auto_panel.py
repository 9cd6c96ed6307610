"""The side panel of an automatic estimate: progress with Cancel while it runs, then the proposal (clock with its
standard error, each object's change, the objects held and why) with a before / after preview and Accept / Reject.

It is a view of a :class:`~evpose.app.auto_sync.Proposal` living in a dock beside the frame view (never over it:
the preview is looked at there); :class:`~evpose.app.auto_controller.ProposalController` runs the job and acts on
the signals.
"""
from __future__ import annotations

from html import escape

import numpy as np
from PySide6 import QtCore, QtWidgets

from evpose.core.align.sync_result import SLOW_STD_NOTE_US

__all__ = ["ProposalDock", "ProposalPanel", "fmt_ms", "fmt_std"]

STATUS_STYLE = {"ok": "", "warn": "color:#a60", "bad": "color:#b00"}


def fmt_ms(us) -> str:
    """A clock offset in ms with sign ('–' for None)."""
    return "–" if us is None else f"{us / 1000.0:+.3f} ms"


def fmt_std(std_us) -> str:
    """`` ± x ms (1σ)`` for a standard error ('' when none was computed)."""
    if std_us is None:
        return ""
    if not np.isfinite(std_us):
        return "  (not pinned)"
    return f"  ± {std_us / 1000.0:.3f} ms (1σ)"


def _num(x, fmt: str) -> str:
    return "–" if x is None or not np.isfinite(x) else format(x, fmt)


def _skew_text(p) -> str:
    before = f"{p.clock_before[1]:+.1f} ppm"
    j = p.joint
    if p.offset_us is None:
        return f"{before} kept"
    if p.skew_ppm is None:
        pinned = "" if j is None or j.skew_std_ppm is None else \
            f" (the windows pin it only to ± {_num(j.skew_std_ppm, '.1f')} ppm)"
        return f"{before} kept{pinned}"
    std = "" if p.skew_std_ppm is None else f" ± {_num(p.skew_std_ppm, '.1f')} ppm (1σ)"
    return f"{before} → {p.skew_ppm:+.1f} ppm{std}"


def _source_text(p) -> str:
    r = p.rate
    parts = []
    if r is not None:
        parts.append(f"event rate: {fmt_ms(r.offset_us)}{fmt_std(r.offset_std_us)}, confidence {r.confidence:.2f}"
                     + ("" if r.reliable else " (not reliable)"))
    if p.joint is not None:
        j = p.joint
        parts.append(f"edges: objective {_num(j.objective_before, '.4f')} → {_num(j.objective_after, '.4f')} "
                     f"(higher is better), {j.n_windows} windows")
    parts.append(f"run time {p.runtime_s:.1f} s")
    return "<br>".join(parts)


def _verdict(p) -> tuple[str, str]:
    """(status, html) of the proposal's verdict."""
    if not p.usable:
        return "bad", f"<b>Nothing to apply:</b> {p.reason or 'no estimate'}."
    if p.kind == "auto" and p.method == "rate":
        loose = p.offset_std_us is None or not p.offset_std_us <= SLOW_STD_NOTE_US
        note = " The event rate pins it only loosely: check it on the frame." if loose else ""
        return "warn", f"<b>Event-rate clock only:</b> {p.reason}.{note} Accept applies it as one undo step."
    if p.kind == "auto" and p.hand_eye_fitted:
        return "warn", ("<b>The camera mounting looks off:</b> clock, hand-eye and poses fitted together from the "
                        "event edges (see the note). Flip the preview between before and after on the frame; "
                        "Accept applies everything, the hand-eye included, as one undo step.")
    what = {"auto": "Clock and poses fitted together from the event edges, started at the event-rate clock.",
            "edges": "Clock and poses fitted together from the event edges, started at the clock in effect.",
            "refine": "Pose fitted to the event edges (clock kept)."}[p.kind]
    return "ok", (f"<b>{what}</b> Flip the preview between before and after on the frame; Accept applies "
                  "everything as one undo step.")


class ProposalPanel(QtWidgets.QWidget):
    """Progress (with Cancel) while a job runs; then the proposal, the preview toggle and Accept / Reject.

    Signals
    -------
    cancelRequested(), acceptRequested(), rejectRequested()
        The Cancel, Accept and Reject buttons.
    previewChanged(bool)
        True: show the proposal on the frame ("after"), False: the document ("before").
    """

    cancelRequested = QtCore.Signal()
    acceptRequested = QtCore.Signal()
    rejectRequested = QtCore.Signal()
    previewChanged = QtCore.Signal(bool)

    def __init__(self, parent=None):
        super().__init__(parent)
        self.proposal = None
        lay = QtWidgets.QVBoxLayout(self)
        lay.setContentsMargins(6, 6, 6, 6)
        self.title = QtWidgets.QLabel()
        lay.addWidget(self.title)
        lay.addWidget(self._progress_box())
        lay.addWidget(self._result_box())
        lay.addStretch(1)
        self.show_running("Automatic estimate")

    # ------------------------------------------------------------------ construction
    def _progress_box(self) -> QtWidgets.QWidget:
        self.progress_box = QtWidgets.QWidget()
        g = QtWidgets.QGridLayout(self.progress_box)
        g.setContentsMargins(0, 0, 0, 0)
        self.bar = QtWidgets.QProgressBar()
        self.bar.setRange(0, 1000)
        self.message = QtWidgets.QLabel()
        self.message.setWordWrap(True)
        self.cancel_button = QtWidgets.QPushButton("Cancel")
        self.cancel_button.clicked.connect(self._cancel_clicked)
        g.addWidget(self.bar, 0, 0)
        g.addWidget(self.cancel_button, 0, 1)
        g.addWidget(self.message, 1, 0, 1, 2)
        return self.progress_box

    def _result_box(self) -> QtWidgets.QWidget:
        self.result_box = QtWidgets.QWidget()
        lay = QtWidgets.QVBoxLayout(self.result_box)
        lay.setContentsMargins(0, 0, 0, 0)
        form = QtWidgets.QFormLayout()
        self.offset_label, self.skew_label = QtWidgets.QLabel(), QtWidgets.QLabel()
        for w in (self.offset_label, self.skew_label):
            w.setTextInteractionFlags(QtCore.Qt.TextSelectableByMouse)
        form.addRow("clock offset", self.offset_label)
        form.addRow("clock skew", self.skew_label)
        lay.addLayout(form)
        self.table = QtWidgets.QTableWidget(0, 4)
        self.table.setHorizontalHeaderLabels(["object", "moved", "rotated", "1σ"])
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QtWidgets.QAbstractItemView.NoEditTriggers)
        self.table.horizontalHeader().setSectionResizeMode(QtWidgets.QHeaderView.ResizeToContents)
        self.table.horizontalHeader().setStretchLastSection(True)
        lay.addWidget(self.table)
        self.held_label, self.verdict, self.details = QtWidgets.QLabel(), QtWidgets.QLabel(), QtWidgets.QLabel()
        for w in (self.held_label, self.verdict, self.details):
            w.setWordWrap(True)
            lay.addWidget(w)
        self.details.setStyleSheet("color:#555")
        row = QtWidgets.QHBoxLayout()
        row.addWidget(QtWidgets.QLabel("Preview on the frame:"))
        self.before_button = QtWidgets.QRadioButton("&before")
        self.after_button = QtWidgets.QRadioButton("&after (proposed)")
        self.before_button.setToolTip("the frame shows the corrections in effect (the document)")
        self.after_button.setToolTip("the frame shows the proposed corrections; nothing is applied before Accept")
        self.preview_group = QtWidgets.QButtonGroup(self)
        for b in (self.before_button, self.after_button):
            self.preview_group.addButton(b)
            row.addWidget(b)
        row.addStretch(1)
        self.after_button.toggled.connect(self._preview_toggled)
        lay.addLayout(row)
        buttons = QtWidgets.QHBoxLayout()
        buttons.addStretch(1)
        self.accept_button = QtWidgets.QPushButton("Accept")
        self.reject_button = QtWidgets.QPushButton("Reject")
        self.accept_button.setToolTip("apply the proposal as one undo step (Ctrl+Z undoes it)")
        self.reject_button.setToolTip("discard the proposal; the frame shows the document again")
        self.accept_button.clicked.connect(self.acceptRequested)
        self.reject_button.clicked.connect(self.rejectRequested)
        buttons.addWidget(self.accept_button)
        buttons.addWidget(self.reject_button)
        lay.addLayout(buttons)
        return self.result_box

    # ------------------------------------------------------------------ states
    def show_running(self, title: str) -> None:
        """Progress from 0 with Cancel; no proposal."""
        self.proposal = None
        self.title.setText(f"<b>{title}</b> — running")
        self.bar.setValue(0)
        self.message.setText("starting…")
        self.cancel_button.setEnabled(True)
        self.progress_box.setVisible(True)
        self.result_box.setVisible(False)

    def set_progress(self, fraction: float, message: str) -> None:
        self.bar.setValue(int(round(min(max(fraction, 0.0), 1.0) * 1000)))
        if message:
            self.message.setText(message)

    def _cancel_clicked(self) -> None:
        self.cancel_button.setEnabled(False)
        self.message.setText("cancelling…")
        self.cancelRequested.emit()

    def show_stopped(self, title: str, message: str) -> None:
        """The job ended without a proposal (cancelled or failed)."""
        self.proposal = None
        self.title.setText(f"<b>{title}</b> — {message}")
        self.cancel_button.setEnabled(False)
        self.progress_box.setVisible(False)
        self.result_box.setVisible(False)

    def show_proposal(self, p, preview_after: bool) -> None:
        """The proposal ``p`` (:class:`~evpose.app.auto_sync.Proposal`); the preview toggle set to ``preview_after``
        (without a signal)."""
        self.proposal = p
        self.title.setText(f"<b>{p.title}</b> — proposal (not applied)")
        self.progress_box.setVisible(False)
        self.result_box.setVisible(True)
        before = p.clock_before[0]
        self.offset_label.setText(f"{fmt_ms(before)} kept" if p.offset_us is None else
                                  f"{fmt_ms(before)} → {fmt_ms(p.offset_us)}{fmt_std(p.offset_std_us)}")
        self.skew_label.setText(_skew_text(p))
        self._fill_table(p)
        held = p.held
        notes = list(p.joint.notes) if p.joint is not None else []     # e.g. the mounting check's finding
        self.held_label.setText("".join(f"<b>{n}</b> kept: {why}<br>" for n, why in held.items())
                                + "".join(f"{escape(n)}<br>" for n in notes))
        self.held_label.setVisible(bool(held or notes))
        status, html = _verdict(p)
        self.verdict.setText(f"<span style='{STATUS_STYLE[status]}'>{html}</span>")
        self.details.setText(_source_text(p))
        self.accept_button.setEnabled(p.usable)
        for b in (self.before_button, self.after_button):
            b.setEnabled(p.usable)
            b.blockSignals(True)
        (self.after_button if preview_after and p.usable else self.before_button).setChecked(True)
        for b in (self.before_button, self.after_button):
            b.blockSignals(False)

    def mark_stale(self, message: str) -> None:
        """The document changed since the estimate was made: it can no longer be accepted or previewed."""
        self.title.setText(f"<b>{self.proposal.title if self.proposal else 'Proposal'}</b> — stale (not applied)")
        self.verdict.setText(f"<span style='{STATUS_STYLE['bad']}'>{message}</span>")
        self.accept_button.setEnabled(False)
        for b in (self.before_button, self.after_button):
            b.blockSignals(True)
            b.setEnabled(False)
        self.before_button.setChecked(True)
        for b in (self.before_button, self.after_button):
            b.blockSignals(False)

    def _fill_table(self, p) -> None:
        rows = [(n, f"{o.dt_mm:.2f} mm", f"{o.dR_deg:.2f}°",
                 f"± {_num(o.std_mm, '.2f')} mm, ± {_num(o.std_deg, '.2f')}°") for n, o in p.poses.items()]
        rows += [(n, "kept", "", "too little evidence" if "evidence" in why else "not pinned")
                 for n, why in p.held.items()]
        if p.hand_eye_fitted:
            j = p.joint
            rows.append(("hand-eye", f"{j.hand_eye_dt_mm:.2f} mm", f"{j.hand_eye_dR_deg:.2f}°",
                         f"± {_num(j.hand_eye_std_mm, '.2f')} mm, ± {_num(j.hand_eye_std_deg, '.2f')}°"))
        self.table.setRowCount(len(rows))
        for r, cells in enumerate(rows):
            for c, text in enumerate(cells):
                self.table.setItem(r, c, QtWidgets.QTableWidgetItem(text))
        self.table.setVisible(bool(rows))
        self.table.resizeRowsToContents()
        self.table.setFixedHeight(self.table.horizontalHeader().sizeHint().height()
                                  + self.table.verticalHeader().length() + 2 * self.table.frameWidth())

    def preview_after(self) -> bool:
        return self.after_button.isChecked()

    def _preview_toggled(self, after: bool) -> None:
        self.previewChanged.emit(bool(after))


class ProposalDock(QtWidgets.QDockWidget):
    """The dock holding a :class:`ProposalPanel` (scrolled: the window never grows for it); ``closed`` when the
    user closes it (a Reject)."""

    closed = QtCore.Signal()

    def set_panel(self, panel: ProposalPanel) -> None:
        scroll = QtWidgets.QScrollArea()
        scroll.setWidgetResizable(True)
        scroll.setFrameShape(QtWidgets.QFrame.NoFrame)
        scroll.setWidget(panel)
        self.setWidget(scroll)

    def closeEvent(self, event) -> None:  # noqa: N802 (Qt API)
        super().closeEvent(event)
        self.closed.emit()
