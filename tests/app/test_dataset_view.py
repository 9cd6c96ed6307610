"""The dataset view (issue 13 point 5): the table of a 3-scene dataset (copies of the tiny scene with different
clock priors), sorting by a numeric column, double-click opens the scene in the main window, a save updates
the row, Score all / Sync all on a LocalCluster of 1 worker fill their columns, and Cancel stops a job."""
from __future__ import annotations

import re
import shutil

import pytest
from PySide6 import QtCore, QtGui

from evpose.core.dataset.tasks import review_progress, score_task
from evpose.widgets.dataset_table import SORT_ROLE

#: scene name -> clock prior (µs) written into its scene.toml; -400 ms moves the first ~120 ms of events before
#: the trajectory's first pose (it starts 280 ms before the first event).
PRIORS_US = {"s1": 20_000, "s2": 5_000, "s3": -400_000}


@pytest.fixture
def dataset_dir(tiny_scene_dir, tmp_path):
    root = tmp_path / "ds"
    for name, prior_us in PRIORS_US.items():
        shutil.copytree(tiny_scene_dir, root / name)
        toml = root / name / "scene.toml"
        text, n = re.subn(r"\[clock\]\noffset_us = 0\n", f"[clock]\noffset_us = {prior_us}\n", toml.read_text())
        assert n == 1
        toml.write_text(text)
    return root


@pytest.fixture
def dwin(qtbot, window, dataset_dir):
    from evpose.app.dataset_window import open_dataset

    win = open_dataset(window, dataset_dir)
    assert win is not None and window.dataset_window is win

    def before_close(w):                # pytest-qt closes and deletes it before fixtures' teardown code runs
        w.cancel_batch()
        qtbot.waitUntil(lambda: not w.jobs, timeout=60_000)

    qtbot.addWidget(win, before_close_func=before_close)
    qtbot.waitUntil(win.rows_loaded, timeout=60_000)
    return win


def _scene(dataset_dir, name):
    from evpose.core.data.scene import Scene

    return Scene.open(dataset_dir / name)


def test_table_shows_each_scenes_facts(dwin, dataset_dir):
    t = dwin.table
    assert t.shown_names() == ["s1", "s2", "s3"]
    shares = {}
    for name, prior_us in PRIORS_US.items():
        v = t.values(name)
        scene = _scene(dataset_dir, name)
        try:
            assert v["n_events"] == scene.events.n_events
            assert v["duration_s"] == pytest.approx((scene.events.t_last_us - scene.events.t_first_us) * 1e-6)
            assert v["n_objects"] == len(scene.object_names) == 3
            assert v["verified_fraction"] == review_progress(scene)["verified_fraction"] == 0.0
        finally:
            scene.close()
        assert v["clock_ms"] == v["prior_ms"] == prior_us / 1000.0
        # the unlabeled share is the score command's (same 10 ms windows, same clock)
        score = score_task(str(dataset_dir / name), None)
        assert v["unlabeled_share"] == pytest.approx(score["unlabeled"] / score["n_windows"])
        shares[name] = v["unlabeled_share"]
        assert v["status"] == "ok"
    assert shares["s3"] > 0.05 and shares["s1"] == 0.0      # the -400 ms prior leaves windows without a pose
    # what the user sees: formatted text
    col = t.column_of("clock_ms")
    assert t.model().index(t.row_of("s2"), col).data() == "+5.0"
    assert t.model().index(t.row_of("s3"), t.column_of("unlabeled_share")).data() == f"{100 * shares['s3']:.1f}"


def test_sort_by_a_numeric_column(qtbot, dwin):
    t = dwin.table
    t.sortByColumn(t.column_of("clock_ms"), QtCore.Qt.AscendingOrder)
    assert t.shown_names() == ["s3", "s2", "s1"]                  # -400 < 5 < 20 (as text "20.0" < "5.0")
    t.sortByColumn(t.column_of("clock_ms"), QtCore.Qt.DescendingOrder)
    assert t.shown_names() == ["s1", "s2", "s3"]
    # an empty cell (no score yet) sorts last in both directions
    t.set_values("s2", {"mean_score": 0.3})
    t.set_values("s3", {"mean_score": 0.1})
    for order, expected in ((QtCore.Qt.AscendingOrder, ["s3", "s2", "s1"]),
                            (QtCore.Qt.DescendingOrder, ["s2", "s3", "s1"])):
        t.sortByColumn(t.column_of("mean_score"), order)
        assert t.shown_names() == expected


