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
