"""The timeline's control row: step back / play-pause / step forward, playback speed, the time readout,
the legend, the score-row toggle, "go to worst" and "Fit". No control takes keyboard focus (keys belong
to the main window)."""
from __future__ import annotations

from PySide6 import QtCore, QtWidgets

from evpose.widgets.labels import Readout
from evpose.widgets.timeline.style import legend_html

__all__ = ["ControlBar", "PLAY_SPEEDS"]

PLAY_SPEEDS = (0.1, 0.25, 0.5, 1.0, 2.0)
READOUT_WIDEST = "-99999.999999 s │ 99999999999999999 µs │ win 9999.5 ms"   # sizes the readout


def _no_focus(w: QtWidgets.QWidget, tip: str) -> QtWidgets.QWidget:
    w.setFocusPolicy(QtCore.Qt.NoFocus)
    w.setToolTip(tip)
    return w


class ControlBar:
    """The control widgets in one horizontal layout (``self.layout``, added to the timeline's).

    Parameters
    ----------
    step : callable(n)
        Move ``n`` windows (the back / forward buttons).
    toggle_play, fit : callable()
        The play / pause and "Fit" buttons.
    scores_toggled : callable(on)
        The "Scores" check box.
    """

    def __init__(self, step, toggle_play, fit, scores_toggled):
        self.back_button = self._tool(QtWidgets.QStyle.SP_MediaSkipBackward, "one window back", lambda: step(-1))
        self.play_button = self._tool(QtWidgets.QStyle.SP_MediaPlay, "play / pause (Space)", toggle_play)
        self.play_button.setCheckable(True)
        self.forward_button = self._tool(QtWidgets.QStyle.SP_MediaSkipForward, "one window forward", lambda: step(1))
        self.speed_combo = _no_focus(QtWidgets.QComboBox(), "playback speed (fraction of real time)")
        for s in PLAY_SPEEDS:
            self.speed_combo.addItem(f"{s:g}×", s)
        self.speed_combo.setCurrentIndex(PLAY_SPEEDS.index(1.0))
        self.readout = _no_focus(Readout(READOUT_WIDEST, fixed_font=True),   # no relayout per time step
                                 "current time: seconds since the first event | event-clock µs | window length")
        self.fit_button = _no_focus(QtWidgets.QToolButton(text="Fit"),
                                    "show the whole sequence (wheel / right drag: zoom; Shift+drag: pan)")
        self.fit_button.setAutoRaise(True)
        self.fit_button.clicked.connect(fit)
        self.scores_check = _no_focus(QtWidgets.QCheckBox("Scores"), "show the per-object alignment score row")
        self.scores_check.setEnabled(False)
        self.scores_check.toggled.connect(scores_toggled)
        self.worst_button = _no_focus(QtWidgets.QToolButton(text="Worst ▾"),
                                      "go to the window with the worst alignment score of an object "
                                      "(among windows with enough evidence: events near its edges, motion, in view)")
        self.worst_button.setPopupMode(QtWidgets.QToolButton.InstantPopup)
        self.worst_menu = QtWidgets.QMenu(self.worst_button)
        self.worst_button.setMenu(self.worst_menu)
        self.worst_button.setEnabled(False)
        self.legend = self._legend()
        self.layout = self._lay_out()

    @staticmethod
    def _tool(icon, tip: str, slot) -> QtWidgets.QToolButton:
        b = _no_focus(QtWidgets.QToolButton(), tip)
        b.setIcon(b.style().standardIcon(icon))
        b.setAutoRaise(True)
        b.clicked.connect(slot)
        return b

    @staticmethod
    def _legend() -> QtWidgets.QLabel:
        legend = QtWidgets.QLabel(legend_html())
        legend.setToolTip("review marks over all objects fill the full height; object-specific marks "
                          "are thin lanes at the top (one lane per object, in the object list's order)")
        small = legend.font()
        small.setPointSize(8)
        legend.setFont(small)
        legend.setSizePolicy(QtWidgets.QSizePolicy.Ignored, QtWidgets.QSizePolicy.Preferred)
        legend.setAlignment(QtCore.Qt.AlignRight | QtCore.Qt.AlignVCenter)
        return legend

    def _lay_out(self) -> QtWidgets.QHBoxLayout:
        c = QtWidgets.QHBoxLayout()
        c.setContentsMargins(0, 0, 0, 0)
        c.setSpacing(2)
        for w in (self.back_button, self.play_button, self.forward_button, self.speed_combo):
            c.addWidget(w)
        c.addSpacing(8)
        c.addWidget(self.readout)
        c.addStretch(1)
        c.addWidget(self.legend, 100)
        c.addSpacing(8)
        for w in (self.scores_check, self.worst_button, self.fit_button):
            c.addWidget(w)
        return c

    @property
    def speed(self) -> float:
        """Playback speed as a fraction of real time."""
        return float(self.speed_combo.currentData())

    def set_speed(self, factor: float) -> None:
        i = self.speed_combo.findData(float(factor))
        if i < 0:
            raise ValueError(f"playback speed must be one of {PLAY_SPEEDS}, got {factor!r}")
        self.speed_combo.setCurrentIndex(i)

    def show_playing(self, playing: bool) -> None:
        """The play button checked with the pause icon while playing (no click signal sent)."""
        self.play_button.blockSignals(True)
        self.play_button.setChecked(playing)
        self.play_button.blockSignals(False)
        self.play_button.setIcon(self.play_button.style().standardIcon(
            QtWidgets.QStyle.SP_MediaPause if playing else QtWidgets.QStyle.SP_MediaPlay))
