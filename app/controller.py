"""User-facing flows: dialogs first, then core calls (DESIGN section 2: dialogs live here, never
in commands). Errors are shown in dialogs naming the file and the field; nothing crashes with a
traceback only.

Another program saving ``corrections.json`` while the scene is open (an ``evpose ... --apply``, a
second app): with no unsaved edits the app reloads silently and says so in the status bar; with
unsaved edits it offers *Merge* (take the other program's edits under ours; a real conflict names
the field and both values and offers keeping ours or theirs), *Reload* (discard ours) or *Later*
(the next save merges). The change taken over is one labelled undo step (see
:mod:`evpose.core.session.model`). Save goes through the same revision check.
"""
from __future__ import annotations

import warnings

from PySide6 import QtCore, QtWidgets

from evpose.app.export_dialog import ExportDialog, export_done_box
from evpose.app.restore_dialog import CHOICES as RESTORE_CHOICES
from evpose.app.restore_dialog import TITLE as RESTORE_TITLE
from evpose.app.restore_dialog import restore_question
from evpose.app.workers import Job, progress_dialog
from evpose.core.document.corrections import CorrectionsError, CorrectionsWarning
from evpose.core.document.corrections_merge import CorrectionsConflict
from evpose.core.errors import InputError
from evpose.core.session.model import Session