def _double_click(qtbot, table, name):
    idx = table.model().index(table.row_of(name), 0)
    table.scrollTo(idx)
    pos = table.visualRect(idx).center()
    qtbot.mouseClick(table.viewport(), QtCore.Qt.LeftButton, pos=pos)    # a real double click: press first
    qtbot.mouseDClick(table.viewport(), QtCore.Qt.LeftButton, pos=pos)


def test_double_click_opens_the_scene_and_a_save_updates_the_row(qtbot, window, dwin, dataset_dir):
    t = dwin.table
    t.sortByColumn(t.column_of("clock_ms"), QtCore.Qt.AscendingOrder)     # rows no longer in dataset order
    _double_click(qtbot, t, "s1")
    s = window.session
    assert s is not None and s.scene.root == (dataset_dir / "s1").resolve()
    assert window.windowTitle().startswith("evpose — ")

    # edit: a clock correction and the whole recording verified, then save
    t0_us, t1_us = s.time_range
    s.set_offset_correction_us(7_000)
    n_windows = t.values("s1")["n_windows"]
    s.add_review("verified", t0_us, t0_us + 10_000 * n_windows)          # the whole 10 ms grid
    window.actions_by_name["save"].trigger()
    assert not s.dirty

    qtbot.waitUntil(lambda: t.values("s1")["clock_ms"] == 27.0, timeout=20_000)
    qtbot.waitUntil(lambda: t.values("s1")["verified_fraction"] == 1.0, timeout=20_000)
    assert t.values("s2")["clock_ms"] == 5.0                     # the other rows are left alone
    # back to the dataset: the window comes forward with the updated row
    window.back_to_dataset_action.trigger()
    assert dwin.isVisible()
    assert t.model().index(t.row_of("s1"), t.column_of("verified_fraction")).data() == "100.0"


def test_open_row_uses_the_dataset_defaults(qtbot, window, dataset_dir):
    """A dataset.toml whose scenes lack [clock] gets its shared clock default in the table and the main window."""
    from evpose.app.dataset_window import open_dataset

    for name in PRIORS_US:
        toml = dataset_dir / name / "scene.toml"
        toml.write_text(re.sub(r"\[clock\]\noffset_us = -?\d+\nskew_ppm = 0.0\n", "", toml.read_text()))
    (dataset_dir / "dataset.toml").write_text('format = "evpose-dataset/1"\nscenes = ["s1", "s2"]\n'
                                              "[defaults.clock]\noffset_us = 12000\n")
    win = open_dataset(window, dataset_dir)
    qtbot.addWidget(win)
    qtbot.waitUntil(win.rows_loaded, timeout=60_000)
    assert win.table.shown_names() == ["s1", "s2"]
    assert win.table.values("s2")["prior_ms"] == 12.0
    session = win.open_row("s2")
    assert session is not None and session.scene.clock.offset_us == 12_000
    win.close()


def test_open_dataset_error_is_one_message(window, tmp_path):
    from evpose.app.dataset_window import open_dataset

    assert open_dataset(window, tmp_path) is None
    assert "not a dataset" in window.last_error and str(tmp_path) in window.last_error


