"""Space-time view: the events around the current time as an (x, y, t) point cloud and the objects'
projected silhouettes stacked along t as "tubes" (vispy, DESIGN sections 1-2).

A clock offset between the event camera and the pose source shows here as a *shear*: the event
sheets swept by a moving edge lean one way, the tubes built from the labelled poses another.

The widget is a view of a :class:`evpose.core.session.model.Session`: it takes the session in its constructor,
subscribes to its changes (view options, object visibility) and draws the display-ready
:class:`evpose.core.session.frames.SpaceTimeData` that core computes (``FrameComputer.spacetime``). The owner
(the app's controller or a test) computes that data, off the GUI thread if it likes, and hands it
over with :meth:`SpaceTimeView.set_data`; the widget never imports ``app``.

Scene layout (units): a data point ``(x px, y px, t ms)`` relative to the data's centre time is
mapped by one :class:`vispy.visuals.transforms.MatrixTransform` on the parent node of every visual
to scene ``X = x - cx``, ``Y = s * t`` (depth), ``Z = cy - y`` with ``s`` the time scale in scene
pixels per millisecond. So the *front* preset looks like the frame view (x right, image rows down,
time running away from the viewer), and the time-scale slider only rewrites that 4x4 matrix:
no data is rebuilt and nothing is uploaded but one uniform.

GPU uploads: the event cloud is **one** ``Markers`` visual (a subclass whose vertex shader takes the
polarity as one float and mixes the ON / OFF colours from uniforms, so a point costs 16 bytes —
position and polarity buffers — instead of the 56 bytes of ``Markers.set_data``'s interleaved
record; size, edge and symbol are constant attributes). Each buffer is re-uploaded only when its
content changed; the tubes (one ``Line`` visual, all objects, segment pairs) likewise. More points
than the session's point budget are thinned by a stride before upload, so the view stays
interactive whatever it is handed; the uploaded points are ordered so that a prefix of about
``LOD_POINTS`` is a time-uniform subset, which alone is drawn (through a fixed index buffer) while
the mouse drags the camera — on software OpenGL (Xvfb, VMs) drawing costs about 1-3 µs a point.

Controls: reset / front / side / top camera presets (``TurntableCamera``: drag orbits, wheel zooms,
shift-drag pans), the time-scale slider, the span (ms) and point-budget spin boxes (both written to
the session's view state; the owner recomputes on ``"view"``), and "N of M events shown".
"""
from __future__ import annotations

import math

import numpy as np
import shiboken6
from PySide6 import QtCore, QtWidgets

from evpose.core.signals import Change
from evpose.widgets.binding import connect_view
from evpose.widgets.labels import Readout

#: Event colours, as in the frame view (``core.represent``): ON red, OFF blue.
ON_RGBA = (1.0, 0.0, 0.0, 0.55)
OFF_RGBA = (0.0, 0.0, 1.0, 0.55)
BACKGROUND = "white"
CAGE_RGBA = (0.45, 0.45, 0.45, 0.8)
SLAB_RGBA = (0.3, 0.3, 0.3, 0.07)
SLAB_EDGE_RGBA = (0.2, 0.2, 0.2, 0.9)
TEXT_RGBA = (0.15, 0.15, 0.15, 1.0)
POINT_SIZE_PX = 2.0
POINT_ANTIALIAS = 0.0      # a 2 px sprite instead of 5-8 px: software GL (Xvfb, VMs) fills 2-3x faster
#: While the camera moves (drag, wheel, time-scale drag) only this many points are drawn (a time-uniform
#: subset: the vertex buffer is ordered so that every prefix is one), then all again.
LOD_POINTS = 40_000
LOD_IDLE_MS = 250
TUBE_WIDTH_PX = 2.0
TUBE_CASING_PX = 5.0       # a white casing under each tube keeps it legible inside a dense event cloud
TUBE_CASING_RGBA = (1.0, 1.0, 1.0, 0.9)

#: Time-scale slider: integer position v -> 10 ** (v / 100 + LOG_SCALE_MIN) scene px per ms.
LOG_SCALE_MIN, LOG_SCALE_MAX = -2.0, 2.0
BUDGET_RANGE = (1_000, 5_000_000)
SPAN_RANGE_MS = (1, 10_000)

