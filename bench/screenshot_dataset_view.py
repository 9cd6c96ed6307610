"""The README's dataset-view pictures: ``docs/dataset_view.png`` (the triage dataset) and, with ``--campaign``,
``docs/dataset_campaign.png`` (a campaign dataset after its group fit).

Default mode: the five-scene dataset of ``tests/dataset/test_triage_verdicts.py`` (one generated recording, 3
objects, 2.5 s at 0.5 m/s, half DAVIS346, seed 12, copied five times: ``a_right`` unchanged, ``b_clock`` its clock
20 ms off, ``c_pose`` the box 5 mm / 3 deg off, ``d_mounting`` the camera mounting 2 mm / 0.5 deg off,
``e_broken`` an unreadable events file) in the dataset window (``evpose gui DS``) at 1300x440 (``--size``):
*with edges* checked, *Triage all*, then *Refine (dry run)* (the window's own actions, on a local Dask cluster of
``--workers``), sorted by rank, the ``d_mounting`` row selected so the Details pane shows its triage and proposal
(the table keeps the height of its rows, Details gets the rest). The *Campaign fit* box beside it shows the grey
hint that no campaign fit is recorded.

``--campaign``: three scenes of one placement and camera mounting (``tests/dataset/test_campaign.py``'s
``campaign``: 0.1, 0.5 and 1.0 m/s, seed 21, every object 3 mm / 1.5 deg off with pose_error_seed 5, the hand-eye
2 mm / 0.5 deg off, half DAVIS346) with a ``dataset.toml`` group ``day1`` sharing hand-eye and placement; a fresh
copy of them gets ``evpose dataset refine DS --joint --shared hand-eye,placement --windows 16 --workers 2 --apply
-q``, then its dataset window (1300x300) is grabbed with the Campaign fit box showing the group's lines.

The generated scenes are kept in ``--work`` (default ``/tmp/evpose_dataset_shots``) and reused by the next run
(delete the folder to build them again); the campaign's refined copy is made afresh each run. Run from the
repository with its venv, under an X display with GLX (the main window behind the dataset window has a GL view)::

    xvfb-run -a -s "-screen 0 1600x1000x24 +extension GLX +render" python bench/screenshot_dataset_view.py
    xvfb-run -a -s "-screen 0 1600x1000x24 +extension GLX +render" python bench/screenshot_dataset_view.py --campaign
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path


REPO = Path(__file__).resolve().parents[1]
MARKER = ".evpose-screenshot-work"          # a --work folder this script made (it removes only its own subfolders)
PART_MARKER = ".evpose-screenshot-part"     # in every subfolder the script made: the only ones it ever removes
CAMPAIGN_TOML = """format = "evpose-dataset/1"
scenes = ["slow", "mid", "fast"]

[[groups]]
name = "day1"
shared = ["hand-eye", "placement"]
scenes = ["slow", "mid", "fast"]
"""
REFINE_CMD = ["dataset", "refine", None, "--joint", "--shared", "hand-eye,placement", "--windows", "16",
              "--workers", "2", "--apply", "-q"]

sys.path.insert(0, str(REPO / "tests"))
from evpose_testing import build_triage_dataset, generate_campaign  # noqa: E402


def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


# ------------------------------------------------------------------------------------------------ datasets
def _own(path: Path) -> bool:
    """Whether ``path`` is a folder this script made (its marker inside; never a symbolic link)."""
    return not path.is_symlink() and path.is_dir() and (path / PART_MARKER).is_file()


def _remove_own(path: Path) -> None:
    """Remove ``path`` when this script made it; anything else in the way -- a folder without the marker, a file,
    a symbolic link -- stops the script with one line, nothing removed."""
    if not (path.exists() or path.is_symlink()):
        return
    if not _own(path):
        sys.exit(f"screenshot_dataset_view: {path} is in the way and not this script's ({PART_MARKER} missing); "
                 "move it away")
    shutil.rmtree(path)


def _fresh(path: Path) -> Path:
    """``path`` as a new, empty folder of this script's (marked), after :func:`_remove_own` of what was there."""
    _remove_own(path)
    path.mkdir()
    (path / PART_MARKER).touch()
    return path


def work_folder(path: Path) -> Path:
    """The work folder, created and marked here; an existing unmarked non-empty folder is refused."""
    path = path.resolve()
    if path.exists() and any(path.iterdir()) and not (path / MARKER).exists():
        sys.exit(f"screenshot_dataset_view: {path} is not empty and not this script's work folder ({MARKER} "
                 f"missing); give another --work")
    path.mkdir(parents=True, exist_ok=True)
    (path / MARKER).touch()
    return path


def _built_once(work: Path, name: str, build) -> Path:
    """``work/name``, built by ``build(part)`` in ``work/name.partial`` and renamed when complete (a run stopped
    midway builds it again), or reused when present."""
    done = work / name
    if done.is_dir():
        log(f"reusing {done}")
        return done
    t0 = time.perf_counter()
    part = _fresh(work / f"{name}.partial")
    build(part)
    part.rename(done)
    log(f"built {done} in {time.perf_counter() - t0:.1f} s")
    return done


