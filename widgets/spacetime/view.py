"""Space-time view: the events around the current time as an (x, y, t) point cloud and the objects'
projected silhouettes stacked along t as "tubes" (vispy, DESIGN sections 1-2).

A clock offset between the event camera and the pose source shows here as a *shear*: the event
sheets swept by a moving edge lean one way, the tubes built from the labelled poses another. To make that
plain, the events within a band of a few pixels of a silhouette (at their own time, computed in core) are
drawn on top in their object's colour and the rest dimmed, and the tubes have a translucent skin: with the
right clock the coloured events hug the skins; with a wrong one the moving edges' events leave the band.

The widget is a view of a :class:`evpose.core.session.model.Session`: it takes the session in its constructor,
subscribes to its changes (view options, object visibility) and draws the display-ready
:class:`evpose.core.views.frame.SpaceTimeData` that core computes (``FrameComputer.spacetime``). The owner
(the app's controller or a test) computes that data, off the GUI thread if it likes, and hands it
over with :meth:`SpaceTimeView.set_data`; the widget never imports ``app``.

Its parts, one module each: the scene layout, camera presets and time scale
(:mod:`~evpose.widgets.spacetime.camera`); the event points in two layers (the rest and the band, split by
:mod:`~evpose.widgets.spacetime.band`), thinned to the point budget and uploaded only when changed
(:mod:`~evpose.widgets.spacetime.points`, drawing with the lean ``Markers`` visual of
:mod:`~evpose.widgets.spacetime.cloud`); the span's cage and the current window's slab
(:mod:`~evpose.widgets.spacetime.cage`); the tubes and their skins (:mod:`~evpose.widgets.spacetime.tubes`); the
legend above the canvas (:mod:`~evpose.widgets.spacetime.legend`); the controls
(:mod:`~evpose.widgets.spacetime.controls`).

Controls: reset / front / side / top camera presets (``TurntableCamera``: drag orbits, wheel zooms,
shift-drag pans), the time-scale slider, the span (ms) and point-budget spin boxes (both written to
the session's view state; the owner recomputes on ``"view"``), "N of M events shown", and the by-object
colouring with its band width (view state too; applied at once to the data at hand) and the share of events
in the band.
"""
from __future__ import annotations

import time

import numpy as np
import shiboken6
from PySide6 import QtCore, QtWidgets

from evpose.core.signals import Change, OBJECTS, VIEW
from evpose.widgets.binding import connect_view
from evpose.widgets.spacetime.band import BandSplitter, band_palette, rest_palette
from evpose.widgets.spacetime.cage import SpanCage, WindowSlab
from evpose.widgets.spacetime.camera import OBLIQUE_FOV, TimeScale, frame_preset
from evpose.widgets.spacetime.cloud import use_vispy
from evpose.widgets.spacetime.controls import SpaceTimeControls
from evpose.widgets.spacetime.legend import Legend
from evpose.widgets.spacetime.points import PointLayer, stride_for
from evpose.widgets.spacetime.style import BACKGROUND, ORDER_BAND_POINTS
from evpose.widgets.spacetime.tubes import TubeLayer

#: After a wheel step, the coarse subset is drawn for this long (ms) before all points again.
LOD_IDLE_MS = 250
#: New data within this long (s) of the last (stepping, playing, scrubbing) is drawn with the coarse subset
#: first; all points follow ``LOD_IDLE_MS`` after the last step. On software OpenGL the full 300k-point budget
#: costs ~120 ms a frame on bench/.data/ycb_5obj_5s, the coarse subset ~40 ms.
STEP_COARSE_S = 0.4


