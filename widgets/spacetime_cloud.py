"""The event cloud's vispy visual: a ``Markers`` subclass whose vertex shader takes the polarity as one
float and mixes the ON / OFF colours from uniforms.

A point then costs 16 bytes on the GPU (a float32 (x, y, t) position and a float32 polarity, two
separately updated vertex buffers) instead of the 56 bytes of ``Markers.set_data``'s interleaved
record; size, edge and symbol are constant attributes. If vispy's marker shader ever stops matching
the two lines this patches, the class falls back to vispy's own shader and ``Markers.set_data``
(``lean`` is then False).

vispy is imported lazily (:func:`use_vispy`): importing this module needs no display.
"""
from __future__ import annotations

import numpy as np

from evpose.widgets.spacetime_style import OFF_RGBA, ON_RGBA


def use_vispy() -> None:
    """Import vispy with the PySide6 backend (or whatever backend this process already chose)."""
    from vispy import app as vapp

    try:
        vapp.use_app("pyside6")
    except RuntimeError:  # another backend already chosen in this process: use whatever is active
        pass


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
        use_vispy()
        _EVENT_CLOUD[lean] = _make_event_cloud_class(lean)
    return _EVENT_CLOUD[lean]
