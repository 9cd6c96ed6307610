"""Applying a clock estimate on top of a non-zero prior (issue 12 point 7).

A sync estimate holds the *total* clock (``offset_us``, ``skew_ppm`` in effect); the scene stores
corrections on top of the manifest's prior, so what is stored must be ``total - prior`` and the clock in
effect afterwards ``prior + correction == total``. With a prior of 0 the sign of the prior cannot show, so
every scene here has a prior offset and skew, and an estimate on the other side of zero from the prior.
Checked in the core functions (:mod:`evpose.core.align.apply`) and through ``evpose sync --apply``.
"""
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from test_sync import T0_POSE, _cli, _Open, rate_events, stop_go_motion, write_scene

from evpose.core.align.apply import apply_offset_result, apply_sync, clock_correction
from evpose.core.align.estimate import sync_scene
from evpose.core.align.refine_result import RefineResult
from evpose.core.align.sync_result import SyncResult
from evpose.core.data.clock import ClockModel
from evpose.core.data.manifest_reader import load_manifest
from evpose.core.document.corrections import Corrections
from evpose.core.document.history import History

PRIOR_OFFSET_US = 150_000
PRIOR_SKEW_PPM = 250.0
TRUE_OFFSET_US = -73_200          # 223 ms from the prior (inside the default ±500 ms search), other sign
#: 3 s of events: the rate pins the offset to ~1 ms (skew not estimated: kept at the prior, which is the truth)
TOL_US = 1_500


@pytest.fixture(scope="module")
def prior_scene(tmp_path_factory) -> Path:
    """A 3 s rate-level scene whose manifest has a prior of +150 ms and 250 ppm; the true clock is -73.2 ms
    and 250 ppm."""
    rng = np.random.default_rng(7)
    traj, true = stop_go_motion(5.0, rng)
    t0_ev = T0_POSE + 1_000_000 - TRUE_OFFSET_US
    clock = ClockModel(TRUE_OFFSET_US, PRIOR_SKEW_PPM, t0_ev)
    ev = rate_events(true, clock, t0_ev, t0_ev + 3_000_000, rng, gain=10.0)
    return write_scene(tmp_path_factory.mktemp("sync_apply") / "prior", traj, ev, PRIOR_OFFSET_US, PRIOR_SKEW_PPM)


@pytest.fixture
def scene_dir(prior_scene, tmp_path) -> Path:
    dst = tmp_path / "scene"
    shutil.copytree(prior_scene, dst)
    return dst


def estimate(offset_us, skew_ppm, offset_std_us=500.0) -> SyncResult:
    """A reliable estimate of the total clock (as sync_scene returns it), 1 sigma ``offset_std_us``."""
    return SyncResult(offset_us, skew_ppm, 0.9, True, "", np.zeros(0), np.zeros(0),
                      prior_offset_us=PRIOR_OFFSET_US, prior_skew_ppm=PRIOR_SKEW_PPM, offset_std_us=offset_std_us)


# ------------------------------------------------------------------------------------------- core
def test_the_correction_is_the_estimate_minus_the_prior(scene_dir):
    with _Open(scene_dir) as scene:
        assert (scene.manifest.clock_offset_us, scene.manifest.clock_skew_ppm) == (PRIOR_OFFSET_US, PRIOR_SKEW_PPM)
        assert clock_correction(scene, estimate(-73_200, 310.5)) == (-223_200, 60.5)
        assert clock_correction(scene, estimate(400_000, 100.0)) == (250_000, -150.0)
        # skew not estimated: the current skew correction is kept (here 0), never the prior subtracted
        assert clock_correction(scene, estimate(-73_200, None)) == (-223_200, 0.0)
        scene.corrections.set(("skew_ppm",), 4.0)
        assert clock_correction(scene, estimate(-73_200, None)) == (-223_200, 4.0)
        assert clock_correction(scene, SyncResult(None, None, 0.0, False, "static", np.zeros(0), np.zeros(0))) is None


def test_apply_sync_makes_the_clock_in_effect_the_estimate(scene_dir):
    with _Open(scene_dir) as scene:
        h = History(scene.corrections)
        assert apply_sync(h, scene, estimate(-73_200, 310.5))
        c = scene.corrections
        assert (c.offset_us, c.skew_ppm) == (-223_200, pytest.approx(60.5))
        assert scene.clock.offset_us == -73_200 and scene.clock.skew_ppm == pytest.approx(310.5)
        # a second estimate replaces the correction (it is not added to the first)
        assert apply_sync(h, scene, estimate(160_000, None))
        assert (c.offset_us, c.skew_ppm) == (10_000, pytest.approx(60.5))
        assert scene.clock.offset_us == 160_000 and scene.clock.skew_ppm == pytest.approx(310.5)
        h.undo()
        assert scene.clock.offset_us == -73_200
        h.undo()
        assert (c.offset_us, c.skew_ppm) == (0, 0.0)
        assert (scene.clock.offset_us, scene.clock.skew_ppm) == (PRIOR_OFFSET_US, PRIOR_SKEW_PPM)


