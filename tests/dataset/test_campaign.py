"""Issue 28.2: one calibration for a recording campaign -- ``dataset.toml``'s ``[[groups]]`` and ``dataset refine
--joint --shared hand-eye,placement``: scenes sharing a hand-eye and a placement fitted together from their summed
normal equations (per-scene terms on the Dask workers), with a sigma for every term.

The campaign: three scenes of one placement (same seed, the same 3 mm / 1.5 deg error on every object) and one
camera mounting (2 mm / 0.5 deg off), recorded at 0.1, 0.5 and 1.0 m/s, each with its own clock."""
from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from evpose_testing import CAMPAIGN_SPEEDS, generate_campaign

SPEEDS = CAMPAIGN_SPEEDS
GROUPS = """
[[groups]]
name = "day1"
shared = ["hand-eye", "placement"]
scenes = ["slow", "mid", "fast"]
"""


def _params():
    from evpose.core.align.joint_result import JointParams

    return JointParams(hand_eye=True, skew="fixed", n_windows=16)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("campaign") / "ds"
    generate_campaign(root)
    (root / "dataset.toml").write_text(f'format = "evpose-dataset/1"\nscenes = {list(SPEEDS)!r}\n{GROUPS}'
                                       .replace("'", '"'))
    return root


def _fit(root: Path, names, shared=("hand-eye", "placement")):
    from evpose.core.align.campaign_fit import fit_campaign
    from evpose.core.align.campaign_terms import LocalEvaluator
    from evpose.core.data.scene import Scene
    from evpose.core.dataset.campaign import campaign_scenes
    from evpose.core.dataset.dataset import Dataset

    ds = Dataset.open(root).only(names)
    scenes = {n: Scene.open(root / n) for n in names}
    try:
        return fit_campaign(LocalEvaluator(scenes, _params()), campaign_scenes(ds, set(shared)), _params())
    finally:
        for s in scenes.values():
            s.close()


@pytest.fixture(scope="module")
def fits(campaign):
    """Each scene's own joint fit (clock, poses, hand-eye) and the campaign fit of all three, in this process."""
    from evpose.core.align.joint_fit import refine_joint
    from evpose.core.data.scene import Scene

    own = {}
    for name in SPEEDS:
        with Scene.open(campaign / name) as scene:
            own[name] = refine_joint(scene, params=_params())
    return own, _fit(campaign, list(SPEEDS))


def _he_error(H, root):
    """(mm, deg) of a total hand-eye correction against the truth."""
    from evpose.core.data.geometry import pose_error
    from evpose.core.sim.synth import load_ground_truth

    et, er = pose_error(np.asarray(H), np.asarray(load_ground_truth(root / "slow")["hand_eye"]["dT_cam"]))
    return float(np.linalg.norm(et) * 1e3), float(np.degrees(np.linalg.norm(er)))


def _centre_error_mm(root, name, T) -> float:
    """Distance of an object's box centre at pose ``T`` from the true one (mm; the spin of a solid of revolution
    cannot move it)."""
    from evpose.core.data.scene import Scene
    from evpose.core.sim.synth import load_ground_truth

    Tt = np.asarray(load_ground_truth(root / "slow")["objects"][name]["T_base_obj"])
    with Scene.open(root / "slow") as scene:
        c = scene.raster_model(name).bbox_center_m
    return float(np.linalg.norm((T[:3, :3] @ c + T[:3, 3]) - (Tt[:3, :3] @ c + Tt[:3, 3])) * 1e3)


def _object_pose(root, scene_name, name, dT_base):
    from evpose.core.data.scene import Scene

    with Scene.open(root / scene_name) as scene:
        return np.asarray(dT_base) @ scene.manifest.object(name).T_base_obj


