"""``evpose import`` without a trajectory (issue 26.4): each event format makes an event-only scene (no
``[trajectory]``, no objects) holding exactly the source's events, says so in its report and summary, and refuses
``--objects`` (they need a trajectory) in one line before anything is written. AEDAT4 and Prophesee are also pinned
in ``test_import_formats.py``, ``ros-events`` in ``test_import_ros_events.py``; the scene itself in
``test_events_only.py``."""
from __future__ import annotations

import json

import numpy as np
import pytest
from test_importers import (  # noqa: F401
    assert_events_equal,
    no_leftovers,
    read_scene,
    src,
    write_dsec,
    write_dsec_yaml,
    write_rpg,
)

from evpose.core.data.manifest_reader import load_manifest
from evpose.core.importers import REPORT_FILENAME, ImportFailure, import_scene


def check_events_only(res: dict, scene, src):  # noqa: F811
    assert res["events_only"] and res["n_poses"] == 0 and res["objects"] == [], res
    m = load_manifest(scene)
    assert not m.has_trajectory and m.objects == [] and not (scene / "trajectory.csv").exists()
    assert "trajectory" not in (scene / "scene.toml").read_text()
    rep = json.loads((scene / REPORT_FILENAME).read_text())
    assert rep["events_only"] is True and any(a.startswith("no trajectory: an event-only scene")
                                              for a in rep["assumptions"])
    assert_events_equal(read_scene(scene)[0], src.ev)


def test_npz_without_poses(src, tmp_path):  # noqa: F811
    npz = tmp_path / "events.npz"
    np.savez(npz, x=src.ev.x, y=src.ev.y, t=src.ev.t, p=src.ev.p, K=src.cam.K, dist=src.cam.dist,
             width=np.int64(src.cam.width), height=np.int64(src.cam.height))
    check_events_only(import_scene("npz", [npz], tmp_path / "s", log=None), tmp_path / "s", src)
    with pytest.raises(ImportFailure, match=r"events.npz: \(arguments\): --objects: objects \(box, cylinder, flatbox\) "
                                            r"are placed in the base frame and need a camera trajectory"):
        import_scene("npz", [npz], tmp_path / "s2", objects=src.objects_arg, log=None)
    assert not (tmp_path / "s2").exists()
    no_leftovers(tmp_path)


def test_dsec_without_a_trajectory(src, tmp_path):  # noqa: F811
    h5 = write_dsec(tmp_path / "events.h5", src.ev)
    yaml = write_dsec_yaml(tmp_path / "cam_to_cam.yaml", src.cam)
    check_events_only(import_scene("dsec", [h5, yaml], tmp_path / "s", log=None), tmp_path / "s", src)


def test_rpg_without_groundtruth(src, tmp_path):  # noqa: F811
    n = 30_000
    folder = write_rpg(tmp_path / "seq", src.ev, src.traj, src.cam, n=n)
    (folder / "groundtruth.txt").unlink()
    res = import_scene("rpg", [folder], tmp_path / "s", width=src.cam.width, height=src.cam.height, log=None)
    assert res["events_only"] and not load_manifest(tmp_path / "s").has_trajectory
    ev = read_scene(tmp_path / "s")[0]
    np.testing.assert_array_equal(ev.t, src.ev.t[:n])
    np.testing.assert_array_equal(ev.x, src.ev.x[:n])


def test_prophesee_objects_need_a_trajectory(src, tmp_path, capsys):  # noqa: F811
    from recording_writers import write_prophesee

    from evpose.app.cli.main import main
    from evpose.core.data.events import EventArray

    ev = EventArray(src.ev.x, src.ev.y, src.ev.t - int(src.ev.t[0]) + 1_000_000, src.ev.p)
    rec = write_prophesee(tmp_path / "rec.raw", ev, version="evt3", size=(src.cam.width, src.cam.height))
    assert main(["import", "prophesee", str(rec), "--camera", str(src.cam_json), "--out", str(tmp_path / "s"),
                 "--objects", src.objects_arg, "-q"]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "--objects: objects (box, cylinder, flatbox) are placed in the base frame" in err[0], err
    assert not (tmp_path / "s").exists()
    assert main(["import", "prophesee", str(rec), "--camera", str(src.cam_json), "--out", str(tmp_path / "s"),
                 "-q"]) == 0
    assert "events only (no trajectory, no objects)" in capsys.readouterr().out
