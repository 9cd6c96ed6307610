"""The event cloud's vispy visual: GL points with their own small shaders, each point's colour one float: the
polarity mixing the ON / OFF colours from uniforms, or (packed mode) a 0xRRGGBB colour of its own, e.g. its
object's, at one alpha (no per-point palette lookup: indexing a uniform array costs software OpenGL ~20 %).

A point costs 16 bytes on the GPU (a float32 (x, y, t) position and a float32 colour index, two separately
updated vertex buffers) instead of the 56 bytes of ``Markers.set_data``'s interleaved record, and its
fragments run a disc test and a colour instead of ``Markers``' symbol, edge, antialiasing and lighting
code: the same pixels (a 2 px disc with no edge and no antialiasing, the same transforms) drawn several
times faster by software OpenGL. ``lean=False`` gives vispy's stock ``Markers`` (for comparisons).

vispy is imported lazily (:func:`use_vispy`): importing this module needs no display.
"""
from __future__ import annotations

import numpy as np

from evpose.widgets.spacetime.style import OFF_RGBA, ON_RGBA

#: Colour classes a layer can tell apart (e.g. objects; more wrap around).
PALETTE_SIZE = 16


def pack_rgb(rgba) -> float:
    """An RGB(A) colour in [0, 1] as the packed float ``0xRRGGBB`` the packed mode reads (exact in float32)."""
    r, g, b = (int(round(255 * float(c))) for c in tuple(rgba)[:3])
    return float((r << 16) | (g << 8) | b)


def use_vispy() -> None:
    """Import vispy with the PySide6 backend (or whatever backend this process already chose)."""
    from vispy import app as vapp

    try:
        vapp.use_app("pyside6")
    except RuntimeError:  # another backend already chosen in this process: use whatever is active
        pass


#: The event points' shaders: a GL point of ``u_size`` framebuffer pixels (a disc, as ``Markers``' "disc" with no
#: edge and no antialiasing draws it), coloured by mixing the OFF and ON colours with the polarity, or by its own
#: packed RGB (``u_packed`` 1). Positions go
#: through the same two transforms as ``Markers`` (visual -> framebuffer -> render), so the points land on the same
#: pixels; the fragment work is one length and one compare instead of ``Markers``' symbol, edge, antialiasing and
#: lighting code, which on software OpenGL (llvmpipe) cost about 4 µs a point.
POINTS_VERTEX_SHADER = """
attribute vec3 a_position;
attribute float a_polarity;
uniform vec4 u_on_color;
uniform vec4 u_off_color;
uniform float u_packed;
uniform float u_packed_alpha;
uniform float u_size;
varying vec4 v_color;
void main() {
    vec4 fb_pos = $visual_to_framebuffer(vec4(a_position, 1.0));
    gl_Position = $framebuffer_to_render(fb_pos);
    gl_PointSize = u_size;
    float v = a_polarity;
    vec3 rgb = vec3(floor(v / 65536.0), mod(floor(v / 256.0), 256.0), mod(v, 256.0)) / 255.0;
    v_color = u_packed > 0.5 ? vec4(rgb, u_packed_alpha) : mix(u_off_color, u_on_color, a_polarity);
}
"""
POINTS_FRAGMENT_SHADER = """
uniform float u_size;
varying vec4 v_color;
void main() {
    if (length((gl_PointCoord - vec2(0.5, 0.5)) * u_size) > 0.5 * u_size)
        discard;
    gl_FragColor = v_color;
}
"""