def test_the_campaign_recovers_what_the_slow_scene_cannot(campaign, fits):
    """The slow scene alone gets its hand-eye wrong beyond its own sigma or cannot pin it (a sigma of millimetres)
    and holds or misplaces its objects; fitted with the faster scenes of its placement and day, the hand-eye and
    every object's pose are nearer the truth, the hand-eye's translation with a sigma a quarter of the slow scene's
    own and within 2 sigma of the truth (its rotation and the objects: the next test)."""
    own, camp = fits
    slow = own["slow"]
    assert camp.accepted, camp.reason
    t_own, r_own = _he_error(slow.hand_eye_dT_cam, campaign)
    he = camp.per_scene["slow"]
    t_c, r_c = _he_error(he.hand_eye_dT_cam, campaign)
    print(f"hand-eye: slow alone {t_own:.2f} mm (+- {slow.hand_eye_std_mm:.2f}) {r_own:.3f} deg "
          f"(+- {slow.hand_eye_std_deg:.3f}); campaign {t_c:.2f} mm (+- {he.hand_eye_std_mm:.2f}) {r_c:.3f} deg "
          f"(+- {he.hand_eye_std_deg:.3f}); {camp.runtime_s:.1f} s, {len(camp.trace)} steps")
    wrong_alone = not (math.isfinite(slow.hand_eye_std_deg) and r_own <= 2 * slow.hand_eye_std_deg
                       and t_own <= 2 * slow.hand_eye_std_mm)
    assert wrong_alone or slow.hand_eye_std_mm > 2.0, "the slow scene pins its own hand-eye: not this test's case"
    assert t_c < t_own and r_c < r_own
    assert t_c <= 2 * he.hand_eye_std_mm and he.hand_eye_std_mm < 0.25 * slow.hand_eye_std_mm
    start = {n: _centre_error_mm(campaign, n, _object_pose(campaign, "slow", n, np.eye(4))) for n in
             ("box", "cylinder", "flatbox")}
    held = [n for n in start if n not in he.objects]
    assert len(held) <= 1, held          # the cylinder (its spin held) is not pinned by the events of this campaign
    for name in start:
        o = he.objects.get(name)
        own_o = slow.objects.get(name)
        e_own = start[name] if own_o is None else _centre_error_mm(campaign, name,
                                                                   _object_pose(campaign, "slow", name, own_o.dT_base))
        if o is None:                                           # kept at its start, as the slow scene keeps it
            assert own_o is None, name
            continue
        e_c = _centre_error_mm(campaign, name, _object_pose(campaign, "slow", name, o.dT_base))
        print(f"{name}: start {start[name]:.2f} mm, slow alone {e_own:.2f} mm "
              f"({'held' if own_o is None else f'+- {own_o.std_mm:.2f}'}), campaign {e_c:.2f} mm (+- {o.std_mm:.2f})")
        assert e_c < e_own
    # every scene of the placement gets the same poses; each keeps its own clock
    for name in ("mid", "fast"):
        other = camp.per_scene[name]
        for n, o in he.objects.items():
            assert np.allclose(_object_pose(campaign, name, n, other.objects[n].dT_base),
                               _object_pose(campaign, "slow", n, o.dT_base), atol=1e-12)
    assert camp.hand_eye["group:day1"].scenes == list(SPEEDS)


@pytest.mark.xfail(strict=True, reason="open: from its start the campaign settles in a second optimum, its hand-eye "
                                       "rotation 0.30 deg off with a sigma of 0.14 and the box 0.74 mm with 0.22 (the "
                                       "summed objective is 10 % higher at the truth; started at the truth the fit "
                                       "stays there, 0.006 deg): a local sigma says nothing of another optimum")
def test_the_campaigns_hand_eye_rotation_and_objects_are_within_2_sigma(campaign, fits):
    """(bench/campaign.py: 100 % of 134 estimates within 2 sigma over 9 other campaigns of both generators.)"""
    _, camp = fits
    he = camp.per_scene["slow"]
    _, r_c = _he_error(he.hand_eye_dT_cam, campaign)
    far = {n: (_centre_error_mm(campaign, n, _object_pose(campaign, "slow", n, o.dT_base)), o.std_mm)
           for n, o in he.objects.items()}
    assert r_c <= 2 * he.hand_eye_std_deg and all(e <= 2 * sd for e, sd in far.values()), (r_c, far)


