"""Manual corrections: clock offset and skew, per-object pose, hand-eye.

Every change goes through the session (and so through the undo history); repeated nudges and
slider drags merge into one undo step. Units are shown on every control: microseconds and ppm
for the clock, millimetres and degrees for poses, with the axes of a selectable frame
(camera: x right, y down, z forward; object: its own axes; base: the robot base).
"""
from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtWidgets

from evpose.core.errors import InputError
from evpose.core.document.pose_edit import FRAMES, delta_components, pose_change
from evpose.core.session.model import Session
from evpose.core.signals import Change, DOCUMENT, OBJECTS, TIME
from evpose.widgets.binding import connect_view
from evpose.widgets.labels import Readout

OFFSET_LIMIT_US = 10_000_000
TRANSLATION_STEPS_MM = (0.1, 0.5, 1.0, 2.0, 5.0, 10.0)
ROTATION_STEPS_DEG = (0.05, 0.1, 0.5, 1.0, 2.0, 5.0)
OFFSET_STEPS_US = (10, 100, 1000, 5000)
#: The pose readout where the trajectory has no camera pose at the view time (two lines: the panel is narrow).
NO_CAMERA_POSE = "no camera pose at this time (outside the trajectory):\ncamera axes unknown; use object or base axes"
FRAME_LABELS = {"camera": "camera (x right, y down, z forward)", "object": "object axes", "base": "robot base"}


def _spin(lo, hi, step, decimals=None, suffix=""):
    w = QtWidgets.QDoubleSpinBox() if decimals is not None else QtWidgets.QSpinBox()
    if decimals is not None:
        w.setDecimals(decimals)
    w.setRange(lo, hi)
    w.setSingleStep(step)
    w.setSuffix(suffix)
    w.setKeyboardTracking(False)
    w.setAccelerated(True)
    return w


def _two_lines(label: QtWidgets.QLabel) -> None:
    """A readout wrapped on at most two lines of constant height, whose width follows the panel (not its text)."""
    label.setWordWrap(True)
    label.setSizePolicy(QtWidgets.QSizePolicy.Ignored, QtWidgets.QSizePolicy.Fixed)
    label.setFixedHeight(2 * label.fontMetrics().lineSpacing() + 4)


class _NudgeGrid(QtWidgets.QWidget):
    """Buttons −/+ along x, y, z for translation and rotation; emits (kind, axis, sign)."""

    nudged = QtCore.Signal(str, int, int)

    def __init__(self, parent=None):
        super().__init__(parent)
        grid = QtWidgets.QGridLayout(self)
        grid.setContentsMargins(0, 0, 0, 0)
        grid.setSpacing(2)
        for c, axis in enumerate("xyz"):
            grid.addWidget(QtWidgets.QLabel(axis, alignment=QtCore.Qt.AlignCenter), 0, 1 + 2 * c, 1, 2)
        for r, (kind, label) in enumerate((("translate", "move"), ("rotate", "rotate"))):
            grid.addWidget(QtWidgets.QLabel(label), r + 1, 0)
            for a in range(3):
                for s, (sign, text) in enumerate(((-1, "−"), (1, "+"))):
                    b = QtWidgets.QToolButton(text=text)
                    b.setAutoRepeat(True)
                    b.setAutoRepeatInterval(80)
                    b.setToolTip(f"{label} {'-' if sign < 0 else '+'}{'xyz'[a]}")
                    b.setObjectName(f"{kind}_{'xyz'[a]}_{'minus' if sign < 0 else 'plus'}")
                    b.clicked.connect(lambda _=False, k=kind, ax=a, sg=sign: self.nudged.emit(k, ax, sg))
                    grid.addWidget(b, r + 1, 1 + 2 * a + s)


