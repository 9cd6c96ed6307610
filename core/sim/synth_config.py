"""The parameters of a synthetic scene (:class:`SynthConfig`) and their validation."""
from __future__ import annotations

from dataclasses import dataclass, field

from evpose.core.sim.evsim import SensorParams


@dataclass
class SynthConfig:
    """Parameters of a synthetic scene (units in the names)."""

    objects: tuple[str, ...] = ("box", "cylinder")
    mesh_dir: str | None = None
    trajectory: str = "B"
    speed_mps: float = 0.5
    duration_s: float = 4.0
    offset_us: int = 0
    skew_ppm: float = 0.0
    pose_error_mm: float = 0.0
    pose_error_deg: float = 0.0
    hand_eye_error_mm: float = 0.0   # camera mounting error written into the trajectory (camera frame)
    hand_eye_error_deg: float = 0.0
    seed: int = 0
    #: None: the pose errors are drawn from the scene's own generator (after the motion and the renderer); an int:
    #: from a generator of their own, so scenes of one placement (same ``seed`` and objects) at other speeds or
    #: durations get the same wrong poses -- a recording campaign's shared placement error (tracker issue 28.2)
    pose_error_seed: int | None = None
    texture: str = "checker"         # objects' texture: "checker", "fine" or "plain" (sim.renderer.SceneRenderer)
    pose_rate_hz: float = 250.0      # the recorded trajectory's sample rate
    motion_rate_hz: float = 4000.0   # the rendered (true) motion's sample rate: smooth at the event time scale
    max_px_per_frame: float = 1.0
    max_frame_interval_us: int = 0   # > 0: render at least this often while moving (finer event timing)
    sensor: SensorParams = field(default_factory=SensorParams)
    camera: dict | None = None  # CameraModel.to_dict(); default DAVIS346

    def validate(self) -> None:
        if self.trajectory not in ("A", "B"):
            raise ValueError(f"trajectory: expected 'A' or 'B', got {self.trajectory!r}")
        if not (0 < self.speed_mps <= 3.0):
            raise ValueError(f"speed: expected 0 < speed <= 3 m/s, got {self.speed_mps}")
        if not (0 < self.duration_s <= 600):
            raise ValueError(f"duration: expected 0 < duration <= 600 s, got {self.duration_s}")
        if self.texture not in ("checker", "fine", "plain"):
            raise ValueError(f"texture: expected 'checker', 'fine' or 'plain', got {self.texture!r}")
        if not self.objects:
            raise ValueError("objects: at least one object is needed")
        if len(set(self.objects)) != len(self.objects):
            raise ValueError(f"objects: names must be unique, got {list(self.objects)}")
        if not (0 < self.pose_rate_hz <= self.motion_rate_hz):
            raise ValueError(f"pose_rate_hz / motion_rate_hz: expected 0 < {self.pose_rate_hz} <= {self.motion_rate_hz}")
        if not self.max_px_per_frame > 0:
            raise ValueError(f"max_px_per_frame: expected > 0, got {self.max_px_per_frame}")
        if self.max_frame_interval_us < 0:
            raise ValueError(f"max_frame_interval_us: expected >= 0 (0: no limit), got {self.max_frame_interval_us}")