class Controller(QtCore.QObject):
    """Opens, saves and exports for a :class:`~evpose.app.main_window.MainWindow`."""

    def __init__(self, window):
        super().__init__(window)
        self.window = window
        self.jobs: list[Job] = []
        #: Warnings from opening the last scene (e.g. unknown object names in corrections.json).
        self.open_warnings: list[str] = []
        self._deferred_signature = None   # an external change the user chose to decide "later"
        self._asking = False
        #: the text of the last question asked under each title (also when answered unattended)
        self.questions: dict[str, str] = {}
        #: the message shown when the last export was done (its "Open folder" button: ``open_button``)
        self.done_box: QtWidgets.QMessageBox | None = None

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
        self.questions[title] = text
        if not getattr(self.window, "modal_dialogs", True):
            return self.window.auto_answer.get(title, default)
        return QtWidgets.QMessageBox.question(self.window, title, text, buttons, default)

    def _choose(self, title: str, text: str, options: list[tuple[str, str]], default: str) -> str:
        """A question with named answers: ``options`` are ``(key, button text)``; returns a key
        (unattended: ``window.auto_answer[title]`` or ``default``)."""
        self.questions[title] = text
        if not getattr(self.window, "modal_dialogs", True):
            return self.window.auto_answer.get(title, default)
        box = QtWidgets.QMessageBox(QtWidgets.QMessageBox.Question, title, text, parent=self.window)
        buttons = {}
        for key, label in options:
            role = QtWidgets.QMessageBox.RejectRole if key in ("later", "cancel") else QtWidgets.QMessageBox.AcceptRole
            buttons[box.addButton(label, role)] = key
            if key == default:
                box.setDefaultButton(list(buttons)[-1])
        box.exec()
        return buttons.get(box.clickedButton(), "cancel")

    # ------------------------------------------------------------------ open / save
    def open_dialog(self) -> None:
        path = QtWidgets.QFileDialog.getExistingDirectory(self.window, "Open scene folder")
        if path:
            self.open_scene(path)

    def open_scene(self, path, defaults: dict | None = None) -> Session | None:
        """Open the scene at ``path`` (``defaults``: its dataset's shared tables) in the window."""
        if not self.maybe_save():
            return None
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", CorrectionsWarning)
                session = Session.open(path, defaults=defaults)
            self.open_warnings = [str(w.message) for w in caught if issubclass(w.category, CorrectionsWarning)]
            for w in caught:
                if not issubclass(w.category, CorrectionsWarning):
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            _ = session.scene.events.n_events   # fail now, not at first draw
            if session.scene.has_poses:
                _ = session.scene.trajectory
        except (InputError, OSError) as exc:     # bad input, or the system refused a read
            self.error("Cannot open the scene", str(exc))
            self.window.settings.remove_recent(path)
            return None
        self.window.set_session(session)
        self.window.settings.add_recent(session.scene.root)
        self.window.refresh_recent_menu()
        self._deferred_signature = None
        self.window.statusBar().showMessage(f"opened {session.scene.root}", 5000)
        self._offer_journal(session)
        if self.open_warnings:
            self.window.statusBar().showMessage("warning: " + "; ".join(self.open_warnings), 20_000)
        return session

    def _offer_journal(self, session: Session) -> None:
        offer = session.pending_journal()
        if session.journal_problem:
            self.window.statusBar().showMessage(session.journal_problem, 15_000)
        if offer is None:
            if session.journal_problem is None:
                session.discard_journal()       # nothing in it the saved file lacks: it only held saved work
            return
        text = restore_question(session.scene.corrections, offer, session.journal_path.stat().st_mtime)
        if offer.conflicts:
            answer = self._choose(RESTORE_TITLE, text, RESTORE_CHOICES, RESTORE_CHOICES[0][0])
        else:
            yes = self._ask(RESTORE_TITLE, text, QtWidgets.QMessageBox.Yes | QtWidgets.QMessageBox.No,
                            QtWidgets.QMessageBox.Yes) == QtWidgets.QMessageBox.Yes
            answer = "keep_saved" if yes else "discard"
        if answer == "discard":
            session.discard_journal()
            return
        if answer not in ("keep_saved", "take_autosaved"):      # closed the question: ask again next time
            return
        conflicts = session.restore_journal(offer, take_autosaved=answer == "take_autosaved")
        kept = "autosaved" if answer == "take_autosaved" else "saved"
        extra = f"; kept the {kept} value for " + ", ".join(c.field for c in conflicts) if conflicts else ""
        self.window.statusBar().showMessage(f"restored autosaved corrections (Ctrl+Z undoes){extra}", 10_000)

    def save(self, prefer: str | None = None) -> bool:
        """Save through the revision check; a conflict with another program's save asks which
        value to keep (or cancels: nothing saved)."""
        s = self.window.session
        if s is None:
            return True
        try:
            path = s.save(prefer=prefer)
        except CorrectionsConflict as exc:
            answer = self._choose("Conflicting change on disk",
                                  f"{exc}\n\nKeep your values for the conflicting fields, or take the other "
                                  "program's? (Either way the other edits of both are kept.)",
                                  [("local", "Keep mine"), ("disk", "Take theirs"), ("cancel", "Cancel")], "cancel")
            if answer in ("local", "disk"):
                return self.save(prefer=answer)
            self.window.statusBar().showMessage("not saved: " + str(exc), 15_000)
            return False
        except CorrectionsError as exc:
            self.error("Cannot save the corrections", str(exc))
            return False
        except OSError as exc:
            self.error("Cannot save the corrections", f"{exc.filename or s.scene.corrections_path}: "
                                                      f"{exc.strerror or exc}")
            return False
        self._deferred_signature = None
        report = s.scene.corrections.last_save
        msg = f"saved {path} (revision {report.revision})"
        if report.from_disk:
            msg += f"; merged {', '.join(report.from_disk)} saved meanwhile by another program (Ctrl+Z undoes)"
        self.window.statusBar().showMessage(msg, 10_000)
        return True

    # ------------------------------------------------------------------ another program saved
    def on_disk_change(self) -> str | None:
        """React to ``corrections.json`` changing on disk; returns what was done ("reloaded",
        "merged", "later", "conflict") or None when nothing changed."""
        s = self.window.session
        if s is None or self._asking:
            return None
        try:
            change = s.check_disk()
        except CorrectionsError as exc:
            self.window.statusBar().showMessage(f"corrections.json on disk cannot be read: {exc}", 15_000)
            return None
        if change is None or change.signature == self._deferred_signature:
            return None
        fields = ", ".join(change.fields) or "nothing"
        if not s.dirty:
            s.reload_from_disk(change)
            self.window.statusBar().showMessage(
                f"corrections.json was changed by another program (revision {change.revision}: {fields}); "
                "reloaded (Ctrl+Z undoes)", 15_000)
            return "reloaded"
        self._asking = True
        try:
            answer = self._choose("Corrections changed on disk",
                                  f"Another program saved {s.scene.corrections_path} (revision {change.revision}; "
                                  f"changed: {fields}) while you have unsaved edits.\n\n"
                                  "Merge: take its edits under yours.\nReload: discard your unsaved edits.\n"
                                  "Later: decide when you save (the save merges).",
                                  [("merge", "Merge"), ("reload", "Reload"), ("later", "Later")], "merge")
            if answer == "reload":
                s.reload_from_disk(change)
                self.window.statusBar().showMessage(
                    f"reloaded corrections.json (revision {change.revision}); your unsaved edits were discarded "
                    "(Ctrl+Z brings them back)", 15_000)
                return "reloaded"
            if answer != "merge":
                self._deferred_signature = change.signature
                self.window.statusBar().showMessage(
                    f"corrections.json changed on disk (revision {change.revision}); it will be merged when you save",
                    15_000)
                return "later"
            try:
                s.merge_from_disk(change)
            except CorrectionsConflict as exc:
                pick = self._choose("Conflicting change on disk",
                                    f"{exc}\n\nKeep your values for the conflicting fields, or take the other "
                                    "program's?", [("local", "Keep mine"), ("disk", "Take theirs"),
                                                   ("cancel", "Cancel")], "cancel")
                if pick not in ("local", "disk"):
                    self._deferred_signature = change.signature
                    self.window.statusBar().showMessage("not merged: " + str(exc), 15_000)
                    return "conflict"
                s.merge_from_disk(change, prefer=pick)
            self.window.statusBar().showMessage(
                f"merged another program's change to corrections.json (revision {change.revision}: {fields}) "
                "under your unsaved edits (Ctrl+Z undoes)", 15_000)
            return "merged"
        finally:
            self._asking = False

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
        dlg = ExportDialog(self.window, s.scene, self.window.settings)
        if dlg.exec() != QtWidgets.QDialog.Accepted:
            return
        opts = dlg.options()
        if not opts["out_dir"]:
            self.error("Export", "choose an output folder")
            return
        dlg.remember()
        self.start_export(**opts)

    def start_export(self, **opts) -> Job:
        """Export the scene with the corrections as they are now (saved or not) in a worker."""
        from evpose.core.export import export_scene

        s = self.window.session
        snapshot = s.scene.with_corrections(s.scene.corrections.copy())
        job = Job(lambda progress, cancel: export_scene(snapshot, progress=progress, cancel=cancel, **opts))
        dlg = progress_dialog(self.window, "Export", f"Exporting {s.scene.name} ({opts['fmt']})…", job)

        def finished(summary):
            dlg.close()
            self.jobs.remove(job)
            self.window.statusBar().showMessage(export_done_text(summary), 30_000)
            self.window.last_export = summary
            self.done_box = export_done_box(self.window, summary, export_done_text(summary))

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


def export_done_text(summary) -> str:
    """The status-bar line after an export, with the review-mark counts of an only-verified export."""
    text = (f"export done: {summary.written} windows written, {summary.skipped_complete} already complete, "
            f"{summary.unlabeled} unlabeled -> {summary.out_dir}")
    if summary.review_marked:
        text += (f"; verified marks touch {summary.review_marked} windows: "
                 f"{summary.review_marked - summary.review_unused} exported")
        if summary.review_unused:
            text += f", {summary.review_unused} not used (" + "; ".join(
                f"{n} {r.split(':')[0]}" for r, n in summary.review_unused_reasons.items()) + ")"
    return text