class CorrectionPanel(QtWidgets.QWidget):
    """Clock, object-pose and hand-eye corrections of the session's scene.

    Signals
    -------
    autoSyncRequested(), edgeSyncRequested(), refineRequested(str), residualsRequested()
        Emitted by the Auto / Edges / Refine / Residuals buttons (the app runs the estimation in a worker, or shows
        the residual view).

    ``compact``: the three groups are tabs (``tabs``) instead of a column, so each group's controls fit a laptop
    screen's dock without scrolling.
    """

    autoSyncRequested = QtCore.Signal()
    edgeSyncRequested = QtCore.Signal()
    refineRequested = QtCore.Signal(str)
    residualsRequested = QtCore.Signal()

    def __init__(self, session: Session, parent=None, compact: bool = False):
        super().__init__(parent)
        self.session = session
        self._updating = False
        lay = QtWidgets.QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        groups = (("Clock", self._clock_group()), ("Object pose", self._object_group()),
                  ("Hand-eye", self._hand_eye_group()))
        self.tabs = QtWidgets.QTabWidget() if compact else None
        for tab, group in groups:
            if self.tabs is None:
                lay.addWidget(group)
                continue
            group.setToolTip(group.title())
            group.setTitle("")
            group.setFlat(True)
            page = QtWidgets.QWidget()
            pl = QtWidgets.QVBoxLayout(page)
            pl.setContentsMargins(0, 0, 0, 0)
            pl.addWidget(group)
            pl.addStretch(1)
            self.tabs.addTab(page, tab)
        if self.tabs is not None:
            self.tabs.setDocumentMode(True)
            lay.addWidget(self.tabs)
        lay.addStretch(1)
        connect_view(self, session.changed, self._on_session, {DOCUMENT, OBJECTS, TIME})
        self.refresh()

    # ------------------------------------------------------------------ construction
    def _clock_group(self) -> QtWidgets.QGroupBox:
        g = QtWidgets.QGroupBox("Clock (event → robot time)")
        form = QtWidgets.QGridLayout(g)
        self.offset_spin = _spin(-OFFSET_LIMIT_US, OFFSET_LIMIT_US, 100, suffix=" µs")
        self.offset_spin.setToolTip("Correction added to the scene's prior offset (pose time − event time), "
                                    "microseconds. Shortcuts: [ and ] (Shift: ×10).")
        self.offset_step = QtWidgets.QComboBox()
        for s in OFFSET_STEPS_US:
            self.offset_step.addItem(f"{s:g} µs" if s < 1000 else f"{s / 1000:g} ms", s)
        self.offset_step.setCurrentIndex(1)
        self.offset_slider = QtWidgets.QSlider(QtCore.Qt.Horizontal)
        self.offset_slider.setRange(-2500, 2500)
        self.offset_fine = QtWidgets.QCheckBox("fine")
        self.offset_fine.setToolTip("coarse: ±250 ms in 0.1 ms steps around 0; fine: ±5 ms in 2 µs steps "
                                    "around the value when switched on")
        self._slider_anchor, self._slider_unit = 0, 100
        self.offset_total = QtWidgets.QLabel()
        _two_lines(self.offset_total)     # the dock never moves when the numbers get longer
        self.skew_spin = _spin(-5000.0, 5000.0, 1.0, decimals=3, suffix=" ppm")
        self.skew_spin.setToolTip("Clock skew correction in parts per million (added to the prior)")
        self.auto_button = QtWidgets.QPushButton("Auto…")
        self.auto_button.setToolTip("Estimate the clock from the event rate vs the robot speed, then the clock and "
                                    "every object's pose together from the event edges; the proposal is shown on "
                                    "the frame (before / after) until you accept it")
        self.edges_button = QtWidgets.QPushButton("Clock and poses from edges…")
        self.edges_button.setToolTip("Fit offset (and skew) and every object's pose together so the events line up "
                                     "with the objects' edges, starting at the clock in effect (a local fit: use "
                                     "Auto when the clock may be far off)")
        reset_offset = QtWidgets.QToolButton(text="⟲")
        reset_offset.setToolTip("reset the offset correction to 0")
        reset_skew = QtWidgets.QToolButton(text="⟲")
        reset_skew.setToolTip("reset the skew correction to 0")
        form.addWidget(QtWidgets.QLabel("offset"), 0, 0)
        form.addWidget(self.offset_spin, 0, 1)
        form.addWidget(self.offset_step, 0, 2)
        form.addWidget(reset_offset, 0, 3)
        form.addWidget(self.offset_slider, 1, 0, 1, 3)
        form.addWidget(self.offset_fine, 1, 3)
        form.addWidget(self.offset_total, 2, 0, 1, 4)
        form.addWidget(QtWidgets.QLabel("skew"), 3, 0)
        form.addWidget(self.skew_spin, 3, 1)
        form.addWidget(self.auto_button, 3, 2)
        form.addWidget(reset_skew, 3, 3)
        form.addWidget(self.edges_button, 4, 1, 1, 2)
        self.offset_spin.valueChanged.connect(lambda v: self._set_offset(int(v)))
        self.offset_step.currentIndexChanged.connect(lambda _: self.offset_spin.setSingleStep(self.offset_step.currentData()))
        self.offset_spin.setSingleStep(self.offset_step.currentData())
        self.offset_slider.valueChanged.connect(self._slider_moved)
        self.offset_slider.sliderReleased.connect(self.session.history.break_merge)
        self.offset_fine.toggled.connect(self._fine_toggled)
        self.skew_spin.valueChanged.connect(lambda v: None if self._updating else self.session.set_skew_correction_ppm(v))
        self.auto_button.clicked.connect(self.autoSyncRequested)
        self.edges_button.clicked.connect(self.edgeSyncRequested)
        reset_offset.clicked.connect(lambda: self.session.reset("offset_us"))
        reset_skew.clicked.connect(lambda: self.session.reset("skew_ppm"))
        return g

    def _object_group(self) -> QtWidgets.QGroupBox:
        g = QtWidgets.QGroupBox("Object pose")
        v = QtWidgets.QVBoxLayout(g)
        row = QtWidgets.QHBoxLayout()
        self.object_combo = QtWidgets.QComboBox()
        self.object_combo.addItems(self.session.object_names)
        self.frame_combo = QtWidgets.QComboBox()
        for combo in (self.object_combo, self.frame_combo):   # as wide as the panel, not as its longest entry
            combo.setSizeAdjustPolicy(QtWidgets.QComboBox.AdjustToMinimumContentsLengthWithIcon)
            combo.setMinimumContentsLength(8)
        for f in FRAMES:
            self.frame_combo.addItem(FRAME_LABELS[f], f)
        row.addWidget(self.object_combo, 1)
        row.addWidget(QtWidgets.QLabel("axes"))
        row.addWidget(self.frame_combo, 1)
        v.addLayout(row)
        row = QtWidgets.QHBoxLayout()
        self.trans_step = QtWidgets.QComboBox()
        for s in TRANSLATION_STEPS_MM:
            self.trans_step.addItem(f"{s:g} mm", s)
        self.trans_step.setCurrentIndex(2)
        self.rot_step = QtWidgets.QComboBox()
        for s in ROTATION_STEPS_DEG:
            self.rot_step.addItem(f"{s:g}°", s)
        self.rot_step.setCurrentIndex(2)
        row.addWidget(QtWidgets.QLabel("step"))
        row.addWidget(self.trans_step)
        row.addWidget(self.rot_step)
        row.addStretch(1)
        self.type_button = QtWidgets.QPushButton("Type…")
        self.type_button.setToolTip("move the object by typed amounts (mm, degrees, in the axes above) or set its "
                                    "pose in the base frame to typed values")
        self.type_button.clicked.connect(self.type_pose)
        row.addWidget(self.type_button)
        v.addLayout(row)
        self.object_nudges = _NudgeGrid()
        self.object_nudges.nudged.connect(lambda k, a, s: self.nudge_object(k, a, s))
        v.addWidget(self.object_nudges)
        # two lines of constant size (it changes at every time step in camera axes): no relayout of the window
        self.object_delta = Readout("centre moved 000.00 mm  [+000.00, +000.00, +000.00] mm", stretch=True, lines=2)
        self.object_delta.setToolTip("The object's correction, as the Refine dialog reports a change: how far its "
                                     "box centre moved and by how much it turned (about that centre); in "
                                     "brackets the components along the axes chosen above")
        v.addWidget(self.object_delta)
        self.label_sigma = Readout("label σ here 000.00 mm, 00.000°, 000.0 px (no σ: clock offset, hand-eye)",
                                   stretch=True)
        self.label_sigma.setToolTip(
            "The 1-sigma of this object's label in the current window (translation in mm and rotation in degrees "
            "of T_cam_obj, and its contour in pixels: the band drawn about it), propagated from the sigmas the "
            "applied estimates stored (clock, this object's pose, hand-eye) and the trajectory's interpolation; "
            "an input without one counts as exact and is named. A hand edit of a value drops its sigma.")
        v.addWidget(self.label_sigma)
        row = QtWidgets.QHBoxLayout()
        self.refine_button = QtWidgets.QPushButton("Refine from events")
        self.refine_button.setToolTip("Fit this object's pose to the event edges over several windows (clock and "
                                      "other objects held); the proposal is shown on the frame until you accept it")
        reset = QtWidgets.QPushButton("Reset pose")
        row.addWidget(self.refine_button)
        row.addWidget(reset)
        v.addLayout(row)
        self.residuals_button = QtWidgets.QPushButton("Residuals")
        self.residuals_button.setToolTip("show the events coloured by their distance to the labels' edges (red "
                                         "outside the drawn outline, blue inside): depth and tilt errors show there")
        self.residuals_button.clicked.connect(self.residualsRequested.emit)
        row.addWidget(self.residuals_button)
        self.object_combo.currentTextChanged.connect(self._object_chosen)
        self.frame_combo.currentIndexChanged.connect(lambda _: self._refresh_object())
        self.refine_button.clicked.connect(lambda: self.refineRequested.emit(self.current_object() or ""))
        reset.clicked.connect(lambda: self.current_object() and self.session.reset(self.current_object()))
        return g

    def type_pose(self, dialog=None) -> bool:
        """Ask for a typed move or pose of the selected object (:class:`~evpose.widgets.pose_entry.PoseEntryDialog`;
        ``dialog`` replaces the modal one in tests) and apply it as one undo step; False when nothing was applied."""
        from evpose.widgets.pose_entry import PoseEntryDialog

        name = self.current_object()
        if not name:
            return False
        dlg = dialog or PoseEntryDialog(name, self.frame_combo.currentText(), self.session.scene.T_base_obj(name),
                                        self)
        if dialog is None and dlg.exec() != QtWidgets.QDialog.Accepted:
            return False
        values = dlg.result_values()
        if values is None:
            return False
        try:
            if values[0] == "move":
                self.session.nudge_object(name, self.current_frame(), rot_deg=values[2], trans_mm=values[1],
                                          mergeable=False)
            else:
                self.session.set_object_pose(name, values[1])
        except ValueError as exc:            # no camera pose here for camera axes: say so, change nothing
            QtWidgets.QToolTip.showText(self.type_button.mapToGlobal(self.type_button.rect().bottomLeft()), str(exc))
            return False
        return True

    def _hand_eye_group(self) -> QtWidgets.QGroupBox:
        g = QtWidgets.QGroupBox("Hand-eye (camera frame)")
        g.setCheckable(True)
        g.setChecked(False)
        inner = QtWidgets.QWidget()
        v = QtWidgets.QVBoxLayout(inner)
        v.setContentsMargins(0, 0, 0, 0)
        self.hand_eye_nudges = _NudgeGrid()
        self.hand_eye_nudges.nudged.connect(self._nudge_hand_eye)
        v.addWidget(self.hand_eye_nudges)
        self.hand_eye_delta = QtWidgets.QLabel()
        _two_lines(self.hand_eye_delta)
        v.addWidget(self.hand_eye_delta)
        reset = QtWidgets.QPushButton("Reset hand-eye")
        reset.clicked.connect(lambda: self.session.reset("hand_eye"))
        v.addWidget(reset)
        QtWidgets.QVBoxLayout(g).addWidget(inner)
        inner.setVisible(False)
        g.toggled.connect(inner.setVisible)
        return g

    # ------------------------------------------------------------------ actions
    def current_object(self) -> str | None:
        return self.object_combo.currentText() or None

    def current_frame(self) -> str:
        return self.frame_combo.currentData()

    def _object_chosen(self, name: str) -> None:
        if not self._updating and name:
            self.session.select(name)
        self._refresh_object()

    def _set_offset(self, value_us: int) -> None:
        if not self._updating:
            self.session.set_offset_correction_us(value_us)

    def _slider_moved(self, k: int) -> None:
        if not self._updating:
            self.session.set_offset_correction_us(self._slider_anchor + k * self._slider_unit)

    def _fine_toggled(self, fine: bool) -> None:
        if fine:
            self._slider_anchor, self._slider_unit = self.session.scene.corrections.offset_us, 2
        else:
            self._slider_anchor, self._slider_unit = 0, 100
        self.session.history.break_merge()
        self.refresh()

    def nudge_offset(self, sign: int, big: bool = False) -> None:
        """Step the offset by the chosen step (×10 with ``big``)."""
        step = int(self.offset_step.currentData()) * (10 if big else 1)
        self.session.set_offset_correction_us(self.session.scene.corrections.offset_us + sign * step)

    def nudge_object(self, kind: str, axis: int, sign: int, big: bool = False) -> None:
        """Nudge the selected object along/about ``axis`` of the chosen frame by one step."""
        name = self.current_object()
        if not name:
            return
        vec = np.zeros(3)
        step = self.trans_step if kind == "translate" else self.rot_step
        vec[axis] = sign * step.currentData() * (10 if big else 1)
        try:
            if kind == "translate":
                self.session.nudge_object(name, self.current_frame(), trans_mm=vec)
            else:
                self.session.nudge_object(name, self.current_frame(), rot_deg=vec)
        except ValueError:                      # camera axes where the trajectory has no camera pose
            self.object_delta.setText(NO_CAMERA_POSE)

    def _nudge_hand_eye(self, kind: str, axis: int, sign: int) -> None:
        vec = np.zeros(3)
        if kind == "translate":
            vec[axis] = sign * self.trans_step.currentData()
            self.session.nudge_hand_eye(trans_mm=vec)
        else:
            vec[axis] = sign * self.rot_step.currentData()
            self.session.nudge_hand_eye(rot_deg=vec)

    # ------------------------------------------------------------------ model -> view
    def _on_session(self, change: Change) -> None:
        if change.kind in ("document", "objects"):
            self.refresh()
        elif change.kind == "time":
            if self.current_frame() == "camera":
                self._refresh_object()      # camera axes turn with the camera
            else:
                self._refresh_sigma()       # the label's sigma follows the camera's motion

    def refresh(self) -> None:
        self._updating = True
        try:
            c = self.session.scene.corrections
            m = self.session.scene.manifest
            self.offset_spin.setValue(int(np.clip(c.offset_us, -OFFSET_LIMIT_US, OFFSET_LIMIT_US)))
            k = int(round((c.offset_us - self._slider_anchor) / self._slider_unit))
            self.offset_slider.setValue(int(np.clip(k, self.offset_slider.minimum(), self.offset_slider.maximum())))
            self.skew_spin.setValue(c.skew_ppm)
            clock = self.session.scene.clock
            self.offset_total.setText(f"in effect: {clock.offset_us / 1000:+.3f} ms = prior {m.clock_offset_us / 1000:+.3f} ms "
                                      f"+ correction {c.offset_us / 1000:+.3f} ms;  skew {clock.skew_ppm:+.3f} ppm")
            sel = self.session.view.selected
            if sel and sel != self.object_combo.currentText():
                self.object_combo.setCurrentText(sel)
            rv, t = delta_components(c.hand_eye_delta)
            self.hand_eye_delta.setText(f"Δ rot {np.linalg.norm(rv):.3f}° [{rv[0]:+.2f}, {rv[1]:+.2f}, {rv[2]:+.2f}]°,"
                                        f" Δ t {np.linalg.norm(t):.2f} mm [{t[0]:+.2f}, {t[1]:+.2f}, {t[2]:+.2f}] mm")
        finally:
            self._updating = False
        self._refresh_object()

    def _refresh_object(self) -> None:
        name = self.current_object()
        self.object_delta.setText(self.pose_readout(name) if name else "")
        self._refresh_sigma()

    def _refresh_sigma(self) -> None:
        name = self.current_object()
        self.label_sigma.setText(self.sigma_readout(name) if name else "")

    def sigma_readout(self, name: str) -> str:
        """Object ``name``'s label sigma in the current window (:meth:`Session.label_sigma
        <evpose.core.session.model.Session.label_sigma>`), with the inputs it lacks."""
        try:
            s = self.session.label_sigma(name)
        except InputError as exc:
            return f"label σ: {exc}"
        if s is None:
            return "label σ: none stored (apply an estimate: Auto, Refine, evpose refine --apply)"
        if not np.isfinite(s["t_mm"]):
            return "label σ: no label in this window"
        px = "" if not np.isfinite(s["px"]) else f", {s['px']:.1f} px"
        return (f"label σ here {s['t_mm']:.2f} mm, {s['deg']:.3f}°{px}"
                + (f" (no σ: {', '.join(s['missing'])})" if s["missing"] else ""))

    def pose_readout(self, name: str) -> str:
        """The correction of object ``name`` in the chosen axes: displacement of its box centre (mm) and
        rotation (degrees), the numbers the Refine dialog reports (:func:`evpose.core.document.pose_edit.pose_change`)."""
        scene = self.session.scene
        try:
            centre = scene.model(name).bbox_center_m
        except InputError as exc:               # an unreadable mesh: the scene's own error says which (the frame
            return f"no readout: {exc}"          # views report it too); the panel stays usable
        T_bc = self.session.current_T_base_cam()
        if T_bc is None and self.current_frame() == "camera":
            return NO_CAMERA_POSE
        angle, rv, moved = pose_change(scene.corrections.object_delta(name), scene.manifest.object(name).T_base_obj,
                                       centre, self.current_frame(), np.eye(4) if T_bc is None else T_bc)
        dist = np.linalg.norm(moved)
        rv, moved = np.round(rv, 3) + 0.0, np.round(moved, 2) + 0.0      # no "-0.00"
        return (f"centre moved {dist:.2f} mm  [{moved[0]:+.2f}, {moved[1]:+.2f}, {moved[2]:+.2f}] mm\n"
                f"rotated {angle:.3f}°  [{rv[0]:+.3f}, {rv[1]:+.3f}, {rv[2]:+.3f}]°")
