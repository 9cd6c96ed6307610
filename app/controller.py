"""User-facing flows: dialogs first, then core calls (DESIGN section 2: dialogs live here, never
in commands). Errors are shown in dialogs naming the file and the field; nothing crashes with a
traceback only."""
from __future__ import annotations

import datetime
from pathlib import Path

from PySide6 import QtCore, QtWidgets

from core.cli import _input_errors
from core.session import Session

from .workers import Job, progress_dialog


class ExportDialog(QtWidgets.QDialog):
    """Format, output folder and window options for ``core.export.export_scene``."""

    def __init__(self, parent, scene_name: str, last_dir: str = ""):
        super().__init__(parent)
        self.setWindowTitle("Export corrected dataset")
        form = QtWidgets.QFormLayout(self)
        self.fmt = QtWidgets.QComboBox()
        for key, text in (("epose", "E-POSE layout (per-window PNG/.mat/.txt)"), ("bop", "BOP (undistorted)"),
                          ("h5", "HDF5 (one file, streaming)")):
            self.fmt.addItem(text, key)
        self.out = QtWidgets.QLineEdit(str(Path(last_dir or Path.home()) / f"{scene_name}_export"))
        browse = QtWidgets.QPushButton("…")
        browse.clicked.connect(self._browse)
        row = QtWidgets.QHBoxLayout()
        row.addWidget(self.out, 1)
        row.addWidget(browse)
        self.window_ms = QtWidgets.QDoubleSpinBox(suffix=" ms", decimals=1, minimum=0.1, maximum=10_000, value=10.0)
        self.window_events = QtWidgets.QSpinBox(minimum=0, maximum=100_000_000, value=0, specialValueText="by time")
        self.label_at = QtWidgets.QComboBox()
        self.label_at.addItem("window centre", "center")
        self.label_at.addItem("window end (E-POSE timing)", "end")
        self.only_verified = QtWidgets.QCheckBox("only windows marked verified")
        self.jobs = QtWidgets.QSpinBox(minimum=1, maximum=max(QtCore.QThread.idealThreadCount(), 1), value=1)
        form.addRow("format", self.fmt)
        form.addRow("output folder", row)
        form.addRow("window length", self.window_ms)
        form.addRow("or events per window", self.window_events)
        form.addRow("label time", self.label_at)
        form.addRow("", self.only_verified)
        form.addRow("processes", self.jobs)
        buttons = QtWidgets.QDialogButtonBox(QtWidgets.QDialogButtonBox.Ok | QtWidgets.QDialogButtonBox.Cancel)
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        form.addRow(buttons)

    def _browse(self) -> None:
        d = QtWidgets.QFileDialog.getExistingDirectory(self, "Export folder", self.out.text())
        if d:
            self.out.setText(d)

    def options(self) -> dict:
        opts = {"fmt": self.fmt.currentData(), "out_dir": self.out.text().strip(), "label_at": self.label_at.currentData(),
                "only_verified": self.only_verified.isChecked(), "jobs": self.jobs.value()}
        if self.window_events.value() > 0:
            opts["window_events"] = self.window_events.value()
        else:
            opts["window_us"] = int(round(self.window_ms.value() * 1000))
        return opts