def test_score_and_sync_all_on_a_local_cluster(qtbot, dwin, dataset_dir):
    job = dwin.run_batch("score", workers=1)
    assert job is not None and dwin.run_batch("score", workers=1) is None     # one dataset job at a time
    assert dwin.cancel_button.isEnabled() and not dwin.score_action.isEnabled()
    qtbot.waitUntil(lambda: dwin.batch_job is None, timeout=120_000)
    assert dwin.last_batch is not None and not dwin.last_batch.failed
    for name in PRIORS_US:
        summary = score_task(str(dataset_dir / name), None)["summary"]       # evpose score SCENE --json
        expected = [summary[o]["mean_score"] for o in ("box", "cylinder", "flatbox")]
        assert dwin.table.values(name)["mean_score"] == pytest.approx(sum(expected) / 3, abs=1e-12)
    assert dwin.table.values("s1")["mean_score"] > dwin.table.values("s3")["mean_score"]
    assert not dwin.cancel_button.isEnabled() and dwin.score_action.isEnabled()

    dwin.run_batch("sync", workers=1)
    qtbot.waitUntil(lambda: dwin.batch_job is None, timeout=120_000)
    for name, prior_us in PRIORS_US.items():
        v = dwin.table.values(name)
        doc = dwin.last_batch.scenes[name]
        assert v["estimate_ms"] == doc["offset_us"] / 1000.0 and v["estimate_reliable"] == doc["reliable"]
        assert v["clock_ms"] == prior_us / 1000.0                  # estimate only: nothing applied
        delta = dwin.table.model().index(dwin.table.row_of(name), dwin.table.column_of("estimate_delta_ms"))
        assert delta.data(SORT_ROLE) == pytest.approx((doc["offset_us"] - prior_us) / 1000.0)
        assert delta.data() == f"{(doc['offset_us'] - prior_us) / 1000.0:+.1f}"
    assert not (dataset_dir / "s1" / "corrections.json").exists()


def test_cancel_a_dataset_job(qtbot, dwin):
    dwin.run_batch("score", workers=1)
    dwin.cancel_button.click()
    assert dwin.progress.format() == "cancelling…"
    qtbot.waitUntil(lambda: dwin.batch_job is None, timeout=120_000)
    assert "cancelled" in dwin.statusBar().currentMessage()
    assert dwin.last_batch is None
    assert all(dwin.table.values(n).get("mean_score") is None for n in PRIORS_US)
    assert dwin.score_action.isEnabled() and not dwin.cancel_button.isEnabled()


def test_evpose_gui_on_a_dataset_folder_shows_the_dataset_view(dataset_dir, tmp_path):
    """``evpose gui DATASET`` (a folder without scene.toml that opens as a dataset) starts on the dataset view."""
    import os
    import subprocess
    import sys

    from PySide6 import QtGui

    if not os.environ.get("DISPLAY"):
        pytest.skip("needs an X display (Xvfb)")
    png = tmp_path / "view.png"
    run = subprocess.run([sys.executable, "-m", "evpose", "gui", str(dataset_dir), "--screenshot", str(png),
                          "--quit-after", "0"], capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, XDG_CONFIG_HOME=str(tmp_path / "config")))
    assert run.returncode == 0, run.stderr
    assert f"screenshot saved to {png}" in run.stderr
    img = QtGui.QImage(str(png))
    assert not img.isNull() and img.width() <= 1366 and img.height() <= 768


def test_triage_all_ranks_the_scenes_with_cause_reasons_and_object_scores(qtbot, dwin, dataset_dir):
    """Issue 24.5: the dataset view shows the triage report's ranking: each scene's rank and cause (coloured),
    the reasons and the next command in the tooltip, every object's median score (not averaged away)."""
    from evpose.app.dataset_window import triage_values

    job = dwin.run_batch("triage", workers=1)
    assert job is not None and not dwin.triage_action.isEnabled()
    qtbot.waitUntil(lambda: dwin.batch_job is None, timeout=180_000)
    doc = dwin.last_triage
    assert doc is not None and not dwin.last_batch.failed
    expected = triage_values(doc)
    ranked = {e["scene"]: e for e in doc["scenes_ranked"]}
    # the tiny scene's true clock is +20 ms and its poses are 5 mm / 3 deg off: s1 (prior right) for its objects,
    # s2 (15 ms off) and s3 (420 ms off) for the clock, s3 first
    assert {n: e["cause"] for n, e in ranked.items()} == {"s1": "object", "s2": "clock", "s3": "clock"}
    assert ranked["s3"]["rank"] == 1
    m = dwin.table.model()
    for name in PRIORS_US:
        v = dwin.table.values(name)
        assert v["rank"] == expected[name]["rank"] and v["cause"] == expected[name]["cause"]
        cause = m.index(dwin.table.row_of(name), dwin.table.column_of("cause"))
        scores = m.index(dwin.table.row_of(name), dwin.table.column_of("lowest_score"))
        assert scores.data().count("·") == 2 and all(o in scores.data() for o in ("box", "cylinder", "flatbox"))
        if name in ranked:
            assert cause.data() == ranked[name]["cause"]
            assert cause.data(QtCore.Qt.ToolTipRole).endswith(f"next: {ranked[name]['next']}")
            assert cause.data(QtCore.Qt.ForegroundRole) is not None
    assert not (dataset_dir / "s1" / "corrections.json").exists()          # triage changes nothing


