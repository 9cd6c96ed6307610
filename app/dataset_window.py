"""The dataset view: a window with the scenes of a dataset in a sortable table (issue 13 point 5).

A separate top-level window beside the main window, not a page of it: the table stays in sight while a
scene is being checked (side by side, or on a second screen), and the main window keeps its layout, its
docks and its one-session-per-window model unchanged. Double-clicking a row opens that scene in the main
window (with the dataset's shared defaults); File -> Back to dataset brings the table forward again.

* Rows are read in a background :class:`~evpose.app.workers.Job` from the scene files, opened locally with
  the dataset's defaults (:func:`scene_row`: ``evpose info`` facts, the unlabeled share of the 10 ms
  windows and :func:`~evpose.core.dataset.tasks.review_progress`); the UI never waits for them.
* A row is read again whenever that scene's ``corrections.json`` changes on disk (a save from the main
  window, or from any other program): a watcher on the scene folders compares the file's signature.
* *Score all* and *Sync all (estimate only)* run :func:`~evpose.core.dataset.batch.map_scenes` on a Dask
  ``LocalCluster`` of N worker processes (:func:`~evpose.core.dataset.cluster.open_client`) in a Job, with a
  progress bar and Cancel; the results fill the mean-score and clock-estimate columns. Cancel takes effect
  when the cluster has started or the next scene completes (Dask cancels the tasks not yet done).
* *Triage all* fills the rank, cause and per-object scores of ``evpose dataset report``. *Refine (dry run)* runs
  the joint fit of ``evpose dataset refine`` (never applied) on the scenes the last triage flags for a cause it
  fixes (every scene before a triage); each row shows its proposed change with its sigma. The detail pane below the
  table shows the selected scene in full (a failure's whole message, the reasons, the next command, the proposal
  and what it keeps) with *Apply proposal* (:func:`~evpose.core.align.refine_run.apply_proposal`: one undo step,
  refused when the corrections changed since the proposal) and *Reject proposal* (nothing written).
* *Export…* runs ``evpose dataset export`` on the cluster, with the same progress bar and Cancel.
* The *Campaign fit* box beside the detail pane shows the groups' fit of ``evpose dataset refine --joint --shared …
  --apply`` (``campaign_fit.json``, :mod:`~evpose.core.dataset.campaign_view`), read again with the rows and when
  the dataset's folder changes.
"""
from __future__ import annotations

import os
from pathlib import Path

from PySide6 import QtCore, QtGui, QtWidgets

from evpose.app.workers import Job
from evpose.core.data.events import Cancelled
from evpose.core.dataset.batch import BatchResult, failure_text
from evpose.core.dataset.campaign import CAMPAIGN_FILENAME
from evpose.core.dataset.campaign_view import campaign_lines
from evpose.core.dataset.dataset import Dataset
from evpose.core.dataset.tasks import TRIAGE_WINDOW_US
from evpose.core.errors import InputError
from evpose.widgets.campaign_panel import CampaignPanel
from evpose.widgets.dataset_table import DatasetTable
from evpose.widgets.scene_detail import SceneDetail

__all__ = ["DatasetWindow", "detail_text", "open_dataset", "open_dataset_dialog", "refine_values", "scene_row",
           "score_values", "show_dataset", "sync_values"]

#: A burst of directory events (an atomic save is a temp file and a rename) is read once, after this pause.
REFRESH_DEBOUNCE_MS = 200


