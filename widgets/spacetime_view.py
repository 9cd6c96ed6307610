"""Space-time view: the events around the current time as an (x, y, t) point cloud and the objects'
projected silhouettes stacked along t as "tubes" (vispy, DESIGN sections 1-2).

A clock offset between the event camera and the pose source shows here as a *shear*: the event
sheets swept by a moving edge lean one way, the tubes built from the labelled poses another.

The widget is a view of a :class:`core.session.Session`: it takes the session in its constructor,
subscribes to its changes (view options, object visibility) and draws the display-ready
:class:`core.session.SpaceTimeData` that core computes (``FrameComputer.spacetime``). The owner
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
interactive whatever it is handed.
"""
from __future__ import annotations

import math

import numpy as np
from PySide6 import QtCore, QtWidgets

#: Event colours, as in the frame view (``core.represent``): ON red, OFF blue.
ON_RGBA = (1.0, 0.0, 0.0, 0.55)
OFF_RGBA = (0.0, 0.0, 1.0, 0.55)
BACKGROUND = "white"
CAGE_RGBA = (0.45, 0.45, 0.45, 0.8)
SLAB_RGBA = (0.25, 0.25, 0.25, 0.10)
SLAB_EDGE_RGBA = (0.15, 0.15, 0.15, 0.9)
TEXT_RGBA = (0.15, 0.15, 0.15, 1.0)
POINT_SIZE_PX = 2.0
TUBE_WIDTH_PX = 2.0

#: Time-scale slider: integer position v -> 10 ** (v / 100 + LOG_SCALE_MIN) scene px per ms.
LOG_SCALE_MIN, LOG_SCALE_MAX = -2.0, 2.0
BUDGET_RANGE = (1_000, 5_000_000)
SPAN_RANGE_MS = (1, 10_000)

#: Camera presets: (azimuth, elevation) in degrees. "front" looks along +t like the frame view;
#: "side" looks along -x (t to the right, image rows down); "oblique" is the reset view.
PRESETS = {"oblique": (-40.0, 22.0), "front": (0.0, 0.0), "side": (90.0, 0.0)}


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
    """The 1-2-5 number nearest above ``x`` (tick spacing)."""
    if x <= 0:
        return 1.0
    e = 10 ** math.floor(math.log10(x))
    for m in (1, 2, 5, 10):
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


def _make_event_cloud_class():
    """Build the ``Markers`` subclass (needs vispy, hence a factory)."""
    from vispy.gloo import VertexBuffer
    from vispy.visuals.markers import MarkersVisual
    from vispy.scene.visuals import create_visual_node

    lean_vs = _lean_vertex_shader(MarkersVisual._shaders["vertex"])

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
            self._size_px = POINT_SIZE_PX
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


_EVENT_CLOUD = None


def event_cloud_node_class():
    global _EVENT_CLOUD
    if _EVENT_CLOUD is None:
        _vispy()
        _EVENT_CLOUD = _make_event_cloud_class()
    return _EVENT_CLOUD


