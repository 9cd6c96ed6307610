"""Helpers shared by tests (a uniquely named module: every test folder has its own conftest)."""
from __future__ import annotations


def half_davis_camera() -> dict:
    """DAVIS346 calibration at half resolution (173x130): same lens, 4x fewer pixels, fast tests."""
    from evpose.core.data.camera import CameraModel

    cam = CameraModel.davis346()
    K = cam.K.copy()
    K[:2] *= 0.5
    # pixel centres are at integers: a half-size pixel grid maps c to (c + 0.5) / 2 - 0.5
    K[0, 2] = (cam.K[0, 2] + 0.5) / 2 - 0.5
    K[1, 2] = (cam.K[1, 2] + 0.5) / 2 - 0.5
    return {"width": 173, "height": 130, "K": K.tolist(), "dist": cam.dist.tolist()}


#: The shared synthetic scene: 3 objects, trajectory B at 0.5 m/s, clock offset and pose error injected.
TINY_SCENE = dict(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5, duration_s=0.8,
                  offset_us=20_000, skew_ppm=0.0, pose_error_mm=5.0, pose_error_deg=3.0, seed=3)


def msidx_cache_file(path):
    """Where EventStore caches the index and validation of an event file (the user cache dir)."""
    import hashlib
    from pathlib import Path

    from evpose.core.data.event_index import default_cache_dir

    return default_cache_dir() / f"{hashlib.sha1(str(Path(path).resolve()).encode()).hexdigest()}.npz"