def triage_dataset(work: Path) -> Path:
    """The five scenes of ``test_triage_verdicts.py``'s ``triage_dataset`` in ``work/ds`` (reused)."""
    def build(part):
        base = _fresh(work / "triage_base.partial")            # the recording they are copied from
        build_triage_dataset(base / "scene", part)
        _remove_own(base)
    return _built_once(work, "ds", build)


def campaign_scenes(work: Path) -> Path:
    """The three generated scenes of ``test_campaign.py``'s ``campaign`` in ``work/campaign_scenes`` (reused)."""
    return _built_once(work, "campaign_scenes", generate_campaign)


def campaign_dataset(work: Path) -> Path:
    """A fresh copy of the campaign's scenes as dataset ``work/campaign`` (its group in dataset.toml), refined
    with ``evpose dataset refine --joint --shared hand-eye,placement --apply``."""
    src = campaign_scenes(work)
    root = _fresh(work / "campaign")
    for name in ("slow", "mid", "fast"):
        shutil.copytree(src / name, root / name)
    (root / "dataset.toml").write_text(CAMPAIGN_TOML)
    cmd = [sys.executable, "-m", "evpose"] + [str(root) if a is None else a for a in REFINE_CMD]
    log("running evpose " + " ".join(cmd[3:]))
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
    log(f"dataset refine: exit {r.returncode} in {time.perf_counter() - t0:.1f} s")
    if r.stdout.strip():
        print(r.stdout.rstrip())
    if r.returncode != 0 or not (root / "campaign_fit.json").is_file():
        sys.exit(f"screenshot_dataset_view: evpose dataset refine failed (exit {r.returncode}):\n{r.stderr}")
    return root


# ------------------------------------------------------------------------------------------------ the window
def run_until(cond, timeout_s: float, what: str) -> None:
    """Run the event loop until ``cond()`` (exit with ``what`` after ``timeout_s``)."""
    from PySide6 import QtCore

    loop = QtCore.QEventLoop()
    deadline = time.monotonic() + timeout_s
    poll = QtCore.QTimer(interval=20)
    poll.timeout.connect(lambda: (cond() or time.monotonic() > deadline) and loop.quit())
    poll.start()
    if not cond():
        loop.exec()
    poll.stop()
    if not cond():
        sys.exit(f"screenshot_dataset_view: timed out after {timeout_s:.0f} s waiting for {what}")


def settle(seconds: float) -> None:
    """Let the window paint (layouts, the status bar) for ``seconds``."""
    t_end = time.monotonic() + seconds
    run_until(lambda: time.monotonic() >= t_end, seconds + 5, "the window to settle")


def open_window(work: Path, root: Path, size: tuple[int, int]):
    """The main window (private settings, not shown) and the dataset window on ``root`` with every row read."""
    from evpose.app.qt_compat import guard_pyside_refcount_leak, share_gl_contexts
    from evpose.app.startup import prepare_process

    prepare_process()
    guard_pyside_refcount_leak()
    share_gl_contexts()
    from PySide6 import QtCore, QtWidgets

    from evpose.app.dataset_window import open_dataset
    from evpose.app.main_window import MainWindow
    from evpose.app.settings import Settings

    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication([sys.argv[0]])
    qs = QtCore.QSettings(str(work / "settings.ini"), QtCore.QSettings.IniFormat)
    main = MainWindow(Settings(qs))
    main.modal_dialogs = False
    main.auto_answer["Unsaved corrections"] = 0x00800000          # Discard (nothing is edited here)
    win = open_dataset(main, root)
    if win is None:
        sys.exit(f"screenshot_dataset_view: cannot open the dataset: {main.last_error}")
    win.resize(*size)
    win.move(40, 40)
    win.raise_()
    win.activateWindow()
    run_until(win.rows_loaded, 120, "the rows to be read")
    return app, main, qs, win


def run_action(win, action, timeout_s: float) -> float:
    """Trigger a batch action of the toolbar and wait for its job; returns its run time (s)."""
    t0 = time.perf_counter()
    action.trigger()
    if win.batch_job is None:
        sys.exit(f"screenshot_dataset_view: {action.text()} started nothing: {win.statusBar().currentMessage()}")
    run_until(lambda: win.batch_job is None, timeout_s, action.text())
    dt = time.perf_counter() - t0
    log(f"{action.text()}: {win.statusBar().currentMessage()} ({dt:.1f} s wall)")
    if win.main.last_error:
        sys.exit(f"screenshot_dataset_view: {action.text()} failed: {win.main.last_error}")
    return dt


def select(win, name: str) -> None:
    win.table.select(name)
    win.table.setFocus()
    win.table.scrollTo(win.table.currentIndex())
    run_until(lambda: win.detail.name == name, 10, f"the details of {name}")