def test_a_scene_that_pins_everything_gets_its_own_answer(campaign, fits):
    """A campaign of one scene is that scene's own joint fit (same model, same windows) within 1 sigma, its sigma
    within 50 %, and in the three-scene campaign the fast scene's terms agree with its own fit within 2 sigma of their
    difference. Not closer: the single fit lends each look's z-buffer to the next (visibility from a nearby state),
    the campaign renders afresh so that its answer does not depend on the worker; from the same start the two paths
    end 0.54 / 0.62 sigma apart (hand-eye translation / rotation) and at other sigmas (the rotation's 1.4x)."""
    own, camp = fits
    fast = own["fast"]
    alone = _fit(campaign, ["fast"]).per_scene["fast"]
    gaps = _he_gap(alone.hand_eye_dT_cam, fast.hand_eye_dT_cam)
    print(f"one-scene campaign vs own fit: {gaps[0] / fast.hand_eye_std_mm:.2f} / {gaps[1] / fast.hand_eye_std_deg:.2f}"
          f" sigma apart; sigma ratios {alone.hand_eye_std_mm / fast.hand_eye_std_mm:.2f} / "
          f"{alone.hand_eye_std_deg / fast.hand_eye_std_deg:.2f}")
    assert _he_close(alone.hand_eye_dT_cam, fast.hand_eye_dT_cam, fast.hand_eye_std_mm, fast.hand_eye_std_deg)
    assert alone.hand_eye_std_mm == pytest.approx(fast.hand_eye_std_mm, rel=0.5)
    assert alone.hand_eye_std_deg == pytest.approx(fast.hand_eye_std_deg, rel=0.5)
    for name, o in fast.objects.items():
        a = alone.objects[name]
        assert _centre_gap_mm(campaign, name, a.dT_base, o.dT_base) < o.std_mm
        assert a.std_mm == pytest.approx(o.std_mm, rel=0.5)
    assert abs(alone.offset_us - fast.offset_us) <= 0.2 * fast.offset_std_us
    c = camp.per_scene["fast"]
    t_gap, r_gap = _he_gap(c.hand_eye_dT_cam, fast.hand_eye_dT_cam)
    assert t_gap <= 2 * math.hypot(c.hand_eye_std_mm, fast.hand_eye_std_mm)
    assert r_gap <= 2 * math.hypot(c.hand_eye_std_deg, fast.hand_eye_std_deg)
    for name, o in fast.objects.items():
        assert _centre_gap_mm(campaign, name, c.objects[name].dT_base, o.dT_base) <= 2 * math.hypot(
            c.objects[name].std_mm, o.std_mm)


def _he_gap(A, B):
    from evpose.core.data.geometry import pose_error

    et, er = pose_error(np.asarray(A), np.asarray(B))
    return float(np.linalg.norm(et) * 1e3), float(np.degrees(np.linalg.norm(er)))


def _he_close(A, B, mm, deg) -> bool:
    t, r = _he_gap(A, B)
    return t <= mm and r <= deg


def _centre_gap_mm(root, name, dA, dB) -> float:
    """Distance between an object's box centre under two corrections of the fast scene's manifest pose (mm)."""
    from evpose.core.data.scene import Scene

    with Scene.open(root / "fast") as scene:
        c = scene.raster_model(name).bbox_center_m
    TA, TB = _object_pose(root, "fast", name, dA), _object_pose(root, "fast", name, dB)
    return float(np.linalg.norm((TA[:3, :3] @ c + TA[:3, 3]) - (TB[:3, :3] @ c + TB[:3, 3])) * 1e3)


