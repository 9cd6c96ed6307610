"""The residual view's feed and dock: session changes -> requests on a worker -> the widget.

The view is a dock tabbed with the space-time view, closed until asked for (View ▸ Panels, or the pose panel's
Residuals button). While it is out of sight nothing is computed; when it comes into sight, and on every change of
the time, the window, the shown objects or the document while it is in sight, one request goes to its
:class:`~evpose.app.view_feed.ViewFeed` (a newer request replaces a pending one; late results are dropped by
serial), which runs :func:`evpose.core.views.residuals.residuals` on the session's snapshot.
"""
from __future__ import annotations

import time

from PySide6 import QtCore, QtWidgets

from evpose.app.view_feed import ViewFeed, in_sight
from evpose.core.signals import Change

__all__ = ["ResidualFeed", "RESIDUAL_KINDS"]

#: The session changes the residual view shows (display-only view options are not among them).
RESIDUAL_KINDS = {"time", "document", "objects", "view"}


class _Compute:
    """The window's residuals and the sweep of the selected object (the first shown one when none is selected), on
    the feed's worker; the sweep's annotator (mesh geometry) is kept for the scene between requests."""

    def __init__(self):
        self._ann, self._key = None, None

    def _annotator(self, scene):
        from evpose.core.label.annotate import Annotator
        from evpose.core.views.spacetime_slices import SLICE_REQUEST

        if self._ann is None or self._key != id(scene.manifest):
            self._ann, self._key = Annotator(scene, SLICE_REQUEST), id(scene.manifest)
        self._ann.scene = scene
        return self._ann

    def release(self) -> None:
        """Drop the annotator (the view is out of sight and the app idle; made again on demand, ~30 ms)."""
        self._ann, self._key = None, None

    def __call__(self, req):
        from evpose.core.views.residuals import residuals
        from evpose.core.views.sweep import silhouette_sweep

        t = time.perf_counter()
        w = req.view.window()
        names = [n for n in req.scene.object_names if n not in req.view.hidden]
        data = residuals(req.scene, w.t0_us, w.t1_us, names=names)
        name = req.view.selected if req.view.selected in names else (names[0] if names else None)
        sweep = None
        if name is not None:
            sweep = silhouette_sweep(req.scene, name, int(req.view.t_us), annotator=self._annotator(req.scene))
        return data, sweep, 1000.0 * (time.perf_counter() - t)


class ResidualFeed(QtCore.QObject):
    """The residual view of ``window`` (a :class:`~evpose.app.main_window.MainWindow`): one worker for the window's
    life; :meth:`attach` makes the dock and the view for a session, :meth:`detach` lets them go."""

    def __init__(self, window):
        super().__init__(window)
        self.window = window
        self.session = None
        self.view = None
        self.dock: QtWidgets.QDockWidget | None = None
        self._connection = None
        self._compute = _Compute()
        self.feed = ViewFeed(self, "residual-worker", self._compute, self._ready, make_request=self._request,
                             in_sight=self.in_sight, on_failed=self._failed)

    def attach(self, session, add_dock, tab_with: QtWidgets.QDockWidget) -> QtWidgets.QDockWidget:
        """Show ``session``'s residuals in a new dock made by ``add_dock(title, widget, area, name)`` (the window's,
        which also removes it with the session), tabbed with ``tab_with`` and closed until asked for."""
        from evpose.app import layout as L
        from evpose.widgets.residual_view import ResidualView

        self.detach()
        self.session = session
        self.view = ResidualView()
        self.dock = add_dock("Residuals (events vs edges)", L.scrolled(self.view), QtCore.Qt.LeftDockWidgetArea,
                             "dock_residuals")
        self.window.tabifyDockWidget(tab_with, self.dock)
        self.dock.hide()
        self.dock.visibilityChanged.connect(lambda on: on and QtCore.QTimer.singleShot(0, self.request))
        self._connection = session.changed.connect(self._on_change, RESIDUAL_KINDS)
        return self.dock

    def detach(self) -> None:
        if self._connection is not None:
            self._connection.disconnect()
            self._connection = None
        self.session = self.view = self.dock = None
        self.feed.drop_pending()             # late results of the old session are dropped

    def show(self) -> None:
        if self.dock is not None:
            self.dock.show()
            self.dock.raise_()

    def in_sight(self) -> bool:
        return in_sight(self.dock)

    def idle_release_tasks(self) -> list:
        """The idle release's task (see :meth:`evpose.app.feeds.ViewFeeds.idle_release_tasks`): the annotator is
        dropped while the view is out of sight."""
        return [] if self.in_sight() else [(self.feed.worker, self._compute.release)]

    def _on_change(self, change: Change) -> None:
        if change.kind in RESIDUAL_KINDS:
            self.request()

    def _request(self):
        return self.session.request() if self.session is not None else None

    def request(self) -> None:
        """Submit the session's state, unless the view is out of sight (computed when shown)."""
        self.feed.request()

    def _ready(self, result, serial: int) -> None:
        if self.view is not None:
            data, sweep, ms = result
            self.view.set_data(data, ms)
            color = None
            if sweep is not None and self.session is not None and sweep.name in self.session.scene.object_names:
                from evpose.core.label.overlay import object_color

                color = object_color(list(self.session.scene.object_names).index(sweep.name))
            self.view.sweep.set_data(sweep, *(() if color is None else (color,)))

    def _failed(self, message: str, serial: int) -> None:
        if self.view is not None:
            self.view.status.setText("could not compute: " + message.strip().splitlines()[-1][:300])

    def stop(self) -> None:
        self.detach()
        self.feed.stop()