#: Camera presets: (azimuth, elevation) in degrees. "front" looks along +t like the frame view;
#: "side" looks along x (t to the right, image rows down: shows vertical motion's shear);
#: "top" looks down the image rows (x to the right, t up: shows horizontal motion's shear);
#: "oblique" is the reset view.
PRESETS = {"oblique": (-40.0, 22.0), "front": (0.0, 0.0), "side": (90.0, 0.0), "top": (0.0, 90.0)}
OBLIQUE_FOV = 30.0


def _vispy():
    """Import vispy with the PySide6 backend (lazily: importing this module needs no display)."""
    import vispy
    from vispy import app as vapp

    try:
        vapp.use_app("pyside6")
    except RuntimeError:  # another backend already chosen in this process: use whatever is active
        pass
    return vispy


def _nice_step(x: float) -> float:
    """The 1-2-2.5-5 number nearest above ``x`` (tick spacing)."""
    if x <= 0:
        return 1.0
    e = 10 ** math.floor(math.log10(x))
    for m in (1, 2, 2.5, 5, 10):
        if m * e >= x:
            return m * e
    return 10 * e


def _lean_vertex_shader(src: str) -> str | None:
    """Markers' vertex shader with the per-point face colour replaced by a polarity in [0, 1] and two
    uniform colours; None when vispy's shader no longer has the expected lines (then the widget falls
    back to ``Markers.set_data``)."""
    decl, assign = "attribute vec4 a_bg_color;", "v_bg_color  = a_bg_color;"
    if decl not in src or assign not in src:
        return None
    src = src.replace(decl, "attribute float a_polarity;\nuniform vec4 u_on_color;\nuniform vec4 u_off_color;")
    return src.replace(assign, "v_bg_color = mix(u_off_color, u_on_color, a_polarity);")


def _make_event_cloud_class(lean: bool):
    """Build the ``Markers`` subclass (needs vispy, hence a factory); ``lean=False`` keeps vispy's shader
    and ``Markers.set_data`` (the fallback, also used by the benchmark for comparison)."""
    from vispy.gloo import VertexBuffer
    from vispy.scene.visuals import create_visual_node
    from vispy.visuals.markers import MarkersVisual

    lean_vs = _lean_vertex_shader(MarkersVisual._shaders["vertex"]) if lean else None

    class EventCloudVisual(MarkersVisual):
        """``Markers`` for events: positions (N, 3) float32 and polarity (N,) float32 as two separately
        updated vertex buffers, colour from uniforms. Falls back to ``Markers.set_data`` when vispy's
        shader changed (``lean`` is then False)."""

        lean = lean_vs is not None
        if lean:
            _shaders = {"vertex": lean_vs, "fragment": MarkersVisual._shaders["fragment"]}

        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            self.unfreeze()
            self._pos_vbo = VertexBuffer(np.zeros((1, 3), np.float32))
            self._pol_vbo = VertexBuffer(np.zeros(1, np.float32))
            self.freeze()
            if self.lean:
                self.set_colors(ON_RGBA, OFF_RGBA)

        def set_colors(self, on_rgba, off_rgba) -> None:
            self.shared_program["u_on_color"] = tuple(float(c) for c in on_rgba)
            self.shared_program["u_off_color"] = tuple(float(c) for c in off_rgba)
            self.update()

        def set_events(self, pos: np.ndarray | None, polarity: np.ndarray | None, size: float) -> None:
            """Upload what is given: ``pos`` (N, 3) float32 and/or ``polarity`` (N,) float32 in {0, 1};
            None keeps that buffer. Both must end up with the same length."""
            if not self.lean:
                raise RuntimeError("lean upload unavailable; use set_data")
            p = self.shared_program
            if pos is not None:
                if len(pos) == 0:
                    self._data = None       # Markers' "nothing to draw" (and no bounds)
                    self.update()
                    return
                self._pos_vbo.set_data(pos)
                p["a_position"] = self._pos_vbo
                self._data = {"a_position": pos}   # what Markers reads for bounds / the draw check
            if polarity is not None:
                self._pol_vbo.set_data(polarity)
                p["a_polarity"] = self._pol_vbo
            p["a_fg_color"] = (0.0, 0.0, 0.0, 0.0)
            p["a_size"] = float(size)
            p["a_edgewidth"] = 0.0
            p["a_symbol"] = float(self._symbol_shader_values["disc"])
            self.update()

    return create_visual_node(EventCloudVisual)


