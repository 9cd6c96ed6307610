"""The kymograph view: an x-t / y-t slice of the events along a line the user draws across an object edge, with
each object's projected edge track on it, so that a clock offset shows as a shift in time between the event
streaks and the tracks (and a skew as a slow drift), and a readout of that shift (pyqtgraph).

The widget is a view of a :class:`evpose.core.session.model.Session`: it draws the display-ready
:class:`evpose.core.views.kymograph.KymographData` that core computes (``KymographComputer``) and that its owner
hands over with :meth:`KymographView.set_data`; it tells the owner when the line changes (``lineChanged``) and
writes the span to the session's view state. Left: the current window's events and the silhouettes, where a
left-drag draws the line (:mod:`~evpose.widgets.kymograph.line`); right: position along the line (x) against time
(y, later up), events dark (ON warm, OFF cool), each object's edge track in its colour, the track moved by the
measured lag dashed, and the current time as a grey line.
"""
from __future__ import annotations

import pyqtgraph as pg
import shiboken6
from PySide6 import QtCore, QtWidgets

from evpose.core.views.kymograph_confidence import REASONS
from evpose.core.signals import Change, VIEW
from evpose.widgets.binding import connect_view
from evpose.widgets.kymograph.line import FramePreview
from evpose.widgets.labels import Readout
from evpose.widgets.plot_data import segments_xy

SPAN_RANGE_MS = (20, 2_000)
#: The readout's widest line (its size hint): of a reading's second line and the reasons a reading is too weak.
READOUT_TEMPLATE = max(("\u2192 clock offset +000.0 ms aligns them", *REASONS), key=len)


def lag_text(lag) -> str:
    """The readout of a :class:`~evpose.core.views.kymograph_lag.LagEstimate`, two lines: how much later the
    events happen than the tracks ± 1σ, and the clock offset change that aligns them (the negative of the lag,
    see :mod:`evpose.core.views.kymograph_lag`); or that the reading is too weak, and why."""
    if lag.lag_ms is None:
        return "events vs track: too weak to read\n" + (lag.weak or "nothing measured")
    return (f"events vs track: {lag.lag_ms:+.1f} \u00b1 {lag.sigma_ms:.1f} ms\n"
            f"\u2192 clock offset {-lag.lag_ms:+.1f} ms aligns them")


