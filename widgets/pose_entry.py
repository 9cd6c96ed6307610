"""Typed pose entry: move an object by exact amounts, or set its pose to exact values (issue 25.5).

Two tabs, each six numbers with their units and axes named:

* **Move by**: translation (mm) along, and rotation (degrees) about, the axes chosen in the pose panel (camera,
  object or base), turning about the object's box centre -- exactly what that many nudges would do, as one step.
* **Set pose**: the object's pose in the robot base frame, ``T_base_obj``: the position of its model origin (mm)
  and its orientation as a rotation vector (axis times angle, degrees), filled with the pose in effect.

The dialog only collects numbers; :meth:`PoseEntryDialog.result_values` returns ``("move", trans_mm, rot_deg)`` or
``("set", T_base_obj)`` and the panel applies them as one undo step.
"""
from __future__ import annotations

import numpy as np
from PySide6 import QtWidgets
from scipy.spatial.transform import Rotation

from evpose.core.data.geometry import make_T

__all__ = ["PoseEntryDialog"]

#: Spin box limits: translations in mm, rotations in degrees.
MAX_MM, MAX_DEG = 10_000.0, 360.0


def _spins(limit: float, decimals: int, suffix: str) -> list[QtWidgets.QDoubleSpinBox]:
    out = []
    for _ in range(3):
        b = QtWidgets.QDoubleSpinBox(minimum=-limit, maximum=limit, decimals=decimals)
        b.setSuffix(suffix)
        b.setKeyboardTracking(False)
        out.append(b)
    return out


def _grid(rows) -> QtWidgets.QWidget:
    w = QtWidgets.QWidget()
    g = QtWidgets.QGridLayout(w)
    for c, axis in enumerate("xyz"):
        g.addWidget(QtWidgets.QLabel(axis), 0, c + 1)
    for r, (label, spins) in enumerate(rows):
        g.addWidget(QtWidgets.QLabel(label), r + 1, 0)
        for c, b in enumerate(spins):
            g.addWidget(b, r + 1, c + 1)
    return w


class PoseEntryDialog(QtWidgets.QDialog):
    """Typed move or pose of object ``name``; ``axes_text`` names the pose panel's axes (for "Move by"),
    ``T_base_obj`` is the pose in effect (fills "Set pose")."""

    def __init__(self, name: str, axes_text: str, T_base_obj: np.ndarray, parent=None):
        super().__init__(parent)
        self.setWindowTitle(f"Type the pose of {name}")
        self.move_t = _spins(MAX_MM, 3, " mm")
        self.move_r = _spins(MAX_DEG, 3, "°")
        self.set_t = _spins(MAX_MM, 3, " mm")
        self.set_r = _spins(MAX_DEG, 4, "°")
        T = np.asarray(T_base_obj, np.float64)
        for b, v in zip(self.set_t, T[:3, 3] * 1e3):
            b.setValue(float(v))
        for b, v in zip(self.set_r, np.degrees(Rotation.from_matrix(T[:3, :3]).as_rotvec())):
            b.setValue(float(v))
        self._shown = [b.value() for b in self.set_t + self.set_r]     # as shown (rounded to the spin boxes)
        self.tabs = QtWidgets.QTabWidget()
        move = QtWidgets.QWidget()
        ml = QtWidgets.QVBoxLayout(move)
        ml.addWidget(QtWidgets.QLabel(f"in {axes_text} axes, turning about the box centre"))
        ml.addWidget(_grid([("move", self.move_t), ("turn", self.move_r)]))
        self.tabs.addTab(move, "Move by")
        pose = QtWidgets.QWidget()
        pl = QtWidgets.QVBoxLayout(pose)
        pl.addWidget(QtWidgets.QLabel("T_base_obj: position of the model origin and rotation vector (axis × angle), "
                                      "robot base frame"))
        pl.addWidget(_grid([("position", self.set_t), ("rotation", self.set_r)]))
        self.tabs.addTab(pose, "Set pose")
        buttons = QtWidgets.QDialogButtonBox(QtWidgets.QDialogButtonBox.Apply | QtWidgets.QDialogButtonBox.Cancel)
        buttons.button(QtWidgets.QDialogButtonBox.Apply).clicked.connect(self.accept)
        buttons.rejected.connect(self.reject)
        lay = QtWidgets.QVBoxLayout(self)
        lay.addWidget(self.tabs)
        lay.addWidget(buttons)

    def result_values(self):
        """``("move", trans_mm (3,), rot_deg (3,))`` or ``("set", T_base_obj 4x4)`` for the tab shown; None when
        nothing was changed (a pose set to the rounded values it showed would move the object by the rounding)."""
        if self.tabs.currentIndex() == 0:
            t, r = np.array([b.value() for b in self.move_t]), np.array([b.value() for b in self.move_r])
            return None if not (t.any() or r.any()) else ("move", t, r)
        if [b.value() for b in self.set_t + self.set_r] == self._shown:
            return None
        R = Rotation.from_rotvec(np.radians([b.value() for b in self.set_r])).as_matrix()
        return ("set", make_T(R, np.array([b.value() for b in self.set_t]) * 1e-3))
