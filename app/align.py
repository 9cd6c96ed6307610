"""Automatic estimates in the app: clock sync, pose refinement and sequence-wide scores.

Each runs the core function (:mod:`evpose.core.align.estimate`, :mod:`evpose.core.align.pose_refine`, :mod:`evpose.core.align.score_table`) on a
snapshot of the scene in a :class:`~evpose.app.workers.Job` (the window stays responsive, a progress
dialog can cancel), then shows the proposal with how sure it is; accepting applies it through
the History as **one** undo step. Nothing is applied without the user's accept.
"""
from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

from evpose.app.workers import Job, progress_dialog
from evpose.core.align.sync_result import SLOW_STD_NOTE_US


def _fmt_ms(us) -> str:
    return "–" if us is None else f"{us / 1000.0:+.3f} ms"


def _fmt_std(std_us) -> str:
    """`` ± x ms (1σ)`` for a sync result's standard error ('' when none was computed)."""
    if std_us is None:
        return ""
    if not np.isfinite(std_us):
        return "  (not pinned by the event rate)"
    return f"  ± {std_us / 1000.0:.3f} ms (1σ)"


def _num(x, fmt: str) -> str:
    """``x`` formatted, or '–' for None / NaN / inf."""
    return "–" if x is None or not np.isfinite(x) else format(x, fmt)


def _accept_cancel(dialog: QtWidgets.QDialog, layout, enabled: bool) -> QtWidgets.QPushButton:
    """Accept (enabled only for a usable proposal) and Cancel buttons; returns Accept."""
    buttons = QtWidgets.QDialogButtonBox()
    accept = buttons.addButton("Accept", QtWidgets.QDialogButtonBox.AcceptRole)
    accept.setEnabled(enabled)
    buttons.addButton(QtWidgets.QDialogButtonBox.Cancel)
    buttons.accepted.connect(dialog.accept)
    buttons.rejected.connect(dialog.reject)
    layout.addWidget(buttons)
    return accept


class SyncDialog(QtWidgets.QDialog):
    """The correlation curve of the event rate against the camera motion, the estimate, its
    confidence, and Accept (only for a reliable estimate); optionally followed by the offset from
    edges (``then_edges``)."""

    def __init__(self, parent, result, current_offset_us: int, current_skew_ppm: float, has_objects: bool = False,
                 edges_default: bool = True):
        super().__init__(parent)
        self.result = result
        self.setWindowTitle("Automatic clock sync")
        lay = QtWidgets.QVBoxLayout(self)
        self.plot = pg.PlotWidget(background="w")
        self.plot.setMinimumSize(520, 240)
        p = self.plot.getPlotItem()
        p.setLabel("bottom", "total clock offset (pose − event time)", units="s")
        p.setLabel("left", "normalised cross-correlation")
        p.showGrid(x=True, y=True, alpha=0.3)
        lags = np.asarray(result.lags_us, np.float64)
        corr = np.asarray(result.correlation, np.float64)
        if len(lags):
            p.plot(lags * 1e-6, np.where(np.isfinite(corr), corr, np.nan), pen=pg.mkPen((40, 40, 40), width=1.5),
                   connect="finite")
        p.addItem(pg.InfiniteLine(current_offset_us * 1e-6, angle=90,
                                  pen=pg.mkPen((120, 120, 120), style=QtCore.Qt.DashLine), label="current",
                                  labelOpts={"position": 0.1, "color": (90, 90, 90)}))
        if result.offset_us is not None and result.offset_std_us is not None and np.isfinite(result.offset_std_us):
            half = result.offset_std_us * 1e-6
            self.std_band = pg.LinearRegionItem((result.offset_us * 1e-6 - half, result.offset_us * 1e-6 + half),
                                                movable=False, brush=pg.mkBrush(200, 30, 30, 40),
                                                pen=pg.mkPen(None))
            p.addItem(self.std_band)
        if result.offset_us is not None:
            p.addItem(pg.InfiniteLine(result.offset_us * 1e-6, angle=90, pen=pg.mkPen((200, 30, 30), width=2),
                                      label="estimate", labelOpts={"position": 0.9, "color": (200, 30, 30)}))
        lay.addWidget(self.plot, 1)
        rows = [("current offset", _fmt_ms(current_offset_us)),
                ("estimated offset", _fmt_ms(result.offset_us) + _fmt_std(result.offset_std_us)),
                ("current skew", f"{current_skew_ppm:+.1f} ppm"),
                ("estimated skew", "kept (not estimated)" if result.skew_ppm is None else f"{result.skew_ppm:+.1f} ppm"),
                ("confidence", f"{result.confidence:.2f}  (peak NCC {result.peak:.2f}, second peak "
                               f"{result.second_peak:.2f})"),
                ("run time", f"{result.runtime_s:.2f} s")]
        form = QtWidgets.QFormLayout()
        for k, v in rows:
            form.addRow(k, QtWidgets.QLabel(v))
        lay.addLayout(form)
        std = result.offset_std_us
        loose = std is not None and not std <= SLOW_STD_NOTE_US
        if not result.reliable:
            verdict = (f"<b style='color:#b00'>No reliable estimate:</b> {result.reason}. Keep the current clock "
                       "and correct by hand.")
        elif loose:
            verdict = ("<b style='color:#a60'>Reliable peak, loose timing:</b> the event rate pins the offset only to "
                       + (f"±{std / 1000:.1f} ms" if np.isfinite(std) else "nothing within its likelihood scan")
                       + " (few or gradual starts and stops). Check it on the event frames, or refine the offset "
                         "from edges once the poses are right. Accept applies it as one undo step.")
        else:
            verdict = "<b>Reliable estimate.</b> Accept applies it as one undo step."
        self.verdict = QtWidgets.QLabel(verdict)
        self.verdict.setWordWrap(True)
        lay.addWidget(self.verdict)
        self.then_edges = QtWidgets.QCheckBox("then refine offset and skew from edges (the object poses must be right)")
        self.then_edges.setToolTip("After Accept, fit the clock so the events line up with the objects' edges, "
                                   "within 3 standard errors of this estimate (a second proposal, its own undo step)")
        self.then_edges.setEnabled(bool(result.reliable) and has_objects)
        self.then_edges.setChecked(bool(result.reliable) and has_objects and edges_default)
        lay.addWidget(self.then_edges)
        self.accept_button = _accept_cancel(self, lay, bool(result.reliable))


