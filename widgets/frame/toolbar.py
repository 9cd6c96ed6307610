"""The frame view's controls, above the image: the representation (indicator, legend), the window
length (ms or events), the contrast of the event image and the display options (opacity of masks and
events, the selected object only, outlines only).

Everything is view state of the session (:class:`~evpose.core.session.view_state.ViewState`): neither saved
nor undoable. The controls take no keyboard focus from a click (the single-key shortcuts keep working);
the spin boxes do while one types in them, and give it back to the frame (:attr:`FrameToolbar.done`) after
Enter.
"""
from __future__ import annotations

from PySide6 import QtCore, QtWidgets

from evpose.core.label.windows import MIN_WINDOW_MS
from evpose.core.session.model import Session
from evpose.core.session.view_state import REPRESENTATION_NAMES
from evpose.core.signals import Change, VIEW
from evpose.widgets.binding import connect_view
from evpose.widgets.frame.legend import LEGENDS, legend_html, legend_text, swatch_icon

MIN_WINDOW_EVENTS = 100
MAX_WINDOW_EVENTS = 10_000_000
MAX_WINDOW_MS = 1000.0


def _no_click_focus(w: QtWidgets.QWidget) -> QtWidgets.QWidget:
    w.setFocusPolicy(QtCore.Qt.TabFocus)
    return w