class KymographView(QtWidgets.QWidget):
    """Frame preview with the line | kymograph with tracks; the readout and the controls below.

    Parameters
    ----------
    session : evpose.core.session.model.Session
        Read: ``view.kymograph_span_us``; written (view state): ``kymograph_span_us``.

    Signals
    -------
    lineChanged : the line changed (drawn, or back to the default): the owner computes a kymograph for
        :attr:`line`.
    """

    lineChanged = QtCore.Signal()

    def __init__(self, session, parent=None):
        super().__init__(parent)
        self.session = session
        self.data = None
        self._framed = None                 # the image rectangle the plot was last fitted to
        self._user_line: tuple | None = None
        self._auto_line: tuple | None = None
        self._closed = False
        self.preview = FramePreview(self._on_line)
        self.plot = pg.PlotWidget(enableMenu=False)
        self._build_plot()
        self.readout = Readout(READOUT_TEMPLATE, stretch=True, lines=2)
        font = self.readout.font()
        font.setBold(True)
        self.readout.setFont(font)
        self.hint = Readout("drag across an object edge in the image", "drag a line across an object edge in the "
                            "image (left)", stretch=True)
        self.hint.setToolTip("Left: the current window's events and silhouettes; drag a line across an object edge. "
                             "Right: the events along the line (x) over time (y, later up) and each object's "
                             "projected edge (solid; dashed: moved by the measured lag). With the right clock the "
                             "edges run along the event streaks; an offset shifts them in time, a skew makes the "
                             "shift drift.")
        self.auto_button = QtWidgets.QPushButton("Default line")
        self.auto_button.setToolTip("A line across an object along its motion (the selected object's first) whose "
                                    "edges tell the most about the lag")
        self.auto_button.clicked.connect(self.reset_line)
        self.span_spin = QtWidgets.QSpinBox()
        self.span_spin.setRange(*SPAN_RANGE_MS)
        self.span_spin.setSingleStep(50)
        self.span_spin.setSuffix(" ms")
        self.span_spin.setKeyboardTracking(False)
        self.span_spin.setToolTip("Time span of the kymograph around the current time")
        self.span_spin.setValue(int(round(session.view.kymograph_span_us / 1000)))
        self.span_spin.valueChanged.connect(lambda ms: session.set_view_option(kymograph_span_us=int(ms) * 1000))
        self._lay_out()
        self._subscription = connect_view(self, session.changed, self._on_session, {VIEW})

    def _build_plot(self) -> None:
        p = self.plot
        p.setLabel("bottom", "along the line (px)")
        p.setLabel("left", "t \u2212 now (ms)")
        p.showGrid(x=False, y=True, alpha=0.15)
        self.image_item = pg.ImageItem(axisOrder="row-major")
        p.addItem(self.image_item)
        self.now_line = pg.InfiniteLine(pos=0.0, angle=0, pen=pg.mkPen((120, 120, 120), width=1,
                                                                          style=QtCore.Qt.DashLine))
        p.addItem(self.now_line)
        self.track_items: dict = {}
        self.fit_items: dict = {}

    def _lay_out(self) -> None:
        split = QtWidgets.QSplitter(QtCore.Qt.Horizontal)
        split.addWidget(self.preview)
        split.addWidget(self.plot)
        split.setStretchFactor(0, 2)
        split.setStretchFactor(1, 3)
        self.plot.setMinimumSize(160, 120)
        controls = QtWidgets.QHBoxLayout()
        controls.addWidget(self.auto_button)
        controls.addWidget(QtWidgets.QLabel("span"))
        controls.addWidget(self.span_spin)
        controls.addWidget(self.hint, 1)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.setSpacing(3)
        layout.addWidget(self.readout)
        layout.addWidget(split, 1)
        layout.addLayout(controls)

    # ------------------------------------------------------------------ public API
    @property
    def line(self) -> tuple | None:
        """The line to compute ``(u0, v0, u1, v1)`` px: the user's, else the default line once one was shown (so
        it stays put while the time or the clock changes), else None (core picks the default)."""
        return self._user_line if self._user_line is not None else self._auto_line

    @property
    def shift_ms(self) -> float | None:
        """The shown kymograph's lag of the events behind the tracks, ms (None: none shown, or too weak to read)."""
        return None if self.data is None else self.data.lag_ms

    @property
    def shift_sigma_ms(self) -> float | None:
        """Its 1σ, ms (None with it)."""
        return None if self.shift_ms is None else self.data.lag.sigma_ms

    def set_line(self, line) -> None:
        """Use ``(u0, v0, u1, v1)`` (px) as the user's line and emit ``lineChanged``."""
        self._user_line = tuple(float(c) for c in line)
        self.preview.set_line(self._user_line)
        self.lineChanged.emit()

    def reset_line(self) -> None:
        """Back to the default line (picked anew by core) and emit ``lineChanged``."""
        self._user_line = self._auto_line = None
        self.preview.set_line(None)
        self.lineChanged.emit()

    def set_data(self, data) -> None:
        """Draw ``data`` (:class:`evpose.core.views.kymograph.KymographData`)."""
        if not self._alive():
            return
        self.data = data
        self.preview.set_image(data.frame_rgb)
        self.preview.set_contours(data.frame_contours)
        if data.auto_line and data.image_rgb.size:
            self._auto_line = data.line.as_tuple()
        shown = data.line.as_tuple() if data.image_rgb.size else None
        self.preview.set_line(self._user_line if self._user_line is not None else shown)
        if data.image_rgb.size:
            n_t, n_s = data.image_rgb.shape[:2]
            self.image_item.setImage(data.image_rgb, levels=(0, 255), autoLevels=False)
            rect = QtCore.QRectF(-0.5, data.t_first_ms, n_s, n_t * data.bin_ms)
            self.image_item.setRect(rect)
            if rect != self._framed:            # a new line or span: frame the image (not the dashed tracks)
                self._framed = rect
                self.plot.setRange(rect, padding=0.02)
        else:
            self.image_item.clear()
        self._draw_tracks(data)
        self.readout.setText(lag_text(data.lag))
        self.readout.setToolTip(self._tooltip(data))

    def shutdown(self) -> None:
        """Unsubscribe from the session (idempotent)."""
        if not self._closed:
            self._closed = True
            self._subscription.disconnect()

    def closeEvent(self, event) -> None:  # noqa: N802 (Qt name)
        self.shutdown()
        super().closeEvent(event)

    # ------------------------------------------------------------------ internals
    def _alive(self) -> bool:
        return not self._closed and shiboken6.isValid(self)

    def _draw_tracks(self, data) -> None:
        seen = set()
        for tr in data.tracks:
            item = self.track_items.get(tr.name)
            if item is None:
                item = self.track_items[tr.name] = pg.PlotCurveItem(connect="pairs")
                fit = self.fit_items[tr.name] = pg.PlotCurveItem(connect="pairs")
                item.setZValue(5)
                fit.setZValue(4)
                self.plot.addItem(fit)
                self.plot.addItem(item)
            item.setPen(pg.mkPen(tr.color, width=2))
            item.setData(*segments_xy(tr.segments))
            fit = self.fit_items[tr.name]
            fit.setPen(pg.mkPen(tr.color, width=1, style=QtCore.Qt.DashLine))
            lag = tr.lag.lag_ms
            fit.setData(*(segments_xy(tr.segments, lag) if lag is not None and abs(lag) > 0.5 else ([], [])))
            seen.add(tr.name)
        for name in self.track_items:
            if name not in seen:
                self.track_items[name].setData([], [])
                self.fit_items[name].setData([], [])

    @staticmethod
    def _tooltip(data) -> str:
        rows = [f"{tr.name}: " + (f"{tr.lag.lag_ms:+.1f} \u00b1 {tr.lag.sigma_ms:.1f} ms" if tr.lag.readable
                                  else f"too weak ({tr.lag.weak})") for tr in data.tracks]
        rows.append(f"{data.n_events:,} events within 1 px of the line; dashed: each track moved by its lag")
        if data.lines_tried:
            rows.append(f"default line: of {data.lines_tried} lines across the objects, the first that reads, by "
                        "how fast their edges move where their events are")
        return "\n".join(rows)

    def _on_line(self, line, final: bool) -> None:
        """The preview draws the line while it is dragged; the kymograph is asked for once, on release."""
        self._user_line = tuple(float(c) for c in line)
        if final:
            self.lineChanged.emit()

    def _on_session(self, change: Change) -> None:
        if not self._alive() or change.kind != "view":
            return
        ms = int(round(self.session.view.kymograph_span_us / 1000))
        if self.span_spin.value() != ms:
            self.span_spin.blockSignals(True)
            self.span_spin.setValue(ms)
            self.span_spin.blockSignals(False)
