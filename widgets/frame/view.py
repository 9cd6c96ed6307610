"""The current window's event frame with per-object overlays (pyqtgraph).

Scene coordinates equal OpenCV pixel coordinates: the image item spans ``[-0.5, W - 0.5)`` so
a pixel centre ``(u, v)`` sits at integer coordinates and overlays computed in core line up
without offsets. The view is the raw (distorted) sensor image, where the events are. The sensor's
border is drawn, and whatever lies outside it (boxes and axes of objects partly out of view) is faded.

Events first, overlays when ready: the app shows a window's event image as soon as it is computed
(:meth:`FrameView.set_events`) and its overlays when the rasteriser is done (:meth:`FrameView.set_overlays`).
Meanwhile the previous overlays stay on screen, dimmed to :data:`STALE_OVERLAY_OPACITY`, and the info line
names their time ("overlays of t … s, updating"); the hover readout then gives no object or depth. Dimmed
overlays rather than none: while scrubbing, the objects stay in sight without flicker, and a dim
outline that lags the events is read as "updating", not as a misalignment.

Display options of the session's view state apply at once, without recomputing the frame: contrast and
opacity of the event image, opacity of the masks, the selected object only, outlines only
(:class:`~evpose.widgets.frame.toolbar.FrameToolbar` sets them). Objects are clicked to select them and
dragged to correct their pose (:mod:`evpose.widgets.frame.drag`).
"""
from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtGui, QtWidgets

from evpose.core.label.overlay import (
    AXIS_COLORS,
    REPRESENTATION_BACKGROUND,
    adjust_contrast,
    compose_masks_rgba,
    drawn_objects,
    mask_contours,
)
from evpose.core.views.frame import EventFrame, FrameData
from evpose.core.session.model import Session
from evpose.core.signals import Change, OBJECTS, VIEW
from evpose.widgets.binding import connect_view
from evpose.widgets.frame.drag import DRAG_HELP, FrameViewBox, pixel_of
from evpose.widgets.frame.toolbar import FrameToolbar
from evpose.widgets.labels import Readout
from evpose.widgets.plot_data import polylines_xy, segments_xy


#: The badge on the frame while the overlays show proposed corrections (:meth:`Session.set_preview`).
PREVIEW_TEXT = "PREVIEW: proposed corrections, not applied"

#: Opacity of overlays drawn over the events of another window (the new events are shown first, their
#: overlays follow when computed; the info line says which time the dimmed overlays belong to).
STALE_OVERLAY_OPACITY = 0.3

#: Outside the sensor: the background colour at this alpha over overlays that leave the image.
OUTSIDE_VEIL_ALPHA = 215

#: View-state fields that change how the event image is drawn, and how the overlays are.
EVENT_DISPLAY_FIELDS = frozenset({"contrast", "event_opacity", "representation"})
OVERLAY_DISPLAY_FIELDS = frozenset({"mask_alpha", "selected_only", "outline_only", "overlays"})
#: View-state fields that only change how the frame on screen is drawn: nothing to compute again.
DISPLAY_ONLY_FIELDS = frozenset({"contrast", "event_opacity", "mask_alpha", "selected_only", "outline_only"})



#: Opacity (0-255) of the band of a label's sigma about its contour.
SIGMA_BAND_ALPHA = 70


def sigma_band_pen(color, sigma_px: float) -> QtGui.QPen:
    """A pen ``2 sigma_px`` wide in image pixels (not screen pixels: it scales with the zoom), translucent, with
    round ends: the contour drawn with it covers the label's +-1 sigma about the contour."""
    pen = pg.mkPen((*color[:3], SIGMA_BAND_ALPHA), width=2.0 * float(sigma_px))
    pen.setCosmetic(False)
    pen.setCapStyle(QtCore.Qt.RoundCap)
    pen.setJoinStyle(QtCore.Qt.RoundJoin)
    return pen

