"""The space-time view's controls under the canvas, in four short rows (the view usually lives in a
narrow dock): the camera presets; the time scale and the span; the point budget and "N of M events
shown"; colouring the events near a silhouette by object, the band's width and the share of events in it."""
from __future__ import annotations

from PySide6 import QtCore, QtWidgets

from evpose.widgets.labels import Readout
from evpose.widgets.spacetime.camera import SLIDER_STEPS

BUDGET_RANGE = (1_000, 5_000_000)
SPAN_RANGE_MS = (1, 10_000)
BAND_RANGE_PX = (0.5, 16.0)


def _button(text: str, tip: str) -> QtWidgets.QPushButton:
    b = QtWidgets.QPushButton(text)
    b.setToolTip(tip)
    return b


class SpaceTimeControls:
    """The control widgets (not yet connected) and their rows (:attr:`rows`, added to the view's layout)."""

    def __init__(self):
        self.reset_button = _button("Reset view",
                                    "Oblique view of the whole span (drag: orbit, wheel: zoom, shift-drag: pan)")
        self.front_button = _button("Front", "Look along the time axis, like the frame view")
        self.side_button = _button("Side", "Look along x: time runs to the right, image rows down; a clock "
                                           "offset shows as a shear between event sheets and tubes (vertical motion)")
        self.top_button = _button("Top", "Look down the image rows: x to the right, time up; "
                                         "shows the shear of horizontal motion")
        self.kymograph_button = _button("Kymograph…", "Open the kymograph: the events along a line you draw "
                                        "across an object edge, against time, with each object's projected edge; "
                                        "an offset shows as a shift between them, measured in ms")
        self.scale_slider = QtWidgets.QSlider(QtCore.Qt.Horizontal)
        self.scale_slider.setRange(0, SLIDER_STEPS)
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
        self.by_object_check = QtWidgets.QCheckBox("events by object within")
        self.by_object_check.setToolTip("Draw the events near a projected silhouette (at their own time) in the object's "
                                        "colour and dim the rest: with the right clock and poses the coloured events "
                                        "hug the tubes; an offset leaves the moving edges' events outside the band")
        self.band_spin = QtWidgets.QDoubleSpinBox()
        self.band_spin.setRange(*BAND_RANGE_PX)
        self.band_spin.setSingleStep(0.5)
        self.band_spin.setDecimals(1)
        self.band_spin.setSuffix(" px")
        self.band_spin.setToolTip("Band: events at most this far from a silhouette edge are coloured by object")
        self.band_spin.setKeyboardTracking(False)
        self.band_label = Readout("100% of shown events in the band", "", stretch=True)
        self.rows = self._lay_out()

    def _lay_out(self) -> list[QtWidgets.QHBoxLayout]:
        self.scale_slider.setMinimumWidth(90)
        row1 = QtWidgets.QHBoxLayout()
        for w in (self.reset_button, self.front_button, self.side_button, self.top_button):
            row1.addWidget(w)
        row1.addStretch(1)
        row1.addWidget(self.kymograph_button)
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
        row4 = QtWidgets.QHBoxLayout()
        row4.addWidget(self.by_object_check)
        row4.addWidget(self.band_spin)
        row4.addSpacing(8)
        row4.addWidget(self.band_label, 1)
        return [row1, row2, row3, row4]

    def show_view_state(self, span_us: int, budget: int, band_px: float = 3.0, by_object: bool = True) -> None:
        """Set the span (µs, shown in ms), budget and band spin boxes and the by-object box without emitting
        their signals."""
        for spin, value in ((self.span_spin, int(round(span_us / 1000))), (self.budget_spin, int(budget)),
                            (self.band_spin, float(band_px))):
            if spin.value() != value:
                spin.blockSignals(True)
                spin.setValue(value)
                spin.blockSignals(False)
        if self.by_object_check.isChecked() != bool(by_object):
            self.by_object_check.blockSignals(True)
            self.by_object_check.setChecked(bool(by_object))
            self.by_object_check.blockSignals(False)
        self.band_spin.setEnabled(bool(by_object))

    def show_band(self, split, band_px: float) -> None:
        """The share of the computed events within the band (``split``: the view's current split, or None)."""
        if split is None or split.in_band is None or not len(split.in_band):
            self.band_label.setText("")
            self.band_label.setToolTip("")
            return
        share = float(split.in_band.mean())
        self.band_label.setText(f"{100 * share:.0f}% of events within {band_px:g} px")
        self.band_label.setToolTip("share of the computed events within the band of a shown silhouette at their "
                                   "own time: higher when events and model move together")

    def show_info(self, data, shown: int, stride: int, budget: int) -> None:
        """The "N of M events shown" readout for ``data`` (a ``SpaceTimeData`` or None) and its tooltip."""
        if data is None:
            self.info_label.setText("no events")
            return
        self.info_label.setText(f"{shown:,} of {int(data.n_total):,} events shown")
        tip = [f"span {data.span_us / 1e3:g} ms around t = {data.t_center_us} µs",
               f"{len(data.points):,} points computed (budget {budget:,})"]
        if stride > 1:
            tip.append(f"every {stride}th point drawn (more points than the budget)")
        self.info_label.setToolTip("\n".join(tip))