class FrameToolbar(QtWidgets.QWidget):
    """The frame's controls bound to ``session``'s view state.

    Signals
    -------
    done()
        Typing in a spin box ended (Enter): the frame may take the keyboard focus back.
    """

    done = QtCore.Signal()

    def __init__(self, session: Session, parent=None):
        super().__init__(parent)
        self.session = session
        self._updating = False
        self._keys: dict[str, str] = {}
        # two rows: what the image shows (indicator, legend), then the controls; the frame view has height to
        # spare (the sensor's aspect) and little width beside the docks on a laptop screen
        rows = QtWidgets.QVBoxLayout(self)
        rows.setContentsMargins(2, 1, 2, 1)
        rows.setSpacing(1)
        top, lay = QtWidgets.QHBoxLayout(), QtWidgets.QHBoxLayout()
        for row in (top, lay):
            row.setSpacing(4)
            rows.addLayout(row)
        self.rep_combo = _no_click_focus(QtWidgets.QComboBox())
        for name in REPRESENTATION_NAMES:
            self.rep_combo.addItem(swatch_icon(name), LEGENDS[name][0], name)
        self.rep_combo.setSizeAdjustPolicy(QtWidgets.QComboBox.AdjustToContents)
        self.legend = QtWidgets.QLabel()
        self.legend.setTextFormat(QtCore.Qt.RichText)
        self.legend.setSizePolicy(QtWidgets.QSizePolicy.Ignored, QtWidgets.QSizePolicy.Preferred)
        self.legend.setMinimumWidth(0)
        self.win_spin = QtWidgets.QDoubleSpinBox()
        self.win_spin.setKeyboardTracking(False)
        self.win_spin.setToolTip("Length of the view's window: milliseconds, or a number of events (the export's "
                                 "tilings: --window-ms / --window-events)")
        self.win_unit = _no_click_focus(QtWidgets.QComboBox())
        self.win_unit.addItems(["ms", "events"])
        self.contrast_spin = QtWidgets.QDoubleSpinBox()
        self.contrast_spin.setRange(1.0, 8.0)
        self.contrast_spin.setSingleStep(0.5)
        self.contrast_spin.setDecimals(1)
        self.contrast_spin.setPrefix("◐ ×")
        self.contrast_spin.setKeyboardTracking(False)
        self.contrast_spin.setToolTip("Contrast: strengthen faint events (counts, time surface) with a gamma on the "
                                      "event image's ink; ×1 shows it as computed")
        self.display_button = _no_click_focus(QtWidgets.QToolButton(text="Display"))
        self.display_button.setPopupMode(QtWidgets.QToolButton.InstantPopup)
        self.display_button.setMenu(self._display_menu())
        self.display_button.setText("Display ●")        # the widest text: its size stays when the dot goes
        self.display_button.setFixedWidth(self.display_button.sizeHint().width())
        top.addWidget(self.rep_combo)
        top.addWidget(self.legend, 1)
        for w in (QtWidgets.QLabel("window"), self.win_spin, self.win_unit, self.contrast_spin, self.display_button):
            lay.addWidget(w)
        lay.addStretch(1)
        self.rep_combo.currentIndexChanged.connect(self._rep_chosen)
        self.win_spin.valueChanged.connect(self._window_typed)
        self.win_unit.currentIndexChanged.connect(self._unit_chosen)
        self.contrast_spin.valueChanged.connect(
            lambda v: None if self._updating else self.session.set_view_option(contrast=float(v)))
        for spin in (self.win_spin, self.contrast_spin):
            spin.editingFinished.connect(self.done)
        connect_view(self, session.changed, self._on_session, {VIEW})
        self.refresh()

    def _display_menu(self) -> QtWidgets.QMenu:
        menu = QtWidgets.QMenu(self)
        box = QtWidgets.QWidget()
        form = QtWidgets.QFormLayout(box)
        form.setContentsMargins(8, 4, 8, 4)
        self.mask_slider = QtWidgets.QSlider(QtCore.Qt.Horizontal, minimum=0, maximum=100)
        self.mask_slider.setToolTip("opacity of the filled masks")
        self.event_slider = QtWidgets.QSlider(QtCore.Qt.Horizontal, minimum=0, maximum=100)
        self.event_slider.setToolTip("opacity of the event image (fades it towards the background)")
        form.addRow("masks", self.mask_slider)
        form.addRow("events", self.event_slider)
        wa = QtWidgets.QWidgetAction(menu)
        wa.setDefaultWidget(box)
        menu.addAction(wa)
        menu.addSeparator()
        self.selected_only_action = menu.addAction("Selected object only")
        self.outline_only_action = menu.addAction("Outlines only (no fill, boxes, axes)")
        for act in (self.selected_only_action, self.outline_only_action):
            act.setCheckable(True)
        self.mask_slider.valueChanged.connect(
            lambda v: None if self._updating else self.session.set_view_option(mask_alpha=v / 100.0))
        self.event_slider.valueChanged.connect(
            lambda v: None if self._updating else self.session.set_view_option(event_opacity=v / 100.0))
        self.selected_only_action.toggled.connect(
            lambda on: None if self._updating else self.session.set_view_option(selected_only=on))
        self.outline_only_action.toggled.connect(
            lambda on: None if self._updating else self.session.set_view_option(outline_only=on))
        return menu

    # ------------------------------------------------------------------ user -> session
    def _rep_chosen(self, index: int) -> None:
        if not self._updating and index >= 0:
            self.session.set_representation(self.rep_combo.itemData(index))

    @property
    def unit(self) -> str:
        return "events" if self.win_unit.currentIndex() == 1 else "ms"

    def _window_typed(self, value: float) -> None:
        if self._updating:
            return
        if self.unit == "events":
            self.session.set_window_events(int(round(value)))
        else:
            self.session.set_window_us(int(round(value * 1000)))

    def _unit_chosen(self, index: int) -> None:
        """Switch between time windows and windows of a number of events, keeping about the same window."""
        if self._updating:
            return
        w = self.session.view.window()
        if self.unit == "events":
            i0, i1 = self.session.scene.events.index_range(w.t0_us, w.t1_us)
            n = max(int(round((i1 - i0), -2)), MIN_WINDOW_EVENTS)
            self.session.set_window_events(min(n, MAX_WINDOW_EVENTS))
        else:
            ms = max((w.t1_us - w.t0_us) / 1000.0, MIN_WINDOW_MS)
            self.session.set_window_us(int(round(min(round(ms, 1), MAX_WINDOW_MS) * 1000)))

    def scale_window(self, factor: float) -> None:
        """Multiply the window length (its unit kept) by ``factor``: the window shortcuts."""
        v = self.session.view
        if v.window_events:
            n = int(round(v.window_events * factor))
            self.session.set_window_events(min(max(n, MIN_WINDOW_EVENTS), MAX_WINDOW_EVENTS))
        else:
            us = int(round(v.window_us * factor))
            self.session.set_window_us(min(max(us, int(MIN_WINDOW_MS * 1000)), int(MAX_WINDOW_MS * 1000)))

    def set_key_hints(self, keys: dict[str, str]) -> None:
        """Show the shortcut keys (representation name or ``"selected_only"``, ``"outline_only"`` -> keys)."""
        self._keys = dict(keys)
        for i in range(self.rep_combo.count()):
            name = self.rep_combo.itemData(i)
            key = self._keys.get(name)
            self.rep_combo.setItemText(i, f"{LEGENDS[name][0]}" + (f" ({key})" if key else ""))
        for name, act, text in (("selected_only", self.selected_only_action, "Selected object only"),
                                ("outline_only", self.outline_only_action, "Outlines only (no fill, boxes, axes)")):
            act.setText(text + (f"\t{self._keys[name]}" if name in self._keys else ""))
        self.refresh()

    def _show_display_state(self) -> None:
        """The Display button says when an option hides part of the overlays or fades the events."""
        v = self.session.view
        on = [text for text, active in (("selected object only", v.selected_only), ("outlines only", v.outline_only),
                                        (f"events at {100 * v.event_opacity:.0f}%", v.event_opacity < 1.0))
              if active]
        self.display_button.setText("Display ●" if on else "Display")
        self.display_button.setToolTip("Opacity of masks and events, selected object only, outlines only"
                                       + (": " + ", ".join(on) if on else ""))

    # ------------------------------------------------------------------ session -> controls
    def _on_session(self, change: Change) -> None:
        if change.kind == "view":           # nothing shown here depends on the time: no work per scrub step
            self.refresh()

    def refresh(self) -> None:
        v = self.session.view
        self._updating = True
        try:
            self.rep_combo.setCurrentIndex(REPRESENTATION_NAMES.index(v.representation))
            self.legend.setText(legend_html(v.representation))
            keys = " / ".join(self._keys[n] for n in REPRESENTATION_NAMES if n in self._keys)
            self.rep_combo.setToolTip(legend_text(v.representation) + (f"\nkeys {keys} switch" if keys else ""))
            self.legend.setToolTip(legend_text(v.representation))
            if v.window_events:
                self.win_unit.setCurrentIndex(1)
                self.win_spin.setDecimals(0)
                self.win_spin.setRange(MIN_WINDOW_EVENTS, MAX_WINDOW_EVENTS)
                self.win_spin.setSingleStep(1000)
                self.win_spin.setValue(v.window_events)
            else:
                self.win_unit.setCurrentIndex(0)
                self.win_spin.setDecimals(1)
                self.win_spin.setRange(MIN_WINDOW_MS, MAX_WINDOW_MS)
                self.win_spin.setSingleStep(1.0)
                self.win_spin.setValue(v.window_us / 1000.0)
            self.contrast_spin.setValue(v.contrast)
            self.mask_slider.setValue(int(round(100 * v.mask_alpha)))
            self.event_slider.setValue(int(round(100 * v.event_opacity)))
            self.selected_only_action.setChecked(v.selected_only)
            self.outline_only_action.setChecked(v.outline_only)
            self._show_display_state()
        finally:
            self._updating = False
