"""The export dialog: format, output folder and window options for
:func:`evpose.core.export.export_scene`, and the message when an export is done.

- The output folder defaults to ``<scene name>_<format>`` beside the scene folder (it follows the format until
  the user edits it).
- Format and options are remembered between exports (:meth:`evpose.app.settings.Settings.export_options`).
- A line under the options says how many windows the export writes and how many of them are verified (what
  "only verified" keeps), updated as the options change.
- When the export is done, a message names what was written and offers "Open folder".
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from PySide6 import QtCore, QtGui, QtWidgets

from evpose.core.export.windows import build_windows, scene_staleness, verified_mask
from evpose.core.label.windows import DEFAULT_WINDOW_US

FORMATS = (("epose", "E-POSE layout (per-window PNG/.mat/.txt)"), ("bop", "BOP (undistorted)"),
           ("h5", "HDF5 (one file, streaming)"))
#: Verified windows are counted in the dialog up to this many candidate windows (beyond: counted by the export).
MAX_COUNTED = 200_000


@dataclass(frozen=True)
class _Span:
    t0_us: int
    t1_us: int


def window_counts(scene, *, window_us: int = DEFAULT_WINDOW_US, window_events: int | None = None,
                  include_stale: bool = False) -> tuple[int, int | None]:
    """``(windows the export tiles the recording into, windows "only verified" keeps)``; the second is None
    when there are too many windows to count quickly."""
    store = scene.events
    if store.t_first_us is None:
        return 0, 0
    reviews = scene.corrections.reviews
    if window_events:
        n = -(-int(store.n_events) // int(window_events))
        if not any(m.status == "verified" for m in reviews):
            return n, 0
        if n > 2_000:        # windows of N events need two event reads each
            return n, None
        windows = build_windows(store, window_events=int(window_events))
    else:
        t_a, w = int(store.t_first_us), int(window_us)
        n = -(-(int(store.t_last_us) + 1 - t_a) // w)
        verified = [m for m in reviews if m.status == "verified"]
        if not verified:
            return n, 0
        # only windows a verified mark overlaps can be kept
        k0 = max((min(m.t0_us for m in verified) - t_a) // w, 0)
        k1 = min(-(-(max(m.t1_us for m in verified) - t_a) // w), n)
        if k1 - k0 > MAX_COUNTED:
            return n, None
        windows = [_Span(t_a + k * w, t_a + (k + 1) * w) for k in range(k0, k1)]
    keep = verified_mask(windows, reviews, list(scene.object_names), None if include_stale else scene_staleness(scene))
    return n, int(keep.sum())


def default_out_dir(scene, fmt: str) -> str:
    """``<scene name>_<format>`` beside the scene folder."""
    root = Path(scene.root)
    return str(root.parent / f"{scene.name}_{fmt}")


class ExportDialog(QtWidgets.QDialog):
    """Options of an export of ``scene``; ``settings`` (:class:`~evpose.app.settings.Settings`) remembers them."""

    def __init__(self, parent, scene, settings):
        super().__init__(parent)
        self.scene, self.settings = scene, settings
        self.setWindowTitle("Export corrected dataset")
        saved = settings.export_options()
        form = QtWidgets.QFormLayout(self)
        self.fmt = QtWidgets.QComboBox()
        for key, text in FORMATS:
            if key == "h5" or scene.has_poses:      # labels need a trajectory: h5 alone for an event-only scene
                self.fmt.addItem(text, key)
        self.fmt.setCurrentIndex(max(self.fmt.findData(saved.get("fmt", "epose")), 0))
        self.out = QtWidgets.QLineEdit(default_out_dir(scene, self.fmt.currentData()))
        self._default_out = self.out.text()
        browse = QtWidgets.QPushButton("…")
        browse.setToolTip("choose the output folder")
        browse.clicked.connect(self._browse)
        row = QtWidgets.QHBoxLayout()
        row.addWidget(self.out, 1)
        row.addWidget(browse)
        self._build_options(saved)
        self.counts = QtWidgets.QLabel()
        self.counts.setWordWrap(True)
        form.addRow("Format", self.fmt)
        form.addRow("Output folder", row)
        form.addRow("Window length", self.window_ms)
        form.addRow("Or events per window", self.window_events)
        form.addRow("Label time", self.label_at)
        form.addRow("", self.only_verified)
        form.addRow("", self.include_stale)
        form.addRow("Processes", self.jobs)
        form.addRow("", self.counts)
        buttons = QtWidgets.QDialogButtonBox(QtWidgets.QDialogButtonBox.Ok | QtWidgets.QDialogButtonBox.Cancel)
        buttons.button(QtWidgets.QDialogButtonBox.Ok).setText("Export")
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        form.addRow(buttons)
        self.fmt.currentIndexChanged.connect(self._format_changed)
        for signal in (self.window_ms.valueChanged, self.window_events.valueChanged, self.only_verified.toggled,
                       self.include_stale.toggled):
            signal.connect(self.update_counts)
        self.update_counts()

    def _build_options(self, saved: dict) -> None:
        self.window_ms = QtWidgets.QDoubleSpinBox(suffix=" ms", decimals=1, minimum=0.1, maximum=10_000,
                                                  value=float(saved.get("window_ms", 10.0)))
        self.window_events = QtWidgets.QSpinBox(minimum=0, maximum=100_000_000, specialValueText="by time",
                                                value=int(saved.get("window_events", 0)))
        for box in (self.window_ms, self.window_events):   # recount on Enter, arrows or leaving the box, not per
            box.setKeyboardTracking(False)                 # keystroke (windows of N events: up to 4000 reads)
        self.label_at = QtWidgets.QComboBox()
        self.label_at.addItem("window centre", "center")
        self.label_at.addItem("window end (E-POSE timing)", "end")
        self.label_at.setCurrentIndex(max(self.label_at.findData(saved.get("label_at", "center")), 0))
        self.only_verified = QtWidgets.QCheckBox("only windows marked verified")
        self.only_verified.setChecked(bool(saved.get("only_verified", False)))
        self.include_stale = QtWidgets.QCheckBox("also verified marks made before a later clock or pose change "
                                                 "(stale)")
        self.include_stale.setChecked(bool(saved.get("include_stale", False)))
        self.include_stale.setEnabled(self.only_verified.isChecked())
        self.only_verified.toggled.connect(self.include_stale.setEnabled)
        n_max = max(QtCore.QThread.idealThreadCount(), 1)
        self.jobs = QtWidgets.QSpinBox(minimum=1, maximum=n_max, value=min(max(int(saved.get("jobs", 1)), 1), n_max))

    def _format_changed(self) -> None:
        new = default_out_dir(self.scene, self.fmt.currentData())
        if self.out.text().strip() == self._default_out:     # not edited by the user: follow the format
            self.out.setText(new)
        self._default_out = new

    def _browse(self) -> None:
        d = QtWidgets.QFileDialog.getExistingDirectory(self, "Export folder", self.out.text())
        if d:
            self.out.setText(d)

    def update_counts(self) -> None:
        """The line saying how many windows will be written and how many are verified."""
        by_events = self.window_events.value() > 0
        try:
            n, verified = window_counts(self.scene, window_us=int(round(self.window_ms.value() * 1000)),
                                        window_events=self.window_events.value() or None,
                                        include_stale=self.include_stale.isChecked())
        except Exception as exc:    # noqa: BLE001 (a count is a hint: the export itself reports the error)
            self.counts.setText(f"cannot count the windows: {exc}")
            return
        size = f"of {self.window_events.value():,} events" if by_events else f"of {self.window_ms.value():g} ms"
        v = "?" if verified is None else f"{verified:,}"
        if self.only_verified.isChecked():
            text = f"<b>{v}</b> windows will be written: the verified ones of {n:,} windows {size}"
        else:
            text = f"<b>{n:,}</b> windows {size} will be written ({v} of them verified)"
        self.counts.setText(text)
        self.n_windows, self.n_verified = n, verified

    def options(self) -> dict:
        opts = {"fmt": self.fmt.currentData(), "out_dir": self.out.text().strip(),
                "label_at": self.label_at.currentData(),
                "only_verified": self.only_verified.isChecked(), "jobs": self.jobs.value(),
                "include_stale": self.only_verified.isChecked() and self.include_stale.isChecked()}
        if self.window_events.value() > 0:
            opts["window_events"] = self.window_events.value()
        else:
            opts["window_us"] = int(round(self.window_ms.value() * 1000))
        return opts

    def remember(self) -> None:
        """Store format and options (not the folder, which follows the scene) for the next export."""
        self.settings.set_export_options({
            "fmt": self.fmt.currentData(), "window_ms": self.window_ms.value(),
            "window_events": self.window_events.value(), "label_at": self.label_at.currentData(),
            "only_verified": self.only_verified.isChecked(), "include_stale": self.include_stale.isChecked(),
            "jobs": self.jobs.value()})


def open_folder(path) -> bool:
    """Show ``path`` in the desktop's file manager."""
    return QtGui.QDesktopServices.openUrl(QtCore.QUrl.fromLocalFile(str(path)))


def export_done_box(parent, summary, text: str) -> QtWidgets.QMessageBox:
    """The message when an export is done (not modal: the window stays usable): ``text`` and the output
    folder, with "Open folder" and "Close"."""
    box = QtWidgets.QMessageBox(QtWidgets.QMessageBox.Information, "Export done", text, parent=parent)
    box.setInformativeText(f"Folder: {summary.out_dir}")
    box.setModal(False)
    box.setAttribute(QtCore.Qt.WA_DeleteOnClose, True)
    box.open_button = box.addButton("Open folder", QtWidgets.QMessageBox.ActionRole)
    box.addButton(QtWidgets.QMessageBox.Close)
    box.open_button.clicked.connect(lambda: open_folder(summary.out_dir))    # then the box closes, as on any button
    box.show()
    return box
