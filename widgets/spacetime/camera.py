"""Camera and time scale of the space-time view.

Scene layout (units): a data point ``(x px, y px, t ms)`` relative to the data's centre time is
mapped by one :class:`vispy.visuals.transforms.MatrixTransform` on the parent node of every visual
to scene ``X = x - cx``, ``Y = s * t`` (depth), ``Z = cy - y`` with ``s`` the time scale in scene
pixels per millisecond. So the *front* preset looks like the frame view (x right, image rows down,
time running away from the viewer), and the time-scale slider only rewrites that 4x4 matrix:
no data is rebuilt and nothing is uploaded but one uniform.
"""
from __future__ import annotations

import math

import numpy as np

#: Camera presets: (azimuth, elevation) in degrees. "front" looks along +t like the frame view;
#: "side" looks along x (t to the right, image rows down: shows vertical motion's shear);
#: "top" looks down the image rows (x to the right, t up: shows horizontal motion's shear);
#: "oblique" is the reset view.
PRESETS = {"oblique": (-40.0, 22.0), "front": (0.0, 0.0), "side": (90.0, 0.0), "top": (0.0, 90.0)}
OBLIQUE_FOV = 30.0

#: Time-scale slider: integer position v -> 10 ** (v / 100 + LOG_SCALE_MIN) scene px per ms.
LOG_SCALE_MIN, LOG_SCALE_MAX = -2.0, 2.0
SLIDER_STEPS = int(round((LOG_SCALE_MAX - LOG_SCALE_MIN) * 100))


def scene_matrix(width_px: int, height_px: int, px_per_ms: float) -> np.ndarray:
    """The 4x4 data -> scene matrix (vispy maps row vectors: ``scene = [x, y, t, 1] @ M``) for a sensor
    of ``width_px`` x ``height_px`` and a time scale of ``px_per_ms`` scene pixels per millisecond."""
    cx, cy, s = (width_px - 1) / 2.0, (height_px - 1) / 2.0, px_per_ms
    return np.array([[1.0, 0.0, 0.0, 0.0],
                     [0.0, 0.0, -1.0, 0.0],
                     [0.0, s, 0.0, 0.0],
                     [-cx, 0.0, cy, 1.0]])


def clip_scale(px_per_ms: float) -> float:
    """The time scale limited to the slider's range."""
    return float(np.clip(px_per_ms, 10 ** LOG_SCALE_MIN, 10 ** LOG_SCALE_MAX))


def slider_position(px_per_ms: float) -> int:
    """The slider position of a time scale within the slider's range."""
    return int(round((math.log10(px_per_ms) - LOG_SCALE_MIN) * 100))


def slider_scale(position: int) -> float:
    """The time scale (scene px per ms) at a slider position."""
    return 10 ** (position / 100 + LOG_SCALE_MIN)


def frame_preset(cam, name: str, extent_px: tuple[float, float, float], aspect: float) -> None:
    """Point the ``TurntableCamera`` ``cam`` as preset ``name`` at the scene origin, framing the box of
    ``extent_px = (width, height, depth)`` scene pixels in a viewport of ``aspect`` (width / height).

    Front, side and top are orthographic, so the frame's geometry and a shear read true; the oblique
    view has perspective."""
    az, el = PRESETS[name]
    cam.fov = 0.0 if name in ("front", "side", "top") else OBLIQUE_FOV
    cam.center = (0.0, 0.0, 0.0)
    cam.azimuth, cam.elevation, cam.roll = az, el, 0.0
    W, H, D = extent_px
    a = aspect
    if name == "front":
        w, h = W, H
    elif name == "side":
        w, h = D, H
    elif name == "top":
        w, h = W, D
    else:
        w = h = 0.95 * math.sqrt(W * W + H * H + D * D)
    # TurntableCamera.scale_factor spans the shorter side of the viewport
    cam.scale_factor = 1.2 * max(w / max(a, 1.0), h / max(1.0 / a, 1.0))
    cam.distance = None


class TimeScale:
    """The time scale (scene pixels of depth per millisecond): the data -> scene ``transform`` of a sensor
    of ``width_px`` x ``height_px``, the ``slider`` and its ``label``; ``canvas`` is redrawn on a change.

    It follows the span (depth = the larger sensor side, :meth:`follow_span`) until it is set by hand
    (:meth:`set` or the slider). Rescaling rewrites the matrix only: no data is rebuilt or uploaded.
    """

    def __init__(self, transform, width_px: int, height_px: int, slider, label, canvas):
        self._transform, self._W, self._H = transform, width_px, height_px
        self._slider, self._label, self._canvas = slider, label, canvas
        self.auto = True
        self.px_per_ms: float | None = None
        slider.valueChanged.connect(self._on_slider)

    def follow_span(self, span_us: int) -> None:
        """Fit a span of ``span_us`` to the sensor's larger side, unless the scale was set by hand."""
        if self.auto:
            self._set(max(self._W, self._H) / max(span_us * 1e-3, 1e-3))

    def set(self, px_per_ms: float) -> None:
        """Set the scale by hand (clipped to the slider's range); moves the slider without its signal."""
        self.auto = False
        self._set(px_per_ms)

    def _set(self, px_per_ms: float) -> None:
        self.px_per_ms = clip_scale(px_per_ms)
        self._slider.blockSignals(True)
        self._slider.setValue(slider_position(self.px_per_ms))
        self._slider.blockSignals(False)
        self._apply()

    def _on_slider(self, position: int) -> None:
        self.auto = False
        self.px_per_ms = slider_scale(position)
        self._apply()

    def _apply(self) -> None:
        self._transform.matrix = scene_matrix(self._W, self._H, self.px_per_ms)
        self._label.setText(f"{self.px_per_ms:.3g} px/ms")
        self._canvas.update()
