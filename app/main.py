"""Start the desktop app: ``evpose gui [SCENE] [--screenshot PNG] [--quit-after S]``."""
from __future__ import annotations

import sys
import traceback
from pathlib import Path


def _install_excepthook(window) -> None:
    """Unexpected errors become a dialog (and a traceback on stderr), never a silent crash."""
    from PySide6 import QtWidgets

    def hook(exc_type, exc, tb):
        text = "".join(traceback.format_exception(exc_type, exc, tb))
        sys.stderr.write(text)
        if window is not None and window.modal_dialogs:
            QtWidgets.QMessageBox.critical(window, "Unexpected error", f"{exc_type.__name__}: {exc}\n\n"
                                           "Your corrections are kept in the autosave journal.")
        elif window is not None:
            window.last_error = text

    sys.excepthook = hook


def run_gui(scene: str | None = None, *, screenshot: str | None = None, quit_after: float | None = None,
            start_busiest: bool = False) -> int:
    """Open the main window (on ``scene`` if given) and run the event loop.

    With ``screenshot``, the window is rendered to that PNG once the first frame is drawn and at
    least ``quit_after`` seconds (default 3) have passed, then the app quits: this works under
    any X display, including Xvfb. ``start_busiest`` opens at the window with the most events
    (the demo uses it so the first view shows motion).
    """
    from PySide6 import QtCore, QtGui, QtWidgets

    from .main_window import MainWindow
    from .qt_compat import guard_pyside_refcount_leak

    guard_pyside_refcount_leak()

    QtCore.QCoreApplication.setOrganizationName("evpose")
    QtCore.QCoreApplication.setApplicationName("evpose")
    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication(sys.argv[:1])
    icon = Path(__file__).resolve().parents[1] / "resources" / "evpose.svg"
    if icon.is_file():
        app.setWindowIcon(QtGui.QIcon(str(icon)))
    window = MainWindow()
    unattended = screenshot is not None or quit_after is not None
    window.modal_dialogs = not unattended
    _install_excepthook(window)
    window.show()
    if scene:
        session = window.controller.open_scene(scene)
        if session is None and unattended:
            sys.stderr.write(f"evpose gui: {window.last_error}\n")
            return 2
        if session is not None and start_busiest:
            session.set_time(session.busiest_time())
    if unattended:
        wait_s = 3.0 if quit_after is None else float(quit_after)
        t_start = QtCore.QElapsedTimer()
        t_start.start()

        def tick():
            drawn = window.session is None or (window.frame is not None and window.spacetime_drawn())
            if t_start.elapsed() >= wait_s * 1000 and drawn:
                if screenshot:
                    path = window.save_screenshot(screenshot)
                    sys.stderr.write(f"evpose gui: screenshot saved to {path}\n")
                window.close()
                app.quit()
            elif t_start.elapsed() > (wait_s + 60) * 1000:  # never hang
                sys.stderr.write("evpose gui: the first frame did not arrive in time\n")
                app.exit(3)

        timer = QtCore.QTimer(window, interval=100)
        timer.timeout.connect(tick)
        timer.start()
    return app.exec()