class ClockRefineDialog(QtWidgets.QDialog):
    """Offset (and skew) from event/edge alignment: before/after with standard errors; Accept
    only when the fit was accepted."""

    def __init__(self, parent, result, current_offset_us: int, current_skew_ppm: float):
        super().__init__(parent)
        self.result = result
        self.setWindowTitle("Clock from edges")
        lay = QtWidgets.QVBoxLayout(self)
        form = QtWidgets.QFormLayout()
        if result.skew_estimated:
            skew = (f"{result.skew_ppm:+.1f} ppm ± {_num(result.skew_std_ppm, '.1f')} ppm "
                    "(1σ, fitted from the windows)")
        elif result.accepted:
            skew = (f"{result.skew_ppm:+.1f} ppm kept (the windows pin it only to "
                    f"± {_num(result.skew_std_ppm, '.1f')} ppm)" if result.skew_std_ppm is not None
                    else f"{result.skew_ppm:+.1f} ppm kept")
        else:
            skew = "–"
        rows = [("current offset", _fmt_ms(current_offset_us)),
                ("offset from edges", (_fmt_ms(result.offset_us) + _fmt_std(result.offset_std_us))
                 if result.accepted else "–"),
                ("current skew", f"{current_skew_ppm:+.1f} ppm"),
                ("skew", skew),
                ("edge objective", f"{_num(result.objective_before, '.4f')} → {_num(result.objective_after, '.4f')} "
                                   "(higher is better)"),
                ("windows used", str(result.n_windows)),
                ("run time", f"{result.runtime_s:.1f} s")]
        for k, v in rows:
            form.addRow(k, QtWidgets.QLabel(v))
        lay.addLayout(form)
        if result.accepted:
            verdict = ("<b>Offset fitted to the event edges.</b> It assumes the object poses are right: a pose "
                       "error shifts the edges like a clock error (5 mm / 3° moved it by 1.6-4.3 ms on the "
                       "benchmark scenes, and the ± above need not show it). Accept applies offset and skew as one "
                       "undo step.")
        else:
            verdict = f"<b style='color:#b00'>Clock kept:</b> {result.reason}"
        self.verdict = QtWidgets.QLabel(verdict)
        self.verdict.setWordWrap(True)
        lay.addWidget(self.verdict)
        self.accept_button = _accept_cancel(self, lay, bool(result.accepted))


