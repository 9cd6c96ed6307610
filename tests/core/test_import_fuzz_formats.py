"""Property test of issue 17's readers, like ``test_import_fuzz.py``: truncated and corrupted AEDAT4 files, ROS2
bags (sqlite3 and MCAP) and Prophesee EVT 2.0 / EVT 3.0 / DAT files end in one ImportFailure naming the file --
never another exception, a crash, a hang or a partial scene folder. A corruption that still parses may import;
then the scene must be complete and loadable.

AEDAT4: ``dv-processing`` spins forever on some corrupt packets; the reading process's watchdog
(:data:`evpose.core.importers.aedat4_reader.STALL_TIMEOUT_S`, 1.5 s here) must turn that into the error.
"""
from __future__ import annotations

import tempfile
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_import_formats import SENSOR_T0_US, shifted, size_of, write_aedat4, write_prophesee, write_ros2_bag
from test_import_fuzz import check_corrupted_import, corruption
from test_importers import src  # noqa: F401

from evpose.core.data.trajectory import Trajectory
from evpose.core.importers import import_scene

N_EVENTS = 3000
CASES = ["aedat4", "ros2-sqlite3", "ros2-mcap", "evt2", "evt3", "dat"]


@pytest.fixture(scope="module")
def bases(src, tmp_path_factory):
    """One valid input per case: (folder, sources relative to it, files to corrupt, options, format)."""
    ev, traj = shifted(src, SENSOR_T0_US)
    ev = ev[np.arange(N_EVENTS)]
    k = int(np.searchsorted(traj.t_us, ev.t[-1])) + 3
    traj = Trajectory(traj.t_us[:k], traj.positions_m[:k], traj.quats_xyzw[:k])
    root = tmp_path_factory.mktemp("fuzz_formats")
    cam = dict(camera=str(src.cam_json))
    out = {}
    d = root / "aedat4"
    d.mkdir()
    write_aedat4(d / "rec.aedat4", ev, traj, size=size_of(src))
    out["aedat4"] = (d, ["rec.aedat4"], ["rec.aedat4"], cam, "aedat4")
    for storage, ext in (("SQLITE3", "db3"), ("MCAP", "mcap")):
        d = root / storage
        d.mkdir()
        write_ros2_bag(d / "rec", ev, traj, storage=storage, width=src.cam.width, height=src.cam.height,
                       numpy_encode=True, msg_events=500)
        out[f"ros2-{storage.lower()}"] = (d, ["rec"], [f"rec/rec.{ext}", "rec/metadata.yaml"], cam, "epose-bag")
    for version in ("evt2", "evt3", "dat"):
        d = root / version
        d.mkdir()
        name = "rec.dat" if version == "dat" else "rec.raw"
        write_prophesee(d / name, ev, version=version, size=size_of(src))
        traj.save_csv(d / "trajectory.csv")
        out[version] = (d, [name, "trajectory.csv"], [name], cam, "prophesee")
    return out


def _check(bases, case: str, how) -> None:
    from evpose.core.importers import aedat4_reader

    base, sources, targets, opts, fmt = bases[case]
    target, how = how
    stall = aedat4_reader.STALL_TIMEOUT_S
    aedat4_reader.STALL_TIMEOUT_S = 1.5
    try:
        check_corrupted_import(fmt, base, sources, targets, opts, target, how, one_line=True)
    finally:
        aedat4_reader.STALL_TIMEOUT_S = stall


_SETTINGS = dict(deadline=timedelta(seconds=25), derandomize=True,
                 suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.mark.parametrize("case", CASES[1:])
@settings(max_examples=15, **_SETTINGS)
@given(target=st.integers(0, 10), how=corruption())
def test_corrupted_recordings_fail_cleanly(bases, case, target, how):
    _check(bases, case, (target, how))


@settings(max_examples=8, **_SETTINGS)
@given(how=corruption())
def test_corrupted_aedat4_fails_cleanly(bases, how):
    """Fewer examples: about half of them make dv-processing spin, each costing the 1.5 s watchdog."""
    _check(bases, "aedat4", (0, how))


def test_fuzz_format_bases_import(bases):
    """The uncorrupted inputs import (so the property above is not vacuous)."""
    for case, (base, sources, _, opts, fmt) in bases.items():
        with tempfile.TemporaryDirectory() as t:
            res = import_scene(fmt, [base / s for s in sources], Path(t) / "scene", log=None, **opts)
            assert res["n_events"] == N_EVENTS, case
