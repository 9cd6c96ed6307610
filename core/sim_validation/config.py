"""The parameters of a validation-family scene (:class:`ValidationConfig`, :class:`SensorModel`) and where the
published E-POSE assets are looked up."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

#: The published E-POSE assets (``camera_davis346.json``, ``models/``, ``time_shifts.csv``): ``$EVPOSE_ASSETS``,
#: else ``shared/assets/epose`` beside the repository. Everything falls back cleanly when they are absent.
ASSETS = Path(os.environ.get("EVPOSE_ASSETS", Path(__file__).resolve().parents[3] / "shared" / "assets" / "epose"))
PROFILES = ("trapezoid", "sine", "sweep", "mixed")


@dataclass(frozen=True)
class SensorModel:
    """The level-crossing pixel (:mod:`evpose.core.sim_validation.sensor`).

    Attributes
    ----------
    contrast, contrast_sigma : float
        Mean and per-pixel standard deviation of the ON and OFF thresholds (log intensity), drawn separately.
    refractory_us : int
        Dead time after each event of a pixel, µs.
    leak_rate_hz : float
        Mean rate of leak (ON) events of a pixel in a static scene, per second.
    noise_rate_hz : float
        Mean shot-noise rate of a pixel (either polarity), per second.
    rate_spread : float
        Log-normal sigma of the per-pixel leak and noise rates (their mean stays as given).
    hot_pixels, hot_rate_hz : int, float
        Pixels firing shot noise at ``hot_rate_hz``.
    dark_level : float
        Dark current, relative to a white surface lit at the table centre: ``log(I + dark_level)``.
    """

    contrast: float = 0.25
    contrast_sigma: float = 0.03
    refractory_us: int = 200
    leak_rate_hz: float = 0.1
    noise_rate_hz: float = 0.3
    rate_spread: float = 0.5
    hot_pixels: int = 5
    hot_rate_hz: float = 150.0
    dark_level: float = 0.02

    def validate(self) -> None:
        if not (0.01 <= self.contrast <= 2.0) or not (0 <= self.contrast_sigma <= 0.5 * self.contrast):
            raise ValueError(f"contrast: expected 0.01 <= C <= 2 and 0 <= sigma <= C/2, got {self.contrast}, "
                             f"{self.contrast_sigma}")
        if self.refractory_us < 0 or self.leak_rate_hz < 0 or self.noise_rate_hz < 0 or self.hot_rate_hz < 0:
            raise ValueError("sensor: refractory period and rates must be >= 0")
        if self.hot_pixels < 0 or self.rate_spread < 0 or self.dark_level <= 0:
            raise ValueError("sensor: hot_pixels and rate_spread must be >= 0, dark_level > 0")


@dataclass
class ValidationConfig:
    """Parameters of a validation-family scene (units in the names; the names shared with
    :class:`evpose.core.sim.synth_config.SynthConfig` mean the same).

    ``trajectory``: ``"A"`` translates the camera at a fixed orientation, ``"B"`` also turns it to look at the
    objects. ``profile``: the moves' speed profiles, ``"trapezoid"``, ``"sine"`` (raised cosine), ``"sweep"``
    (back and forth without a stop) or ``"mixed"``. ``objects``: YCB names (the E-POSE meshes, or procedural
    stand-ins of their size when absent), ``box``/``cylinder``/``flatbox``, or meshes in ``mesh_dir``.
    ``clutter``: distractor objects on the table that the manifest does not list. ``camera``: a
    ``CameraModel.to_dict()``; default: ``camera_davis346.json`` of the E-POSE assets (or the same numbers).
    """

    objects: tuple[str, ...] = ("sugar_box", "mustard_bottle")
    mesh_dir: str | None = None
    trajectory: str = "B"
    speed_mps: float = 0.5
    duration_s: float = 5.0
    offset_us: int = 0
    skew_ppm: float = 0.0
    pose_error_mm: float = 0.0
    pose_error_deg: float = 0.0
    hand_eye_error_mm: float = 0.0
    hand_eye_error_deg: float = 0.0
    seed: int = 0
    pose_rate_hz: float = 100.0
    clutter: int = 0
    profile: str = "mixed"
    max_px_per_frame: float = 0.5
    supersample: int = 1             # rays per pixel side (1: one jittered ray per pixel)
    pose_jitter_us: float = 20.0     # the robot samples its pose this far (1 sigma) from its timestamp
    ringing_mm: float = 0.1          # arm vibration after each stop (rendered, not in the recorded poses)
    shadows: bool = True
    camera: dict | None = None
    sensor: SensorModel = field(default_factory=SensorModel)

    def validate(self) -> None:
        if self.trajectory not in ("A", "B"):
            raise ValueError(f"trajectory: expected 'A' or 'B', got {self.trajectory!r}")
        if not (0 < self.speed_mps <= 3.0):
            raise ValueError(f"speed: expected 0 < speed <= 3 m/s, got {self.speed_mps}")
        if not (0 < self.duration_s <= 600):
            raise ValueError(f"duration: expected 0 < duration <= 600 s, got {self.duration_s}")
        if not self.objects or len(set(self.objects)) != len(self.objects):
            raise ValueError(f"objects: expected unique names, at least one, got {list(self.objects)}")
        if not (1 <= self.pose_rate_hz <= 2000):
            raise ValueError(f"pose_rate_hz: expected 1 to 2000 Hz, got {self.pose_rate_hz}")
        if not (0 <= self.clutter <= 30):
            raise ValueError(f"clutter: expected 0 to 30 distractors, got {self.clutter}")
        if self.profile not in PROFILES:
            raise ValueError(f"profile: expected one of {PROFILES}, got {self.profile!r}")
        if not (0.05 <= self.max_px_per_frame <= 5):
            raise ValueError(f"max_px_per_frame: expected 0.05 to 5 px, got {self.max_px_per_frame}")
        if self.supersample not in (1, 2, 3, 4):
            raise ValueError(f"supersample: expected 1 to 4, got {self.supersample}")
        if abs(self.skew_ppm) > 1000 or abs(self.offset_us) > 10_000_000:
            raise ValueError(f"clock: expected |skew| <= 1000 ppm and |offset| <= 10 s, got {self.skew_ppm}, "
                             f"{self.offset_us}")
        if self.pose_jitter_us < 0 or self.ringing_mm < 0:
            raise ValueError("pose_jitter_us and ringing_mm must be >= 0")
        self.sensor.validate()