class FrameView(QtWidgets.QWidget):
    """Shows :class:`~evpose.core.views.frame.FrameData`; reports hover information.

    Signals
    -------
    hoverText(str)
        ``"u, v | n events | object | depth"`` under the cursor (empty when outside or when the mouse leaves).
    """

    hoverText = QtCore.Signal(str)

    def __init__(self, session: Session, parent=None):
        super().__init__(parent)
        self.session = session
        self.frame: FrameData | None = None      # the overlays on screen (labels, masks, contours, ...)
        self.events: EventFrame | None = None    # the event image on screen
        self._items: dict[str, dict[str, pg.GraphicsObject]] = {}
        self._masks_from_frame = True            # the frame's mask image fits the display options

        self.toolbar = FrameToolbar(session)
        self.glw = pg.GraphicsLayoutWidget()
        self.glw.setBackground("w")
        self.glw.setFocusPolicy(QtCore.Qt.StrongFocus)     # a click on the frame takes the keyboard focus
        self.setFocusProxy(self.glw)
        self.glw.setToolTip(DRAG_HELP)
        self.vb = FrameViewBox(session, self.pick, lockAspect=True, invertY=True, enableMenu=False)
        self.glw.addItem(self.vb)
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
        self._sensor_frame(rect)
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
        # while the session previews proposed corrections (an estimate before Accept) the frame says so
        self.preview_badge = pg.TextItem(PREVIEW_TEXT, color=(255, 255, 255), fill=pg.mkBrush(200, 90, 0, 200),
                                         anchor=(0, 1))
        self.preview_badge.setZValue(11)
        self.preview_badge.setPos(-0.5, session.scene.camera.height - 0.5)     # bottom left of the image
        self.preview_badge.setVisible(False)
        self.vb.addItem(self.preview_badge)
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
        lay.setSpacing(0)
        lay.addWidget(self.toolbar)
        lay.addWidget(self.glw, 1)
        lay.addWidget(self.info)
        self._hover: tuple[int, int] | None = None
        self.vb.drag_refused.connect(self.info.setRightText)      # why the object did not move
        self._proxy = pg.SignalProxy(self.glw.scene().sigMouseMoved, rateLimit=30, slot=self._mouse_moved)
        self.glw.viewport().installEventFilter(self)
        self.toolbar.done.connect(lambda: self.glw.setFocus(QtCore.Qt.OtherFocusReason))
        connect_view(self, session.changed, self._on_session, {VIEW, OBJECTS})

    # ------------------------------------------------------------------ items
    def _sensor_frame(self, rect: QtCore.QRectF) -> None:
        """The sensor's border, and a veil in the background colour over everything outside it."""
        outside = QtGui.QPainterPath()
        outside.addRect(rect.adjusted(-100 * rect.width(), -100 * rect.height(), 100 * rect.width(),
                                      100 * rect.height()))
        outside.addRect(rect)                   # odd-even fill: a hole where the sensor is
        self.outside_veil = QtWidgets.QGraphicsPathItem(outside)
        self.outside_veil.setPen(QtGui.QPen(QtCore.Qt.NoPen))
        self.outside_veil.setBrush(QtGui.QColor(255, 255, 255, OUTSIDE_VEIL_ALPHA))
        self.outside_veil.setZValue(8)
        pen = QtGui.QPen(QtGui.QColor(80, 80, 80))
        pen.setCosmetic(True)
        pen.setWidthF(1.5)
        self.sensor_border = QtWidgets.QGraphicsRectItem(rect)
        self.sensor_border.setPen(pen)
        self.sensor_border.setZValue(9)
        for it in (self.outside_veil, self.sensor_border):
            self.vb.addItem(it, ignoreBounds=True)

    def _ensure_items(self, name: str) -> dict:
        if name in self._items:
            return self._items[name]
        color = self.session.color(name)
        items = {
            "contour": pg.PlotCurveItem(pen=pg.mkPen(color, width=2), connect="finite"),
            "box": pg.PlotCurveItem(pen=pg.mkPen(color, width=1.5), connect="pairs"),
            # the label's +-1 sigma about the contour (image pixels: it widens as you zoom in)
            "band": pg.PlotCurveItem(pen=sigma_band_pen(color, 1.0), connect="finite"),
        }
        items["contour"].setZValue(3)
        items["box"].setZValue(2)
        items["band"].setZValue(2.5)
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
        self._draw_events()
        self._show_overlay_state()

    def set_overlays(self, data: FrameData) -> None:
        """Display a window's labels and overlays (the app's second stage; ``data.image_rgb`` is not used)."""
        self.frame = data
        self._masks_from_frame = True
        self._draw_overlays()
        self._show_overlay_state()

    def _draw_events(self) -> None:
        """The event image with the view's contrast and opacity."""
        if self.events is None:
            return
        v = self.session.view
        img = adjust_contrast(self.events.image_rgb, v.contrast, REPRESENTATION_BACKGROUND.get(v.representation,
                                                                                                "white"))
        self.image_item.setImage(img, autoLevels=False, levels=(0, 255))
        self.image_item.setOpacity(v.event_opacity)

    def drawn(self) -> list[bool]:
        """Per object of the scene: are its overlays drawn (not hidden; the selected one in selected-only mode)?"""
        v = self.session.view
        return drawn_objects(self.session.object_names, v.hidden, v.selected, v.selected_only)

    def _mask_image(self, drawn: list[bool]) -> np.ndarray | None:
        """The frame's mask image, or one composed again for the display options (selected only, opacity)."""
        f, v = self.frame, self.session.view
        if f is None or f.mask_rgba is None or v.outline_only or "mask" not in v.overlays:
            return None
        lab = f.labels
        if (self._masks_from_frame and not v.selected_only) or lab.label_map is None:
            return f.mask_rgba
        colors = [self.session.color(n) for n in self.session.object_names]
        return compose_masks_rgba(lab.label_map, colors, v.mask_alpha, drawn)

    def _draw_overlays(self) -> None:
        f, v = self.frame, self.session.view
        if f is None:
            return
        drawn = self.drawn()
        masks = self._mask_image(drawn)
        if masks is not None:
            self.mask_item.setImage(masks, autoLevels=False, levels=None)
        self.mask_item.setVisible(masks is not None)
        shown = {o.name: o for o in f.overlays}
        axes, centers = [[], [], []], []
        full = not v.outline_only
        for k, name in enumerate(self.session.object_names):
            items = self._ensure_items(name)
            ov = shown.get(name)
            if ov is None or not drawn[k]:
                for it in items.values():
                    it.setData([], [])
                continue
            contours = ov.contours
            if not contours and v.outline_only and f.labels.label_map is not None:
                contours = mask_contours(f.labels.label_map == k)     # outlines even with contours off
            items["contour"].setData(*polylines_xy(contours))
            band = ov.sigma_px is not None and ov.sigma_px > 0 and bool(contours) and not v.outline_only
            items["band"].setData(*(polylines_xy(contours) if band else ([], [])))
            if band:
                items["band"].setPen(sigma_band_pen(ov.color, ov.sigma_px))
            items["box"].setData(*segments_xy(ov.box_segments if full else np.zeros((0, 2, 2))))
            for a in range(3):
                if full and len(ov.axes) == 3 and len(ov.axes[a]):
                    axes[a].append(ov.axes[a])
            if full and ov.center_uv is not None:
                centers.append({"pos": tuple(ov.center_uv), "pen": pg.mkPen(ov.color, width=2.5)})
            width = 3.5 if name == v.selected else 2.0
            items["contour"].setPen(pg.mkPen(ov.color, width=width))
        for a in range(3):
            segs = np.concatenate(axes[a]) if axes[a] else np.zeros((0, 2, 2))
            self.axis_items[a].setData(*segments_xy(segs))
        self.center_item.setData(centers)

    def _on_session(self, change: Change) -> None:
        """Display options and selection apply to what is on screen at once (the worker's frame follows)."""
        fields = change.fields or frozenset()
        if change.kind == "view" and fields & EVENT_DISPLAY_FIELDS:
            self._draw_events()
        if change.kind == "objects" or (change.kind == "view" and fields & OVERLAY_DISPLAY_FIELDS):
            self._masks_from_frame = self._masks_from_frame and not (fields & {"mask_alpha", "hidden"})
            self._draw_overlays()
        if change.kind == "view" and "preview" in fields:
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
        if e is None and f is None:
            return
        stale = self.overlays_stale
        opacity = STALE_OVERLAY_OPACITY if stale else 1.0
        for it in self._overlay_items():
            it.setOpacity(opacity)
        self.preview_badge.setVisible(getattr(self.session, "preview", None) is not None)
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

    # ------------------------------------------------------------------ picking
    def pick(self, u: int, v: int) -> str | None:
        """The object drawn at pixel (u, v) of the frame on screen (its visible mask), or None: off the
        objects, hidden or not drawn, or while the overlays on screen are of another window."""
        f = self.frame
        if f is None or self.overlays_stale or not f.labels.valid or f.labels.label_map is None:
            return None
        lm = f.labels.label_map
        if not (0 <= u < lm.shape[1] and 0 <= v < lm.shape[0]) or lm[v, u] < 0:
            return None
        name = f.labels.objects[int(lm[v, u])].name
        return name if self.drawn()[self.session.object_names.index(name)] else None

    # ------------------------------------------------------------------ hover
    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt API)
        if obj is self.glw.viewport() and event.type() == QtCore.QEvent.Leave:
            self.clear_hover()
        return False

    def clear_hover(self) -> None:
        """The mouse left the view: no pixel readout (and no late, rate-limited move to bring it back)."""
        self._proxy.flush()
        self._hover = None
        self._update_readout()

    def _mouse_moved(self, evt) -> None:
        pos = evt[0]
        if not self.vb.sceneBoundingRect().contains(pos):
            self._hover = None
        else:
            p = self.vb.mapSceneToView(pos)
            self._hover = pixel_of(p.x(), p.y())
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
        cursor = QtCore.Qt.OpenHandCursor if self._hover and self.pick(*self._hover) else QtCore.Qt.ArrowCursor
        self.glw.viewport().setCursor(QtCore.Qt.ClosedHandCursor if self.vb.dragging else cursor)
        self.info.setRightText(text)
        self.hoverText.emit(text)
