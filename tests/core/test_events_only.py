"""Event-only scenes (issue 26.4): a scene without ``[trajectory]`` and without objects.

Made by ``evpose import npz`` from the tiny synthetic scene's events alone. It opens; what needs poses refuses it in
one line naming scene.toml and the missing table (when asked, not at open); ``info`` says what it is; the ``h5``
export writes its windows and event frames without labels, byte-identical across runs and ``--jobs``, and loads
neither meshes nor the rasteriser's numba kernels; ``epose`` and ``bop`` refuse it in one line. ``evpose scene
set-trajectory`` and ``add-objects`` then make it a labelled scene whose export has the source scene's labels; the
edit replaces scene.toml only when nobody changed it meanwhile, never replaces a file it did not write, and a rerun
after a kill completes. The importers' side (each format without a trajectory) is in ``test_events_only_import.py``.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_importers import src  # noqa: F401  (the session's source scene: tiny synthetic scene + helper files)

from evpose.app.cli.main import main
from evpose.core.data.manifest import NoPosesError, SceneError
from evpose.core.data.manifest_reader import load_manifest
from evpose.core.data.scene import Scene
from evpose.core.importers import import_scene

MISSING = r"scene\.toml: \[trajectory\]: missing table"
#: Modules an event-only scene's info and h5 export must not load: meshes, the rasteriser and its numba kernels.
HEAVY = ("numba", "trimesh", "open3d", "evpose.core.label.raster", "evpose.core.label.raster_kernels",
         "evpose.core.label.annotate")


@pytest.fixture(scope="module")
def eo_scene(src, tmp_path_factory) -> Path:  # noqa: F811
    """The tiny scene's events as an event-only scene (never modified: copy it with ``scene_copy``)."""
    work = tmp_path_factory.mktemp("events_only")
    npz = work / "events.npz"
    np.savez(npz, x=src.ev.x, y=src.ev.y, t=src.ev.t, p=src.ev.p, t_unit=np.array("us"))
    res = import_scene("npz", [npz], work / "eo", camera=str(src.cam_json), log=None)
    assert res["events_only"] and res["n_poses"] == 0 and res["objects"] == []
    return work / "eo"


def scene_copy(eo_scene: Path, dst: Path) -> Path:
    """A copy keeping sizes and modification times (so the scene's ownership log still proves its files)."""
    shutil.copytree(eo_scene, dst, symlinks=True)
    return dst


