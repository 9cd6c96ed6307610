"""``evpose import bop`` (issue 17, point 4): a BOP scene of event frames back into an evpose scene, and the
round trip evpose -> BOP -> evpose -> BOP, which must reproduce the windows, the poses and the lit pixels.
Files are compared as JSON and pixels (independent of the importer's code)."""
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from evpose.core.data.scene import Scene
from evpose.core.document.corrections import ReviewMark
from evpose.core.export import export_scene
from evpose.core.importers import ImportFailure, import_scene

SD = ("test", "000000")


def _read(root, *parts):
    return json.loads(Path(root).joinpath(*parts).read_text())


def _tree(root) -> dict:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(Path(root).rglob("*")) if p.is_file()}


def _rgb(root, im_id) -> np.ndarray:
    return cv2.imread(str(Path(root).joinpath(*SD, "rgb", f"{int(im_id):06d}.png")), cv2.IMREAD_UNCHANGED)


@pytest.fixture(scope="module")
def exported(tiny_scene_dir, tmp_path_factory):
    """The tiny scene with a clock correction and a gap: windows 20-44 and 60-79 only (only-verified)."""
    base = tmp_path_factory.mktemp("bop-import")
    scene_dir = base / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    scene = Scene.open(scene_dir)
    t0 = scene.events.t_first_us
    scene.corrections.set(("offset_us",), 12_345)
    scene.corrections.set(("skew_ppm",), 150.0)
    scene.corrections.set(("reviews",), [ReviewMark(t0 + 200_000, t0 + 450_000, "verified"),
                                         ReviewMark(t0 + 600_000, t0 + 800_000, "verified")])
    scene.save_corrections()
    scene.close()
    out = base / "bop"
    s = export_scene(scene_dir, "bop", out, only_verified=True)
    assert s.written == 45
    return scene_dir, out


def test_round_trip_reproduces_windows_poses_and_pixels(exported, tmp_path):
    """evpose -> BOP -> evpose -> BOP: every image comes back with its window, label time and poses
    (camera in the world, every object in the camera) to 1e-9 mm / 1e-12, its lit pixels per polarity
    exactly, its masks (to float32 mesh rounding); the imported scene keeps the names, the camera and
    the timing, and the source folder is untouched."""
    _, bop = exported
    before = _tree(bop)
    summary = import_scene("bop", [bop], tmp_path / "imp", scene="0", log=None)
    assert _tree(bop) == before
    assert summary["objects"] == ["box", "cylinder", "flatbox"] and summary["n_poses"] == 45
    scene = Scene.open(tmp_path / "imp")
    side = _read(bop, *SD, "evpose_scene.json")
    np.testing.assert_array_equal(scene.camera.K, side["K_opencv"])
    assert not scene.camera.has_distortion and scene.camera.width == side["width"]
    assert (scene.clock.offset_us, scene.clock.skew_ppm) == (0, 0.0)       # the poses are on the event clock
    times_a = _read(bop, *SD, "scene_times.json")
    assert scene.events.t_first_us == min(t["t_start_us"] for t in times_a.values())
    scene.close()
    re = tmp_path / "re"
    s = export_scene(tmp_path / "imp", "bop", re)
    gt_a, gt_b = _read(bop, *SD, "scene_gt.json"), _read(re, *SD, "scene_gt.json")
    cam_a, cam_b = _read(bop, *SD, "scene_camera.json"), _read(re, *SD, "scene_camera.json")
    times_b = _read(re, *SD, "scene_times.json")
    by_start = {t["t_start_us"]: k for k, t in times_b.items()}
    assert len(times_b) == s.written and set(by_start) >= {t["t_start_us"] for t in times_a.values()}
    for ia, ta in times_a.items():
        ib = by_start[ta["t_start_us"]]
        assert (times_b[ib]["t_end_us"], times_b[ib]["t_label_us"]) == (ta["t_end_us"], ta["t_label_us"])
        assert int(ib) == int(ia) - 20                  # ids restart at the first image with events
        assert cam_b[ib]["cam_K"] == cam_a[ia]["cam_K"]
        np.testing.assert_allclose(cam_b[ib]["cam_t_w2c"], cam_a[ia]["cam_t_w2c"], rtol=0, atol=1e-9)
        np.testing.assert_allclose(cam_b[ib]["cam_R_w2c"], cam_a[ia]["cam_R_w2c"], rtol=0, atol=1e-12)
        for ea, eb in zip(gt_a[ia], gt_b[ib], strict=True):
            assert ea["obj_id"] == eb["obj_id"]
            np.testing.assert_allclose(eb["cam_t_m2c"], ea["cam_t_m2c"], rtol=0, atol=1e-9)
            np.testing.assert_allclose(eb["cam_R_m2c"], ea["cam_R_m2c"], rtol=0, atol=1e-12)
        a, b = _rgb(bop, ia), _rgb(re, ib)
        for ch in (0, 2):                                 # OpenCV order: B = OFF, R = ON
            assert np.array_equal(a[..., ch] > 0, b[..., ch] > 0), (ia, ch)
        assert times_b[ib]["n_events"] == int((a[..., 0] > 0).sum() + (a[..., 2] > 0).sum())
        for g in range(len(gt_a[ia])):
            ma = cv2.imread(str(bop.joinpath(*SD, "mask", f"{int(ia):06d}_{g:06d}.png")), cv2.IMREAD_UNCHANGED) > 0
            mb = cv2.imread(str(re.joinpath(*SD, "mask", f"{int(ib):06d}_{g:06d}.png")), cv2.IMREAD_UNCHANGED) > 0
            assert (ma ^ mb).sum() <= 2, (ia, g)
    # the gap between the verified ranges has no pose samples: its windows get no label, none is invented
    assert not any(20 + 25 <= int(k) + 20 < 60 for k in times_b)