_EVENT_CLOUD: dict = {}


def event_cloud_node_class(lean: bool = True):
    """The scene-node class of the event cloud (a ``Markers`` subclass); ``.lean`` tells whether the
    16-byte-per-point upload is in use (False if vispy's marker shader no longer matches)."""
    if lean not in _EVENT_CLOUD:
        _vispy()
        _EVENT_CLOUD[lean] = _make_event_cloud_class(lean)
    return _EVENT_CLOUD[lean]


def stride_for(n: int, budget: int) -> int:
    """Smallest stride ``k`` with ``ceil(n / k) <= budget`` (1 when within budget)."""
    budget = max(int(budget), 1)
    return 1 if n <= budget else -(-n // budget)


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

    def __init__(self, session, parent=None):
        super().__init__(parent)
        _vispy()
        from vispy import scene
        from vispy.visuals.transforms import MatrixTransform

        self.session = session
        cam = session.scene.camera
        self._W, self._H = int(cam.width), int(cam.height)
        self._data = None
        self._tubes_all: list = []
        self._shown = 0
        self._stride = 1
        self._last_pos_src = None      # (array, stride) last uploaded as positions (arrays are not mutated)
        self._lod_count = 0            # vertices in the coarse prefix drawn while interacting
        self._lod_ib = None
        self._interacting = False
        self._lod_timer = QtCore.QTimer(self)
        self._lod_timer.setSingleShot(True)
        self._lod_timer.setInterval(LOD_IDLE_MS)
        self._lod_timer.timeout.connect(lambda: self.set_interacting(False))
        self._last_pol: np.ndarray | None = None
        self._last_tube_key = None
        self._cage_key = None
        self._legend_key = None
        self._closed = False
        #: Buffer uploads since construction (``points``, ``polarity``, ``tubes``, ``cage``, ``slab``, ``lod``):
        #: tests and the benchmark check that only changed buffers go to the GPU.
        self.upload_counts = {"points": 0, "polarity": 0, "tubes": 0, "cage": 0, "slab": 0, "lod": 0}

        # ------------------------------------------------------------------ canvas and scene
        self.canvas = scene.SceneCanvas(keys=None, show=False, bgcolor=BACKGROUND, size=(640, 480),
                                        parent=self)
        self.view = self.canvas.central_widget.add_view()
        self.view.camera = scene.TurntableCamera(fov=OBLIQUE_FOV, up="+z")
        self.root = scene.Node(parent=self.view.scene)
        self._transform = MatrixTransform()
        self.root.transform = self._transform

        Cloud = event_cloud_node_class(self.lean_upload)
        self.markers = Cloud(parent=self.root, scaling="fixed", antialias=POINT_ANTIALIAS)
        self.markers.set_gl_state("translucent", depth_test=False, cull_face=False)
        self.markers.order = 0
        self.cage = scene.visuals.Line(parent=self.root, color=CAGE_RGBA, connect="segments", width=1,
                                       method="gl", antialias=False)
        self.cage.set_gl_state("translucent", depth_test=False)
        self.cage.order = -1
        self.slab = scene.visuals.Mesh(parent=self.root, color=SLAB_RGBA)
        self.slab.set_gl_state("translucent", depth_test=False, cull_face=False)
        self.slab.order = 1
        self.slab_edge = scene.visuals.Line(parent=self.root, color=SLAB_EDGE_RGBA, connect="segments",
                                            width=1.5, method="gl", antialias=False)
        self.slab_edge.set_gl_state("translucent", depth_test=False)
        self.slab_edge.order = 2
        self.tube_casing = scene.visuals.Line(parent=self.root, connect="segments", width=TUBE_CASING_PX,
                                              color=TUBE_CASING_RGBA, method="gl", antialias=False)
        self.tube_casing.set_gl_state("translucent", depth_test=False)
        self.tube_casing.order = 3
        self.tube_casing.visible = False
        self.tubes = scene.visuals.Line(parent=self.root, connect="segments", width=TUBE_WIDTH_PX,
                                        method="gl", antialias=False)
        self.tubes.set_gl_state("translucent", depth_test=False)
        self.tubes.order = 4
        self.tubes.visible = False
        self.axis_text = scene.visuals.Text(parent=self.root, color=TEXT_RGBA, font_size=9, bold=True)
        self.axis_text.order = 5
        self.tick_text = scene.visuals.Text(parent=self.root, color=TEXT_RGBA, font_size=7)
        self.tick_text.order = 5
        self.legend = QtWidgets.QLabel(self.canvas.native)   # top-left corner, over the canvas
        self.legend.setAttribute(QtCore.Qt.WA_TransparentForMouseEvents)
        self.legend.setStyleSheet("background: transparent; font-size: 8pt;")
        self.legend.move(6, 4)

        # ------------------------------------------------------------------ controls
        self.reset_button = QtWidgets.QPushButton("Reset view")
        self.reset_button.setToolTip("Oblique view of the whole span (drag: orbit, wheel: zoom, shift-drag: pan)")
        self.front_button = QtWidgets.QPushButton("Front")
        self.front_button.setToolTip("Look along the time axis, like the frame view")
        self.side_button = QtWidgets.QPushButton("Side")
        self.side_button.setToolTip("Look along x: time runs to the right, image rows down; a clock offset "
                                    "shows as a shear between event sheets and tubes (vertical motion)")
        self.top_button = QtWidgets.QPushButton("Top")
        self.top_button.setToolTip("Look down the image rows: x to the right, time up; "
                                   "shows the shear of horizontal motion")
        self.scale_slider = QtWidgets.QSlider(QtCore.Qt.Horizontal)
        self.scale_slider.setRange(0, int(round((LOG_SCALE_MAX - LOG_SCALE_MIN) * 100)))
        self.scale_slider.setToolTip("Time scale: scene pixels of depth per millisecond (no recomputation)")
        self.scale_label = QtWidgets.QLabel()
        self.scale_label.setMinimumWidth(64)
        self.span_spin = QtWidgets.QSpinBox()
        self.span_spin.setRange(*SPAN_RANGE_MS)
        self.span_spin.setSuffix(" ms")
        self.span_spin.setToolTip("Time span of events shown around the current time")
        self.span_spin.setKeyboardTracking(False)
        self.budget_spin = QtWidgets.QSpinBox()
        self.budget_spin.setRange(*BUDGET_RANGE)
        self.budget_spin.setSingleStep(50_000)
        self.budget_spin.setGroupSeparatorShown(True)
        self.budget_spin.setToolTip("Point budget: at most this many events are drawn (decimated in time)")
        self.budget_spin.setKeyboardTracking(False)
        self.info_label = Readout("99,999,999 of 99,999,999 events shown", "no events", stretch=True)

        # three short rows: the view usually lives in a narrow dock
        self.scale_slider.setMinimumWidth(90)
        row1 = QtWidgets.QHBoxLayout()
        for w in (self.reset_button, self.front_button, self.side_button, self.top_button):
            row1.addWidget(w)
        row1.addStretch(1)
        row2 = QtWidgets.QHBoxLayout()
        row2.addWidget(QtWidgets.QLabel("time scale"))
        row2.addWidget(self.scale_slider, 1)
        row2.addWidget(self.scale_label)
        row2.addSpacing(8)
        row2.addWidget(QtWidgets.QLabel("span"))
        row2.addWidget(self.span_spin)
        row3 = QtWidgets.QHBoxLayout()
        row3.addWidget(QtWidgets.QLabel("budget"))
        row3.addWidget(self.budget_spin)
        row3.addSpacing(8)
        row3.addWidget(self.info_label, 1)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.setSpacing(3)
        layout.addWidget(self.canvas.native, 1)
        layout.addLayout(row1)
        layout.addLayout(row2)
        layout.addLayout(row3)

        self.reset_button.clicked.connect(self.reset_view)
        self.front_button.clicked.connect(lambda: self.set_preset("front"))
        self.side_button.clicked.connect(lambda: self.set_preset("side"))
        self.top_button.clicked.connect(lambda: self.set_preset("top"))
        self.scale_slider.valueChanged.connect(self._on_scale_slider)
        self.scale_slider.sliderPressed.connect(lambda: self.set_interacting(True))
        self.scale_slider.sliderReleased.connect(lambda: self.set_interacting(False))
        self.span_spin.valueChanged.connect(self._on_span_spin)
        self.budget_spin.valueChanged.connect(self._on_budget_spin)

        # ------------------------------------------------------------------ model binding
        self._sync_from_view()
        self._scale_auto = True          # follow the span (depth ~ sensor width) until the user sets a scale
        self._auto_scale(self.session.view.spacetime_span_us)
        self._update_cage(self.session.view.spacetime_span_us)
        self._update_slab(self.session.view.window_us)
        self._preset = None             # the preset in effect until the user moves the camera
        self.reset_view()
        self.canvas.events.mouse_press.connect(self._on_mouse_press)
        self.canvas.events.mouse_release.connect(self._on_mouse_release)
        self.canvas.events.mouse_wheel.connect(self._on_mouse_wheel)
        self.canvas.events.resize.connect(self._on_canvas_resize)
        self._subscription = connect_view(self, session.changed, self._on_session)

    # ====================================================================== public API
    @property
    def data(self):
        """The :class:`SpaceTimeData` last given to :meth:`set_data` (None before)."""
        return self._data

    @property
    def shown_count(self) -> int:
        """Events drawn now (after the widget's own stride)."""
        return self._shown

    @property
    def time_scale(self) -> float:
        """Scene pixels of depth per millisecond."""
        return self._scale

    def set_data(self, data) -> None:
        """Draw ``data`` (:class:`evpose.core.session.frames.SpaceTimeData`): events coloured by polarity, tubes of the
        objects not hidden in the session, the current-window slab at t = 0 and the span's cage.

        More points than ``session.view.spacetime_budget`` are thinned by a stride before upload. The
        arrays are treated as immutable: handing the same ``points`` array again uploads nothing, and the
        polarity buffer is uploaded only when its content changed."""
        self._data = data
        if not self._alive():
            return      # closed or deleted with its parent: a late worker result has nowhere to go
        pts = data.points
        n = len(pts)
        budget = int(self.session.view.spacetime_budget)
        self._stride = stride_for(n, budget)
        last = self._last_pos_src
        same = last is not None and last[0] is pts and last[1] == self._stride and self._last_pol is not None
        if n == 0:
            self._upload_points(np.zeros((0, 3), np.float32), np.zeros(0, np.uint8))
            self._last_pos_src = None
            self._lod_count = 0
        else:
            idx, self._lod_count = self._draw_order(n)
            pol = np.asarray(data.polarity)[idx]
            if not same:
                self._upload_points(np.ascontiguousarray(pts[idx], dtype=np.float32), pol)
                self._last_pos_src = (pts, self._stride)
            else:   # the same array again: positions stay; polarity uploaded only if it changed
                self._upload_points(None, pol)
        self._shown = len(range(0, n, self._stride))
        self._apply_lod()
        self._tubes_all = list(data.tubes)
        self._update_tubes()
        span_us = data.span_us or self.session.view.spacetime_span_us
        self._auto_scale(span_us)
        if self._update_cage(span_us) and self._preset:
            self.set_preset(self._preset)      # the span changed and the user has not moved the camera
        self._update_slab(self.session.view.window_us)
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
        self._apply_lod()
        self.canvas.update()

    def set_time_scale(self, px_per_ms: float) -> None:
        """Depth per millisecond (scene pixels); moves the slider without recomputing data. Until this is
        called or the slider is moved, the scale follows the span so that its depth is the sensor width."""
        self._scale_auto = False
        self._set_scale(px_per_ms)

    def _auto_scale(self, span_us: int) -> None:
        if self._scale_auto:
            self._set_scale(max(self._W, self._H) / max(span_us * 1e-3, 1e-3))

    def _set_scale(self, px_per_ms: float) -> None:
        px_per_ms = float(np.clip(px_per_ms, 10 ** LOG_SCALE_MIN, 10 ** LOG_SCALE_MAX))
        v = int(round((math.log10(px_per_ms) - LOG_SCALE_MIN) * 100))
        self._scale = px_per_ms
        self.scale_slider.blockSignals(True)
        self.scale_slider.setValue(v)
        self.scale_slider.blockSignals(False)
        self._apply_transform()

    def set_preset(self, name: str) -> None:
        """Camera preset: ``"front"`` (along +t, like the frame view), ``"side"`` (along x: t to the right,
        rows down), ``"top"`` (down the rows: x to the right, t up) or ``"oblique"`` (the reset view).
        Front, side and top are orthographic, so the frame's geometry and a shear read true; the oblique
        view has perspective."""
        az, el = PRESETS[name]
        cam = self.view.camera
        cam.fov = 0.0 if name in ("front", "side", "top") else OBLIQUE_FOV
        cam.center = (0.0, 0.0, 0.0)
        cam.azimuth, cam.elevation, cam.roll = az, el, 0.0
        W, H, D = self._W, self._H, self._depth_extent()
        a = self._aspect()
        if name == "front":
            w, h = W, H
        elif name == "side":
            w, h = D, H
        elif name == "top":
            w, h = W, D
        else:
            w = h = 0.95 * math.sqrt(W * W + H * H + D * D)
        # TurntableCamera.scale_factor spans the shorter side of the viewport
        cam.scale_factor = 1.2 * max(w / max(a, 1.0), h / max(1.0 / a, 1.0))
        cam.distance = None
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
        return span_ms * self._scale

    def _apply_transform(self) -> None:
        cx, cy, s = (self._W - 1) / 2.0, (self._H - 1) / 2.0, self._scale
        # vispy maps row vectors: scene = [x, y, t, 1] @ M
        M = np.array([[1.0, 0.0, 0.0, 0.0],
                      [0.0, 0.0, -1.0, 0.0],
                      [0.0, s, 0.0, 0.0],
                      [-cx, 0.0, cy, 1.0]])
        self._transform.matrix = M
        self.scale_label.setText(f"{s:.3g} px/ms")
        self.canvas.update()

    def _draw_order(self, n: int) -> tuple[np.ndarray, int]:
        """Indices into the ``n`` given points: every ``stride``-th (the budget), ordered in ``k``
        interleaved runs so that the first run alone is a time-uniform coarse subset of about
        ``LOD_POINTS`` events. Returns (indices, length of the first run)."""
        s = self._stride
        m = len(range(0, n, s))
        k = max(1, -(-m // LOD_POINTS))
        if k == 1:
            return np.arange(0, n, s), m
        runs = [np.arange(j * s, n, k * s) for j in range(k)]
        return np.concatenate(runs), len(runs[0])

    def _apply_lod(self) -> None:
        from vispy.gloo import IndexBuffer

        if self._interacting and 0 < self._lod_count < self._shown:
            if self._lod_ib is None or self._lod_ib.size != self._lod_count:
                self._lod_ib = IndexBuffer(np.arange(self._lod_count, dtype=np.uint32))
                self.upload_counts["lod"] += 1
            self.markers._index_buffer = self._lod_ib
        else:
            self.markers._index_buffer = None
        self.markers.update()

    def _upload_points(self, pos: np.ndarray | None, pol_u8: np.ndarray) -> None:
        cloud = self.markers
        if pos is not None and len(pos) == 0:
            if cloud.lean:
                cloud.set_events(pos, None, POINT_SIZE_PX)
            else:
                cloud.set_data(None)
            self._last_pol = None
            return
        if not cloud.lean:   # fallback: the stock interleaved upload of everything
            if pos is None:
                pos = cloud._data["a_position"]
            colors = np.where(pol_u8[:, None] > 0, np.asarray(ON_RGBA, np.float32),
                              np.asarray(OFF_RGBA, np.float32))
            cloud.set_data(pos, face_color=colors, edge_width=0, size=POINT_SIZE_PX, symbol="disc")
            self.upload_counts["points"] += 1
            self.upload_counts["polarity"] += 1
            self._last_pol = pol_u8.copy()
            return
        pol_changed = (self._last_pol is None or len(self._last_pol) != len(pol_u8)
                       or not np.array_equal(self._last_pol, pol_u8))
        pol = (pol_u8 > 0).astype(np.float32) if pol_changed else None
        cloud.set_events(pos, pol, POINT_SIZE_PX)
        if pos is not None:
            self.upload_counts["points"] += 1
        if pol_changed:
            self.upload_counts["polarity"] += 1
            self._last_pol = np.array(pol_u8, copy=True)

    def _update_tubes(self) -> None:
        hidden = self.session.view.hidden
        verts, segs, cols = [], [], []
        base = 0
        for name, rgb, polys in self._tubes_all:
            if name in hidden:
                continue
            rgba = np.array([*(c / 255.0 for c in rgb), 1.0], np.float32)
            for poly in polys:
                m = len(poly)
                if m < 2:
                    continue
                verts.append(np.asarray(poly, np.float32))
                idx = base + np.arange(m)
                segs.append(np.stack([idx, np.roll(idx, -1)], axis=1))   # closed polyline
                cols.append(np.broadcast_to(rgba, (m, 4)))
                base += m
        key = None
        if verts:
            v = np.concatenate(verts)
            c = np.concatenate(cols)
            s = np.concatenate(segs).astype(np.uint32)
            key = (v.tobytes(), c.tobytes())
        if key == self._last_tube_key:
            return
        self._last_tube_key = key
        if key is None:
            self.tubes.visible = self.tube_casing.visible = False
        else:
            self.tube_casing.set_data(pos=v, connect=s)
            self.tubes.set_data(pos=v, color=c, connect=s)
            self.tubes.visible = self.tube_casing.visible = True
            self.upload_counts["tubes"] += 1
        self._update_legend()

    def _update_legend(self) -> None:
        """The legend is a Qt label over the canvas, not GL text: vispy rasterises every new glyph
        on the CPU and compiles a shader per text visual (seconds on software GL)."""
        import html

        hidden = self.session.view.hidden
        entries = [("ON events", ON_RGBA[:3]), ("OFF events", OFF_RGBA[:3]), ("current window", SLAB_EDGE_RGBA[:3])]
        entries += [(name, tuple(c / 255.0 for c in rgb)) for name, rgb, _ in self._tubes_all if name not in hidden]
        key = tuple(entries)
        if key == self._legend_key:
            return
        self._legend_key = key
        rows = []
        for i, (text, rgb) in enumerate(entries):
            mark = "\u00b7 " if i < 2 else ("[ ] " if i == 2 else "\u2014 ")
            color = "#%02x%02x%02x" % tuple(int(round(255 * c)) for c in rgb)
            rows.append(f"<span style='color:{color}'>{html.escape(mark + text)}</span>")
        self.legend.setText("<b>" + "<br>".join(rows) + "</b>")
        self.legend.adjustSize()

    def _update_cage(self, span_us: int) -> bool:
        """Sensor rectangles at both ends of the span joined along t, axis names and t ticks (ms);
        True when they changed."""
        W, H = self._W - 1, self._H - 1
        h = 0.5 * span_us * 1e-3
        key = (W, H, h)
        if key == self._cage_key:
            return False
        self._cage_key = key
        corners = np.array([[0, 0], [W, 0], [W, H], [0, H]], np.float32)
        pts, segs = [], []
        for t in (-h, h):
            base = len(pts)
            pts += [[x, y, t] for x, y in corners]
            segs += [[base + i, base + (i + 1) % 4] for i in range(4)]
        segs += [[i, i + 4] for i in range(4)]
        step = _nice_step(2 * h / 4)
        ticks = np.arange(math.ceil(-h / step) * step, h + 1e-9, step)
        tick_len = 0.03 * max(W, H)
        for t in ticks:               # small ticks on the bottom-left edge (x = 0, y = H)
            base = len(pts)
            pts += [[0, H, t], [-tick_len, H, t]]
            segs.append([base, base + 1])
        self.cage.set_data(pos=np.array(pts, np.float32), connect=np.array(segs, np.uint32))
        self.upload_counts["cage"] += 1
        labels = [f"{t:+g}" if t else "0" for t in ticks]
        labels[-1] += " ms"
        self.tick_text.text = labels
        self.tick_text.pos = np.array([[-2.2 * tick_len, H + 0.04 * H, t] for t in ticks], np.float32)
        self.axis_text.text = ["x", "y", "t (ms)"]
        self.axis_text.pos = np.array([[W + 0.06 * W, 0, -h], [0, H + 0.09 * H, -h],
                                       [-0.05 * W, H + 0.15 * H, h + 0.08 * 2 * h]], np.float32)
        return True

    def _update_slab(self, window_us: int) -> None:
        """A translucent box over the sensor for the current window ``[-w/2, w/2]`` around t = 0."""
        W, H = self._W - 1, self._H - 1
        w = 0.5 * window_us * 1e-3
        key = (W, H, w)
        if getattr(self, "_slab_key", None) == key:
            return
        self._slab_key = key
        v = np.array([[x, y, t] for t in (-w, w) for x, y in ((0, 0), (W, 0), (W, H), (0, H))], np.float32)
        faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7],      # t = -w/2, +w/2
                          [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5],
                          [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]], np.uint32)
        self.slab.set_data(vertices=v, faces=faces, color=SLAB_RGBA)
        mid = np.array([[x, y, 0.0] for x, y in ((0, 0), (W, 0), (W, H), (0, H))], np.float32)
        self.slab_edge.set_data(pos=mid, connect=np.array([[0, 1], [1, 2], [2, 3], [3, 0]], np.uint32))
        self.upload_counts["slab"] += 1

    def _update_info(self) -> None:
        d = self._data
        if d is None:
            self.info_label.setText("no events")
            return
        self.info_label.setText(f"{self._shown:,} of {int(d.n_total):,} events shown")
        tip = [f"span {d.span_us / 1e3:g} ms around t = {d.t_center_us} µs",
               f"{len(d.points):,} points computed (budget {self.session.view.spacetime_budget:,})"]
        if self._stride > 1:
            tip.append(f"every {self._stride}th point drawn (more points than the budget)")
        self.info_label.setToolTip("\n".join(tip))

    def _sync_from_view(self) -> None:
        v = self.session.view
        for spin, value in ((self.span_spin, int(round(v.spacetime_span_us / 1000))),
                            (self.budget_spin, int(v.spacetime_budget))):
            if spin.value() != value:
                spin.blockSignals(True)
                spin.setValue(value)
                spin.blockSignals(False)

    # ------------------------------------------------------------------ slots
    def _on_session(self, change: Change) -> None:
        if not self._alive():
            return
        if change.kind == "view":
            self._sync_from_view()
            self._update_slab(self.session.view.window_us)
            if self._data is not None and stride_for(len(self._data.points),
                                                     self.session.view.spacetime_budget) != self._stride:
                self.set_data(self._data)     # the budget changed: re-thin what we have until new data comes
            self.canvas.update()
        elif change.kind == "objects":
            self._update_tubes()    # hide / show at once with the tubes at hand; new data follows
            self.canvas.update()

    def _on_mouse_press(self, event) -> None:
        self._preset = None       # the user moves the camera: stop re-framing on resize
        self.set_interacting(True)

    def _on_mouse_release(self, event) -> None:
        self.set_interacting(False)

    def _on_mouse_wheel(self, event) -> None:
        self._preset = None
        self.set_interacting(True)
        self._lod_timer.start()

    def _on_canvas_resize(self, event) -> None:
        if self._preset and self._alive():
            self.set_preset(self._preset)

    def _on_scale_slider(self, v: int) -> None:
        self._scale_auto = False
        self._scale = 10 ** (v / 100 + LOG_SCALE_MIN)
        self._apply_transform()

    def _on_span_spin(self, ms: int) -> None:
        self.session.set_view_option(spacetime_span_us=int(ms) * 1000)

    def _on_budget_spin(self, n: int) -> None:
        self.session.set_view_option(spacetime_budget=int(n))
