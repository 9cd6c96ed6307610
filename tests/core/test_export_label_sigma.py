"""Label uncertainty in every export format (issue 28.1): with --label-sigma, BOP's scene_gt_uncertainty.json, the
E-POSE .mat fields and the HDF5 dataset hold each label's sigma as evpose.core.label.uncertainty computes it;
--max-label-sigma-mm/-deg leave out (and count) the windows above; without the option nothing changes."""
from __future__ import annotations

import json

import h5py
import hdf5plugin  # noqa: F401 - the HDF5 export's compression filter
import numpy as np
import pytest
import scipy.io

from evpose.core.data.scene import Scene
from evpose.core.export import export_scene
from evpose.core.label.uncertainty import InputSigmas, LabelSigmaOptions, label_sigmas

SIG = InputSigmas(offset_us=3000, skew_ppm=20, pose_mm=1.5, pose_deg=0.7, hand_eye_mm=1.0, hand_eye_deg=0.3)


def _expected(scene_dir, index, K=None):
    scene = Scene.open(scene_dir)
    try:
        from evpose.core.export.windows import build_windows

        windows = {w.index: w for w in build_windows(scene.events, window_us=10_000)}
        t = np.array([windows[i].t_label_us for i in index], np.int64)
        s = label_sigmas(scene, t, scene.object_names, SIG, K=K)
        return np.stack([s.sigma_t_mm, s.sigma_R_deg, s.sigma_px], -1)
    finally:
        scene.close()


def test_bop_writes_scene_gt_uncertainty(tiny_scene_dir, tmp_path):
    out = tmp_path / "bop"
    s = export_scene(tiny_scene_dir, "bop", out, label_sigma=LabelSigmaOptions(SIG))
    doc = json.loads((out / "test/000000/scene_gt_uncertainty.json").read_text())
    gt = json.loads((out / "test/000000/scene_gt.json").read_text())
    assert doc.keys() == gt.keys() and len(doc) == s.written
    index = sorted(map(int, doc))
    scene = Scene.open(tiny_scene_dir)
    K = scene.camera.undistorted(scene.camera.K).K
    scene.close()
    want = _expected(tiny_scene_dir, index, K)
    for r, i in enumerate(index):
        assert [e["obj_id"] for e in doc[str(i)]] == [g["obj_id"] for g in gt[str(i)]]
        got = np.array([[e["sigma_t_mm"], e["sigma_R_deg"], e["sigma_px"]] for e in doc[str(i)]])
        assert np.allclose(got, want[r], rtol=1e-12)
    assert "test/000000/scene_gt_uncertainty.json" in s.files
    plain = export_scene(tiny_scene_dir, "bop", tmp_path / "plain")
    assert not (tmp_path / "plain/test/000000/scene_gt_uncertainty.json").exists() and plain.written == s.written


def test_epose_and_h5_carry_the_sigma_of_each_label(tiny_scene_dir, tmp_path):
    opts = LabelSigmaOptions(SIG)
    export_scene(tiny_scene_dir, "epose", tmp_path / "e", label_sigma=opts, jobs=2)
    export_scene(tiny_scene_dir, "h5", tmp_path / "h", label_sigma=opts)
    mats = sorted((tmp_path / "e").rglob("*_data.mat"))
    assert mats
    manifest = json.loads((tmp_path / "e" / "export_manifest.json").read_text())
    written = [i for i, st in zip(manifest["windows"]["index"], manifest["windows"]["status"]) if st == "written"]
    want = _expected(tiny_scene_dir, written)
    for r, path in enumerate(mats):
        m = scipy.io.loadmat(path)
        got = np.stack([m["sigma_t_mm"][0], m["sigma_R_deg"][0], m["sigma_px"][0]], -1)
        assert np.allclose(got, want[r], rtol=1e-12), path.name
    h5 = next((tmp_path / "h").glob("*.h5"))
    with h5py.File(h5, "r") as f:
        valid = f["windows"]["valid"][:]
        idx = f["windows"]["index"][:]
        sig = f["label_sigma"][:]
    w2 = _expected(tiny_scene_dir, idx[valid])
    assert np.allclose(sig[valid], w2, rtol=1e-12) and np.isnan(sig[~valid]).all()


def test_max_label_sigma_leaves_windows_out_and_counts_them(tiny_scene_dir, tmp_path):
    all_ = export_scene(tiny_scene_dir, "bop", tmp_path / "all", label_sigma=LabelSigmaOptions(SIG))
    doc = json.loads((tmp_path / "all/test/000000/scene_gt_uncertainty.json").read_text())
    worst = {int(i): max(e["sigma_t_mm"] for e in v) for i, v in doc.items()}
    limit = float(np.median(list(worst.values())))
    cut = export_scene(tiny_scene_dir, "bop", tmp_path / "cut", label_sigma=LabelSigmaOptions(SIG, max_mm=limit))
    kept = json.loads((tmp_path / "cut/test/000000/scene_gt.json").read_text())
    assert {int(i) for i in kept} == {i for i, v in worst.items() if v <= limit}
    assert cut.filtered_label_sigma == sum(v > limit for v in worst.values()) > 0
    assert cut.written + cut.filtered_label_sigma == all_.written
    status = json.loads((tmp_path / "cut/export_manifest.json").read_text())["windows"]["status"]
    assert status.count("filtered_label_sigma") == cut.filtered_label_sigma
    with pytest.raises(ValueError, match="max_label_sigma_mm"):
        LabelSigmaOptions(SIG, max_mm=-1)