def test_the_schur_step_is_the_dense_solve():
    """The driver's step eliminates each scene's private terms (its clock, poses nobody shares) by their Schur
    complement: the same step as the dense solve of the summed, damped normal equations."""
    from evpose.core.align import campaign_fit as CF
    from evpose.core.align.campaign_terms import SceneInfo, SceneTerms
    from evpose.core.align.joint_result import JointParams

    rng = np.random.default_rng(3)
    scenes = [CF.CampaignScene("a", "group:g", "group:p"), CF.CampaignScene("b", "group:g", "group:p"),
              CF.CampaignScene("c", "group:g", "scene:c")]
    names = {"a": ["box", "can"], "b": ["box"], "c": ["box", "can"]}
    infos = {n: SceneInfo(v, 0, 0.0, 0, {}, {}, np.eye(4), {o: np.zeros(3) for o in v}, {o: 0.05 for o in v},
                          {}, (1.0,), 4) for n, v in names.items()}
    prob = CF._Problem(scenes, infos, JointParams(hand_eye=True))
    # 3 clocks, the hand-eye, p's box and can, c's own box and can; shared: the hand-eye and p's box (only a has a can)
    assert prob.n == 3 + 6 + 12 + 12 and prob.shared.sum() == 6 + 6
    terms = {}
    for cs in scenes:
        n = 8 + 6 * len(names[cs.name])
        X = rng.normal(size=(3 * n, n))
        A = X.T @ X
        A[1, :] = A[:, 1] = 0                                            # the skew is held
        g = rng.normal(size=n)
        g[1] = 0
        terms[cs.name] = SceneTerms(0.0, 1.0, 100, A, g, A, np.full(n, np.inf))
    lam = 0.01
    A = np.zeros((prob.n, prob.n))
    g = np.zeros(prob.n)
    for name, t in terms.items():
        m = prob.maps[name]
        loc = np.flatnonzero(m >= 0)
        A[np.ix_(m[loc], m[loc])] += t.A[np.ix_(loc, loc)]
        g[m[loc]] += t.g[loc]
    dense = np.linalg.solve(A + np.diag(lam * np.diag(A)), g)
    assert np.allclose(CF._step(prob, terms, lam), dense, rtol=1e-8, atol=1e-10)


def test_differing_corrections_in_effect_within_a_group_are_noted():
    """A group shares one hand-eye and one placement; scenes whose corrections in effect already differ (one
    scene's hand-eye or an object edited alone) keep that difference under the shared increment: each is noted."""
    from evpose.core.align import campaign_fit as CF
    from evpose.core.align.campaign_terms import SceneInfo

    def info(he_mm, box_mm):
        H, T = np.eye(4), np.eye(4)
        H[0, 3], T[1, 3] = he_mm * 1e-3, box_mm * 1e-3
        return SceneInfo(["box"], 0, 0.0, 0, {"box": T}, {"box": np.eye(4)}, H, {"box": np.zeros(3)},
                         {"box": 0.05}, {}, (1.0,), 4)

    scenes = [CF.CampaignScene(n, "group:g", "group:p") for n in ("a", "b", "c")]
    _, notes = CF._start(scenes, {"a": info(0, 0), "b": info(0.01, 0), "c": info(1.5, 2.0)})
    assert len(notes) == 2, notes                                  # b's 0.01 mm is below the 0.05 mm of a note
    assert any(n.startswith("c: its hand-eye correction in effect differs from a's by 1.50 mm") for n in notes)
    assert any(n.startswith("c: box's pose in effect differs from group:p's start by 2.00 mm") for n in notes)


def test_an_object_one_scene_holds_gets_the_pose_its_placement_fitted():
    """One T_base_obj per placement: an object a scene would hold on its own (mostly out of its view) but the
    group's other scenes pinned gets the placement's pose in that scene's share too (with a note), so that --apply
    leaves the placement agreeing; an object nobody pinned stays held with the fit's reason."""
    from evpose.core.align.campaign_result import CampaignResult, UnitFit, scene_result
    from evpose.core.align.campaign_terms import SceneInfo
    from evpose.core.align.joint_result import JointParams

    T = np.eye(4)
    T[0, 3] = 0.002
    info = SceneInfo(["box", "can"], 0, 0.0, 0, {"box": np.eye(4), "can": np.eye(4)},
                     {"box": np.eye(4), "can": np.eye(4)}, np.eye(4), {"box": np.zeros(3), "can": np.zeros(3)},
                     {"box": 0.05, "can": 0.05}, {"box": "mostly out of view"}, (1.0,), 4)
    camp = CampaignResult(JointParams(hand_eye=True), ["a", "b"], accepted=True)
    camp.placements = {"group:p": {"box": UnitFit(["a", "b"], T, 2.0, 0.0, 0.3, 0.1, True),
                                   "can": UnitFit(["a", "b"], np.eye(4), reason="not pinned")}}
    from evpose.core.align import campaign_fit as CF

    r = scene_result(CF.CampaignScene("a", "group:g", "group:p"), info, 0.0, 100.0, camp, JointParams(hand_eye=True))
    assert np.allclose(r.objects["box"].dT_base, T) and "box" not in r.held
    assert any(n.startswith("box: held in this scene (mostly out of view)") for n in r.notes), r.notes
    assert r.held == {"can": "not pinned"} and "can" not in r.objects