def scene_row(path: str, defaults) -> dict:
    """The table's values of one scene, read from its files (no Qt: runs on a worker thread).

    Returns
    -------
    dict
        ``n_events``, ``duration_s`` (s), ``n_objects``, ``unlabeled_share`` (fraction of the
        :data:`~evpose.core.dataset.tasks.TRIAGE_WINDOW_US` windows whose label time has no pose under the
        clock in effect), ``clock_ms`` / ``prior_ms`` (clock offset in effect / of scene.toml, ms),
        the :func:`~evpose.core.dataset.tasks.review_progress` fields, ``path``, ``status``.
    """
    import numpy as np

    from evpose.core.data.scene import Scene
    from evpose.core.data.scene_summary import scene_info
    from evpose.core.dataset.tasks import review_progress
    from evpose.core.export.windows import build_windows

    scene = Scene.open(path, defaults=defaults)
    try:
        info = scene_info(scene)
        windows = build_windows(scene.events, window_us=TRIAGE_WINDOW_US)
        t_label_us = np.array([w.t_label_us for w in windows], np.int64)
        if not scene.has_poses:                      # an event-only scene: no window has a label
            no_pose = len(windows)
        else:
            no_pose = sum(r is not None for r in scene.unlabeled_reasons(t_label_us)) if len(windows) else 0
        review = review_progress(scene, TRIAGE_WINDOW_US, windows)     # the same tiling, built once
    finally:
        scene.close()
    clock = info["clock"]
    return {"path": info["path"], "n_events": info["n_events"], "duration_s": info["duration_s"],
            "n_objects": len(info["objects"]), "unlabeled_share": no_pose / len(windows) if windows else None,
            "clock_ms": clock["offset_us"] / 1000.0, "prior_ms": clock["prior_offset_us"] / 1000.0,
            **review, "status": "ok", "failed": False}


def score_values(doc: dict) -> dict:
    """Table values of one ``evpose score --json`` document: ``mean_score``, the mean over the objects of
    their mean window score (objects without a scored window left out; None when none scored)."""
    means = [s["mean_score"] for s in doc["summary"].values() if s["mean_score"] is not None]
    return {"mean_score": sum(means) / len(means) if means else None}


def sync_values(doc: dict) -> dict:
    """Table values of one ``evpose sync --json`` document: the rate estimate ``estimate_ms`` ± ``estimate_std_ms``
    (ms; None without an estimate) and whether it is ``estimate_reliable``."""
    est, std = doc.get("offset_us"), doc.get("offset_std_us")
    return {"estimate_ms": None if est is None else est / 1000.0,
            "estimate_std_ms": None if std is None else std / 1000.0, "estimate_reliable": bool(doc.get("reliable"))}


def triage_values(doc: dict) -> dict:
    """Table values of the triage document ``doc`` (:func:`evpose.core.dataset.triage.triage`), per scene name:
    ``rank`` and ``cause`` of the scenes it ranks (None: nothing flagged), ``reasons`` (every flag, for the
    tooltip), ``next`` (the command to run) and ``object_scores`` (each object's median score, not averaged away;
    ``lowest_score`` sorts them)."""
    ranked = {e["scene"]: e for e in doc.get("scenes_ranked") or []}
    out = {}
    for r in doc["scenes"]:
        e = ranked.get(r["name"])
        medians = {n: s["quantiles"]["p50"] for n, s in (r.get("scores") or {}).items() if s.get("quantiles")}
        looked = r.get("looked_at") or {}
        text = " · ".join(f"{n} {m:.2f}" + (" (looked at)" if n in looked else "") for n, m in medians.items())
        out[r["name"]] = {"rank": None if e is None else e["rank"], "cause": None if e is None else e["cause"],
                          "reasons": [] if e is None else list(e["reasons"]), "next": None if e is None else e["next"],
                          "object_scores": text or None, "lowest_score": min(medians.values(), default=None)}
    return out


def refine_values(doc: dict) -> dict:
    """Table values of one dry-run ``evpose refine --joint --json`` document: ``proposal`` (the changes with their
    sigma, or why nothing would change), ``proposal_state`` ("proposed" or "none") and the document itself
    (``proposal_doc``, what Apply stores)."""
    values = [c for c in doc.get("changes") or [] if c["part"] != "sigma"]   # not the confirmed parts' sigma
    if values:
        return {"proposal": "; ".join(c["text"] for c in values), "proposal_state": "proposed", "proposal_doc": doc}
    text = "no change (within sigma)" if doc.get("accepted") else f"start kept: {doc.get('reason') or 'not accepted'}"
    return {"proposal": text, "proposal_state": "none", "proposal_doc": doc}