def test_cli_label_sigma(tiny_scene_dir, tmp_path, capsys):
    from evpose.app.cli import main

    assert main(["export", str(tiny_scene_dir), "--format", "bop", "--out", str(tmp_path / "b"), "-q",
                 "--label-sigma", "offset_us=3000,pose_mm=1.5", "--max-label-sigma-mm", "1e9"]) == 0
    assert (tmp_path / "b/test/000000/scene_gt_uncertainty.json").is_file()
    for args, msg in ((["--label-sigma", "pose=2"], "expected KEY=VALUE"),
                      (["--label-sigma", "pose_mm=-2"], "pose_mm"),
                      (["--max-label-sigma-deg", "2"], "need --label-sigma")):
        capsys.readouterr()
        assert main(["export", str(tiny_scene_dir), "--format", "bop", "--out", str(tmp_path / "c"), "-q",
                     *args]) != 0
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err


def test_label_sigma_auto_starts_from_the_sigmas_the_applied_estimates_stored(scene_copy, tmp_path):
    """Issue 28.3: ``--label-sigma auto`` gives each object the sigma of its own stored pose estimate (and the clock's
    and hand-eye's when stored): the same numbers as those inputs given by hand; an object without a stored sigma
    gets only the interpolation bound."""
    from evpose.app.cli import main
    from evpose.core.document.estimates import apply_clock_estimate, apply_pose_estimate
    from evpose.core.document.history import History

    with Scene.open(scene_copy) as scene:
        names = scene.object_names
        h = History(scene.corrections)
        apply_pose_estimate(h, names[0], scene.corrections.object_delta(names[0]) @ np.diag([1, 1, 1, 1.0]),
                            std_mm=1.5, std_deg=0.7)                        # same value: only its sigma stored
        apply_clock_estimate(h, scene, scene.clock.offset_us + 1, None, offset_std_us=3000)
        scene.save_corrections()
    assert main(["export", str(scene_copy), "--format", "h5", "--out", str(tmp_path / "a"), "-q",
                 "--label-sigma", "auto"]) == 0
    with h5py.File(next((tmp_path / "a").rglob("*.h5")), "r") as f:
        valid, index, got = f["windows"]["valid"][:], f["windows"]["index"][:], f["label_sigma"][:]
    got, index = got[valid], index[valid]
    with Scene.open(scene_copy) as scene:
        from evpose.core.export.windows import build_windows

        windows = {w.index: w for w in build_windows(scene.events, window_us=10_000)}
        t = np.array([windows[int(i)].t_label_us for i in index], np.int64)
        first = label_sigmas(scene, t, names[:1], InputSigmas(offset_us=3000, pose_mm=1.5, pose_deg=0.7))
        other = label_sigmas(scene, t, names[1:2], InputSigmas(offset_us=3000))
    assert np.allclose(got[:, 0, 0], first.sigma_t_mm[:, 0], rtol=1e-9, equal_nan=True)
    assert np.allclose(got[:, 1, 0], other.sigma_t_mm[:, 0], rtol=1e-9, equal_nan=True)
    assert np.nanmedian(got[:, 0, 0]) > np.nanmedian(got[:, 1, 0])


def test_label_sigma_auto_is_exported_again_when_a_stored_sigma_changes(scene_copy, tmp_path):
    """The stored sigmas are inputs of an auto export: a rerun after one changed writes the windows again instead
    of reporting the old files complete."""
    from evpose.core.document.estimates import apply_pose_estimate
    from evpose.core.document.history import History

    out = tmp_path / "a"
    first = export_scene(scene_copy, "h5", out, label_sigma=LabelSigmaOptions(None))
    with Scene.open(scene_copy) as scene:
        n = scene.object_names[0]
        apply_pose_estimate(History(scene.corrections), n, scene.corrections.object_delta(n), std_mm=5.0, std_deg=2.0)
        scene.save_corrections()
    again = export_scene(scene_copy, "h5", out, label_sigma=LabelSigmaOptions(None), force=True)
    assert first.written > 0 and again.written == first.written and again.skipped_complete == 0
    with h5py.File(next(out.glob("*.h5")), "r") as f:
        assert np.nanmax(f["label_sigma"][:, 0, 0]) > 1.0
