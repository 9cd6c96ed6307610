"""The current window's event frame with per-object overlays (pyqtgraph).

Scene coordinates equal OpenCV pixel coordinates: the image item spans ``[-0.5, W - 0.5)`` so
a pixel centre ``(u, v)`` sits at integer coordinates and overlays computed in core line up
without offsets. The view is the raw (distorted) sensor image, where the events are.

Events first, overlays when ready: the app shows a window's event image as soon as it is computed
(:meth:`FrameView.set_events`) and its overlays when the rasteriser is done (:meth:`FrameView.set_overlays`).
Meanwhile the previous overlays stay on screen, dimmed to :data:`STALE_OVERLAY_OPACITY`, and the info line
names their time ("overlays of t … s, updating"); the hover readout then gives no object or depth. Dimmed
overlays rather than none: while scrubbing, the objects stay in sight without flicker, and a dim
outline that lags the events is read as "updating", not as a misalignment.
"""
from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtGui, QtWidgets

from evpose.core.label.overlay import AXIS_COLORS
from evpose.core.session.frames import EventFrame, FrameData
from evpose.core.session.model import Session
from evpose.widgets.labels import Readout


def _polylines_to_nan_separated(polys: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate polylines with NaN breaks for one ``PlotCurveItem(connect='finite')``."""
    if not polys:
        return np.zeros(0), np.zeros(0)
    parts = []
    for p in polys:
        parts.append(p[:, :2])
        parts.append(np.full((1, 2), np.nan))
    xy = np.concatenate(parts)
    return xy[:, 0], xy[:, 1]


def _segments_to_pairs(segs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, 2, 2) segments -> x, y arrays for ``PlotCurveItem(connect='pairs')``."""
    flat = np.asarray(segs, dtype=np.float64).reshape(-1, 2)
    return flat[:, 0], flat[:, 1]


#: Opacity of overlays drawn over the events of another window (the new events are shown first, their
#: overlays follow when computed; the info line says which time the dimmed overlays belong to).
STALE_OVERLAY_OPACITY = 0.3


class FrameView(QtWidgets.QWidget):
    """Shows :class:`~evpose.core.session.frames.FrameData`; reports hover information.

    Signals
    -------
    hoverText(str)
        ``"u, v | n events | object | depth"`` under the cursor (empty when outside).
    """

    hoverText = QtCore.Signal(str)

    def __init__(self, session: Session, parent=None):
        super().__init__(parent)
        self.session = session
        self.frame: FrameData | None = None      # the overlays on screen (labels, masks, contours, ...)
        self.events: EventFrame | None = None    # the event image on screen
        self._items: dict[str, dict[str, pg.GraphicsObject]] = {}

        self.glw = pg.GraphicsLayoutWidget()
        self.glw.setBackground("w")
        self.vb: pg.ViewBox = self.glw.addViewBox(lockAspect=True, invertY=True, enableMenu=False)
        self.vb.setDefaultPadding(0.01)
        self.image_item = pg.ImageItem(axisOrder="row-major")
        self.mask_item = pg.ImageItem(axisOrder="row-major")
        self.vb.addItem(self.image_item)
        self.vb.addItem(self.mask_item)
        cam = session.scene.camera
        rect = QtCore.QRectF(-0.5, -0.5, cam.width, cam.height)
        # image pixel (u, v) covers [u - 0.5, u + 0.5): scene coordinates = OpenCV pixel coordinates
        for item in (self.image_item, self.mask_item):
            item.setTransform(QtGui.QTransform.fromTranslate(-0.5, -0.5))
        self.mask_item.setZValue(1)
        self.axis_items = [pg.PlotCurveItem(pen=pg.mkPen(c, width=2), connect="pairs") for c in AXIS_COLORS]
        for it in self.axis_items:
            it.setZValue(4)
            self.vb.addItem(it)
        self.center_item = pg.ScatterPlotItem(size=9, symbol="+", pen=pg.mkPen("k", width=2))
        self.center_item.setZValue(5)
        self.vb.addItem(self.center_item)
        self.message = pg.TextItem("", color=(200, 0, 0), anchor=(0, 0))
        self.message.setZValue(10)
        self.vb.addItem(self.message)
        self.message.setPos(0, 0)
        for name in session.object_names:
            self._ensure_items(name)
        self.vb.setRange(rect, padding=0.01)

        # one constant-size line: frame info on the left, hover readout on the right; the texts
        # change every frame / mouse move without a relayout of the window (evpose.widgets.labels)
        self.info = Readout("t 9999.9999 s   win 99 ms   99,999 ev   on masks 99.9%   (99 ms)",
                            stretch=True)
        self.info.setToolTip("current window; right: what is under the mouse (pixel, events, object, depth)")
        lay = QtWidgets.QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.glw, 1)
        lay.addWidget(self.info)
        self._hover: tuple[int, int] | None = None
        self._proxy = pg.SignalProxy(self.glw.scene().sigMouseMoved, rateLimit=30, slot=self._mouse_moved)

    # ------------------------------------------------------------------ items
    def _ensure_items(self, name: str) -> dict:
        if name in self._items:
            return self._items[name]
        color = self.session.color(name)
        items = {
            "contour": pg.PlotCurveItem(pen=pg.mkPen(color, width=2), connect="finite"),
            "box": pg.PlotCurveItem(pen=pg.mkPen(color, width=1.5), connect="pairs"),
        }
        items["contour"].setZValue(3)
        items["box"].setZValue(2)
        for it in items.values():
            self.vb.addItem(it)
        self._items[name] = items
        return items

    def sizeHint(self) -> QtCore.QSize:  # noqa: N802 (Qt API)
        return QtCore.QSize(720, 560)       # the main view: it gets the room the docks leave

    def minimumSizeHint(self) -> QtCore.QSize:  # noqa: N802 (Qt API)
        return QtCore.QSize(420, 320)       # a DAVIS346 frame stays readable next to the docks

    def reset_zoom(self) -> None:
        cam = self.session.scene.camera
        self.vb.setRange(QtCore.QRectF(-0.5, -0.5, cam.width, cam.height), padding=0.01)

    # ------------------------------------------------------------------ data
    def set_frame(self, data: FrameData) -> None:
        """Display a computed frame, events and overlays together (called on the GUI thread)."""
        self.set_events(EventFrame(data.window, data.n_events, data.image_rgb, data.counts, data.compute_ms))
        self.set_overlays(data)

    def set_events(self, part: EventFrame) -> None:
        """Display a window's event image at once (the app's first stage); the overlays on screen stay,
        dimmed and marked in the info line, until :meth:`set_overlays` brings those of this window."""
        self.events = part
        self.image_item.setImage(part.image_rgb, autoLevels=False, levels=(0, 255))
        self._show_overlay_state()

    def set_overlays(self, data: FrameData) -> None:
        """Display a window's labels and overlays (the app's second stage; ``data.image_rgb`` is not used)."""
        self.frame = data
        if data.mask_rgba is not None:
            self.mask_item.setImage(data.mask_rgba, autoLevels=False, levels=None)
            self.mask_item.setVisible(True)
        else:
            self.mask_item.setVisible(False)
        shown = {o.name: o for o in data.overlays}
        axes = [[], [], []]
        centers = []
        for name in self.session.object_names:
            items = self._ensure_items(name)
            ov = shown.get(name)
            if ov is None:
                for it in items.values():
                    it.setData([], [])
                continue
            items["contour"].setData(*_polylines_to_nan_separated(ov.contours))
            items["box"].setData(*_segments_to_pairs(ov.box_segments))
            for k in range(3):
                if len(ov.axes) == 3 and len(ov.axes[k]):
                    axes[k].append(ov.axes[k])
            if ov.center_uv is not None:
                centers.append({"pos": tuple(ov.center_uv), "pen": pg.mkPen(ov.color, width=2.5)})
            width = 3.5 if name == self.session.view.selected else 2.0
            items["contour"].setPen(pg.mkPen(ov.color, width=width))
        for k in range(3):
            segs = np.concatenate(axes[k]) if axes[k] else np.zeros((0, 2, 2))
            self.axis_items[k].setData(*_segments_to_pairs(segs))
        self.center_item.setData(centers)
        self._show_overlay_state()

    @property
    def overlays_stale(self) -> bool:
        """True while the overlays on screen belong to another window than the events on screen."""
        e, f = self.events, self.frame
        return e is not None and f is not None and (f.window.t0_us, f.window.t1_us) != (e.window.t0_us, e.window.t1_us)

    def _overlay_items(self) -> list:
        return [self.mask_item, *self.axis_items, self.center_item,
                *(it for items in self._items.values() for it in items.values())]

    def _show_overlay_state(self) -> None:
        """Opacity of the overlays (dimmed while stale), the label message and the info line."""
        e, f = self.events, self.frame
        stale = self.overlays_stale
        opacity = STALE_OVERLAY_OPACITY if stale else 1.0
        for it in self._overlay_items():
            it.setOpacity(opacity)
        if f is not None and not f.labels.valid and not stale:
            self.message.setText(f"no label: {f.labels.reason}")
        else:
            self.message.setText("")
        w = e.window if e is not None else f.window
        t0 = self.session.time_range[0]
        n = e.n_events if e is not None else f.n_events
        if f is None:
            tail = "overlays: computing"
        elif stale:
            tail = f"overlays of t {(f.window.t_label_us - t0) / 1e6:.4f} s, updating"
        else:
            tail = "on masks " + ("–" if f.inside_fraction is None else f"{100 * f.inside_fraction:.1f}%")
        ms = (e.compute_ms if e is not None else 0.0) + (f.compute_ms if f is not None and not stale else 0.0)
        self.info.setText(f"t {(w.t_label_us - t0) / 1e6:.4f} s   win {(w.t1_us - w.t0_us) / 1000:g} ms   "
                          f"{n:,} ev   {tail}   ({ms:.0f} ms)")
        self._update_readout()

    # ------------------------------------------------------------------ hover
    def _mouse_moved(self, evt) -> None:
        pos = evt[0]
        if not self.vb.sceneBoundingRect().contains(pos):
            self._hover = None
        else:
            p = self.vb.mapSceneToView(pos)
            self._hover = (int(np.floor(p.x() + 0.5)), int(np.floor(p.y() + 0.5)))
        self._update_readout()

    def hover_info(self, u: int, v: int) -> dict | None:
        """What is at pixel (u, v) in the current frame (None outside the image)."""
        e, f = self.events, self.frame
        if e is None or not (0 <= u < e.counts.shape[1] and 0 <= v < e.counts.shape[0]):
            return None
        info = {"u": u, "v": v, "events": int(e.counts[v, u]), "object": None, "depth_m": None}
        lab = f.labels if f is not None and not self.overlays_stale else None   # never another window's labels
        if lab is not None and lab.valid and lab.label_map is not None:
            k = int(lab.label_map[v, u])
            if k >= 0:
                info["object"] = lab.objects[k].name
                if lab.depth_m is not None and np.isfinite(lab.depth_m[v, u]):
                    info["depth_m"] = float(lab.depth_m[v, u])
        return info

    def _update_readout(self) -> None:
        info = self.hover_info(*self._hover) if self._hover else None
        if info is None:
            text = ""
        else:
            text = f"u {info['u']}, v {info['v']} | {info['events']} ev"
            if info["object"]:
                text += f" | {info['object']}"
                if info["depth_m"] is not None:
                    text += f" @ {info['depth_m'] * 1000:.1f} mm"
        self.info.setRightText(text)
        self.hoverText.emit(text)