def test_a_campaign_of_two_camera_resolutions_is_refused_with_the_scenes_named():
    """The kernel widths are px of each scene's camera; a campaign fits at one width per level, so scenes whose
    cameras give other widths (a binned and a full-resolution recording) are refused, not fitted at wrong widths."""
    from evpose.core.align import campaign_fit as CF
    from evpose.core.align.campaign_terms import SceneInfo
    from evpose.core.align.joint_result import JointParams

    class Fake:
        def __init__(self, infos):
            self._infos = infos

        def infos(self):
            return self._infos

        def evaluate(self, requests):
            raise AssertionError("nothing is evaluated")

    def info(sigmas):
        return SceneInfo(["box"], 0, 0.0, 0, {"box": np.eye(4)}, {"box": np.eye(4)}, np.eye(4), {"box": np.zeros(3)},
                         {"box": 0.05}, {}, sigmas, 4)

    scenes = [CF.CampaignScene(n, "group:g", "group:p") for n in ("half", "full")]
    r = CF.fit_campaign(Fake({"half": info((1.5, 0.08)), "full": info((3.0, 0.16))}), scenes,
                        JointParams(hand_eye=True))
    assert not r.accepted and "cameras differ" in r.reason and "full" in r.reason, r.reason


# ------------------------------------------------------------------------------------------ dataset.toml groups
BAD_GROUPS = {
    "groups = 3": "groups: expected an array of tables",
    '[[groups]]\nshared = ["hand-eye"]\nscenes = ["slow"]': "groups[0].name: expected a non-empty string",
    '[[groups]]\nname = "a"\nshared = ["hand_eye"]\nscenes = ["slow"]': "groups[0].shared: unknown kind 'hand_eye'",
    '[[groups]]\nname = "a"\nshared = []\nscenes = ["slow"]': "groups[0].shared: expected a list of distinct kinds",
    '[[groups]]\nname = "a"\nshared = ["placement"]\nscenes = ["nope"]': "groups[0].scenes: 'nope' is not a scene",
    '[[groups]]\nname = "a"\nshared = ["placement"]\nscenes = []': "groups[0].scenes: expected a non-empty list",
    '[[groups]]\nname = "a"\nshared = ["placement"]\nscenes = ["slow"]\ncolour = 1': "groups[0].colour: not a group",
    ('[[groups]]\nname = "a"\nshared = ["placement"]\nscenes = ["slow"]\n'
     '[[groups]]\nname = "a"\nshared = ["hand-eye"]\nscenes = ["mid"]'): "groups[1].name: a second group named 'a'",
    ('[[groups]]\nname = "a"\nshared = ["placement"]\nscenes = ["slow", "mid"]\n'
     '[[groups]]\nname = "b"\nshared = ["placement", "hand-eye"]\nscenes = ["mid"]'):
        "groups[1].scenes: 'mid' is also in group 'a', which shares placement too",
}


@pytest.mark.parametrize("text", list(BAD_GROUPS), ids=range(len(BAD_GROUPS)))
def test_bad_groups_are_refused_in_one_line_naming_the_file_and_the_field(campaign, tmp_path, text):
    from evpose.core.dataset.dataset import Dataset, DatasetError

    root = tmp_path / "ds"
    root.mkdir()
    for name in SPEEDS:
        (root / name).symlink_to(campaign / name)
    toml = root / "dataset.toml"
    toml.write_text(f'format = "evpose-dataset/1"\nscenes = ["slow", "mid", "fast"]\n{text}\n')
    with pytest.raises(DatasetError) as e:
        Dataset.open(root)
    assert str(e.value).startswith(f"{toml}: {BAD_GROUPS[text]}"), str(e.value)
    assert "\n" not in str(e.value)


