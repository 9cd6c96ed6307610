"""The residual view's computation (evpose.core.views.residuals, issue 25.2), without Qt: on the tiny scene (objects
5 mm / 3 deg off, the true clock set) each object's silhouette events say which way its outline is off; with the
true poses the outline's shift is within its sigma; the colours; the cases with nothing to show."""
from __future__ import annotations

import numpy as np
import pytest

from evpose.core.data.geometry import inv_T
from evpose.core.data.scene import Scene
from evpose.core.sim.synth import load_ground_truth
from evpose.core.views.residuals import residual_rgb, residuals


@pytest.fixture(scope="module")
def scene_and_truth(tiny_scene_dir):
    gt = load_ground_truth(tiny_scene_dir)
    scene = Scene.open(tiny_scene_dir, corrections=None)
    scene.corrections.offset_us = gt["clock"]["offset_us"] - scene.manifest.clock_offset_us
    yield scene, gt
    scene.close()


def _times(scene, n):
    """Window centres where the camera moves (the last 300 ms of the tiny scene are nearly still)."""
    ev = scene.events
    mid = (ev.t_first_us + ev.t_last_us) // 2
    return np.linspace(mid - 300_000, mid, n).astype(np.int64)


def _centre_shift_px(scene, gt, name, t_us):
    """How far the truth's box centre is from the labels' in the image (px): where the outline should go."""
    T_cb = inv_T(scene.T_base_cam(np.array([t_us]))[0][0])
    K, c = scene.camera.K, scene.model(name).bbox_center_m

    def px(T):
        p = T_cb[:3, :3] @ (T[:3, :3] @ c + T[:3, 3]) + T_cb[:3, 3]
        return np.array([K[0, 0] * p[0] / p[2], K[1, 1] * p[1] / p[2]])
    return px(np.asarray(gt["objects"][name]["T_base_obj"])) - px(scene.T_base_obj(name))


def test_the_outline_shift_points_where_the_object_is(scene_and_truth):
    scene, gt = scene_and_truth
    agree, n = 0, 0
    for t in _times(scene, 4):
        r = residuals(scene, t - 5000, t + 5000)
        assert not r.reason and set(r.objects) == set(scene.object_names)
        assert len(r.uv) == len(r.signed_px) == len(r.obj) and np.all(np.abs(r.signed_px) <= 1.5 * r.band_px)   # band at the sub-window pose
        for name, o in r.objects.items():
            assert o.n_events > 50 and o.rms_px is not None
            truth = _centre_shift_px(scene, gt, name, t)
            n += 1
            agree += float(o.shift_px @ truth) > 0.5 * np.linalg.norm(o.shift_px) * np.linalg.norm(truth)
    assert agree >= 0.8 * n, f"{agree} of {n} shifts point within 60 deg of where the object is"


def test_with_the_true_poses_the_shift_is_within_its_sigma(scene_and_truth, tmp_path):
    scene, gt = scene_and_truth
    true = scene.with_corrections(scene.corrections.copy())
    for name in true.object_names:
        true.corrections.object_deltas[name] = np.asarray(gt["objects"][name]["T_base_obj"]) @ inv_T(
            true.manifest.object(name).T_base_obj)
    z_true, z_start = [], []
    for t in _times(scene, 4):
        for sc, z in ((true, z_true), (scene, z_start)):
            for o in residuals(sc, t - 5000, t + 5000).objects.values():
                z += list(np.abs(o.shift_px) / o.shift_std_px)
    z_true, z_start = np.array(z_true), np.array(z_start)
    assert np.mean(z_true <= 2) >= 0.8, z_true
    assert np.median(z_start) > 2 * np.median(z_true), (np.median(z_start), np.median(z_true))


def test_colours_and_the_cases_with_nothing_to_show(scene_and_truth):
    scene, _ = scene_and_truth
    t = _times(scene, 1)[0]
    r = residuals(scene, t - 5000, t + 5000)
    img = residual_rgb(r)
    assert img.shape == (scene.camera.height, scene.camera.width, 3) and img.dtype == np.uint8
    px = img.reshape(-1, 3).astype(int)
    red = (px[:, 0] > 150) & (px[:, 2] < 120)
    blue = (px[:, 2] > 150) & (px[:, 0] < 120)
    assert red.sum() > 20 and blue.sum() > 20                      # events outside and inside the drawn outlines
    assert (px == 255).all(axis=1).mean() > 0.3                    # white where no event fell
    assert residuals(scene, t - 5000, t + 5000, names=[]).reason == "no object shown"
    ev = scene.events
    late = residuals(scene, ev.t_last_us + 1_000_000, ev.t_last_us + 1_010_000)
    assert late.reason and len(late.uv) == 0 and not late.objects