def one_error_line(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ------------------------------------------------------------------------------------------ the scene model
def test_event_only_scene_opens_and_refuses_poses_only_when_asked(eo_scene, src):  # noqa: F811
    m = load_manifest(eo_scene)
    assert m.trajectory_path is None and not m.has_trajectory and m.objects == []
    assert "trajectory" not in m.to_toml_dict()
    # a dataset's shared [defaults.trajectory] (frame, hand_eye: never a path) does not make one
    assert not load_manifest(eo_scene, defaults={"trajectory": {"frame": "cam"}}).has_trajectory
    with Scene.open(eo_scene) as s:
        assert not s.has_poses and s.object_names == []
        assert s.events.n_events == len(src.ev) and s.clock.t_ref_us == int(src.ev.t[0])
        ev = s.events.read(0, 1000)
        np.testing.assert_array_equal(ev.t, src.ev.t[:1000])
        t = np.array([src.ev.t[500]], np.int64)
        for ask in (lambda: s.trajectory, lambda: s.T_base_cam(t), lambda: s.T_cam_obj(t),
                    lambda: s.unlabeled_reasons(t), lambda: s.trajectory_holes()):
            with pytest.raises(NoPosesError, match=MISSING + r": a camera trajectory is needed for poses; this "
                                                   r"scene holds events only: no trajectory, no objects"):
                ask()
        with pytest.raises(NoPosesError, match=MISSING + r": a camera trajectory is needed for alignment scores"):
            from evpose.core.align.score_table import score_windows

            score_windows(s)


def test_objects_without_a_trajectory_are_refused_at_load(eo_scene, src, tmp_path):  # noqa: F811
    sc = scene_copy(eo_scene, tmp_path / "sc")
    text = (sc / "scene.toml").read_text()
    spec = src.man.objects[0]
    (sc / "scene.toml").write_text(text + f'\n[[objects]]\nname = "box"\nmesh = "{spec.mesh}"\n'
                                   f"T_base_obj = {np.eye(4).tolist()}\n")
    with pytest.raises(SceneError, match=MISSING + r": the scene has 1 object\(s\) \(box\), placed in the base "
                                         r"frame, and they need a camera trajectory"):
        load_manifest(sc)


def test_info_says_events_only(eo_scene, src, capsys):  # noqa: F811
    assert main(["info", str(eo_scene)]) == 0
    out = capsys.readouterr().out
    assert "labels     events only: no trajectory, no objects" in out and f"{len(src.ev):,}" in out
    assert main(["info", str(eo_scene), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["events_only"] is True and doc["labels"] == "events only: no trajectory, no objects"
    assert doc["n_poses"] == 0 and doc["trajectory"] is None and doc["objects"] == []
    assert doc["n_events"] == len(src.ev) and doc["t0_us"] == int(src.ev.t[0])


def test_score_sync_and_refine_refuse_in_one_line(eo_scene, capsys):
    for cmd in (["score"], ["sync"], ["refine"]):
        assert main([*cmd, str(eo_scene)]) == 2, cmd
        line = one_error_line(capsys)
        assert "scene.toml: [trajectory]: missing table: a camera trajectory is needed" in line, line


# ------------------------------------------------------------------------------------------ exports
def test_h5_export_has_event_frames_no_labels_and_the_same_bytes(eo_scene, src, tmp_path, capsys):  # noqa: F811
    import h5py
    import hdf5plugin  # noqa: F401

    before = {p.name: digest(p) for p in eo_scene.iterdir() if p.is_file()}
    assert main(["export", str(eo_scene), "--format", "h5", "--out", str(tmp_path / "a"), "-q", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["events_only"] and s["written"] == s["windows_total"] > 0 and s["unlabeled"] == 0
    assert main(["export", str(eo_scene), "--format", "h5", "--out", str(tmp_path / "b"), "-q", "--jobs", "2"]) == 0
    assert "events only (no trajectory, no objects): event frames without labels" in capsys.readouterr().out
    for name in ("eo.h5", "export_manifest.json", "README.txt"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    with h5py.File(tmp_path / "a" / "eo.h5", "r") as f:
        names = set()
        f.visit(names.add)
        assert names == {"windows", "frames", "frames/counts", "_done"}, names      # no label dataset at all
        assert bool(f.attrs["events_only"]) and len(f.attrs["object_names"]) == 0
        win, counts = f["windows"][:], f["frames/counts"][:]
        assert not win["valid"].any() and f["_done"][:].all()
        # every event is in exactly one window, and in that window's frame (the tiny scene saturates no pixel)
        assert win["n_events"].sum() == len(src.ev) and win["i1"][-1] == len(src.ev)
        np.testing.assert_array_equal(counts.reshape(len(win), -1).sum(axis=1), win["n_events"])
        k = len(win) // 2
        i0, i1 = int(win["i0"][k]), int(win["i1"][k])
        on = np.zeros((src.cam.height, src.cam.width), np.int64)
        sel = src.ev.p[i0:i1] == 1
        np.add.at(on, (src.ev.y[i0:i1][sel], src.ev.x[i0:i1][sel]), 1)
        np.testing.assert_array_equal(counts[k, 0], on)
    man = json.loads((tmp_path / "a" / "export_manifest.json").read_text())
    assert man["events_only"] is True and set(man["windows"]["status"]) == {"written"}
    assert {p.name: digest(p) for p in eo_scene.iterdir() if p.is_file()} == before     # the scene is only read


@pytest.mark.parametrize("fmt", ["bop", "epose"])
def test_label_formats_refuse_in_one_line(eo_scene, tmp_path, capsys, fmt):
    assert main(["export", str(eo_scene), "--format", fmt, "--out", str(tmp_path / "x")]) == 2
    line = one_error_line(capsys)
    assert f"scene.toml: [trajectory]: missing table: --format {fmt} writes labels, and labels need a trajectory" \
        in line and "--format h5 exports its events and event frames" in line, line
    assert not (tmp_path / "x").exists()
    assert main(["export", str(eo_scene), "--format", "h5", "--out", str(tmp_path / "y"), "--only-verified"]) == 2
    assert "only_verified: " in one_error_line(capsys) and not (tmp_path / "y").exists()


def test_info_and_h5_export_load_no_mesh_nor_rasteriser(eo_scene, tmp_path):
    """Nothing heavy for an event-only scene: no mesh library, no rasteriser, no numba (its import and compile)."""
    code = ("import sys\n"
            "from evpose.app.cli.main import main\n"
            f"assert main(['info', {str(eo_scene)!r}]) == 0\n"
            f"assert main(['export', {str(eo_scene)!r}, '--format', 'h5', '--out', {str(tmp_path / 'x')!r}, '-q']) == 0\n"
            f"heavy = [m for m in {HEAVY!r} if m in sys.modules]\n"
            "print('HEAVY', heavy)\n"
            "sys.exit(3 if heavy else 0)\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "x" / "eo.h5").is_file()


# ------------------------------------------------------------------------------------------ set-trajectory
def test_set_trajectory_and_add_objects_make_a_labelled_scene(eo_scene, src, tmp_path, capsys):  # noqa: F811
    import h5py
    import hdf5plugin  # noqa: F401

    from evpose.core.data.owned_files import inventory

    sc = scene_copy(eo_scene, tmp_path / "sc")
    events = digest(sc / "events.h5")
    traj_src = src.dir / "trajectory.csv"
    src_digest = digest(traj_src)
    # objects first: refused, they need the trajectory
    assert main(["scene", "add-objects", str(sc), "--objects", src.objects_arg]) == 2
    assert "[trajectory]: missing table: objects are placed in the base frame" in one_error_line(capsys)
    assert main(["scene", "set-trajectory", str(sc), str(traj_src), "-q",
                 "--offset-us", str(src.man.clock_offset_us)]) == 0
    assert "trajectory of" in capsys.readouterr().out
    with Scene.open(sc) as s:
        assert s.has_poses and s.manifest.trajectory_path == sc / "trajectory.csv"
        np.testing.assert_array_equal(s.trajectory.t_us, src.traj.t_us)
        np.testing.assert_allclose(s.trajectory.positions_m, src.traj.positions_m, rtol=0, atol=1e-12)
    assert main(["scene", "set-trajectory", str(sc), str(traj_src)]) == 2           # once only
    assert "the scene has a trajectory already" in one_error_line(capsys)
    assert main(["scene", "add-objects", str(sc), "--objects", src.objects_arg, "-q"]) == 0
    assert "added box, cylinder, flatbox" in capsys.readouterr().out
    assert main(["info", str(sc), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert not info["events_only"] and info["n_poses"] == len(src.traj) and info["objects"] == src.scene.object_names
    # the scene is evpose's as a whole still (import --force may replace it); the inputs were only read
    assert inventory(sc, "scene").clean, inventory(sc, "scene").foreign
    assert digest(sc / "events.h5") == events and digest(traj_src) == src_digest
    # its export has the labels of the source scene
    assert main(["export", str(sc), "--format", "h5", "--out", str(tmp_path / "x"), "-q", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert not s["events_only"] and s["written"] > 0
    with h5py.File(tmp_path / "x" / "eo.h5", "r") as f:           # (the scene keeps its name)
        assert not bool(f.attrs["events_only"]) and list(f.attrs["object_names"]) == src.scene.object_names
        win, T = f["windows"][:], f["T_cam_obj"][:]
    v = win["valid"]
    assert v.sum() == s["written"] > 0 and np.isfinite(T[v]).all()
    T_src, ok = src.scene.T_cam_obj(win["t_label_us"][v])
    assert ok.all()
    np.testing.assert_allclose(T[v], T_src, rtol=0, atol=1e-9)


def test_set_trajectory_never_overwrites_what_changed_or_is_not_ours(eo_scene, src, tmp_path, capsys,  # noqa: F811
                                                                     monkeypatch):
    from evpose.core.importers import scene_edit

    sc = scene_copy(eo_scene, tmp_path / "sc")
    toml0 = (sc / "scene.toml").read_bytes()
    traj_src = str(src.dir / "trajectory.csv")
    # another program writes scene.toml while the edit runs: it is kept, the edit undone
    real_check = scene_edit.check_scene

    def meanwhile(manifest):
        real_check(manifest)
        (sc / "scene.toml").write_bytes(toml0 + b"\n# edited meanwhile\n")

    monkeypatch.setattr(scene_edit, "check_scene", meanwhile)
    assert main(["scene", "set-trajectory", str(sc), traj_src, "-q"]) == 2
    assert "scene.toml: changed since this command read it" in one_error_line(capsys)
    assert (sc / "scene.toml").read_bytes() == toml0 + b"\n# edited meanwhile\n"
    assert not (sc / "trajectory.csv").exists() and not [p for p in os.listdir(sc) if p.endswith(".tmp")]
    monkeypatch.setattr(scene_edit, "check_scene", real_check)
    (sc / "scene.toml").write_bytes(toml0)
    # a trajectory.csv evpose did not write is never replaced
    (sc / "trajectory.csv").write_text("mine\n")
    assert main(["scene", "set-trajectory", str(sc), traj_src, "-q"]) == 2
    line = one_error_line(capsys)
    assert "trajectory.path: " in line and "trajectory.csv exists and evpose did not write it" in line, line
    assert (sc / "trajectory.csv").read_text() == "mine\n" and (sc / "scene.toml").read_bytes() == toml0


def test_set_trajectory_resumes_after_a_kill_between_its_two_writes(eo_scene, src, tmp_path):  # noqa: F811
    sc = scene_copy(eo_scene, tmp_path / "sc")
    toml0 = (sc / "scene.toml").read_bytes()
    code = ("import os\n"
            "from evpose.core.importers import scene_edit\n"
            "scene_edit.SceneEdit.commit = lambda self, doc, check=None: os._exit(9)\n"
            f"scene_edit.set_trajectory({str(sc)!r}, {str(src.dir / 'trajectory.csv')!r})\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 9, r.stderr
    assert (sc / "trajectory.csv").is_file() and (sc / "scene.toml").read_bytes() == toml0     # killed in between
    assert main(["scene", "set-trajectory", str(sc), str(src.dir / "trajectory.csv"), "-q"]) == 0
    assert load_manifest(sc).has_trajectory


def test_dataset_info_lists_an_event_only_scene(eo_scene, tmp_path, capsys):
    scene_copy(eo_scene, tmp_path / "ds" / "eo")
    assert main(["dataset", "info", str(tmp_path / "ds"), "--workers", "1", "-q"]) == 0
    row = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("eo "))
    assert row.split()[-1:] == ["only"] and "events only" in row, row
