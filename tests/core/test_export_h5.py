"""HDF5 export: read back against the scene and the annotator, chunking and compression, resume from a
partial file, unlabeled rows, jobs=2 identical to jobs=1."""
import json
import shutil

import h5py
import hdf5plugin  # noqa: F401  (Blosc filter for reading)
import numpy as np
import pytest

from evpose.core.data.events import Cancelled
from evpose.core.data.scene import Scene
from evpose.core.export import export_scene
from evpose.core.label.annotate import Annotator
from evpose.core.label.labels import Request
from evpose.core.label.windows import time_windows
from evpose.core.label.event_frames.counts import polarity_counts
from evpose.core.label.event_frames.display import three_channel_rgb
from evpose.core.label.event_frames.three_channel import three_channel

DATASETS = ("windows", "T_cam_obj", "T_base_cam", "bbox_obj", "bbox_visib", "keypoints_uv", "corners_cam",
            "center_uv", "visib_fract", "px_count_all", "px_count_visib", "label_map", "frames/counts",
            "frames/three_channel", "objects/corners_obj", "_done")


def read_all(path) -> dict:
    with h5py.File(path, "r") as f:
        out = {k: f[k][()] for k in DATASETS if k in f}
        out["attrs"] = {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in f.attrs.items()}
    return out


def assert_same(a: dict, b: dict) -> None:
    assert set(a) == set(b)
    for k in a:
        if k == "attrs":
            assert a[k] == b[k]
        else:
            assert np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"), k


@pytest.fixture(scope="module")
def h5_export(tiny_scene_dir, tmp_path_factory):
    base = tmp_path_factory.mktemp("h5")
    scene_dir = base / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    scene = Scene.open(scene_dir)
    scene.corrections.set(("offset_us",), 20_000)
    scene.save_corrections()
    scene.close()
    out = base / "out"
    s = export_scene(scene_dir, "h5", out, format_options={"three_channel": True})
    return scene_dir, out, s


def test_read_back(h5_export):
    scene_dir, out, s = h5_export
    scene = Scene.open(scene_dir)
    path = out / f"{scene.name}.h5"
    assert path.is_file() and not list(out.glob(".*.partial"))
    d = read_all(path)
    wins = time_windows(scene.events, 10_000)
    N, K = len(wins), len(scene.object_names)
    H, W = scene.camera.height, scene.camera.width
    assert d["windows"].shape == (N,) and d["windows"]["valid"].all()
    assert np.array_equal(d["windows"]["t0_us"], [w.t0_us for w in wins])
    assert np.array_equal(d["windows"]["i1"] - d["windows"]["i0"], d["windows"]["n_events"])
    assert d["T_cam_obj"].shape == (N, K, 4, 4) and d["label_map"].shape == (N, H, W)
    assert d["frames/counts"].shape == (N, 2, H, W) and d["frames/counts"].dtype == np.uint16
    assert d["keypoints_uv"].shape == (N, K, 8, 2) and d["corners_cam"].shape == (N, K, 8, 3)
    assert d["attrs"]["clock_offset_us"] == 20_000 and d["attrs"]["object_names"] == scene.object_names
    assert d["attrs"]["counts_saturation"] == 65535
    T_ref, valid = scene.T_cam_obj(d["windows"]["t_label_us"])
    np.testing.assert_allclose(d["T_cam_obj"], T_ref, atol=1e-12)
    assert np.array_equal(d["_done"], np.ones(N, np.uint8))
    ann = Annotator(scene, Request(keypoints=True, label_map=True))
    for r in (5, 33, 71):
        lab = ann.annotate(wins[r])
        assert np.array_equal(d["label_map"][r], lab.label_map)
        for k, o in enumerate(lab.objects):
            np.testing.assert_allclose(d["keypoints_uv"][r, k], o.corners_uv, atol=1e-9)
            assert tuple(d["bbox_visib"][r, k]) == o.bbox_visib
            assert d["visib_fract"][r, k] == pytest.approx(o.visib_fract)
        ev = scene.events.read(wins[r].i0, wins[r].i1)
        pos, neg = polarity_counts(ev, W, H)
        assert np.array_equal(d["frames/counts"][r, 0], pos) and np.array_equal(d["frames/counts"][r, 1], neg)
        rgb = three_channel_rgb(three_channel(ev, W, H, wins[r].t0_us, wins[r].t1_us))
        assert np.array_equal(d["frames/three_channel"][r], rgb) and ((neg > 0) & (pos == 0)).any()
    assert d["frames/counts"].sum() == scene.events.n_events
    with h5py.File(path, "r") as f:
        assert f["label_map"].chunks == (1, H, W) and f["frames/counts"].chunks == (1, 2, H, W)
        assert 32001 in f["label_map"]._filters or "32001" in str(f["label_map"]._filters)   # Blosc
        assert f["T_cam_obj"].chunks[0] > 1
    man = json.loads((out / "export_manifest.json").read_text())
    assert man["files"] == ["README.txt", "export_manifest.json", path.name]


def test_resume_from_partial_file_and_jobs2(h5_export, tmp_path):
    scene_dir, out_ref, _ = h5_export
    ref = read_all(next(out_ref.glob("*.h5")))
    out = tmp_path / "out"
    calls = {"n": 0}

    def cancel():
        calls["n"] += 1
        return calls["n"] > 40

    with pytest.raises(Cancelled):
        export_scene(scene_dir, "h5", out, format_options={"three_channel": True}, cancel=cancel)
    partial = list(out.glob(".*.h5.partial"))
    assert len(partial) == 1 and not list(out.glob("*.h5")) and not list(out.rglob(".*.tmp"))
    with h5py.File(partial[0], "r") as f:
        n_done = int(f["_done"][()].sum())
    assert 0 < n_done < 80
    s = export_scene(scene_dir, "h5", out, format_options={"three_channel": True}, jobs=2)
    assert s.skipped_complete == n_done and s.written == 80 - n_done
    assert not list(out.glob(".*.partial"))
    assert_same(read_all(next(out.glob("*.h5"))), ref)
    # a rerun of a complete export does nothing
    s = export_scene(scene_dir, "h5", out, format_options={"three_channel": True})
    assert s.written == 0 and s.skipped_complete == 80


def test_unlabeled_rows(tiny_scene_dir, tmp_path):
    scene_dir = tmp_path / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    scene = Scene.open(scene_dir)
    scene.corrections.set(("offset_us",), 1_000_000)   # 1 s: the trajectory ends before the last windows
    s = export_scene(scene, "h5", tmp_path / "out")
    assert 0 < s.unlabeled < s.windows_total
    d = read_all(tmp_path / "out" / f"{scene.name}.h5")
    bad = ~d["windows"]["valid"]
    assert bad.sum() == s.unlabeled
    assert np.isnan(d["T_cam_obj"][bad]).all() and (d["label_map"][bad] == -1).all()
    assert (d["bbox_obj"][bad] == -1).all()
    assert d["frames/counts"][bad].sum() > 0          # frames are still there for unlabeled windows
    assert {u["index"] for u in s.unlabeled_windows} == set(d["windows"]["index"][bad].tolist())