class RefineDialog(QtWidgets.QDialog):
    """Before/after of a pose refinement; Accept only when the fit improved."""

    def __init__(self, parent, result):
        super().__init__(parent)
        self.result = result
        self.setWindowTitle(f"Refine {result.object}")
        lay = QtWidgets.QVBoxLayout(self)
        form = QtWidgets.QFormLayout()
        rows = [("object", str(result.object)),
                ("change found", f"{result.dt_mm:.2f} mm (object centre, base frame), {result.dR_deg:.2f}°"),
                ("alignment score", f"{_num(result.score_before, '+.3f')} → {_num(result.score_after, '+.3f')} "
                                    "(higher is better)"),
                ("edge objective", f"{_num(result.objective_before, '.4f')} → {_num(result.objective_after, '.4f')}"),
                ("windows used", str(result.n_windows)),
                ("iterations", str(result.iterations)),
                ("run time", f"{result.runtime_s:.1f} s")]
        for k, v in rows:
            form.addRow(k, QtWidgets.QLabel(v))
        lay.addLayout(form)
        verdict = QtWidgets.QLabel("<b>The fit improved the alignment.</b> Accept applies it as one undo step."
                                   if result.accepted else f"<b style='color:#b00'>Start kept:</b> {result.reason}")
        verdict.setWordWrap(True)
        lay.addWidget(verdict)
        self.accept_button = _accept_cancel(self, lay, bool(result.accepted))