def test_refine_dry_run_then_apply_and_reject_in_the_detail_pane(qtbot, dwin, dataset_dir):
    """Issue 24.5: Refine (dry run) proposes each scene's changes with their sigma and writes nothing; the detail
    pane shows the selected scene in full; Apply stores the proposal as the dry run's document says (one undo step,
    the same corrections ``refine --joint --apply`` stores), a second Apply of a stale proposal is refused in one
    line, and Reject writes nothing."""
    from evpose.app.dataset_window import detail_text
    from evpose.core.document.corrections import Corrections

    dwin.last_triage = {"scenes_ranked": [{"scene": "s2", "cause": "clock", "rank": 1, "reasons": [], "next": ""},
                                          {"scene": "s1", "cause": "object", "rank": 2, "reasons": [], "next": ""}]}
    dwin.refine_windows = 12          # as the CLI tests of the joint fit (24 by default): half the time
    job = dwin.run_batch("refine", workers=1)
    assert job is not None and not dwin.refine_action.isEnabled()
    qtbot.waitUntil(lambda: dwin.batch_job is None, timeout=300_000)
    assert set(dwin.last_batch.scenes) == {"s1", "s2"}                  # only the flagged scenes
    assert not any((dataset_dir / n / "corrections.json").exists() for n in PRIORS_US)
    s2 = dwin.table.values("s2")
    doc = s2["proposal_doc"]
    assert s2["proposal_state"] == "proposed" and any(c["part"] == "clock" for c in doc["changes"])
    assert "+-" in s2["proposal"] and dwin.table.values("s3").get("proposal") is None
    cell = dwin.table.model().index(dwin.table.row_of("s2"), dwin.table.column_of("proposal"))
    assert cell.data(QtCore.Qt.ForegroundRole) is not None

    dwin.table.select("s2")
    assert dwin.detail.name == "s2" and dwin.detail.apply_button.isEnabled()
    assert dwin.detail.text.toPlainText() == detail_text("s2", dwin.table.values("s2"))
    assert f"proposal: {s2['proposal']}" in dwin.detail.text.toPlainText()
    dwin.detail.apply_button.click()
    qtbot.waitUntil(lambda: dwin.table.values("s2")["proposal_state"] == "applied", timeout=60_000)
    saved = Corrections.load(dataset_dir / "s2" / "corrections.json")
    assert saved.revision == 1
    assert saved.offset_us + PRIORS_US["s2"] == doc["offset_us"]        # the clock the dry run proposed
    assert not dwin.detail.apply_button.isEnabled()

    # the same proposal again: the corrections changed since it was made
    dwin._set("s2", {"proposal_doc": doc, "proposal_state": "proposed"})
    dwin.apply_proposal("s2")
    qtbot.waitUntil(lambda: dwin.table.values("s2")["proposal_state"] == "stale", timeout=60_000)
    assert "corrections changed since the proposal" in dwin.table.values("s2")["proposal"]
    assert Corrections.load(dataset_dir / "s2" / "corrections.json").revision == 1

    s1 = dwin.table.values("s1")
    dwin.table.select("s1")
    if s1["proposal_state"] == "proposed":
        dwin.detail.reject_button.click()
        assert dwin.table.values("s1")["proposal_state"] == "rejected"
    assert not (dataset_dir / "s1" / "corrections.json").exists()
    qtbot.waitUntil(lambda: not dwin.jobs, timeout=60_000)