def test_an_estimate_the_clock_in_effect_is_within_is_not_applied(scene_dir):
    """Issue 23: a right clock is never replaced by a noisier copy of itself: an estimate within 2 sigma of the
    clock in effect, or one without a standard error, changes nothing; 2 sigma and a little more does."""
    from evpose.core.align.apply import APPLY_SIGMAS

    with _Open(scene_dir) as scene:
        h = History(scene.corrections)
        near = PRIOR_OFFSET_US + int(APPLY_SIGMAS * 500) - 10
        # the clock is kept; the estimate's sigma (with its distance in quadrature) is stored beside it (issue 28.3)
        assert apply_sync(h, scene, estimate(near, None, offset_std_us=500.0))
        assert scene.corrections.offset_us == 0
        assert scene.corrections.sigma("clock") == {"offset_us": pytest.approx(math.hypot(near - PRIOR_OFFSET_US, 500))}
        assert not apply_sync(h, scene, estimate(PRIOR_OFFSET_US - 900, None, offset_std_us=500.0))   # has one now
        assert not apply_sync(h, scene, estimate(-73_200, None, offset_std_us=None))
        assert not apply_sync(h, scene, estimate(-73_200, None, offset_std_us=float("inf")))
        assert scene.corrections.offset_us == 0 and len(h) == 1
        assert apply_sync(h, scene, estimate(PRIOR_OFFSET_US + int(APPLY_SIGMAS * 500) + 10, None, 500.0))
        assert scene.corrections.offset_us == int(APPLY_SIGMAS * 500) + 10
        # the skew alone, when estimated with its standard error, counts too
        r = RefineResult("offset", None, offset_us=scene.clock.offset_us, skew_ppm=PRIOR_SKEW_PPM + 30.0,
                         accepted=True, offset_std_us=300.0, skew_std_ppm=10.0)
        assert apply_offset_result(h, scene, r)
        r.skew_std_ppm, r.skew_ppm = 20.0, scene.clock.skew_ppm + 30.0
        assert not apply_offset_result(h, scene, r)


def test_apply_offset_result_makes_the_clock_in_effect_the_refined_one(scene_dir):
    with _Open(scene_dir) as scene:
        h = History(scene.corrections)
        r = RefineResult("offset", None, offset_us=-70_000, skew_ppm=245.0, accepted=True, offset_std_us=300.0)
        assert apply_offset_result(h, scene, r)
        assert (scene.corrections.offset_us, scene.corrections.skew_ppm) == (-220_000, pytest.approx(-5.0))
        assert scene.clock.offset_us == -70_000 and scene.clock.skew_ppm == pytest.approx(245.0)


def test_a_real_estimate_applied_on_the_prior_gives_the_true_clock(scene_dir):
    with _Open(scene_dir) as scene:
        res = sync_scene(scene)
        assert res.reliable, res.reason
        assert res.skew_ppm is None                                    # 3 s: skew kept
        assert abs(res.offset_us - TRUE_OFFSET_US) < TOL_US, res.offset_us    # the estimate is the total
        assert (res.prior_offset_us, res.prior_skew_ppm) == (PRIOR_OFFSET_US, PRIOR_SKEW_PPM)
        assert apply_sync(History(scene.corrections), scene, res)
        assert scene.corrections.offset_us == res.offset_us - PRIOR_OFFSET_US
        assert scene.corrections.skew_ppm == 0.0
        assert scene.clock.offset_us == res.offset_us
        assert abs(scene.clock.offset_us - TRUE_OFFSET_US) < TOL_US
        assert scene.clock.skew_ppm == PRIOR_SKEW_PPM


# ------------------------------------------------------------------------------------------- CLI
def test_cli_sync_apply_on_a_nonzero_prior(scene_dir):
    rc, out = _cli(["sync", str(scene_dir), "--json", "--apply", "-q"])
    assert rc == 0
    data = json.loads(out)
    assert data["reliable"] and data["applied"]
    assert abs(data["offset_us"] - TRUE_OFFSET_US) < TOL_US
    assert data["correction"]["offset_us"] == data["offset_us"] - PRIOR_OFFSET_US
    assert data["correction"]["skew_ppm"] == 0.0
    saved = Corrections.load(scene_dir / "corrections.json")
    assert (saved.offset_us, saved.skew_ppm) == (data["offset_us"] - PRIOR_OFFSET_US, 0.0)
    man = load_manifest(scene_dir)                                  # the prior itself is never rewritten
    assert (man.clock_offset_us, man.clock_skew_ppm) == (PRIOR_OFFSET_US, PRIOR_SKEW_PPM)
    with _Open(scene_dir) as scene:
        assert scene.clock.offset_us == data["offset_us"]
        assert abs(scene.clock.offset_us - TRUE_OFFSET_US) < TOL_US
        assert scene.clock.skew_ppm == PRIOR_SKEW_PPM


def test_cli_sync_apply_replaces_earlier_corrections_with_estimate_minus_prior(scene_dir, monkeypatch):
    """An estimate with a skew, applied over corrections saved earlier: the stored corrections are the total
    minus the prior (not added to the earlier ones), in the JSON, the text and the file."""
    import evpose.core.align.estimate as estimate_module

    earlier = Corrections()
    earlier.set(("offset_us",), 5_000)
    earlier.set(("skew_ppm",), 1.5)
    earlier.save(scene_dir / "corrections.json")
    monkeypatch.setattr(estimate_module, "sync_scene", lambda scene, **kw: estimate(95_000, 262.0))
    rc, out = _cli(["sync", str(scene_dir), "--json", "--apply", "-q"])
    assert rc == 0
    data = json.loads(out)
    assert data["applied"] and (data["offset_us"], data["skew_ppm"]) == (95_000, 262.0)
    assert data["correction"] == {"offset_us": -55_000, "skew_ppm": pytest.approx(12.0)}
    saved = Corrections.load(scene_dir / "corrections.json")
    assert (saved.offset_us, saved.skew_ppm) == (-55_000, pytest.approx(12.0))
    with _Open(scene_dir) as scene:
        assert scene.clock.offset_us == 95_000 and scene.clock.skew_ppm == pytest.approx(262.0)
    rc, text = _cli(["sync", str(scene_dir), "-q"])                # the text states the same correction
    assert rc == 0 and "correction on top of the prior: offset -55000 us, skew 12.00 ppm" in text
