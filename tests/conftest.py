"""Shared fixtures: paths to the optional E-POSE assets (never copied into the repo), the tiny
synthetic scene, and the Qt platform choice (Xvfb via pytest-xvfb, offscreen without a display)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from evpose_testing import TINY_SCENE, half_davis_camera

@pytest.hookimpl(trylast=True)
def pytest_configure(config):
    # after pytest-xvfb has set DISPLAY; without any display Qt widgets still run offscreen
    if not os.environ.get("DISPLAY"):
        os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from app.qt_compat import guard_pyside_refcount_leak

    guard_pyside_refcount_leak()


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