class AlignController(QtCore.QObject):
    """Runs sync / refine / score jobs for a :class:`~evpose.app.main_window.MainWindow`.

    In tests and screenshot runs (``window.modal_dialogs`` False) the proposal dialogs do not
    block: ``window.auto_answer["sync"]`` / ``["edge_sync"]`` / ``["refine"]`` (default True)
    decide, ``["sync_edges"]`` (default False) whether an accepted sync goes on to the edges, and
    the last results are kept in ``last_sync``, ``last_clock_refine``, ``last_refine`` and
    ``last_scores``.
    """

    def __init__(self, window):
        super().__init__(window)
        self.window = window
        self.jobs: list[Job] = []
        self.last_sync = None
        self.last_clock_refine = None
        self.last_refine = None
        self.last_scores = None
        #: event windows of the clock-from-edges fit (the CLI's ``--windows``; default 24)
        self.edge_windows = 24

    # ------------------------------------------------------------------ plumbing
    def _run(self, title: str, fn, on_done) -> Job | None:
        session = self.window.session
        if session is None:
            return None
        snapshot = session.scene.with_corrections(session.scene.corrections.copy())
        job = Job(lambda progress, cancel: fn(snapshot, progress, cancel))
        dlg = progress_dialog(self.window, title, title + "…", job)

        def finished(result):
            dlg.close()
            self.jobs.remove(job)
            if self.window.session is session:   # the scene may have been closed meanwhile
                on_done(session, result)

        def failed(message, details):
            dlg.close()
            self.jobs.remove(job)
            if message == "cancelled":
                self.window.statusBar().showMessage(f"{title.lower()} cancelled", 5000)
            else:
                self.window.controller.error(title, message, details)

        job.signals.finished.connect(finished)
        job.signals.failed.connect(failed)
        self.jobs.append(job)
        self.window.statusBar().showMessage(f"{title.lower()}…")
        return job.start()

    def _decide(self, dlg: QtWidgets.QDialog, key: str) -> bool:
        if getattr(self.window, "modal_dialogs", True):
            return dlg.exec() == QtWidgets.QDialog.Accepted
        return bool(self.window.auto_answer.get(key, True)) and dlg.accept_button.isEnabled()

    def cancel_all(self) -> None:
        for job in list(self.jobs):
            job.cancel()

    # ------------------------------------------------------------------ clock sync
    def auto_sync(self) -> Job | None:
        from evpose.core.align.estimate import sync_scene

        return self._run("Automatic clock sync",
                         lambda scene, progress, cancel: sync_scene(scene, progress=progress, cancel=cancel),
                         self._sync_done)

    def _sync_done(self, session, result) -> None:
        self.last_sync = result
        clock = session.scene.clock
        modal = getattr(self.window, "modal_dialogs", True)
        dlg = SyncDialog(self.window, result, int(clock.offset_us), float(clock.skew_ppm),
                         has_objects=bool(session.object_names),
                         edges_default=True if modal else bool(self.window.auto_answer.get("sync_edges", False)))
        then_edges = False
        if self._decide(dlg, "sync") and result.reliable and result.offset_us is not None:
            session.apply_clock_estimate(result.offset_us, result.skew_ppm, "automatic clock sync")
            self.window.statusBar().showMessage(
                f"clock set to {result.offset_us / 1000:+.3f} ms (confidence {result.confidence:.2f}); Ctrl+Z undoes",
                8000)
            then_edges = dlg.then_edges.isChecked()
        elif not result.reliable:
            self.window.statusBar().showMessage(f"clock sync: no reliable estimate ({result.reason})", 8000)
        dlg.deleteLater()
        if then_edges:
            self.refine_clock()

    # ------------------------------------------------------------------ clock from edges
    def refine_clock(self) -> Job | None:
        """Offset (and skew) from event/edge alignment. Right after an accepted automatic sync
        (the clock in effect is its estimate) it searches within 3 of that estimate's standard
        errors (:func:`evpose.core.align.sync_edges.refine_offset_from_sync`); otherwise ±3 ms around the clock in
        effect."""
        from evpose.core.align.clock_refine import refine_offset
        from evpose.core.align.sync_edges import refine_offset_from_sync

        session = self.window.session
        if session is None:
            return None
        if not session.object_names:
            self.window.statusBar().showMessage("clock from edges: the scene has no objects", 5000)
            return None
        sync = self.last_sync
        clock, est = session.scene.clock, None if sync is None or not sync.reliable else sync.clock()
        from_sync = (est is not None and clock.offset_us == est.offset_us
                     and abs(clock.skew_ppm - est.skew_ppm) < 1e-6)

        from evpose.core.align.refine_result import RefineParams

        params = RefineParams(n_windows=self.edge_windows)

        def fn(scene, progress, cancel):
            if from_sync:
                return refine_offset_from_sync(scene, sync, params=params, progress=progress, cancel=cancel)
            return refine_offset(scene, params=params, progress=progress, cancel=cancel)

        return self._run("Clock from edges", fn, self._clock_done)

    def _clock_done(self, session, result) -> None:
        self.last_clock_refine = result
        clock = session.scene.clock
        dlg = ClockRefineDialog(self.window, result, int(clock.offset_us), float(clock.skew_ppm))
        if self._decide(dlg, "edge_sync") and result.accepted and result.offset_us is not None:
            session.apply_clock_estimate(result.offset_us, result.skew_ppm, "clock from edges")
            self.window.statusBar().showMessage(
                f"clock set to {result.offset_us / 1000:+.3f} ms from edges; Ctrl+Z undoes", 8000)
        dlg.deleteLater()

    # ------------------------------------------------------------------ pose refinement
    def refine(self, name: str) -> Job | None:
        from evpose.core.align.pose_refine import refine_object

        session = self.window.session
        if session is None or name not in session.object_names:
            self.window.statusBar().showMessage("select an object to refine", 5000)
            return None
        return self._run(f"Refine {name}",
                         lambda scene, progress, cancel: refine_object(scene, name, progress=progress, cancel=cancel),
                         self._refine_done)

    def _refine_done(self, session, result) -> None:
        self.last_refine = result
        dlg = RefineDialog(self.window, result)
        if self._decide(dlg, "refine") and result.accepted:
            session.apply_pose_estimate(result.object, result.dT_base, f"refine {result.object}")
            self.window.statusBar().showMessage(
                f"{result.object}: moved {result.dt_mm:.2f} mm, {result.dR_deg:.2f}°; Ctrl+Z undoes", 8000)
        dlg.deleteLater()

    # ------------------------------------------------------------------ scores over the sequence
    def score_all(self) -> Job | None:
        from evpose.core.align.score_table import score_windows

        session = self.window.session
        if session is None:
            return None
        window_us = int(session.view.window_us)
        return self._run("Score all windows",
                         lambda scene, progress, cancel: score_windows(scene, window_us=window_us, progress=progress,
                                                                       cancel=cancel),
                         self._scores_done)

    def _scores_done(self, session, table) -> None:
        self.last_scores = table
        tl = self.window.timeline
        if tl is None:
            return
        t_s = np.array([tl.x_of(t) for t in table.t_label_us], np.float64)
        tl.set_scores(t_s, {n: np.ma.filled(table.score[n].astype(np.float64), np.nan) for n in table.objects})
        self.window.ensure_timeline_height(300)   # room for the score row
        means = ", ".join(f"{n} {m:+.2f}" for n in table.objects if (m := table.mean_score(n)) is not None)
        self.window.statusBar().showMessage(f"scored {len(table)} windows in {table.runtime_s:.1f} s: {means}", 10_000)