def fit_table(win) -> None:
    """Give the Details dock the height the table does not need: the table shows all its rows and no empty band
    (as dragging the splitter above Details would)."""
    from PySide6 import QtCore

    t = win.table
    settle(0.3)
    need = (t.horizontalHeader().height() + t.model().rowCount() * t.verticalHeader().defaultSectionSize()
            + t.horizontalScrollBar().sizeHint().height() + 2 * t.frameWidth() + 2)
    spare = t.height() - need
    if spare > 0:
        win.resizeDocks([win.detail_dock], [win.detail_dock.height() + spare], QtCore.Qt.Vertical)
    settle(0.3)
    log(f"table {t.height()} px (needs {need}), Details dock {win.detail_dock.height()} px")


def grab(win, out: Path) -> None:
    settle(1.0)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not win.grab().save(str(out)):
        sys.exit(f"screenshot_dataset_view: could not write {out}")
    log(f"{out}: {win.width()}x{win.height()}")


def report(win) -> None:
    """What the picture shows, as text (for checking it without looking)."""
    t = win.table
    print("rows (as shown):")
    for name in t.shown_names():
        v = t.values(name)
        print(f"  {name:11s} rank {v.get('rank')!s:4s} cause {v.get('cause')!s:9s} proposal: {v.get('proposal')}")
    print(f"selected: {t.current_name()}")
    print("details:\n  " + win.detail.text.toPlainText().replace("\n", "\n  "))
    print(f"campaign fit box ({win.campaign.state}):\n  " + "\n  ".join(win.campaign.lines()))
    print(f"status bar: {win.statusBar().currentMessage()}")


def close(app, main, qs, win) -> None:
    import shiboken6

    win.close()
    main.close()
    for feeds in (getattr(main, "feeds", None), getattr(main, "residual_feed", None)):
        if feeds is not None:
            feeds.stop()
    app.processEvents()
    shiboken6.delete(main)
    qs.sync()


def shoot_triage(args, work: Path) -> None:
    from PySide6 import QtCore

    root = triage_dataset(work)
    app, main, qs, win = open_window(work, root, args.size or (1300, 440))
    win.workers_spin.setValue(args.workers)
    if args.refine_windows:
        win.refine_windows = args.refine_windows
    win.edges_check.setChecked(True)
    run_action(win, win.triage_action, args.timeout)
    run_action(win, win.refine_action, args.timeout)
    win.table.sortByColumn(win.table.column_of("rank"), QtCore.Qt.AscendingOrder)
    select(win, "d_mounting")
    fit_table(win)
    run_until(lambda: win.campaign.state == "absent", 10, "the campaign box's hint")
    report(win)
    grab(win, Path(args.out))
    close(app, main, qs, win)


def shoot_campaign(args, work: Path) -> None:
    root = campaign_dataset(work)
    app, main, qs, win = open_window(work, root, args.size or (1300, 300))
    win.workers_spin.setValue(args.workers)
    run_until(lambda: win.campaign.state == "ok", 10, "the campaign fit in its box")
    select(win, "slow")
    fit_table(win)
    report(win)
    grab(win, Path(args.out))
    close(app, main, qs, win)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", default="/tmp/evpose_dataset_shots",
                    help="folder of the generated datasets, reused by the next run (default %(default)s)")
    ap.add_argument("--out", default=None,
                    help="PNG to write (default docs/dataset_view.png; docs/dataset_campaign.png with --campaign)")
    ap.add_argument("--campaign", action="store_true",
                    help="the campaign dataset after dataset refine --joint --shared hand-eye,placement --apply")
    ap.add_argument("--size", type=lambda t: tuple(int(v) for v in t.lower().split("x")), metavar="WxH",
                    help="window size in px (default 1300x440; 1300x300 with --campaign: three rows and six lines)")
    ap.add_argument("--workers", type=int, default=2, help="Dask worker processes of the window's jobs (default 2)")
    ap.add_argument("--refine-windows", type=int, default=None,
                    help="event windows of Refine (dry run) (default: the window's, evpose refine --joint's 24)")
    ap.add_argument("--timeout", type=float, default=1800, help="seconds allowed to each batch job")
    args = ap.parse_args()
    if args.out is None:
        args.out = str(REPO / "docs" / ("dataset_campaign.png" if args.campaign else "dataset_view.png"))
    if not os.environ.get("DISPLAY"):
        sys.exit("screenshot_dataset_view: needs an X display with GLX, e.g. "
                 "xvfb-run -a -s \"-screen 0 1600x1000x24 +extension GLX +render\"")
    work = work_folder(Path(args.work))
    os.environ.setdefault("XDG_CACHE_HOME", str(work / "cache"))    # the event-index cache: not the user's
    t0 = time.perf_counter()
    (shoot_campaign if args.campaign else shoot_triage)(args, work)
    log(f"done in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
