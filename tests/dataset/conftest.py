"""Fixtures of the dataset tests: a tiny synthetic dataset (3 scenes of 0.4 s with different clocks) and a
Dask ``LocalCluster`` of 2 worker processes shared by the tests of this folder."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from evpose_testing import TINY_SCENE, half_davis_camera

#: (seed, true clock offset in µs) of each scene of the tiny dataset.
SCENES = {"scene_a": (3, 20_000), "scene_b": (4, -15_000), "scene_c": (5, 5_000)}


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """Built once per session; never modify it (use ``dataset_copy``)."""
    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    root = tmp_path_factory.mktemp("dataset") / "ds"
    for name, (seed, offset_us) in SCENES.items():
        cfg = dict(TINY_SCENE, seed=seed, offset_us=offset_us, duration_s=0.4)
        generate(root / name, SynthConfig(**cfg, camera=half_davis_camera()))
    return root


@pytest.fixture
def dataset_copy(tiny_dataset, tmp_path) -> Path:
    dst = tmp_path / "ds"
    shutil.copytree(tiny_dataset, dst)
    return dst


@pytest.fixture(scope="session")
def dask_client():
    """A LocalCluster of 2 single-threaded worker processes (closed at the end of the session)."""
    from evpose.core.dataset.cluster import ClusterSpec, open_client

    with open_client(ClusterSpec(workers=2)) as client:
        yield client