class SpaceTimeView(QtWidgets.QWidget):
    """(x, y, t) event cloud + silhouette tubes, with camera presets, a time scale and budget controls.

    Parameters
    ----------
    session : evpose.core.session.model.Session
        The model. Read: ``view.spacetime_budget``, ``view.spacetime_span_us``, ``view.window_us``,
        ``view.hidden``, the camera size. Written (view state only): ``spacetime_budget`` and
        ``spacetime_span_us`` through ``set_view_option``.
    """

    #: Use the lean event upload when vispy's shader allows it (class switch for benchmarks and tests).
    lean_upload = True
    #: Data arriving within this long (s) of the last counts as stepping (drawn coarse first; benchmarks set it).
    step_coarse_s = STEP_COARSE_S
    #: The "Kymograph…" button: the owner shows the kymograph view (an x-t slice along a drawn line).
    kymographRequested = QtCore.Signal()

    def __init__(self, session, parent=None):
        super().__init__(parent)
        use_vispy()
        self.session = session
        cam = session.scene.camera
        self._W, self._H = int(cam.width), int(cam.height)
        self._data = None
        self._tubes_all: list = []
        self._surfaces_all: list = []
        self._drawn_settings = None
        self._interacting = False
        self._mouse_down = False
        self._last_data_s = -1e9        # perf_counter of the last set_data
        self._closed = False
        #: Buffer uploads since construction (``points``, ``polarity``, ``tubes``, ``cage``, ``slab``, ``lod``):
        #: tests and the benchmark check that only changed buffers go to the GPU.
        self.upload_counts = {"points": 0, "polarity": 0, "band_points": 0, "band_colors": 0, "tubes": 0, "cage": 0,
                              "slab": 0, "lod": 0}
        self.splitter = BandSplitter()
        self.split = None               # the Split drawn now (spacetime_band.Split)
        self._lod_timer = QtCore.QTimer(self)
        self._lod_timer.setSingleShot(True)
        self._lod_timer.setInterval(LOD_IDLE_MS)
        self._lod_timer.timeout.connect(lambda: self.set_interacting(False))
        self._build_scene()
        self._build_controls()
        self._connect_controls()
        self._bind_session()

    # ====================================================================== construction
    def _build_scene(self) -> None:
        """The canvas, its turntable camera and the visuals, all under one node (``root``) whose transform
        maps data ``(x px, y px, t ms)`` to the scene; the legend (a row above the canvas)."""
        from vispy import scene
        from vispy.visuals.transforms import MatrixTransform

        self.canvas = scene.SceneCanvas(keys=None, show=False, bgcolor=BACKGROUND, size=(640, 480),
                                        parent=self)
        self.view = self.canvas.central_widget.add_view()
        self.view.camera = scene.TurntableCamera(fov=OBLIQUE_FOV, up="+z")
        self.root = scene.Node(parent=self.view.scene)
        self._transform = MatrixTransform()
        self.root.transform = self._transform
        self.point_layer = PointLayer(self.root, self.lean_upload, self.upload_counts)
        self.markers = self.point_layer.markers
        self.band_layer = PointLayer(self.root, self.lean_upload, self.upload_counts, ORDER_BAND_POINTS,
                                     ("band_points", "band_colors"))
        self.cage = SpanCage(self.root, self._W, self._H, self.upload_counts)
        self.slab = WindowSlab(self.root, self._W, self._H, self.upload_counts)
        self.tube_layer = TubeLayer(self.root, self.upload_counts)
        self.legend = Legend(self)

    def show_band_controls(self, on: bool) -> None:
        """Show the band's controls and the objects' legend (off for an event-only scene: no silhouettes)."""
        c = self.controls
        for w in (c.by_object_check, c.band_spin, c.band_label, self.legend.label):
            w.setVisible(on)

    def _build_controls(self) -> None:
        """The control rows under the canvas; their widgets are also attributes of the view."""
        c = self.controls = SpaceTimeControls()
        self.reset_button, self.front_button, self.side_button, self.top_button = (
            c.reset_button, c.front_button, c.side_button, c.top_button)
        self.scale_slider, self.scale_label, self.span_spin, self.budget_spin, self.info_label = (
            c.scale_slider, c.scale_label, c.span_spin, c.budget_spin, c.info_label)
        self.by_object_check, self.band_spin = c.by_object_check, c.band_spin
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.setSpacing(3)
        layout.addWidget(self.legend.label)
        layout.addWidget(self.canvas.native, 1)
        for row in c.rows:
            layout.addLayout(row)

    def _connect_controls(self) -> None:
        self.time_axis = TimeScale(self._transform, self._W, self._H, self.scale_slider, self.scale_label,
                                   self.canvas)     # owns the slider's valueChanged
        self.reset_button.clicked.connect(self.reset_view)
        self.front_button.clicked.connect(lambda: self.set_preset("front"))
        self.side_button.clicked.connect(lambda: self.set_preset("side"))
        self.top_button.clicked.connect(lambda: self.set_preset("top"))
        self.controls.kymograph_button.clicked.connect(self.kymographRequested.emit)
        self.scale_slider.sliderPressed.connect(lambda: self.set_interacting(True))
        self.scale_slider.sliderReleased.connect(lambda: self.set_interacting(False))
        self.span_spin.valueChanged.connect(self._on_span_spin)
        self.budget_spin.valueChanged.connect(self._on_budget_spin)
        self.band_spin.valueChanged.connect(lambda px: self.session.set_view_option(spacetime_band_px=float(px)))
        self.by_object_check.toggled.connect(lambda on: self.session.set_view_option(spacetime_by_object=bool(on)))

    def _bind_session(self) -> None:
        """Show the session's view state, frame the empty span, then follow the session and the mouse."""
        self._sync_from_view()
        self.time_axis.follow_span(self.session.view.spacetime_span_us)
        self.cage.update(self.session.view.spacetime_span_us)
        self.slab.update(self.session.view.window_us)
        self._preset = None             # the preset in effect until the user moves the camera
        self.reset_view()
        self.canvas.events.mouse_press.connect(self._on_mouse_press)
        self.canvas.events.mouse_release.connect(self._on_mouse_release)
        self.canvas.events.mouse_wheel.connect(self._on_mouse_wheel)
        self.canvas.events.resize.connect(self._on_canvas_resize)
        self._subscription = connect_view(self, self.session.changed, self._on_session, {VIEW, OBJECTS})

    # ====================================================================== public API
    @property
    def shown_count(self) -> int:
        """Events drawn now (after the widget's own stride), both layers."""
        return self.point_layer.shown + self.band_layer.shown

    @property
    def time_scale(self) -> float:
        """Scene pixels of depth per millisecond."""
        return self.time_axis.px_per_ms

    def set_data(self, data) -> None:
        """Draw ``data`` (:class:`evpose.core.views.frame.SpaceTimeData`): the events within the session's band
        of a silhouette in their object's colour on top and the rest dimmed (or all by polarity, when the data has
        no distances or the session's ``spacetime_by_object`` is off), tubes and skins of the objects not hidden
        in the session, the current-window slab at t = 0 and the span's cage.

        More points than ``session.view.spacetime_budget`` are thinned by a stride before upload (the budget
        shared by the two layers). The arrays are treated as immutable: handing the same ``points`` array again
        uploads nothing, and a colour buffer is uploaded only when its content changed."""
        self._data = data
        if not self._alive():
            return      # closed or deleted with its parent: a late worker result has nowhere to go
        now = time.perf_counter()
        if now - self._last_data_s < self.step_coarse_s and not self._mouse_down:
            self._interacting = True             # stepping: the coarse subset now, all points once it stops
            self._lod_timer.start()
        self._last_data_s = now
        self._set_points(data)
        self._tubes_all = list(data.tubes)
        self._surfaces_all = list(getattr(data, "surfaces", ()))
        self._update_tubes()
        span_us = data.span_us or self.session.view.spacetime_span_us
        self.time_axis.follow_span(span_us)
        if self.cage.update(span_us) and self._preset:
            self.set_preset(self._preset)      # the span changed and the user has not moved the camera
        self.slab.update(self.session.view.window_us)
        self._update_info()
        self.canvas.update()

    def set_interacting(self, on: bool) -> None:
        """Draw only the coarse prefix (about ``LOD_POINTS`` events, uniform in time) while ``on``; the
        canvas's mouse drag / wheel and the time-scale slider switch it, so the camera stays fluid on
        slow (software) OpenGL whatever the budget."""
        on = bool(on)
        if on == self._interacting or not self._alive():
            return
        self._interacting = on
        self.point_layer.show_coarse(on)
        self.band_layer.show_coarse(on)
        self.canvas.update()

    def set_time_scale(self, px_per_ms: float) -> None:
        """Depth per millisecond (scene pixels); moves the slider without recomputing data. Until this is
        called or the slider is moved, the scale follows the span so that its depth is the sensor width."""
        self.time_axis.set(px_per_ms)

    def set_preset(self, name: str) -> None:
        """Camera preset: ``"front"`` (along +t, like the frame view), ``"side"`` (along x: t to the right,
        rows down), ``"top"`` (down the rows: x to the right, t up) or ``"oblique"`` (the reset view).
        Front, side and top are orthographic, so the frame's geometry and a shear read true; the oblique
        view has perspective. The axis names and t ticks follow (those of an axis seen end-on are hidden)."""
        frame_preset(self.view.camera, name, (self._W, self._H, self._depth_extent()), self._aspect())
        self.cage.set_preset(name)
        self._preset = name
        self.canvas.update()

    def reset_view(self) -> None:
        """The default oblique camera framing the whole span."""
        self.set_preset("oblique")

    def render_image(self) -> np.ndarray:
        """The canvas as ``(H, W, 4)`` uint8 RGBA (``canvas.render()``, an offscreen framebuffer at the
        canvas size; works before the widget is shown, but needs an X display with GLX)."""
        return np.asarray(self.canvas.render(alpha=True))

    def shutdown(self) -> None:
        """Unsubscribe from the session and release the GL canvas (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._lod_timer.stop()
        try:
            self._subscription.disconnect()
        finally:
            if shiboken6.isValid(self.canvas.native):
                self.canvas.close()

    def closeEvent(self, event) -> None:  # noqa: N802 (Qt name)
        self.shutdown()
        super().closeEvent(event)

    # ====================================================================== internals
    def _alive(self) -> bool:
        """False once closed, or once Qt deleted the widget or its GL canvas (e.g. with a parent dock)."""
        return not self._closed and shiboken6.isValid(self) and shiboken6.isValid(self.canvas.native)

    def _aspect(self) -> float:
        w, h = self.canvas.size
        return w / max(h, 1)

    def _depth_extent(self) -> float:
        span_ms = (self._data.span_us if self._data is not None and self._data.span_us
                   else self.session.view.spacetime_span_us) * 1e-3
        return span_ms * self.time_axis.px_per_ms

    def _set_points(self, data) -> None:
        """Split ``data``'s events into the band and the rest (session settings, hidden objects) and hand each
        layer its share of the budget."""
        v = self.session.view
        names = self.session.object_names
        hidden_index = {k for k, n in enumerate(names) if n in v.hidden}
        sp = self.split = self.splitter.split(data, v.spacetime_band_px, v.spacetime_by_object, hidden_index)
        n = max(len(data.points), 1)
        budget = int(v.spacetime_budget)
        self.point_layer.set_palette(rest_palette(sp.by_object))
        self.band_layer.set_palette(band_palette(getattr(data, "object_colors", ()) or ()))
        band_budget = max(1, int(round(budget * len(sp.band_points) / n)))
        self.point_layer.set_points(sp.rest_points, sp.rest_colors, max(1, budget - band_budget)
                                    if len(sp.band_points) else budget)
        self.band_layer.set_points(sp.band_points, sp.band_colors, band_budget)
        self.point_layer.show_coarse(self._interacting)
        self.band_layer.show_coarse(self._interacting)
        self._drawn_settings = self._point_settings()

    def _point_settings(self) -> tuple:
        """What the split depends on besides the data (a change re-splits the data at hand)."""
        v = self.session.view
        return (float(v.spacetime_band_px), bool(v.spacetime_by_object), frozenset(v.hidden),
                stride_for(len(self._data.points) if self._data is not None else 0, v.spacetime_budget))

    def _update_tubes(self) -> None:
        hidden = self.session.view.hidden
        v = self.session.view
        band = float(v.spacetime_band_px) if self.split is not None and self.split.by_object else None
        self.tube_layer.update(self._tubes_all, hidden, self._surfaces_all)
        self.legend.show(self._tubes_all, hidden, band)

    def _update_info(self) -> None:
        self.controls.show_info(self._data, self.shown_count, self.point_layer.stride,
                                self.session.view.spacetime_budget)
        self.controls.show_band(self.split, self.session.view.spacetime_band_px)

    def _sync_from_view(self) -> None:
        v = self.session.view
        self.controls.show_view_state(v.spacetime_span_us, v.spacetime_budget, v.spacetime_band_px,
                                      v.spacetime_by_object)

    # ------------------------------------------------------------------ slots
    def _on_session(self, change: Change) -> None:
        if not self._alive():
            return
        if change.kind == "view":
            self._sync_from_view()
            self.slab.update(self.session.view.window_us)
            if self._data is not None and self._point_settings() != self._drawn_settings:
                self.set_data(self._data)     # budget or band changed: re-split what we have until new data comes
            self.canvas.update()
        elif change.kind == "objects":
            if self._data is not None:
                self.set_data(self._data)   # hide / show at once with the data at hand; new data follows
            self.canvas.update()

    def _on_mouse_press(self, event) -> None:
        self._preset = None       # the user moves the camera: stop re-framing on resize
        self._mouse_down = True
        self._lod_timer.stop()
        self.set_interacting(True)

    def _on_mouse_release(self, event) -> None:
        self._mouse_down = False
        self.set_interacting(False)

    def _on_mouse_wheel(self, event) -> None:
        self._preset = None
        self.set_interacting(True)
        self._lod_timer.start()

    def _on_canvas_resize(self, event) -> None:
        if self._preset and self._alive():
            self.set_preset(self._preset)


    def _on_span_spin(self, ms: int) -> None:
        self.session.set_view_option(spacetime_span_us=int(ms) * 1000)

    def _on_budget_spin(self, n: int) -> None:
        self.session.set_view_option(spacetime_budget=int(n))
