"""The objects' tubes in the space-time view: each object's projected silhouettes stacked along t as
closed polylines, all objects in one ``Line`` visual (segment pairs) over a white casing, and the translucent
skin joining consecutive silhouettes (core's ``SpaceTimeData.surfaces``) in one lean triangle visual
(:func:`surface_node_class`).

A clock offset between the event camera and the pose source shows as a *shear* between these tubes
(built from the labelled poses) and the event sheets a moving edge sweeps.
"""
from __future__ import annotations

import numpy as np

from evpose.widgets.spacetime.style import (
    ORDER_SURFACES,
    ORDER_TUBE_CASING,
    ORDER_TUBES,
    SURFACE_ALPHA,
    TUBE_CASING_PX,
    TUBE_CASING_RGBA,
    TUBE_WIDTH_PX,
)


def tube_segments(tubes, hidden) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The tubes of the objects not in ``hidden`` as one segment list.

    Parameters
    ----------
    tubes : list of (name, (r, g, b) 0-255, list of (M, 3) polylines in (x px, y px, t ms))
    hidden : collection of object names

    Returns
    -------
    (vertices (V, 3) float32, colours (V, 4) float32 RGBA in [0, 1], segments (S, 2) uint32), or None
    when nothing is to be drawn. Each polyline of at least two vertices is closed.
    """
    verts, segs, cols = [], [], []
    base = 0
    for name, rgb, polys in tubes:
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
    if not verts:
        return None
    return np.concatenate(verts), np.concatenate(cols), np.concatenate(segs).astype(np.uint32)


def surface_mesh(surfaces, hidden, alpha: float = SURFACE_ALPHA):
    """The surfaces of the objects not in ``hidden`` as one mesh: ``(vertices (V, 3) float32, triangles (F, 3)
    uint32, vertex colours (V, 4) float32)``, or None when there is none.

    ``surfaces``: ``[(name, (r, g, b) 0-255, vertices (V, 3), triangles (F, 3))]``."""
    verts, faces, cols = [], [], []
    base = 0
    for name, rgb, v, f in surfaces:
        if name in hidden or len(f) == 0:
            continue
        verts.append(np.asarray(v, np.float32))
        faces.append(np.asarray(f, np.uint32) + base)
        cols.append(np.broadcast_to(np.array([*(c / 255.0 for c in rgb), alpha], np.float32), (len(v), 4)))
        base += len(v)
    if not verts:
        return None
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(cols)


#: The skin's shaders: a vertex's position through the scene's transforms and its own RGBA colour, nothing else.
SURFACE_VERTEX_SHADER = """
attribute vec3 a_position;
attribute vec4 a_color;
varying vec4 v_color;
void main() {
    gl_Position = $transform(vec4(a_position, 1.0));
    v_color = a_color;
}
"""
SURFACE_FRAGMENT_SHADER = """
varying vec4 v_color;
void main() {
    gl_FragColor = v_color;
}
"""

_SURFACE_NODE: list = []


def surface_node_class():
    """The skin's visual node class: unlit triangles with per-vertex colours whose vertex, colour and index
    buffers are updated in place. vispy's ``Mesh.set_data`` builds a new colour transform function and a new
    colormap texture on every call, so each step of the view recompiled the mesh's program (14 ms of a
    136 ms step on bench/.data/ycb_5obj_5s under Xvfb); this one compiles once."""
    if not _SURFACE_NODE:
        from vispy.gloo import IndexBuffer, VertexBuffer
        from vispy.scene.visuals import create_visual_node
        from vispy.visuals import Visual

        class SurfaceVisual(Visual):
            def __init__(self, **kwargs):
                self._pos_vbo = VertexBuffer(np.zeros((1, 3), np.float32))
                self._col_vbo = VertexBuffer(np.zeros((1, 4), np.float32))
                self._ibo = IndexBuffer(np.zeros(3, np.uint32))
                self._pos = None
                Visual.__init__(self, vcode=SURFACE_VERTEX_SHADER, fcode=SURFACE_FRAGMENT_SHADER, **kwargs)
                self._draw_mode = "triangles"
                self._index_buffer = self._ibo
                self.shared_program["a_position"] = self._pos_vbo
                self.shared_program["a_color"] = self._col_vbo

            def set_data(self, vertices, faces, vertex_colors) -> None:
                """(V, 3) float32 positions, (F, 3) triangles, (V, 4) RGBA in [0, 1]."""
                self._pos = np.ascontiguousarray(vertices, np.float32)
                self._pos_vbo.set_data(self._pos)
                self._col_vbo.set_data(np.ascontiguousarray(vertex_colors, np.float32))
                self._ibo.set_data(np.ascontiguousarray(faces, np.uint32).ravel())
                self.update()

            def _prepare_transforms(self, view) -> None:
                view.view_program.vert["transform"] = view.get_transform()

            def _prepare_draw(self, view) -> bool:
                return self._pos is not None and len(self._pos) > 0

            def _compute_bounds(self, axis, view):
                if self._pos is None or not len(self._pos):
                    return None
                return (float(self._pos[:, axis].min()), float(self._pos[:, axis].max()))

        _SURFACE_NODE.append(create_visual_node(SurfaceVisual))
    return _SURFACE_NODE[0]


class TubeLayer:
    """The tube, casing and surface visuals; ``upload_counts["tubes"]`` counts the uploads."""

    def __init__(self, parent, upload_counts: dict):
        from vispy import scene

        self.upload_counts = upload_counts
        self._key = None
        self.casing = scene.visuals.Line(parent=parent, connect="segments", width=TUBE_CASING_PX,
                                         color=TUBE_CASING_RGBA, method="gl", antialias=False)
        self.casing.set_gl_state("translucent", depth_test=False)
        self.casing.order = ORDER_TUBE_CASING
        self.casing.visible = False
        self.line = scene.visuals.Line(parent=parent, connect="segments", width=TUBE_WIDTH_PX,
                                       method="gl", antialias=False)
        self.line.set_gl_state("translucent", depth_test=False)
        self.line.order = ORDER_TUBES
        self.line.visible = False
        self.surface = surface_node_class()(parent=parent)
        self.surface.set_gl_state("translucent", depth_test=False, cull_face=False)
        self.surface.order = ORDER_SURFACES
        self.surface.visible = False

    def update(self, tubes, hidden, surfaces=()) -> bool:
        """Draw the tubes and surfaces of the objects not ``hidden`` (see :func:`tube_segments` and
        :func:`surface_mesh`); True when what is drawn changed (nothing is uploaded otherwise)."""
        packed = tube_segments(tubes, hidden)
        mesh = surface_mesh(surfaces, hidden)
        key = (None if packed is None else (packed[0].tobytes(), packed[1].tobytes()),
               None if mesh is None else (mesh[0].tobytes(), mesh[2].tobytes()))
        if key == self._key:
            return False
        self._key = key
        if packed is None:
            self.line.visible = self.casing.visible = False
        else:
            v, c, s = packed
            self.casing.set_data(pos=v, connect=s)
            self.line.set_data(pos=v, color=c, connect=s)
            self.line.visible = self.casing.visible = True
        if mesh is None:
            self.surface.visible = False
        else:
            v, f, c = mesh
            self.surface.set_data(vertices=v, faces=f, vertex_colors=c)
            self.surface.visible = True
        if packed is not None or mesh is not None:
            self.upload_counts["tubes"] += 1
        return True