def test_detail_pane_shows_a_failure_in_full(dwin):
    long = "events.h5: t: " + "timestamps go back " * 20 + "(the end)"
    dwin._set("s3", {"status": long, "failed": True, "cause": "failed", "rank": 1, "reasons": ["unreadable"],
                     "next": "evpose info s3"})
    dwin.table.select("s3")
    text = dwin.detail.text.toPlainText()
    assert f"FAILED: {long}" in text and "next: evpose info s3" in text and "  - unreadable" in text
    assert not dwin.detail.apply_button.isEnabled()


def test_export_from_the_dataset_view(qtbot, dwin, dataset_dir, tmp_path):
    """Export… runs ``dataset export`` on the cluster: the same files as the command, each scene's count in its
    detail; a refused output folder (inside a scene) is one error line and starts nothing."""
    out = tmp_path / "out"
    job = dwin.run_batch("export", workers=1, fmt="epose", out=str(out))
    assert job is not None and not dwin.export_action.isEnabled()
    qtbot.waitUntil(lambda: dwin.batch_job is None, timeout=300_000)
    assert not dwin.last_batch.failed
    for name in PRIORS_US:
        assert any((out / name).glob("*_data.mat")), name
        written = dwin.last_batch.scenes[name]["written"]
        assert written > 0 and dwin.table.values(name)["exported"].startswith(f"{written} windows written")
    dwin.table.select("s1")
    assert "export: " in dwin.detail.text.toPlainText()


def test_export_dialog_refuses_a_folder_inside_a_scene(dwin, dataset_dir, window, monkeypatch):
    from PySide6 import QtWidgets

    monkeypatch.setattr(QtWidgets.QInputDialog, "getItem", lambda *a, **k: ("epose", True))
    monkeypatch.setattr(QtWidgets.QFileDialog, "getExistingDirectory", lambda *a, **k: str(dataset_dir / "s1"))
    assert dwin.export_dialog() is None and dwin.batch_job is None
    assert "s1" in window.last_error


def test_ctrl_q_in_the_dataset_view_quits(qtbot, dwin, window):
    assert dwin.quit_action.shortcut() == QtGui.QKeySequence(QtGui.QKeySequence.Quit)
    dwin.quit_action.trigger()
    assert not window.isVisible() and not dwin.isVisible()


def test_a_window_deleted_while_its_rows_are_read_does_not_crash_the_app(qtbot, window, dataset_dir, monkeypatch):
    """A CI run segfaulted in a row-reading job: the job emitted each row on an object the deleted window owned.
    The window is deleted (as Qt does on close with WA_DeleteOnClose, or pytest-qt at teardown) while its job is
    still reading; the job then emits its rows and ends without crashing (before the fix its emit on the deleted
    object raised in the job's thread, or crashed the process)."""
    import threading

    import shiboken6

    from evpose.app import dataset_window as dw

    gate, entered = threading.Event(), threading.Event()
    real_row = dw.scene_row

    def slow_row(path, defaults):
        entered.set()
        assert gate.wait(30)
        return real_row(path, defaults)

    monkeypatch.setattr(dw, "scene_row", slow_row)
    win = dw.DatasetWindow(window, dw.Dataset.open(dataset_dir))
    job = win.load_rows()
    ended = []
    signals = job.signals
    signals.finished.connect(lambda n: ended.append(n))
    assert entered.wait(30)
    win.jobs.clear()
    shiboken6.delete(win)                       # the C++ window and its children are gone
    del win
    gate.set()
    qtbot.waitUntil(lambda: bool(ended), timeout=30_000)
    assert ended == [len(PRIORS_US)]