def test_without_evpose_sidecars_the_bop_conventions_are_used(exported, tmp_path):
    """A plain BOP scene (no scene_times.json, no evpose_scene.json, models elsewhere): the camera is cam_K
    shifted back to pixel centres (cx - 0.5, cy - 0.5), image i is the window [i f, (i + 1) f) of the nominal
    frame period f labelled at its centre, objects are named obj_OOOOOO, every assumption is reported."""
    _, bop = exported
    plain = tmp_path / "plain"
    shutil.copytree(bop, plain)
    for name in ("scene_times.json", "evpose_scene.json"):
        (plain.joinpath(*SD) / name).unlink()
    shutil.move(plain / "models", tmp_path / "models")
    summary = import_scene("bop", [plain / "test"], tmp_path / "imp", scene="0", models=str(tmp_path / "models"),
                           frame_us=20_000, log=None)
    assert summary["objects"] == ["obj_000001", "obj_000002", "obj_000003"]
    assert any("scene_times.json" in a for a in summary["assumptions"])
    assert any("cx - 0.5" in a for a in summary["assumptions"])
    scene = Scene.open(tmp_path / "imp")
    side = _read(bop, *SD, "evpose_scene.json")
    np.testing.assert_allclose(scene.camera.K, side["K_opencv"], rtol=0, atol=1e-12)
    ids = sorted(int(k) for k in _read(plain, *SD, "scene_gt.json"))
    traj = np.loadtxt(tmp_path / "imp" / "trajectory.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(traj[:, 0].astype(np.int64), [i * 20_000 + 10_000 for i in ids])
    assert scene.events.t_first_us == ids[0] * 20_000
    assert scene.events.t_last_us < (ids[-1] + 1) * 20_000
    scene.close()


def test_the_scene_folder_itself_as_source(exported, tmp_path):
    _, bop = exported
    s = import_scene("bop", [bop.joinpath(*SD)], tmp_path / "imp", log=None)
    assert s["n_poses"] == 45


def _bad_copy(exported, tmp_path):
    dst = tmp_path / "bad"
    shutil.copytree(exported[1], dst)
    return dst


@pytest.mark.parametrize("case", ["green", "cam_K", "json", "missing_scene", "two_splits", "times"])
def test_bad_input_names_the_file_and_field(exported, tmp_path, case):
    bop = _bad_copy(exported, tmp_path)
    sd = bop.joinpath(*SD)
    scene = "0"
    if case == "green":
        img = cv2.imread(str(sd / "rgb" / "000030.png"), cv2.IMREAD_UNCHANGED)
        img[5, 7, 1] = 9
        cv2.imwrite(str(sd / "rgb" / "000030.png"), img)
        where, fld = "000030.png", "G"
    elif case == "cam_K":
        cams = _read(sd, "scene_camera.json")
        cams["25"]["cam_K"][0] += 1.0
        (sd / "scene_camera.json").write_text(json.dumps(cams))
        where, fld = "scene_camera.json", "cam_K"
    elif case == "json":
        (sd / "scene_gt.json").write_text('{"20": [}')
        where, fld = "scene_gt.json", "line 1"
    elif case == "missing_scene":
        scene, where, fld = "7", str(bop), "--scene"
    elif case == "two_splits":
        shutil.copytree(bop / "test", bop / "val")
        where, fld = "val", "--scene"
    else:
        times = _read(sd, "scene_times.json")
        times["21"]["t_label_us"] = "soon"
        (sd / "scene_times.json").write_text(json.dumps(times))
        where, fld = "scene_times.json", "t_label_us"
    with pytest.raises(ImportFailure) as exc:
        import_scene("bop", [bop], tmp_path / "imp", scene=scene, log=None)
    assert where in str(exc.value) and fld in str(exc.value), str(exc.value)
    assert not (tmp_path / "imp").exists()


def test_cli_import_bop(exported, tmp_path):
    """The command: one JSON document on stdout; bad input: exit 2 and one line naming file and field."""
    _, bop = exported
    cmd = [sys.executable, "-m", "evpose", "import", "bop", str(bop), "--scene", "0", "--out"]
    p = subprocess.run(cmd + [str(tmp_path / "imp"), "--json", "-q"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["objects"] == ["box", "cylinder", "flatbox"]
    bad = _bad_copy(exported, tmp_path)
    (bad.joinpath(*SD) / "rgb" / "000040.png").write_bytes(b"\x89PNG truncated")
    p = subprocess.run([sys.executable, "-m", "evpose", "import", "bop", str(bad), "--scene", "0", "--out",
                        str(tmp_path / "imp2"), "-q"], capture_output=True, text=True, timeout=300)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip() and not ln.startswith("evpose import: warning")]
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert len(lines) == 1 and "000040.png" in lines[0] and "rgb" in lines[0], p.stderr
    assert not (tmp_path / "imp2").exists()