def test_groups_are_read(campaign):
    from evpose.core.dataset.campaign import campaign_scenes
    from evpose.core.dataset.dataset import Dataset

    ds = Dataset.open(campaign)
    assert [(g.name, g.shared, g.scenes) for g in ds.groups] == [("day1", ("hand-eye", "placement"),
                                                                  ("slow", "mid", "fast"))]
    units = campaign_scenes(ds, {"placement"})
    assert [(c.hand_eye, c.placement) for c in units] == [(f"scene:{n}", "group:day1") for n in SPEEDS]


# ------------------------------------------------------------------------------------------ the command
def _evpose(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "evpose", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def _files(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_dataset_refine_shared_on_dask_is_the_local_fit_and_apply_stores_each_scenes_share(campaign, fits, tmp_path):
    """On 2 Dask workers (no events through the scheduler: each worker keeps its scenes) the campaign fit gives
    the numbers of the fit in one process; the dry run writes nothing; ``--apply`` stores every scene's share --
    the group's hand-eye on top of its own correction, the placement's poses, its own clock where beyond its
    sigma -- and records the group fit in campaign_fit.json."""
    from evpose.core.data.scene import Scene

    _, local = fits
    root = tmp_path / "ds"
    shutil.copytree(campaign, root)
    before = _files(root)
    r = _evpose("dataset", "refine", root, "--joint", "--shared", "hand-eye,placement", "--windows", "16",
                "--workers", "2", "--json", "-q")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert _files(root) == before                                       # a dry run
    fit = doc["campaign"]
    mine = local.to_json()
    for key in ("hand_eye", "placements"):
        for unit, v in mine[key].items():
            got = fit[key][unit]
            for a, b in ([(got, v)] if key == "hand_eye" else [(got[n], v[n]) for n in v]):
                assert np.allclose(a["T"], b["T"], rtol=0, atol=1e-9)
                assert a["dt_std_mm"] == b["dt_std_mm"] or a["dt_std_mm"] == pytest.approx(b["dt_std_mm"], rel=1e-6)
    assert set(doc["scenes"]) == set(SPEEDS) and not doc["failed"]
    assert any(c["part"] == "hand-eye" for c in doc["scenes"]["slow"]["changes"])
    r = _evpose("dataset", "refine", root, "--joint", "--shared", "hand-eye,placement", "--windows", "16",
                "--workers", "2", "--apply", "--json", "-q")
    assert r.returncode == 0, r.stderr
    applied = json.loads(r.stdout)
    record = json.loads((root / "campaign_fit.json").read_text())
    assert record["format"] == "evpose-campaign-fit/1" and record["groups"][0]["name"] == "day1"
    assert applied["recorded"] == str(root / "campaign_fit.json")
    for name in SPEEDS:
        d = applied["scenes"][name]
        assert d["applied"] and record["stored"][name]["revision"] == d["revision"]
        assert record["stored"][name]["values"] == any(c["part"] != "sigma" for c in d["changes"])
        mine = local.per_scene[name]
        with Scene.open(root / name) as scene:
            assert np.allclose(scene.corrections.hand_eye_delta, mine.hand_eye_dT_cam, atol=1e-9)
            for n, o in mine.objects.items():
                if any(c["part"] == "object" and c["name"] == n for c in d["changes"]):
                    assert np.allclose(scene.corrections.object_delta(n), o.dT_base, atol=1e-9)


def test_the_campaign_share_is_one_undo_step(campaign, fits, tmp_path):
    from evpose.core.align.apply import plan_joint_result, store_changes
    from evpose.core.data.scene import Scene
    from evpose.core.document.history import History

    _, local = fits
    shutil.copytree(campaign / "slow", tmp_path / "slow")
    with Scene.open(tmp_path / "slow") as scene:
        poses0 = {n: scene.T_base_obj(n) for n in scene.object_names}
        he0 = scene.corrections.hand_eye_delta.copy()
        h = History(scene.corrections)
        changes, _ = plan_joint_result(scene, local.per_scene["slow"])
        assert {c.part for c in changes} >= {"hand-eye", "object"}
        assert store_changes(h, changes, "campaign fit") and len(h) == 1
        assert not np.allclose(scene.corrections.hand_eye_delta, he0)
        h.undo()
        assert np.allclose(scene.corrections.hand_eye_delta, he0)
        assert all(np.allclose(scene.T_base_obj(n), T) for n, T in poses0.items())


def test_shared_needs_groups_and_is_refused_in_one_line(campaign, tmp_path):
    root = tmp_path / "ds"
    shutil.copytree(campaign, root)
    (root / "dataset.toml").write_text('format = "evpose-dataset/1"\nscenes = ["slow", "mid"]\n')
    r = _evpose("dataset", "refine", root, "--shared", "placement", "--workers", "1", "-q")
    assert r.returncode == 2 and "no [[groups]]" in r.stderr and "placement" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    r = _evpose("dataset", "refine", root, "--shared", "hand-eye,mounting", "-q")
    assert r.returncode == 2 and "unknown kind 'mounting'" in r.stderr


def test_a_campaign_record_evpose_did_not_write_is_never_replaced(campaign, tmp_path):
    from evpose.core.align.campaign_result import CampaignResult
    from evpose.core.dataset.batch import BatchResult
    from evpose.core.dataset.campaign import record_campaign
    from evpose.core.dataset.dataset import Dataset, DatasetError

    root = tmp_path / "ds"
    shutil.copytree(campaign, root)
    foreign = root / "campaign_fit.json"
    foreign.write_text('{"mine": true}\n')
    before = _files(root)
    r = _evpose("dataset", "refine", root, "--joint", "--shared", "placement", "--apply", "--workers", "1", "-q")
    assert r.returncode == 2 and "not a campaign fit evpose recorded" in r.stderr, r.stderr
    assert _files(root) == before                    # refused before anything was stored
    ds = Dataset.open(root)
    with pytest.raises(DatasetError, match="not a campaign fit evpose recorded"):
        record_campaign(ds, CampaignResult(_params(), list(SPEEDS)), BatchResult(ds.name))
    assert foreign.read_text() == '{"mine": true}\n'
    foreign.unlink()
    path = record_campaign(ds, CampaignResult(_params(), list(SPEEDS)), BatchResult(ds.name))
    assert json.loads(path.read_text())["format"] == "evpose-campaign-fit/1"
    record_campaign(ds, CampaignResult(_params(), list(SPEEDS)), BatchResult(ds.name))     # its own: replaced


def test_a_scene_without_windows_says_nothing_and_does_not_stop_the_campaign(campaign):
    """A static scene in a group (no window with camera motion) contributes no terms: the others are fitted."""
    from evpose.core.align.campaign_fit import fit_campaign
    from evpose.core.align.campaign_terms import LocalEvaluator
    from evpose.core.data.scene import Scene
    from evpose.core.dataset.campaign import campaign_scenes
    from evpose.core.dataset.dataset import Dataset

    p = _params().__class__(**{**_params().__dict__, "sigmas_px": (1.5, 0.8)})
    names = ["slow", "fast"]
    scenes = {n: Scene.open(campaign / n) for n in names}
    try:
        ev = LocalEvaluator(scenes, p)
        ev.work["slow"].fit = None                      # as a scene whose camera never moves
        r = fit_campaign(ev, campaign_scenes(Dataset.open(campaign).only(names), {"hand-eye", "placement"}), p)
    finally:
        for s in scenes.values():
            s.close()
    assert r.accepted and r.hand_eye["group:day1"].fitted and r.objective_after["slow"] == 0.0


def test_a_share_planned_on_other_corrections_is_refused(campaign, fits, tmp_path):
    """Another program saved the scene while the campaign was fitted: its share is not stored over that edit."""
    from evpose.core.align.refine_run import ProposalError
    from evpose.core.data.scene import Scene
    from evpose.core.dataset.campaign import campaign_scene_task

    _, local = fits
    shutil.copytree(campaign / "slow", tmp_path / "slow")
    with Scene.open(tmp_path / "slow") as scene:
        planned = scene.corrections.digest()
        assert planned == local.planned_on["slow"]
        scene.corrections.set(("offset_us",), 1234)             # the other program's edit, saved
        scene.save_corrections()
    before = (tmp_path / "slow" / "corrections.json").read_bytes()
    with pytest.raises(ProposalError, match="planned_on"):
        campaign_scene_task(str(tmp_path / "slow"), None, local.per_scene["slow"], True, planned)
    assert (tmp_path / "slow" / "corrections.json").read_bytes() == before