class Controller(QtCore.QObject):
    """Opens, saves and exports for a :class:`~app.main_window.MainWindow`."""

    def __init__(self, window):
        super().__init__(window)
        self.window = window
        self.jobs: list[Job] = []

    # ------------------------------------------------------------------ helpers
    def error(self, title: str, message: str, details: str = "") -> None:
        box = QtWidgets.QMessageBox(QtWidgets.QMessageBox.Critical, title, message, parent=self.window)
        if details:
            box.setDetailedText(details)
        if getattr(self.window, "modal_dialogs", True):
            box.exec()
        else:  # tests and --screenshot runs: never block
            self.window.last_error = message
        self.window.statusBar().showMessage(f"{title}: {message}", 10_000)

    def _ask(self, title: str, text: str, buttons, default):
        if not getattr(self.window, "modal_dialogs", True):
            return self.window.auto_answer.get(title, default)
        return QtWidgets.QMessageBox.question(self.window, title, text, buttons, default)

    # ------------------------------------------------------------------ open / save
    def open_dialog(self) -> None:
        path = QtWidgets.QFileDialog.getExistingDirectory(self.window, "Open scene folder")
        if path:
            self.open_scene(path)

    def open_scene(self, path) -> Session | None:
        if not self.maybe_save():
            return None
        try:
            session = Session.open(path)
            _ = session.scene.events.n_events, session.scene.trajectory  # fail now, not at first draw
        except _input_errors() as exc:
            self.error("Cannot open the scene", str(exc))
            self.window.settings.remove_recent(path)
            return None
        self.window.set_session(session)
        self.window.settings.add_recent(session.scene.root)
        self.window.refresh_recent_menu()
        self._offer_journal(session)
        self.window.statusBar().showMessage(f"opened {session.scene.root}", 5000)
        return session

    def _offer_journal(self, session: Session) -> None:
        journal = session.pending_journal()
        if journal is None:
            return
        when = datetime.datetime.fromtimestamp(session.journal_path.stat().st_mtime).strftime("%Y-%m-%d %H:%M")
        answer = self._ask("Restore unsaved corrections?",
                           f"Corrections autosaved on {when} were never saved (the app may have crashed).\n"
                           "Restore them? (You can undo the restore.)",
                           QtWidgets.QMessageBox.Yes | QtWidgets.QMessageBox.No, QtWidgets.QMessageBox.Yes)
        if answer == QtWidgets.QMessageBox.Yes:
            session.restore_journal(journal)
            self.window.statusBar().showMessage("restored autosaved corrections (Ctrl+Z undoes)", 8000)
        else:
            session.discard_journal()

    def save(self) -> bool:
        s = self.window.session
        if s is None:
            return True
        try:
            path = s.save()
        except OSError as exc:
            self.error("Cannot save the corrections", f"{s.scene.corrections_path}: {exc.strerror or exc}")
            return False
        self.window.statusBar().showMessage(f"saved {path}", 5000)
        return True

    def maybe_save(self) -> bool:
        """Ask about unsaved changes; False if the user cancels."""
        s = self.window.session
        if s is None or not s.dirty:
            return True
        answer = self._ask("Unsaved corrections",
                           f"Save the corrections of '{s.scene.name}' before closing it?",
                           QtWidgets.QMessageBox.Save | QtWidgets.QMessageBox.Discard | QtWidgets.QMessageBox.Cancel,
                           QtWidgets.QMessageBox.Save)
        if answer == QtWidgets.QMessageBox.Save:
            return self.save()
        if answer == QtWidgets.QMessageBox.Discard:
            s.discard_journal()
            return True
        return False

    # ------------------------------------------------------------------ export
    def export_dialog(self) -> None:
        s = self.window.session
        if s is None:
            return
        dlg = ExportDialog(self.window, s.scene.name, self.window.settings.last_export_dir())
        if dlg.exec() != QtWidgets.QDialog.Accepted:
            return
        opts = dlg.options()
        if not opts["out_dir"]:
            self.error("Export", "choose an output folder")
            return
        self.window.settings.set_last_export_dir(str(Path(opts["out_dir"]).parent))
        self.start_export(**opts)

    def start_export(self, **opts) -> Job:
        """Export the scene with the corrections as they are now (saved or not) in a worker."""
        from core.export import export_scene

        s = self.window.session
        snapshot = s.scene.with_corrections(s.scene.corrections.copy())
        job = Job(lambda progress, cancel: export_scene(snapshot, progress=progress, cancel=cancel, **opts))
        dlg = progress_dialog(self.window, "Export", f"Exporting {s.scene.name} ({opts['fmt']})…", job)

        def finished(summary):
            dlg.close()
            self.jobs.remove(job)
            self.window.statusBar().showMessage(
                f"export done: {summary.written} windows written, {summary.skipped_complete} already complete, "
                f"{summary.unlabeled} unlabeled -> {summary.out_dir}", 15_000)
            self.window.last_export = summary

        def failed(message, details):
            dlg.close()
            self.jobs.remove(job)
            if message == "cancelled":
                self.window.statusBar().showMessage("export cancelled (complete windows are kept; rerun resumes)", 8000)
            else:
                self.error("Export failed", message, details)

        job.signals.finished.connect(finished)
        job.signals.failed.connect(failed)
        self.jobs.append(job)
        return job.start()
