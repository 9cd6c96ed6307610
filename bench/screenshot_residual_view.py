"""The README's residual-view picture (``docs/residual_view.png``): the demo scene with the clock and every pose at
the truth, the box moved 6 mm along the line of sight, the residual view's widget (720×1000) grabbed.

Usage: ``python bench/screenshot_residual_view.py [--scene DIR] [--out docs/residual_view.png]`` (needs an X display
with GLX; the scene is ``evpose demo``'s, copied into a folder of the run that is removed at the end)."""
from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default=str(Path.home() / ".local/share/evpose/demo_scene"))
    ap.add_argument("--out", default=str(BENCH.parent / "docs" / "residual_view.png"))
    args = ap.parse_args()
    if not os.environ.get("DISPLAY"):
        sys.exit("screenshot_residual_view: needs an X display with GLX (e.g. xvfb-run -a -s '-screen 0 1920x1080x24')")
    from synth_scenes import run_dir

    with run_dir("residual_shot") as tmp:
        return shoot(Path(args.scene), tmp, Path(args.out))


def shoot(src: Path, tmp: Path, out: Path) -> int:
    import numpy as np
    import shiboken6
    from bench_scrub import run_until
    from bench_user_session import _apply_truth

    from evpose.app.qt_compat import share_gl_contexts
    share_gl_contexts()
    from PySide6 import QtCore, QtWidgets

    from evpose.app.main_window import MainWindow
    from evpose.app.settings import Settings
    from evpose.core.session.model import Session
    from evpose.core.sim.synth import load_ground_truth

    QtWidgets.QApplication.instance() or QtWidgets.QApplication([])
    shutil.copytree(src, tmp / "scene")
    gt = load_ground_truth(tmp / "scene")
    qs = QtCore.QSettings(str(tmp / "settings.ini"), QtCore.QSettings.IniFormat)
    window = MainWindow(Settings(qs))
    window.modal_dialogs = False
    window.auto_answer["Unsaved corrections"] = 0x00800000
    window.resize(1900, 1050)
    window.show()
    session = Session.open(tmp / "scene")
    window.set_session(session)
    run_until(window.frame_up_to_date, timeout_s=180)
    session.set_time(session.busiest_time())
    _apply_truth(session, gt)
    session.select("box")
    session.nudge_object("box", "camera", trans_mm=np.array([0.0, 0.0, 6.0]), mergeable=False)
    feed = window.residual_feed
    window.panel.residuals_button.click()
    run_until(lambda: False, timeout_s=0.5)
    run_until(lambda: feed.feed.up_to_date() and feed.view.sweep.data is not None
              and feed.view.sweep.data.name == "box", timeout_s=180)
    feed.dock.setFloating(True)
    feed.dock.resize(720, 1000)
    run_until(lambda: False, timeout_s=1.0)
    out.parent.mkdir(parents=True, exist_ok=True)
    ok = feed.view.grab().save(str(out))
    print(f"{out}: {'saved' if ok else 'NOT saved'}; table: {feed.view.row_texts()}")
    window.close()
    shiboken6.delete(window)          # QSettings writes on destruction: before the run's folder goes
    qs.sync()
    shiboken6.delete(qs)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
