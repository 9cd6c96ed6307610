"""Start the desktop app: ``evpose gui [SCENE] [--screenshot PNG] [--quit-after S]``."""
from __future__ import annotations

import re
import sys
import traceback

from evpose.core.errors import InputError


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


def _shut_down(app, window) -> None:
    """Close the window and stop its worker threads: a QThread destroyed while running aborts the
    process (exit 134, "QThread: Destroyed while thread ... is still running") at interpreter exit."""
    if window.isVisible():
        window.close()                  # closeEvent stops the frame / space-time workers
    for feeds in (getattr(window, "feeds", None), getattr(window, "residual_feed", None)):
        if feeds is not None:
            feeds.stop()
    app.processEvents()


def _one_line(message: str) -> str:
    """The last line of a worker's traceback text, without the exception's class name."""
    lines = [ln.strip() for ln in str(message).strip().splitlines() if ln.strip()]
    last = lines[-1] if lines else "unknown error"
    head, sep, rest = last.partition(": ")
    return rest if sep and re.fullmatch(r"[A-Za-z_][\w.]*(Error|Exception|Failure)", head) else last


def _load_for_unattended(session) -> str | None:
    """Load every mesh now (an unattended run has no dialog to show a late error in); returns the
    error line or None."""
    try:
        for name in session.scene.object_names:
            session.scene.model(name)
    except (InputError, OSError) as exc:
        return str(exc)
    return None


#: The app icon in ``evpose.resources``: the drawing, and a 256 px rendering of it for Qt builds
#: without the SVG plugin.
ICON_FILES = ("evpose.svg", "evpose.png")


def app_icon():
    """The evpose icon (``resources/evpose.svg``, with its PNG rendering), as a ``QIcon``."""
    from importlib.resources import files

    from PySide6 import QtGui

    icon = QtGui.QIcon()
    for name in ICON_FILES:
        path = files("evpose.resources") / name
        if path.is_file():
            icon.addFile(str(path))
    return icon


def _needs_raster(scene: str | None) -> bool:
    """False when ``scene`` is an event-only scene (no trajectory, no objects): nothing will be rasterised. Any
    other case (no scene yet, a scene that does not open: its error comes later, once) says True."""
    if scene is None:
        return True
    try:
        from evpose.core.data.manifest_reader import load_manifest

        return load_manifest(scene, check_files=False).has_trajectory
    except Exception:            # reported when the window opens the scene
        return True


def _warm_up_in_background() -> None:
    """Load (or compile, on the very first start) the rasteriser's kernels in a background thread, so the
    first frame does not pay for them (issue 14: 0.5 s from the disk cache, ~10 s to compile)."""
    import threading

    from evpose.core.label.raster import warm_up

    threading.Thread(target=warm_up, name="evpose-raster-warm-up", daemon=True).start()


def run_gui(scene: str | None = None, *, screenshot: str | None = None, quit_after: float | None = None,
            start_busiest: bool = False, dataset: str | None = None, at_s: float | None = None) -> int:
    """Open the main window (on ``scene`` if given) and run the event loop.

    With ``screenshot``, the window is rendered to that PNG once the first frame is drawn and at
    least ``quit_after`` seconds (default 3) have passed, then the app quits: this works under
    any X display, including Xvfb. ``start_busiest`` opens at the window with the most events
    (the demo uses it so the first view shows motion); ``at_s`` at that many seconds after the first event (the
    triage report's "open it" commands). ``dataset``: open the dataset view on that folder
    instead (the main window appears when a scene is opened from it; the screenshot is of the dataset view
    once every row is read).
    """
    from evpose.app.startup import prepare_process

    prepare_process()                     # malloc settings and the engine's imports, before Qt (app/memory.py)
    from PySide6 import QtCore, QtWidgets

    from evpose.app.main_window import MainWindow
    from evpose.app.qt_compat import guard_pyside_refcount_leak, share_gl_contexts

    guard_pyside_refcount_leak()
    share_gl_contexts()         # a floated dock's GL view keeps its buffers

    QtCore.QCoreApplication.setOrganizationName("evpose")
    QtCore.QCoreApplication.setApplicationName("evpose")
    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication(sys.argv[:1])
    app.setWindowIcon(app_icon())
    if dataset or _needs_raster(scene):
        _warm_up_in_background()
    window = MainWindow()
    unattended = screenshot is not None or quit_after is not None
    window.modal_dialogs = not unattended
    _install_excepthook(window)
    if dataset:
        from evpose.app.dataset_window import open_dataset

        if open_dataset(window, dataset) is None:
            if unattended:
                sys.stderr.write(f"evpose gui: error: {_one_line(window.last_error or dataset)}\n")
                _shut_down(app, window)
                return 2
            window.show()
    else:
        window.show()
    if scene:
        session = window.controller.open_scene(scene)
        problem = window.last_error if session is None else (_load_for_unattended(session) if unattended else None)
        if problem is not None and unattended:
            sys.stderr.write(f"evpose gui: error: {_one_line(problem)}\n")
            _shut_down(app, window)
            return 2
        if session is not None and start_busiest:
            session.set_time(session.busiest_time())
        if session is not None and at_s is not None:
            session.set_time(session.time_range[0] + round(at_s * 1e6))          # clamped to the recording
    if unattended:
        wait_s = 3.0 if quit_after is None else float(quit_after)
        t_start = QtCore.QElapsedTimer()
        t_start.start()

        def tick():
            if window.last_error:           # a view could not be computed: report it, do not wait for it
                timer.stop()
                sys.stderr.write(f"evpose gui: error: {_one_line(window.last_error)}\n")
                app.exit(2)
                return
            drawn = window.session is None or (window.frame is not None and window.spacetime_drawn())
            shown = window.dataset_window if dataset else window
            if dataset:
                drawn = shown is not None and shown.rows_loaded()
            if t_start.elapsed() >= wait_s * 1000 and drawn:
                timer.stop()                # closing may run the event loop: no second tick saves a closed window
                if screenshot:
                    path = shown.save_screenshot(screenshot)
                    sys.stderr.write(f"evpose gui: screenshot saved to {path}\n")
                window.close()
                app.quit()
            elif t_start.elapsed() > (wait_s + 60) * 1000:  # never hang
                timer.stop()
                sys.stderr.write("evpose gui: the first frame did not arrive in time\n")
                app.exit(3)

        timer = QtCore.QTimer(window, interval=100)
        timer.timeout.connect(tick)
        timer.start()
    rc = app.exec()
    _shut_down(app, window)
    return rc
