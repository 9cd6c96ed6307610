"""Shared fixtures: paths to the optional E-POSE assets (never copied into the repo)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: Real E-POSE assets, looked up beside the repository (``../shared/assets/epose``) or via EVPOSE_ASSETS.
ASSETS = Path(os.environ.get("EVPOSE_ASSETS", REPO.parent / "shared" / "assets" / "epose"))
MODELS = ASSETS / "models"


@pytest.fixture
def assets_dir() -> Path:
    if not (ASSETS / "camera_davis346.json").is_file():
        pytest.skip(f"E-POSE assets not found at {ASSETS}")
    return ASSETS


@pytest.fixture
def models_dir() -> Path:
    if not MODELS.is_dir() or not any(MODELS.iterdir()):
        pytest.skip(f"E-POSE meshes not found at {MODELS}")
    return MODELS


def half_davis_camera() -> dict:
    """DAVIS346 calibration at half resolution (173x130): same lens, 4x fewer pixels, fast tests."""
    from core.camera import CameraModel

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


@pytest.fixture(scope="session")
def tiny_scene_dir(tmp_path_factory) -> Path:
    """Built once per test session; never modify it (use ``scene_copy``)."""
    from core.synth import SynthConfig, generate

    out = tmp_path_factory.mktemp("scenes") / "tiny"
    generate(out, SynthConfig(**TINY_SCENE, camera=half_davis_camera()))
    return out


@pytest.fixture
def scene_copy(tiny_scene_dir, tmp_path) -> Path:
    """A private copy of the tiny scene that a test may modify."""
    import shutil

    dst = tmp_path / "scene"
    shutil.copytree(tiny_scene_dir, dst)
    return dst
