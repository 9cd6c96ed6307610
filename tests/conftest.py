"""Shared fixtures: paths to the optional E-POSE assets (never copied into the repo), the tiny
synthetic scene, and the Qt platform choice (Xvfb via pytest-xvfb, offscreen without a display)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from evpose_testing import TINY_SCENE, half_davis_camera


@pytest.hookimpl(trylast=True)
def pytest_configure(config):
    # after pytest-xvfb has set DISPLAY; without any display Qt widgets still run offscreen. Under pytest-xdist the
    # controller starts no Xvfb of its own and its workers inherit its environment: a worker with a display drops
    # the offscreen choice the controller made (else every GL test runs without GL)
    if not os.environ.get("DISPLAY"):
        if "QT_QPA_PLATFORM" not in os.environ:
            os.environ["QT_QPA_PLATFORM"] = "offscreen"
            os.environ["EVPOSE_TEST_OFFSCREEN"] = "1"
    elif os.environ.pop("EVPOSE_TEST_OFFSCREEN", None):
        os.environ.pop("QT_QPA_PLATFORM", None)
    from evpose.app.qt_compat import guard_pyside_refcount_leak, share_gl_contexts

    guard_pyside_refcount_leak()
    share_gl_contexts()


REPO = Path(__file__).resolve().parents[1]
#: Real E-POSE assets, looked up beside the repository (``../shared/assets/epose``) or via EVPOSE_ASSETS.
ASSETS = Path(os.environ.get("EVPOSE_ASSETS", REPO.parent / "shared" / "assets" / "epose"))
MODELS = ASSETS / "models"


@pytest.fixture(scope="session", autouse=True)
def private_user_cache(tmp_path_factory):
    """Tests (and the evpose processes they start) never write into the user's cache dir."""
    old = os.environ.get("XDG_CACHE_HOME")
    os.environ["XDG_CACHE_HOME"] = str(tmp_path_factory.mktemp("xdg-cache"))
    yield
    if old is None:
        os.environ.pop("XDG_CACHE_HOME", None)
    else:
        os.environ["XDG_CACHE_HOME"] = old


@pytest.fixture
def private_cache(tmp_path_factory, monkeypatch):
    """A fresh cache dir for one test; returns the folder of the event-index cache."""
    xdg = tmp_path_factory.mktemp("xdg-cache")
    monkeypatch.setenv("XDG_CACHE_HOME", str(xdg))
    return xdg / "evpose" / "msidx"


@pytest.fixture(scope="session")
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
    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    out = tmp_path_factory.mktemp("scenes") / "tiny"
    generate(out, SynthConfig(**TINY_SCENE, camera=half_davis_camera()))
    return out


@pytest.fixture(scope="session")
def occlusion_scene_dir(tmp_path_factory) -> Path:
    """A scene where objects hide each other (tests/occlusion_scene.py), built once per test session;
    never modify it."""
    from occlusion_scene import build_occlusion_scene

    return build_occlusion_scene(tmp_path_factory.mktemp("occlusion"))


@pytest.fixture
def scene_copy(tiny_scene_dir, tmp_path) -> Path:
    """A private copy of the tiny scene that a test may modify."""
    import shutil

    dst = tmp_path / "scene"
    shutil.copytree(tiny_scene_dir, dst)
    return dst