def _make_event_cloud_class(lean: bool):
    """Build the event cloud's visual class (needs vispy, hence a factory): ``lean=True`` the 16-byte-per-point
    :class:`EventPointsVisual` with its own shaders; ``lean=False`` vispy's ``Markers`` and its
    ``set_data`` (the benchmark's comparison)."""
    from vispy.gloo import VertexBuffer
    from vispy.scene.visuals import create_visual_node
    from vispy.visuals import Visual
    from vispy.visuals.markers import MarkersVisual

    if not lean:
        class StockMarkersVisual(MarkersVisual):
            """vispy's ``Markers`` (56 bytes a point, per-point colours through ``set_data``)."""

            lean = False

            def set_events(self, *a, **k):
                raise RuntimeError("lean upload unavailable; use set_data")

            def set_colors(self, *a) -> None:           # colours go per point through set_data
                pass

            def set_packed(self, *a) -> None:
                pass

        return create_visual_node(StockMarkersVisual)

    class EventPointsVisual(Visual):
        """Events as GL points: positions (N, 3) float32 and one colour float each (N,) float32 (the polarity, or
        a packed 0xRRGGBB in packed mode) in two separately updated vertex buffers, the colours and size from
        uniforms (see :data:`POINTS_VERTEX_SHADER`).

        ``_index_buffer`` (a ``Visual`` attribute) may be set to draw a subset (the coarse prefix)."""

        lean = True

        def __init__(self, scaling="fixed", antialias=0.0, **kwargs):
            del scaling, antialias          # always screen-sized, never antialiased (see the shaders)
            self._pos_vbo = VertexBuffer(np.zeros((1, 3), np.float32))
            self._pol_vbo = VertexBuffer(np.zeros(1, np.float32))
            self._n = 0
            self._size_px = 1.0
            self._pos = None                # the uploaded positions (for the bounds, computed on demand)
            Visual.__init__(self, vcode=POINTS_VERTEX_SHADER, fcode=POINTS_FRAGMENT_SHADER, **kwargs)
            self._draw_mode = "points"
            self.set_colors(ON_RGBA, OFF_RGBA)

        def set_colors(self, on_rgba, off_rgba) -> None:
            """Polarity mode: ON and OFF colours (RGBA in [0, 1])."""
            self.shared_program["u_on_color"] = tuple(float(c) for c in on_rgba)
            self.shared_program["u_off_color"] = tuple(float(c) for c in off_rgba)
            self.shared_program["u_packed"] = 0.0
            self.shared_program["u_packed_alpha"] = 1.0
            self.update()

        def set_packed(self, alpha: float) -> None:
            """Packed mode: each point's float is its 0xRRGGBB colour (:func:`pack_rgb`), drawn at ``alpha``."""
            self.shared_program["u_packed"] = 1.0
            self.shared_program["u_packed_alpha"] = float(alpha)
            self.update()

        def set_events(self, pos: np.ndarray | None, polarity: np.ndarray | None, size: float) -> None:
            """Upload what is given: ``pos`` (N, 3) float32 and/or ``polarity`` (N,) float32 colour floats;
            None keeps that buffer. Both must end up with the same length. ``size``: point diameter in
            logical pixels."""
            p = self.shared_program
            if pos is not None:
                self._n = len(pos)
                self._pos = pos if self._n else None
                if self._n == 0:
                    self.update()
                    return
                self._pos_vbo.set_data(pos)
                p["a_position"] = self._pos_vbo
            if polarity is not None:
                self._pol_vbo.set_data(polarity)
                p["a_polarity"] = self._pol_vbo
            self._size_px = float(size)
            self.update()

        def _prepare_transforms(self, view) -> None:
            vert = view.view_program.vert
            vert["visual_to_framebuffer"] = view.get_transform("visual", "framebuffer")
            vert["framebuffer_to_render"] = view.get_transform("framebuffer", "render")

        def _prepare_draw(self, view) -> bool:
            if self._n == 0:
                return False
            view.view_program["u_size"] = self._size_px * view.transforms.pixel_scale
            return True

        def _compute_bounds(self, axis, view):
            if self._pos is None:
                return None
            return (float(self._pos[:, axis].min()), float(self._pos[:, axis].max()))

    return create_visual_node(EventPointsVisual)


_EVENT_CLOUD: dict = {}


def event_cloud_node_class(lean: bool = True):
    """The scene-node class of the event cloud: the lean points (``lean``, 16 bytes a point, see
    :data:`POINTS_VERTEX_SHADER`) or vispy's stock ``Markers``; ``.lean`` tells which."""
    if lean not in _EVENT_CLOUD:
        use_vispy()
        _EVENT_CLOUD[lean] = _make_event_cloud_class(lean)
    return _EVENT_CLOUD[lean]