def detail_text(name: str, row: dict) -> str:
    """Everything the dataset view knows about scene ``name`` (its table values ``row``) as plain text, in full."""
    lines = [f"{name}    {row.get('path') or ''}".rstrip()]
    status = row.get("status")
    if status:
        lines.append(("FAILED: " if row.get("failed") else "status: ") + str(status))
    if row.get("cause"):
        lines.append(f"triage: rank {row.get('rank')}, cause {row['cause']}")
        lines += [f"  - {r}" for r in row.get("reasons") or []]
        if row.get("next"):
            lines.append(f"  next: {row['next']}")
    elif row.get("rank") is None and "cause" in row:
        lines.append("triage: nothing flagged")
    if row.get("object_scores"):
        lines.append(f"object scores (median): {row['object_scores']}")
    doc = row.get("proposal_doc")
    if row.get("proposal"):
        lines.append(f"proposal: {row['proposal']}")
    if doc is not None:
        lines += [f"  kept: {k}" for k in doc.get("kept") or []]
        lines += [f"  held: {n}: {why}" for n, why in (doc.get("held") or {}).items()]
        lines += [f"  note: {n}" for n in doc.get("notes") or []]
    if row.get("exported"):
        lines.append(f"export: {row['exported']}")
    return "\n".join(lines)


