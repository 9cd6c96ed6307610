"""The space-time view's frame of reference: the span's cage (the sensor rectangle at both ends of the
span joined along t, with t ticks in ms and the axis names) and the current window's slab.

The texts follow the camera preset (:meth:`SpanCage.set_preset`): an axis seen end-on has no name and no ticks
(in the front view the t ticks would all land on one spot), and the names sit beside the sensor's edges, inside
the margin the presets leave around the box.

Coordinates are data coordinates ``(x px, y px, t ms)`` relative to the data's centre time; the parent
node's transform maps them to the scene (:mod:`evpose.widgets.spacetime.camera`).
"""
from __future__ import annotations

import math

import numpy as np

from evpose.widgets.spacetime.style import (
    CAGE_RGBA,
    ORDER_CAGE,
    ORDER_SLAB,
    ORDER_SLAB_EDGE,
    ORDER_TEXT,
    SLAB_EDGE_RGBA,
    SLAB_RGBA,
    TEXT_RGBA,
)


def nice_step(x: float) -> float:
    """The 1-2-2.5-5 number nearest above ``x`` (tick spacing)."""
    if x <= 0:
        return 1.0
    e = 10 ** math.floor(math.log10(x))
    for m in (1, 2, 2.5, 5, 10):
        if m * e >= x:
            return m * e
    return 10 * e


class SpanCage:
    """The cage line and its text (axis names, t tick labels) for a sensor of ``width`` x ``height`` px.

    ``upload_counts["cage"]`` counts the rebuilds."""

    def __init__(self, parent, width: int, height: int, upload_counts: dict):
        from vispy import scene

        self._W, self._H = width - 1, height - 1
        self.upload_counts = upload_counts
        self._key = None
        self._preset = "oblique"
        self._ticks = np.zeros(0)
        self.line = scene.visuals.Line(parent=parent, color=CAGE_RGBA, connect="segments", width=1,
                                       method="gl", antialias=False)
        self.line.set_gl_state("translucent", depth_test=False)
        self.line.order = ORDER_CAGE
        self.axis_text = scene.visuals.Text(parent=parent, color=TEXT_RGBA, font_size=9, bold=True)
        self.axis_text.order = ORDER_TEXT
        self.tick_text = scene.visuals.Text(parent=parent, color=TEXT_RGBA, font_size=7)
        self.tick_text.order = ORDER_TEXT

    def update(self, span_us: int) -> bool:
        """Rebuild for a span of ``span_us`` centred on t = 0; True when it changed."""
        W, H = self._W, self._H
        h = 0.5 * span_us * 1e-3
        key = (W, H, h)
        if key == self._key:
            return False
        self._key = key
        corners = np.array([[0, 0], [W, 0], [W, H], [0, H]], np.float32)
        pts, segs = [], []
        for t in (-h, h):
            base = len(pts)
            pts += [[x, y, t] for x, y in corners]
            segs += [[base + i, base + (i + 1) % 4] for i in range(4)]
        segs += [[i, i + 4] for i in range(4)]
        step = nice_step(2 * h / 4)
        ticks = np.arange(math.ceil(-h / step) * step, h + 1e-9, step)
        tick_len = 0.03 * max(W, H)
        for t in ticks:               # small ticks on the bottom-left edge (x = 0, y = H)
            base = len(pts)
            pts += [[0, H, t], [-tick_len, H, t]]
            segs.append([base, base + 1])
        self.line.set_data(pos=np.array(pts, np.float32), connect=np.array(segs, np.uint32))
        self.upload_counts["cage"] += 1
        self._ticks = ticks
        self._place_text()
        return True

    def set_preset(self, name: str) -> None:
        """Show the axis names and t ticks that camera preset ``name`` can read (see the module docstring)."""
        if name != self._preset:
            self._preset = name
            self._place_text()

    def _place_text(self) -> None:
        """Axis names beside the sensor's edges (x over the top edge, y left of the left edge, t under the
        bottom-left edge at the span's end) and the t tick labels, those of axes seen end-on left out."""
        W, H, preset = self._W, self._H, self._preset
        ticks = self._ticks
        h = self._key[2] if self._key else 0.0
        tick_len = 0.03 * max(W, H)
        # t's name clear of its tick labels: under their middle where t runs across the screen (side), past the
        # last one where it runs up (top), beside their middle in the oblique view (its far ticks crowd together)
        t_name = {"side": [-2.2 * tick_len, H + 0.16 * H, 0.0], "top": [-2.2 * tick_len, H, h + 0.14 * h]}.get(
            preset, [-7.0 * tick_len, H + 0.12 * H, 0.0])
        names = {"x": [W / 2, -0.08 * H, -h], "y": [-0.08 * W, H / 2, -h], "t (ms)": t_name}
        hidden = {"front": ("t (ms)",), "side": ("x",), "top": ("y",)}.get(preset, ())
        shown = [n for n in names if n not in hidden]
        self.axis_text.text = shown
        self.axis_text.pos = np.array([names[n] for n in shown], np.float32)
        if preset == "front" or not len(ticks):
            self.tick_text.visible = False
            return
        labels = [f"{t:+g}" if t else "0" for t in ticks]
        self.tick_text.text = labels
        self.tick_text.pos = np.array([[-2.2 * tick_len, H + 0.07 * H, t] for t in ticks], np.float32)
        self.tick_text.visible = True


class WindowSlab:
    """A translucent box over the sensor for the current window ``[-w/2, w/2]`` around t = 0, its
    mid-plane outlined. ``upload_counts["slab"]`` counts the rebuilds."""

    def __init__(self, parent, width: int, height: int, upload_counts: dict):
        from vispy import scene

        self._W, self._H = width - 1, height - 1
        self.upload_counts = upload_counts
        self._key = None
        self.mesh = scene.visuals.Mesh(parent=parent, color=SLAB_RGBA)
        self.mesh.set_gl_state("translucent", depth_test=False, cull_face=False)
        self.mesh.order = ORDER_SLAB
        self.edge = scene.visuals.Line(parent=parent, color=SLAB_EDGE_RGBA, connect="segments",
                                       width=1.5, method="gl", antialias=False)
        self.edge.set_gl_state("translucent", depth_test=False)
        self.edge.order = ORDER_SLAB_EDGE

    def update(self, window_us: int) -> None:
        """Rebuild for a window of ``window_us`` (nothing when unchanged)."""
        W, H = self._W, self._H
        w = 0.5 * window_us * 1e-3
        key = (W, H, w)
        if self._key == key:
            return
        self._key = key
        v = np.array([[x, y, t] for t in (-w, w) for x, y in ((0, 0), (W, 0), (W, H), (0, H))], np.float32)
        faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7],      # t = -w/2, +w/2
                          [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5],
                          [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]], np.uint32)
        self.mesh.set_data(vertices=v, faces=faces, color=SLAB_RGBA)
        mid = np.array([[x, y, 0.0] for x, y in ((0, 0), (W, 0), (W, H), (0, H))], np.float32)
        self.edge.set_data(pos=mid, connect=np.array([[0, 1], [1, 2], [2, 3], [3, 0]], np.uint32))
        self.upload_counts["slab"] += 1
