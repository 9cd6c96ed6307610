"""The event points of the space-time view: thinning to the point budget, the draw order whose prefix
is a coarse time-uniform subset, and uploads of only the buffers whose content changed.

More points than the session's point budget are thinned by a stride before upload, so the view stays
interactive whatever it is handed. The uploaded points are ordered so that a prefix of about
``LOD_POINTS`` is a time-uniform subset, which alone is drawn (through a fixed index buffer) while
the mouse drags the camera: on software OpenGL (Xvfb, VMs) drawing costs about 1-3 µs a point.
"""
from __future__ import annotations

import numpy as np

from evpose.widgets.spacetime.cloud import event_cloud_node_class, pack_rgb
from evpose.widgets.spacetime.style import OFF_RGBA, ON_RGBA, ORDER_POINTS, POINT_ANTIALIAS, POINT_SIZE_PX

#: Upload counter names of a layer: (positions, colour indices).
DEFAULT_COUNTERS = ("points", "polarity")

#: While the camera moves (drag, wheel, time-scale drag) only this many points are drawn (a time-uniform
#: subset: the vertex buffer is ordered so that every prefix is one), then all again.
LOD_POINTS = 40_000


def stride_for(n: int, budget: int) -> int:
    """Smallest stride ``k`` with ``ceil(n / k) <= budget`` (1 when within budget)."""
    budget = max(int(budget), 1)
    return 1 if n <= budget else -(-n // budget)


def draw_order(n: int, stride: int) -> tuple[np.ndarray, int]:
    """Indices into ``n`` points: every ``stride``-th (the budget), ordered in ``k`` interleaved runs so
    that the first run alone is a time-uniform coarse subset of about ``LOD_POINTS`` events (points
    given in time order). Returns (indices, length of the first run)."""
    s = stride
    m = len(range(0, n, s))
    k = max(1, -(-m // LOD_POINTS))
    if k == 1:
        return np.arange(0, n, s), m
    runs = [np.arange(j * s, n, k * s) for j in range(k)]
    return np.concatenate(runs), len(runs[0])


class PointLayer:
    """The event cloud visual and what was last uploaded to it.

    Parameters
    ----------
    parent : vispy.scene.Node
        The node carrying the (x px, y px, t ms) -> scene transform.
    lean : bool
        Use the 16-byte-per-point upload when vispy's shader allows it (else ``Markers.set_data``).
    upload_counts : dict
        The view's buffer-upload counters; this layer increments ``counters`` (positions, colour indices) and
        ``lod``.
    order : int
        Draw order of the visual.
    counters : (str, str)
        Names of this layer's upload counters.

    Attributes
    ----------
    markers : the event cloud visual (``.lean`` tells which upload is in use).
    stride : every ``stride``-th point given is drawn (1 within the budget).
    shown : points drawn when not interacting.
    lod_count : points in the coarse prefix drawn while interacting.
    """

    def __init__(self, parent, lean: bool, upload_counts: dict, order: int = ORDER_POINTS,
                 counters: tuple[str, str] = DEFAULT_COUNTERS):
        cloud_class = event_cloud_node_class(lean)
        self.markers = cloud_class(parent=parent, scaling="fixed", antialias=POINT_ANTIALIAS)
        self.markers.set_gl_state("translucent", depth_test=False, cull_face=False)
        self.markers.order = order
        self.upload_counts = upload_counts
        self._counters = counters
        for name in counters:
            upload_counts.setdefault(name, 0)
        self.palette: tuple = (OFF_RGBA, ON_RGBA)
        self._packed: np.ndarray | None = None  # packed 0xRRGGBB per class (palettes of more than two colours)
        self.stride = 1
        self.shown = 0
        self.lod_count = 0
        self._lod_ib = None
        self._last_pos_src = None      # (array, stride) last uploaded as positions (arrays are not mutated)
        self._last_pol: np.ndarray | None = None

    def set_palette(self, colors) -> None:
        """The RGBA colours that the colour indices select: two (OFF, ON: the polarity, mixed in the shader) or
        more (classes, e.g. objects: each point's colour packed into its float, one alpha for all). The lean
        visual re-colours its points without an upload of positions; the stock ``Markers`` fallback re-uploads on
        the next :meth:`set_points`."""
        colors = tuple(tuple(float(c) for c in rgba) for rgba in colors)
        if colors == self.palette:
            return
        self.palette = colors
        self._packed = None if len(colors) <= 2 else np.array([pack_rgb(c) for c in colors], np.float32)
        if self._packed is None:
            self.markers.set_colors(colors[1], colors[0])
        else:
            self.markers.set_packed(colors[0][3])
        self._last_pol = None                   # the colour floats change meaning: upload them again

    def set_points(self, points: np.ndarray, polarity: np.ndarray, budget: int) -> None:
        """Upload ``points`` (N, 3) (x px, y px, t ms) and colour indices ``polarity`` (N,) (the polarity, {0, 1},
        or indices into :meth:`set_palette`'s colours), thinned to ``budget``.
        The arrays are treated as immutable: the same ``points`` array again uploads no positions, and
        the colour buffer is uploaded only when its content changed."""
        n = len(points)
        self.stride = stride_for(n, int(budget))
        last = self._last_pos_src
        same = last is not None and last[0] is points and last[1] == self.stride and self._last_pol is not None
        if n == 0:
            self._upload(np.zeros((0, 3), np.float32), np.zeros(0, np.uint8))
            self._last_pos_src = None
            self.lod_count = 0
        else:
            idx, self.lod_count = draw_order(n, self.stride)
            pol = np.asarray(polarity)[idx]
            if not same:
                self._upload(np.ascontiguousarray(points[idx], dtype=np.float32), pol)
                self._last_pos_src = (points, self.stride)
            else:   # the same array again: positions stay; polarity uploaded only if it changed
                self._upload(None, pol)
        self.shown = len(range(0, n, self.stride))

    def show_coarse(self, on: bool) -> None:
        """Draw only the coarse prefix (``on``, when there is more than it) or every uploaded point."""
        from vispy.gloo import IndexBuffer

        if on and 0 < self.lod_count < self.shown:
            if self._lod_ib is None or self._lod_ib.size != self.lod_count:
                self._lod_ib = IndexBuffer(np.arange(self.lod_count, dtype=np.uint32))
                self.upload_counts["lod"] += 1
            self.markers._index_buffer = self._lod_ib
        else:
            self.markers._index_buffer = None
        self.markers.update()

    def _upload(self, pos: np.ndarray | None, pol_u8: np.ndarray) -> None:
        cloud = self.markers
        if pos is not None and len(pos) == 0:
            if cloud.lean:
                cloud.set_events(pos, None, POINT_SIZE_PX)
            else:
                cloud.set_data(None)
            self._last_pol = None
            return
        n_pos, n_col = self._counters
        if not cloud.lean:   # fallback: the stock interleaved upload of everything
            if pos is None:
                pos = cloud._data["a_position"]
            colors = np.asarray(self.palette, np.float32)[np.asarray(pol_u8, np.int64)]
            cloud.set_data(pos, face_color=colors, edge_width=0, size=POINT_SIZE_PX, symbol="disc")
            self.upload_counts[n_pos] += 1
            self.upload_counts[n_col] += 1
            self._last_pol = pol_u8.copy()
            return
        pol_changed = (self._last_pol is None or len(self._last_pol) != len(pol_u8)
                       or not np.array_equal(self._last_pol, pol_u8))
        pol = None
        if pol_changed:
            idx = np.asarray(pol_u8, np.int64)
            pol = self._packed[idx] if self._packed is not None else idx.astype(np.float32)
        cloud.set_events(pos, pol, POINT_SIZE_PX)
        if pos is not None:
            self.upload_counts[n_pos] += 1
        if pol_changed:
            self.upload_counts[n_col] += 1
            self._last_pol = np.array(pol_u8, copy=True)