def _signature(path: Path):
    """What tells a changed ``corrections.json`` (None when absent)."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size, st.st_ino


class _RowSignal(QtCore.QObject):
    row = QtCore.Signal(str, object, int)      # scene name, values, request serial


class DatasetWindow(QtWidgets.QMainWindow):
    """The table of ``dataset``'s scenes; ``main`` is the :class:`~evpose.app.main_window.MainWindow` that
    opens a scene when its row is double-clicked."""

    #: event windows of each scene's joint fit in Refine (dry run); None: ``evpose refine --joint``'s default
    refine_windows: int | None = None

    def __init__(self, main, dataset: Dataset):
        super().__init__(None)
        self.main = main
        self.dataset = dataset
        self.jobs: list[Job] = []
        self.batch_job: Job | None = None
        self.last_batch: BatchResult | None = None
        self.last_triage: dict | None = None     # the triage document of the last Triage all
        self._serial = 0
        self._requested: dict[str, int] = {}
        self._pending_refresh: set[str] = set()
        self._by_dir = {str(ref.path): ref for ref in dataset.scenes}
        self._seen = {ref.name: _signature(ref.path / "corrections.json") for ref in dataset.scenes}
        # parentless and captured by each reading job: a job still running when this window is deleted emits on
        # a live object (a child would be deleted with the window, and emitting on it from the job's thread crashed)
        self._rows = _RowSignal()
        self._rows.row.connect(self._row_ready)
        self.setWindowTitle(f"evpose dataset — {dataset.name} ({len(dataset)} scenes)")

        self.table = DatasetTable()
        self.table.set_scenes([ref.name for ref in dataset.scenes])
        self.table.sceneActivated.connect(self.open_row)
        self.table.sceneSelected.connect(self._show_detail)
        self.setCentralWidget(self.table)
        self.detail = SceneDetail()
        self.detail.applyRequested.connect(self.apply_proposal)
        self.detail.rejectRequested.connect(self.reject_proposal)
        dock = QtWidgets.QDockWidget("Details", self)
        dock.setObjectName("detail_dock")
        dock.setFeatures(QtWidgets.QDockWidget.NoDockWidgetFeatures)
        self.campaign = CampaignPanel()             # beside the detail pane: the groups' campaign_fit.json
        split = QtWidgets.QSplitter(QtCore.Qt.Horizontal)
        split.addWidget(self.detail)
        split.addWidget(self.campaign)
        split.setSizes([740, 560])
        dock.setWidget(split)
        self.detail.setMinimumHeight(6 * self.fontMetrics().height())
        self.addDockWidget(QtCore.Qt.BottomDockWidgetArea, dock)
        self.detail_dock = dock
        self._build_toolbar()
        self.quit_action = QtGui.QAction("Quit", self, shortcut=QtGui.QKeySequence.Quit)
        self.quit_action.triggered.connect(self.quit_app)
        self.addAction(self.quit_action)
        self.statusBar().showMessage(f"{dataset.root} — double-click a scene to open it")

        self._campaign_changed = False
        self.watcher = QtCore.QFileSystemWatcher([str(ref.path) for ref in dataset.scenes] + [str(dataset.root)], self)
        self.watcher.directoryChanged.connect(self._folder_changed)
        self._refresh_timer = QtCore.QTimer(self, singleShot=True, interval=REFRESH_DEBOUNCE_MS)
        self._refresh_timer.timeout.connect(self._refresh_changed)
        row_px = self.table.verticalHeader().defaultSectionSize()
        detail_px = 10 * self.fontMetrics().height()
        self.resize(1300, min(190 + row_px * max(len(dataset), 4) + detail_px, 700))      # fits a 1366x768 screen
        self.resizeDocks([dock], [detail_px], QtCore.Qt.Vertical)

    # ------------------------------------------------------------------ layout
    def _build_toolbar(self) -> None:
        bar = self.addToolBar("Dataset")
        bar.setObjectName("dataset_toolbar")
        bar.setMovable(False)
        self.reload_action = bar.addAction("Reload", lambda: self.load_rows())
        self.reload_action.setToolTip("read every scene's facts and review progress again")
        bar.addSeparator()
        self.score_action = bar.addAction("Score all", lambda: self.run_batch("score"))
        self.score_action.setToolTip("alignment score of every 10 ms window of every scene, on a local Dask cluster")
        self.sync_action = bar.addAction("Sync all (estimate only)", lambda: self.run_batch("sync"))
        self.sync_action.setToolTip("event-rate clock estimate of every scene (never applied), on a local Dask cluster")
        self.triage_action = bar.addAction("Triage all", lambda: self.run_batch("triage"))
        self.triage_action.setToolTip("the triage report's ranking of every scene: its cause, its reasons, the next "
                                      "command and each object's median score (evpose dataset report)")
        self.edges_check = QtWidgets.QCheckBox("with edges")
        self.edges_check.setToolTip("Triage all also fits clock and poses from the event edges (evpose dataset report "
                                    "--edges): verdicts on each object's pose and the camera mounting; slower")
        bar.addWidget(self.edges_check)
        self.refine_action = bar.addAction("Refine (dry run)", lambda: self.run_batch("refine"))
        self.refine_action.setToolTip("joint fit of clock and poses (evpose dataset refine, never applied) on the "
                                      "scenes the last Triage all flags for clock, pose or mounting (every scene "
                                      "before a triage); Apply or Reject each proposal in the detail pane")
        self.export_action = bar.addAction("Export…", self.export_dialog)
        self.export_action.setToolTip("evpose dataset export of every scene (BOP, E-POSE or HDF5) on the cluster")
        bar.addWidget(QtWidgets.QLabel("  workers "))
        self.workers_spin = QtWidgets.QSpinBox(minimum=1, maximum=max(os.cpu_count() or 1, 1))
        self.workers_spin.setValue(min(os.cpu_count() or 1, max(len(self.dataset), 1)))
        self.workers_spin.setToolTip("worker processes of the local Dask cluster")
        bar.addWidget(self.workers_spin)
        bar.addSeparator()
        self.progress = QtWidgets.QProgressBar(minimum=0, maximum=1000)
        self.progress.setFixedWidth(260)
        self.progress.setFormat("")
        self.progress.setTextVisible(True)
        bar.addWidget(self.progress)
        self.cancel_button = QtWidgets.QPushButton("Cancel")
        self.cancel_button.setEnabled(False)
        self.cancel_button.clicked.connect(self.cancel_batch)
        bar.addWidget(self.cancel_button)

    # ------------------------------------------------------------------ rows
    def load_rows(self, names: list[str] | None = None) -> Job:
        """Read the rows of ``names`` (default: every scene) in a background Job; each row fills as it arrives."""
        refs = [self.dataset.scene(n) for n in names] if names is not None else list(self.dataset.scenes)
        self._serial += 1
        serial = self._serial
        for ref in refs:
            self._requested[ref.name] = serial
            if names is None:
                self.table.set_values(ref.name, {"status": "loading…"})
        self.show_campaign()
        defaults = self.dataset.defaults or None
        rows = self._rows                   # keeps the signal's object alive while the job runs

        def work(progress, cancel):
            for k, ref in enumerate(refs):
                if cancel():
                    raise Cancelled("reading the scenes cancelled")
                try:
                    values = scene_row(str(ref.path), defaults)
                except (InputError, OSError) as exc:
                    values = {"status": failure_text(exc), "failed": True}
                rows.row.emit(ref.name, values, serial)
                progress((k + 1) / len(refs), ref.name)
            return len(refs)

        return self._start(Job(work))

    def show_campaign(self) -> None:
        """Read ``campaign_fit.json`` beside ``dataset.toml`` again into the Campaign fit box (small: read here)."""
        self.campaign.show_lines(*campaign_lines(self.dataset.root), str(self.dataset.root / CAMPAIGN_FILENAME))

    def _row_ready(self, name: str, values: dict, serial: int) -> None:
        if serial < self._requested.get(name, 0):
            return                          # an older read finished after a newer one was asked for
        self._set(name, values)

    def _set(self, name: str, values: dict) -> None:
        """Update scene ``name``'s row (and the detail pane when it shows that scene)."""
        self.table.set_values(name, values)
        if self.detail.name == name:
            self._show_detail(name)

    def _show_detail(self, name: str) -> None:
        row = self.table.values(name)
        self.detail.show_scene(name, detail_text(name, row), row.get("proposal_state") == "proposed")

    def rows_loaded(self) -> bool:
        """True when no row is still being read."""
        return not self.jobs and all(self.table.values(n).get("status") not in ("", "loading…")
                                     for n in self._requested)

    def _folder_changed(self, folder: str) -> None:
        ref = self._by_dir.get(str(Path(folder)))
        if ref is None:
            self._campaign_changed = True             # the dataset's folder: campaign_fit.json may have changed
            self._refresh_timer.start()
            return
        sig = _signature(ref.path / "corrections.json")
        if sig != self._seen.get(ref.name):
            self._seen[ref.name] = sig
            self._pending_refresh.add(ref.name)
            self._refresh_timer.start()

    def _refresh_changed(self) -> None:
        names, self._pending_refresh = sorted(self._pending_refresh), set()
        if names:
            self.statusBar().showMessage(f"{', '.join(names)}: corrections changed on disk, row read again", 5000)
            self.load_rows(names)                   # reads campaign_fit.json again too
        elif self._campaign_changed:
            self.show_campaign()
        self._campaign_changed = False

    # ------------------------------------------------------------------ open a scene
    def open_row(self, name: str):
        """Open scene ``name`` in the main window (with the dataset's defaults); returns the session or None."""
        ref = self.dataset.scene(name)
        self.main.dataset_window = self
        self.main.show()
        session = self.main.controller.open_scene(ref.path, defaults=self.dataset.defaults or None)
        if session is not None:
            self.main.raise_()
            self.main.activateWindow()
        return session

    # ------------------------------------------------------------------ dataset jobs
    def run_batch(self, kind: str, workers: int | None = None, **export) -> Job | None:
        """Run ``score``, ``sync`` (the rate estimate, never applied), ``triage``, ``refine`` (dry run) or ``export``
        (keywords ``fmt`` and ``out``) over the dataset's scenes on a local Dask cluster of ``workers`` processes
        (default: the spin box) in a background Job; None when one already runs or nothing is to do."""
        from evpose.core.align.refine_run import JointRunOptions
        from evpose.core.align.sync_run import SyncOptions
        from evpose.core.dataset.batch import map_scenes
        from evpose.core.dataset.cluster import ClusterSpec, open_client
        from evpose.core.dataset.tasks import refine_task, score_task, sync_task, triage_task

        if self.batch_job is not None:
            return None
        dataset = self._batch_scope(kind)
        if dataset is None:
            return None
        spec = ClusterSpec(workers=int(workers or self.workers_spin.value()))
        if kind == "export":
            from evpose.core.dataset.export import export_dataset

            def run(client, progress, cancel):
                return export_dataset(client, dataset, export["fmt"], export["out"], progress=progress, cancel=cancel)
        else:
            refine = JointRunOptions(apply=False, windows=self.refine_windows or JointRunOptions.windows)
            fn, args = {"score": (score_task, (TRIAGE_WINDOW_US,)), "sync": (sync_task, (SyncOptions(apply=False),)),
                        "triage": (triage_task, (SyncOptions(apply=False, edges=self.edges_check.isChecked()),)),
                        "refine": (refine_task, (refine,))}[kind]

            def run(client, progress, cancel):
                return map_scenes(client, dataset, fn, *args, label=kind, progress=progress, cancel=cancel)

        def work(progress, cancel):
            progress(0.0, f"starting a {spec.describe()}…")
            with open_client(spec) as client:
                if cancel():
                    raise Cancelled(f"{dataset.root}: {kind} cancelled")
                return run(client, progress, cancel)

        job = Job(work)
        job.signals.progress.connect(self._batch_progress)
        job.signals.finished.connect(lambda result: self._batch_done(kind, result, export))
        job.signals.failed.connect(lambda message, details: self._batch_failed(kind, message, details))
        self.batch_job = job
        self._set_busy(True, f"{kind}: starting…")
        return self._start(job)

    def _batch_scope(self, kind: str) -> Dataset | None:
        """The scenes a batch runs on: Refine takes those the last triage flags for a cause it fixes (all before a
        triage; None and a status line when it flags none)."""
        if kind != "refine" or self.last_triage is None:
            return self.dataset
        from evpose.core.dataset.report_files import FIXABLE, ranked_for

        names = ranked_for(self.last_triage, FIXABLE["refine"])
        if not names:
            self.statusBar().showMessage("refine: the last triage flags no scene for clock, pose or mounting", 20_000)
            return None
        return self.dataset.only(names)

    def export_dialog(self) -> Job | None:
        """Ask for the format and the output folder, then :meth:`run_batch` ``export``."""
        fmt, ok = QtWidgets.QInputDialog.getItem(self, "Export the dataset", "format", ["epose", "bop", "h5"], 0, False)
        if not ok:
            return None
        out = QtWidgets.QFileDialog.getExistingDirectory(self, "Export into folder")
        if not out:
            return None
        try:
            from evpose.core.dataset.export import check_dataset_export

            check_dataset_export(self.dataset, out, fmt)          # refused before a cluster starts
        except InputError as exc:
            self.main.controller.error("Cannot export the dataset", str(exc))
            return None
        return self.run_batch("export", fmt=fmt, out=out)

    # ------------------------------------------------------------------ proposals
    def apply_proposal(self, name: str) -> Job | None:
        """Store scene ``name``'s proposal (:func:`~evpose.core.align.refine_run.apply_proposal`) in a Job: one undo
        step in its ``corrections.json``; refused in one line when the corrections changed since the proposal."""
        from evpose.core.align.refine_run import apply_proposal

        doc = self.table.values(name).get("proposal_doc")
        if not doc or not doc.get("changes"):
            return None
        ref = self.dataset.scene(name)
        dataset = self.dataset

        def work(progress, cancel):
            scene = dataset.open_scene(ref)
            try:
                return apply_proposal(scene, dict(doc))
            finally:
                scene.close()

        text = self.table.values(name).get("proposal")
        job = Job(work)
        job.signals.finished.connect(lambda line: self._proposal_applied(name, text, line))
        job.signals.failed.connect(lambda message, _details: self._proposal_failed(name, message))
        self._set(name, {"proposal": f"applying: {text}", "proposal_state": "applying"})
        return self._start(job)

    def _proposal_applied(self, name: str, text: str, line: str) -> None:
        self._set(name, {"proposal": f"applied: {text}", "proposal_state": "applied", "proposal_doc": None})
        self.statusBar().showMessage(f"{name}: {line}", 20_000)

    def _proposal_failed(self, name: str, message: str) -> None:
        doc = self.table.values(name).get("proposal_doc") or {}
        self._set(name, {**refine_values(doc), "proposal": f"not applied: {message}", "proposal_state": "stale"})
        self.statusBar().showMessage(f"{name}: not applied: {message}", 20_000)

    def reject_proposal(self, name: str) -> None:
        """Drop scene ``name``'s proposal; nothing is written."""
        self._set(name, {"proposal": "rejected (nothing written)", "proposal_state": "rejected", "proposal_doc": None})
        self.statusBar().showMessage(f"{name}: proposal rejected; nothing written", 10_000)

    def cancel_batch(self) -> None:
        if self.batch_job is not None:
            self.batch_job.cancel()
            self.cancel_button.setEnabled(False)
            self.progress.setFormat("cancelling…")

    def _batch_progress(self, fraction: float, message: str) -> None:
        self.progress.setValue(int(fraction * 1000))
        if not self.batch_job.cancelled:
            self.progress.setFormat(message)

    def _batch_done(self, kind: str, result: BatchResult, export: dict | None = None) -> None:
        self.last_batch = result
        if kind == "export":
            for name, doc in result.scenes.items():
                self._set(name, {"exported": f"{doc.get('written', 0)} windows written, {doc.get('skipped_complete', 0)} "
                                             f"already complete, to {Path(export['out']) / name} ({export['fmt']})"})
        elif kind == "triage":
            from evpose.core.dataset.triage import triage

            refs = self.dataset.scenes
            self.last_triage = triage(result.to_json(), order=[r.name for r in refs],
                                      paths={r.name: str(r.path) for r in refs})
            for name, v in triage_values(self.last_triage).items():
                self._set(name, v)
        else:
            values = {"score": score_values, "sync": sync_values, "refine": refine_values}[kind]
            for name, doc in result.scenes.items():
                self._set(name, values(doc))
        for name, error in result.failed.items():
            self._set(name, {"status": f"{kind} failed: {error}", "failed": True})
        self._set_busy(False, "")
        self.statusBar().showMessage(f"{kind}: {len(result.scenes)} scenes done, {len(result.failed)} failed "
                                     f"in {result.runtime_s:.1f} s", 20_000)

    def _batch_failed(self, kind: str, message: str, details: str) -> None:
        self._set_busy(False, "")
        if message == "cancelled":
            self.statusBar().showMessage(f"{kind} cancelled", 10_000)
        else:
            self.main.controller.error(f"Dataset {kind} failed", message, details)
            self.statusBar().showMessage(f"{kind} failed: {message}", 20_000)

    def _set_busy(self, busy: bool, text: str) -> None:
        if not busy:
            self.batch_job = None
        for act in (self.score_action, self.sync_action, self.triage_action, self.refine_action, self.export_action):
            act.setEnabled(not busy)
        self.workers_spin.setEnabled(not busy)
        self.edges_check.setEnabled(not busy)
        self.cancel_button.setEnabled(busy)
        self.progress.setValue(0)
        self.progress.setFormat(text)

    def _start(self, job: Job) -> Job:
        self.jobs.append(job)

        def forget(*_):
            if job in self.jobs:
                self.jobs.remove(job)

        job.signals.finished.connect(forget)
        job.signals.failed.connect(forget)
        return job.start()

    def quit_app(self) -> bool:
        """Ctrl+Q here as in the main window: close the main window (which asks about unsaved corrections), then
        this one; False when the main window stayed open."""
        if not self.main.close():
            return False
        self.close()
        return True

    # ------------------------------------------------------------------ screenshots, close
    def save_screenshot(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        QtWidgets.QApplication.processEvents()
        if not self.grab().toImage().save(str(path)):
            raise OSError(f"{path}: could not write the screenshot")
        return path

    def closeEvent(self, event: QtGui.QCloseEvent) -> None:
        for job in list(self.jobs):
            job.cancel()
        event.accept()


def open_dataset(main, path) -> DatasetWindow | None:
    """Open the dataset at ``path`` in a dataset window beside ``main`` (replacing an open one); errors go to
    ``main``'s error dialog (None returned)."""
    try:
        dataset = Dataset.open(path)
    except InputError as exc:
        main.controller.error("Cannot open the dataset", str(exc))
        return None
    old = getattr(main, "dataset_window", None)
    if old is not None:
        old.close()
    win = DatasetWindow(main, dataset)
    win.setWindowIcon(main.windowIcon())
    main.dataset_window = win
    win.show()
    win.load_rows()
    return win


def open_dataset_dialog(main) -> DatasetWindow | None:
    path = QtWidgets.QFileDialog.getExistingDirectory(main, "Open dataset folder")
    return open_dataset(main, path) if path else None


def show_dataset(main) -> None:
    """Bring the dataset window of ``main`` forward (File -> Back to dataset)."""
    win = getattr(main, "dataset_window", None)
    if win is not None:
        win.show()
        win.raise_()
        win.activateWindow()