def stride_for(n: int, budget: int) -> int:
    """Smallest stride ``k`` with ``ceil(n / k) <= budget`` (1 when within budget)."""
    budget = max(int(budget), 1)
    return 1 if n <= budget else -(-n // budget)


class SpaceTimeView(QtWidgets.QWidget):
    """(x, y, t) event cloud + silhouette tubes, with camera presets, a time scale and budget controls.

    Parameters
    ----------
    session : core.session.Session
        The model. Read: ``view.spacetime_budget``, ``view.spacetime_span_us``, ``view.window_us``,
        ``view.hidden``, the camera size. Written (view state only): ``spacetime_budget`` and
        ``spacetime_span_us`` through ``set_view_option``.
    """

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
        self._last_pos_src = None      # (id, shape) of the array last uploaded as positions
        self._last_pol: np.ndarray | None = None
        self._last_tube_key = None
        self._cage_key = None
        self._legend_key = None
        self._closed = False
        #: Buffer uploads since construction (``points``, ``polarity``, ``tubes``, ``cage``, ``slab``):
        #: tests and the benchmark check that only changed buffers go to the GPU.
        self.upload_counts = {"points": 0, "polarity": 0, "tubes": 0, "cage": 0, "slab": 0}

        # ------------------------------------------------------------------ canvas and scene
        self.canvas = scene.SceneCanvas(keys=None, show=False, bgcolor=BACKGROUND, size=(640, 480),
                                        parent=self)
        self.view = self.canvas.central_widget.add_view()
        self.view.camera = scene.TurntableCamera(fov=30.0, up="+z")
        self.root = scene.Node(parent=self.view.scene)
        self._transform = MatrixTransform()
        self.root.transform = self._transform

        Cloud = event_cloud_node_class()
        self.markers = Cloud(parent=self.root, scaling="fixed", antialias=0.6)
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
        self.tubes = scene.visuals.Line(parent=self.root, connect="segments", width=TUBE_WIDTH_PX,
                                        method="gl", antialias=False)
        self.tubes.set_gl_state("translucent", depth_test=False)
        self.tubes.order = 3
        self.tubes.visible = False
        self.axis_text = scene.visuals.Text(parent=self.root, color=TEXT_RGBA, font_size=9, bold=True)
        self.axis_text.order = 4
        self.tick_text = scene.visuals.Text(parent=self.root, color=CAGE_RGBA, font_size=7)
        self.tick_text.order = 4
        self.legend: list = []          # Text visuals in canvas pixels (top-left corner)

        # ------------------------------------------------------------------ controls
        self.reset_button = QtWidgets.QPushButton("Reset view")
        self.reset_button.setToolTip("Oblique view of the whole span (drag: orbit, wheel: zoom, shift-drag: pan)")
        self.front_button = QtWidgets.QPushButton("Front")
        self.front_button.setToolTip("Look along the time axis, like the frame view")
        self.side_button = QtWidgets.QPushButton("Side")
        self.side_button.setToolTip("Look along x: time runs to the right, image rows down; "
                                    "a clock offset shows as a shear between event sheets and tubes")
        self.scale_slider = QtWidgets.QSlider(QtCore.Qt.Horizontal)
        self.scale_slider.setRange(0, int(round((LOG_SCALE_MAX - LOG_SCALE_MIN) * 100)))
        self.scale_slider.setToolTip("Time scale: scene pixels of depth per millisecond (no recomputation)")
        self.scale_label = QtWidgets.QLabel()
        self.scale_label.setMinimumWidth(70)
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
        self.info_label = QtWidgets.QLabel("no events")
        self.info_label.setTextInteractionFlags(QtCore.Qt.TextSelectableByMouse)

        row1 = QtWidgets.QHBoxLayout()
        for w in (self.reset_button, self.front_button, self.side_button):
            row1.addWidget(w)
        row1.addSpacing(12)
        row1.addWidget(QtWidgets.QLabel("time scale"))
        row1.addWidget(self.scale_slider, 1)
        row1.addWidget(self.scale_label)
        row2 = QtWidgets.QHBoxLayout()
        row2.addWidget(QtWidgets.QLabel("span"))
        row2.addWidget(self.span_spin)
        row2.addSpacing(12)
        row2.addWidget(QtWidgets.QLabel("budget"))
        row2.addWidget(self.budget_spin)
        row2.addSpacing(12)
        row2.addWidget(self.info_label, 1)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.setSpacing(3)
        layout.addWidget(self.canvas.native, 1)
        layout.addLayout(row1)
        layout.addLayout(row2)

        self.reset_button.clicked.connect(self.reset_view)
        self.front_button.clicked.connect(lambda: self.set_preset("front"))
        self.side_button.clicked.connect(lambda: self.set_preset("side"))
        self.scale_slider.valueChanged.connect(self._on_scale_slider)
        self.span_spin.valueChanged.connect(self._on_span_spin)
        self.budget_spin.valueChanged.connect(self._on_budget_spin)

        # ------------------------------------------------------------------ model binding
        self._sync_from_view()
        span_ms = max(self.session.view.spacetime_span_us * 1e-3, 1e-3)
        self.set_time_scale(max(self._W, self._H) / span_ms)    # depth of the span ~ sensor width
        self._update_cage(self.session.view.spacetime_span_us)
        self._update_slab(self.session.view.window_us)
        self.reset_view()
        unsubscribe = session.subscribe(self._on_session)
        self._unsubscribe = unsubscribe
        self.destroyed.connect(lambda *_: unsubscribe())   # no reference to self: safe after deletion

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
        """Draw ``data`` (:class:`core.session.SpaceTimeData`): events coloured by polarity, tubes of the
        objects not hidden in the session, the current-window slab at t = 0 and the span's cage."""
        self._data = data
        pts = data.points
        n = len(pts)
        budget = int(self.session.view.spacetime_budget)
        self._stride = stride_for(n, budget)
        src_key = (id(pts), pts.shape, self._stride)
        if n == 0:
            self._upload_points(np.zeros((0, 3), np.float32), np.zeros(0, np.uint8))
            self._last_pos_src = None
        elif src_key != self._last_pos_src or self._last_pol is None:
            p = pts[:: self._stride] if self._stride > 1 else pts
            pol = data.polarity[:: self._stride] if self._stride > 1 else data.polarity
            self._upload_points(np.ascontiguousarray(p, dtype=np.float32), np.asarray(pol))
            self._last_pos_src = src_key
        else:   # the same array again: positions stay; polarity uploaded only if it changed
            pol = data.polarity[:: self._stride] if self._stride > 1 else data.polarity
            self._upload_points(None, np.asarray(pol))
        self._shown = len(range(0, n, self._stride))
        self._tubes_all = list(data.tubes)
        self._update_tubes()
        self._update_cage(data.span_us or self.session.view.spacetime_span_us)
        self._update_slab(self.session.view.window_us)
        self._update_info()
        self.canvas.update()

    def set_time_scale(self, px_per_ms: float) -> None:
        """Depth per millisecond (scene pixels); moves the slider without recomputing data."""
        px_per_ms = float(np.clip(px_per_ms, 10 ** LOG_SCALE_MIN, 10 ** LOG_SCALE_MAX))
        v = int(round((math.log10(px_per_ms) - LOG_SCALE_MIN) * 100))
        self._scale = px_per_ms
        self.scale_slider.blockSignals(True)
        self.scale_slider.setValue(v)
        self.scale_slider.blockSignals(False)
        self._apply_transform()

    def set_preset(self, name: str) -> None:
        """Camera preset: ``"front"`` (along +t, like the frame view), ``"side"`` (t to the right) or
        ``"oblique"`` (the reset view). Keeps the zoom of :meth:`reset_view`."""
        az, el = PRESETS[name]
        cam = self.view.camera
        cam.center = (0.0, 0.0, 0.0)
        cam.azimuth, cam.elevation, cam.roll = az, el, 0.0
        depth = self._depth_extent()
        if name == "front":
            extent = max(self._W, self._H * self._aspect())
        elif name == "side":
            extent = max(depth, self._H * self._aspect())
        else:
            extent = max(self._W, depth, self._H * self._aspect())
        cam.scale_factor = 1.15 * extent
        cam.distance = None
        self.canvas.update()

    def reset_view(self) -> None:
        """The default oblique camera framing the whole span."""
        self.set_preset("oblique")

    def render_image(self) -> np.ndarray:
        """The canvas as ``(H, W, 4)`` uint8 RGBA (``canvas.render()``); the widget must have been shown."""
        return np.asarray(self.canvas.render(alpha=True))

    def shutdown(self) -> None:
        """Unsubscribe from the session and release the GL canvas (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._unsubscribe()
        finally:
            self.canvas.close()

    def closeEvent(self, event) -> None:  # noqa: N802 (Qt name)
        self.shutdown()
        super().closeEvent(event)

    # ====================================================================== internals
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
            self.tubes.visible = False
        else:
            self.tubes.set_data(pos=v, color=c, connect=s)
            self.tubes.visible = True
            self.upload_counts["tubes"] += 1
        self._update_legend()

    def _update_legend(self) -> None:
        from vispy import scene

        hidden = self.session.view.hidden
        entries = [("ON events", ON_RGBA[:3]), ("OFF events", OFF_RGBA[:3])]
        entries += [(name, tuple(c / 255.0 for c in rgb)) for name, rgb, _ in self._tubes_all if name not in hidden]
        key = tuple(entries)
        if key == self._legend_key:
            return
        self._legend_key = key
        for t in self.legend:
            t.parent = None
        self.legend = []
        for i, (text, rgb) in enumerate(entries):
            mark = "\u25cf " if i < 2 else "\u2014 "
            t = scene.visuals.Text(mark + text, parent=self.canvas.scene, color=(*rgb, 1.0), font_size=8,
                                   bold=True, anchor_x="left", anchor_y="top", pos=(8, 8 + 15 * i))
            t.order = 10
            self.legend.append(t)

    def _update_cage(self, span_us: int) -> None:
        """Sensor rectangles at both ends of the span joined along t, axis names and t ticks (ms)."""
        W, H = self._W - 1, self._H - 1
        h = 0.5 * span_us * 1e-3
        key = (W, H, h)
        if key == self._cage_key:
            return
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
        self.tick_text.text = [f"{t:+g}" if t else "0" for t in ticks]
        self.tick_text.pos = np.array([[-2.2 * tick_len, H + 0.04 * H, t] for t in ticks], np.float32)
        self.axis_text.text = ["x", "y", "t (ms)"]
        self.axis_text.pos = np.array([[W + 0.06 * W, 0, -h], [0, H + 0.09 * H, -h],
                                       [-0.05 * W, H + 0.15 * H, h + 0.08 * 2 * h]], np.float32)

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
    def _on_session(self, what: str) -> None:
        if self._closed:
            return
        if what == "view":
            self._sync_from_view()
            self._update_slab(self.session.view.window_us)
            self.canvas.update()
        elif what == "objects":
            self._update_tubes()    # hide / show at once with the tubes at hand; new data follows
            self.canvas.update()

    def _on_scale_slider(self, v: int) -> None:
        self._scale = 10 ** (v / 100 + LOG_SCALE_MIN)
        self._apply_transform()

    def _on_span_spin(self, ms: int) -> None:
        self.session.set_view_option(spacetime_span_us=int(ms) * 1000)

    def _on_budget_spin(self, n: int) -> None:
        self.session.set_view_option(spacetime_budget=int(n))
