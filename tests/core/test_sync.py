"""Clock synchronisation (evpose.core.align.estimate and its stages): accuracy on rate-level and rendered
synthetic scenes, the E-POSE minima baseline, reliability decisions and the stiff cases of DESIGN section 7."""
from __future__ import annotations

import argparse
import io
import json
import math
import shutil
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evpose.core.align.apply import apply_sync, clock_correction
from evpose.core.align.correlation import _masked_ncc
from evpose.core.align.estimate import estimate_clock, sync_scene
from evpose.core.align.likelihood import joint_skew, likelihood_std_us
from evpose.core.align.minima_baseline import sync_minima_baseline
from evpose.core.align.proxy import MotionProxy, motion_proxy
from evpose.core.align.sync_result import SLOW_STD_NOTE_US, SyncResult
from evpose.core.data.camera import CameraModel
from evpose.core.data.event_writer import EventWriter, write_events_h5
from evpose.core.data.events import EventArray
from evpose.core.data.manifest import SceneManifest
from evpose.core.data.scene import Scene
from evpose.core.data.clock import ClockModel
from evpose.core.data.trajectory import Trajectory
from evpose.core.document.history import History

T0_POSE = 1_700_000_000_000_000   # epoch pose clock: precision problems would show
FX = 60.0


def small_camera() -> CameraModel:
    return CameraModel([[FX, 0, 31.5], [0, FX, 23.5], [0, 0, 1]], [], 64, 48)


def stop_go_motion(duration_s: float, rng, speed=0.3, dwell=(0.15, 0.4), rate_hz=250, rotate=False,
                   motion_hz=4000) -> tuple[Trajectory, Trajectory]:
    """Camera looking down, translating (and optionally turning) through random waypoints with
    minimum-jerk moves and stops: ``(recorded, true)``, the motion sampled at ``rate_hz`` on an
    epoch pose clock (what a robot reports) and at ``motion_hz`` (the smooth motion the events
    follow)."""
    from scipy.spatial.transform import Slerp

    t, pos, rot = [np.zeros(1)], [np.zeros((1, 3))], [Rotation.identity(1)]
    p, r, now = np.zeros(3), Rotation.identity(), 0.0
    while now < duration_s:
        d = rng.normal(size=3)
        d[2] *= 0.3
        d *= rng.uniform(0.05, 0.15) / np.linalg.norm(d)
        r_next = r * Rotation.from_rotvec(rng.normal(scale=0.15, size=3)) if rotate else r
        T = 1.875 * np.linalg.norm(d) / speed
        tau = np.linspace(0, 1, max(int(T * motion_hz), 2) + 1)[1:]
        s = tau**3 * (10 - 15 * tau + 6 * tau**2)
        t.append(now + T * tau)
        pos.append(p + s[:, None] * d)
        rot.append(r * Rotation.from_rotvec(s[:, None] * (r.inv() * r_next).as_rotvec()))
        p, r = p + d, r_next
        now = now + T + rng.uniform(*dwell)
        t.append(np.array([now]))
        pos.append(p[None].copy())
        rot.append(Rotation.concatenate([r]))
    t = np.rint(np.concatenate(t) * 1e6) * 1e-6            # whole µs, as the trajectory stores them
    pos, rot = np.concatenate(pos), Rotation.concatenate(rot)
    keep = np.r_[True, np.diff(t) > 0]
    t, pos, rot = t[keep], pos[keep], rot[keep]
    down = Rotation.from_matrix(np.diag([1.0, -1.0, -1.0]))
    true = Trajectory(T0_POSE + np.rint(t * 1e6).astype(np.int64), pos, (down * rot).as_quat())
    grid = np.arange(0, t[-1], 1.0 / rate_hz)
    P = np.stack([np.interp(grid, t, pos[:, i]) for i in range(3)], 1)
    R = Slerp(t, rot)(grid)
    return Trajectory(T0_POSE + np.rint(grid * 1e6).astype(np.int64), P, (down * R).as_quat()), true


def stop_go_trajectory(duration_s: float, rng, **kw) -> Trajectory:
    """The recorded trajectory of :func:`stop_go_motion`."""
    return stop_go_motion(duration_s, rng, **kw)[0]


def rate_events(traj: Trajectory, clock: ClockModel, t0_ev: int, t1_ev: int, rng, gain=2.5, noise_per_ms=2.0,
                depth=0.5, hot_per_ms=0.5):
    """Events whose rate is ``gain * fx * (|v| / depth + |w|)`` per ms (``fx * ...`` in px/s) at
    the pose time of each 1 ms bin, plus background noise and a hot pixel: a rate-level event
    camera (~100 events/ms at 0.3 m/s)."""
    bins = np.arange(t0_ev, t1_ev, 1000, dtype=np.int64)
    v, w, ok = traj.speed(clock.pose_time(bins + 500))
    lam = np.where(ok, gain * FX * (v / depth + w), 0.0) + noise_per_ms
    n = rng.poisson(lam)
    t = np.repeat(bins, n) + rng.integers(0, 1000, int(n.sum()))
    hot = np.sort(rng.integers(t0_ev, t1_ev, rng.poisson(hot_per_ms * (t1_ev - t0_ev) / 1000)))
    t = np.sort(np.concatenate([t, hot]))
    x = rng.integers(0, 64, len(t)).astype(np.uint16)
    y = rng.integers(0, 48, len(t)).astype(np.uint16)
    return EventArray(x, y, t, rng.integers(0, 2, len(t)).astype(np.uint8))


def write_scene(folder: Path, traj: Trajectory, events: EventArray | None, prior_offset_us=0, prior_skew=0.0) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    if events is None or len(events) == 0:
        with EventWriter(folder / "events.h5"):
            pass
    else:
        write_events_h5(folder / "events.h5", events)
    traj.save_csv(folder / "trajectory.csv")
    SceneManifest(folder / "scene.toml", folder.name, small_camera(), folder / "events.h5", folder / "trajectory.csv",
                  "cam", None, int(prior_offset_us), float(prior_skew), []).save()
    return folder


def make_rate_scene(folder, duration_s, offset_us, skew_ppm, seed, *, margin_s=1.0, prior_offset_us=0, gain=10.0,
                    rotate=False):
    """A rate-level scene; ``gain=10`` gives ~400 events/ms at 0.3 m/s (a full-resolution DAVIS
    is in the 10^3/ms range: the timing precision is limited by the Poisson noise of the rate)."""
    rng = np.random.default_rng(seed)
    traj, true = stop_go_motion(duration_s + 2 * margin_s, rng, rotate=rotate)
    # events start margin_s after the first pose (on the pose clock)
    t0_ev = T0_POSE + int(margin_s * 1e6) - int(offset_us)
    clock = ClockModel(int(offset_us), float(skew_ppm), t0_ev)
    ev = rate_events(true, clock, t0_ev, t0_ev + int(duration_s * 1e6), rng, gain=gain)
    return write_scene(Path(folder), traj, ev, prior_offset_us), clock


# ---------------------------------------------------------------------------- rate-level accuracy
@pytest.fixture(scope="module")
def rate20(tmp_path_factory):
    """Three 20 s rate-level scenes (skews -640, +150, +870 ppm), ~330 k events/s like a DAVIS346
    at 0.5 m/s."""
    base = tmp_path_factory.mktemp("sync")
    return [make_rate_scene(base / f"rate20_{i}", 20.0, off, skew, seed=seed, gain=25.0)
            for i, (off, skew, seed) in enumerate([(-73_200, 150.0, 11), (33_900, -640.0, 12), (-12_000, 870.0, 13)])]


def test_offset_and_skew_on_ideal_rate(rate20):
    off_err, skew_err = [], []
    for folder, truth in rate20:
        with _Open(folder) as scene:
            res = sync_scene(scene, kind="speed")
        assert res.reliable, res.reason
        assert res.skew_ppm is not None, res.notes
        off_err.append(abs(res.offset_us - truth.offset_us))
        skew_err.append(abs(res.skew_ppm - truth.skew_ppm))
        assert 0.5 < res.confidence <= 1.0
        # the curve is for the GUI: lags are total offsets, NaN only where the overlap is too small
        assert res.lags_us.shape == res.correlation.shape
        i_best = int(np.nanargmax(res.correlation))
        assert abs(res.lags_us[i_best] - res.offset_us) < 3 * abs(truth.skew_ppm) * 1e-6 * 20e6 + 2000
        assert sum(s.used for s in res.segments) >= 4
        assert max(off_err[-1], skew_err[-1] * 10) < 400, (off_err, skew_err, res.notes)
    assert np.median(off_err) < 200, off_err
    assert np.median(skew_err) < 10, skew_err


def test_offset_std_is_calibrated_and_shrinks_with_the_event_count(tmp_path):
    """``offset_std_data_us`` (curvature of the likelihood) against the spread of the estimates over
    seeds: the same trajectories at two event rates 25x apart; the standard error must track the
    actual error (RMS of error / sigma near 1) and grow as the events thin out. These rate-level scenes have no
    model error: the printed ``offset_std_us`` adds the model-error floor in quadrature (issue 23.2)."""
    from evpose.core.align.uncertainty import RATE_OFFSET_FLOOR_US

    ratios, sig = [], {}
    for gain in (0.4, 10.0):
        for seed in range(6):
            folder, truth = make_rate_scene(tmp_path / f"g{gain}_{seed}", 5.0, -40_000 + 9_000 * seed, 0.0,
                                            seed=100 + seed, gain=gain)
            with _Open(folder) as scene:
                res = sync_scene(scene, kind="speed")
            assert res.reliable, res.reason
            std = res.offset_std_data_us
            assert std is not None and 0 < std < math.inf
            assert res.offset_std_us == pytest.approx(math.hypot(std, RATE_OFFSET_FLOOR_US))
            sig.setdefault(gain, []).append(std)
            ratios.append((res.offset_us - truth.offset_us) / std)
            assert res.to_json()["offset_std_us"] == pytest.approx(res.offset_std_us)
            assert res.to_json()["offset_std_data_us"] == pytest.approx(std)
    rms = math.sqrt(np.mean(np.square(ratios)))
    print(f"RMS error / sigma {rms:.2f}; sigma {np.median(sig[10.0]):.0f} / {np.median(sig[0.4]):.0f} us")
    # 1.18 measured; a sigma halved (2.36) or doubled (0.59) falls outside (12 seeds: an honest sigma leaves this
    # band with probability < 1 %)
    assert 0.6 < rms < 2.0, (rms, ratios)
    # at least the 1 / sqrt(25) of pure counting; more, as the fixed noise floor (2.5 events/ms)
    # drowns the slow starts and stops of the sparse rate (measured ~21x)
    scale = np.median(sig[0.4]) / np.median(sig[10.0])
    assert 4.0 < scale < 60, (scale, sig)


def test_loose_offset_is_flagged(tmp_path):
    """Few events: a reliable peak, but the standard error is above a millisecond and a note
    says so; the NCC-only path computes no standard error."""
    folder, truth = make_rate_scene(tmp_path / "sparse", 5.0, 12_000, 0.0, seed=7, gain=0.05)
    with _Open(folder) as scene:
        res = sync_scene(scene, kind="speed")
        ncc = sync_scene(scene, kind="speed", refine="ncc")
    assert res.reliable, res.reason
    assert res.offset_std_us > SLOW_STD_NOTE_US
    assert any("pins the offset only to" in n for n in res.notes), res.notes
    assert ncc.offset_std_us is None and ncc.to_json()["offset_std_us"] is None


def test_joint_skew_accepts_only_a_significant_consistent_skew():
    """A Theil-Sen line too wide to accept alone is checked on the whole sequence's likelihood:
    accepted when the likelihood ratio against the current clock passes and the joint optimum
    stays inside the line's interval."""
    class Quadratic:       # log-likelihood with its optimum at (o_star, s_star)
        def __init__(self, o_star, s_star, sd_o=300.0, sd_s=20.0):
            self.o, self.s, self.sd_o, self.sd_s = o_star, s_star, sd_o, sd_s

        def loglik(self, o, s):
            return -0.5 * ((o - self.o) / self.sd_o) ** 2 - 0.5 * ((s - self.s) / self.sd_s) ** 2

    line = (-140.0, -14_500.0, 150.0)                     # slope ppm, offset us, half CI ppm
    o, s, lr = joint_skew(Quadratic(-15_000.0, -150.0), -16_000.0, 0.0, line, 1000, 1500.0)
    assert o == pytest.approx(-15_000, abs=5) and s == pytest.approx(-150, abs=0.5) and lr > 50
    # weak: the prior skew is only ~1.5 sigma worse (LR ~2)
    assert joint_skew(Quadratic(-15_000.0, -30.0), -15_000.0, 0.0, line, 1000, 1500.0) is None
    # the joint optimum far outside the line's interval: not the skew the segments saw
    assert joint_skew(Quadratic(-15_000.0, 400.0), -15_000.0, 0.0, line, 1000, 1500.0) is None


def test_likelihood_std_follows_the_envelope_not_the_ripple():
    """A quadratic log-likelihood (sigma 3 ms) with a 4 ms ripple of 3 log units: the standard
    error is the envelope's, not the ripple's sharp local curvature; flat or upward: inf."""
    x = np.arange(-30_000, 30_001, 250.0)
    env = -0.5 * (x / 3000.0) ** 2
    ripple = 1.5 * np.cos(2 * np.pi * x / 4000.0)
    std = likelihood_std_us(x, env + ripple, 0.0, 1000)
    assert 2400 < std < 3600, std
    assert likelihood_std_us(x, env, 0.0, 1000) == pytest.approx(3000, rel=1e-6)
    assert likelihood_std_us(x, np.zeros_like(x), 0.0, 1000) == math.inf
    assert likelihood_std_us(x, +1e-9 * x**2, 0.0, 1000) == math.inf


class _Open:
    """``with _Open(folder) as scene``: a scene closed afterwards."""

    def __init__(self, folder):
        self.scene = Scene.open(folder)

    def __enter__(self):
        return self.scene

    def __exit__(self, *exc):
        self.scene.close()


@pytest.mark.parametrize("skew", [1000.0, -1000.0])
def test_extreme_skew(tmp_path, skew):
    folder, truth = make_rate_scene(tmp_path / "s", 20.0, 25_000, skew, seed=5, gain=25.0)
    with _Open(folder) as scene:
        res = sync_scene(scene, kind="speed")
    assert res.reliable, res.reason
    assert abs(res.skew_ppm - skew) < 25          # median over seeds ~6 ppm (bench/accuracy.py)
    assert abs(res.offset_us - truth.offset_us) < 400


def test_no_skew_estimate_on_short_sequences(tmp_path):
    folder, truth = make_rate_scene(tmp_path / "s", 3.0, 41_000, 0.0, seed=2)
    with _Open(folder) as scene:
        res = sync_scene(scene, kind="speed")
        corr = clock_correction(scene, res)
    assert res.reliable and res.skew_ppm is None
    assert abs(res.offset_us - truth.offset_us) < 500
    assert corr == (res.offset_us, 0.0)
    assert any("skew not estimated" in n for n in res.notes)


def test_offset_at_the_edge_of_the_search_range(tmp_path):
    # 480 ms away from the prior: inside the default ±500 ms, found
    folder, truth = make_rate_scene(tmp_path / "in", 4.0, 480_000, 0.0, seed=3, margin_s=1.5)
    with _Open(folder) as scene:
        res = sync_scene(scene, kind="speed")
    assert res.reliable, res.reason
    assert abs(res.offset_us - truth.offset_us) < max(500, 3 * res.offset_std_data_us)
    # 560 ms away: outside the range -> no guess, the reason says so
    folder, truth = make_rate_scene(tmp_path / "out", 4.0, 560_000, 0.0, seed=3, margin_s=1.5)
    with _Open(folder) as scene:
        res = sync_scene(scene, kind="speed")
        wide = sync_scene(scene, kind="speed", range_ms=700)
    assert not res.reliable and res.offset_us is None
    assert "range" in res.reason
    assert wide.reliable and abs(wide.offset_us - truth.offset_us) < max(500, 3 * wide.offset_std_data_us)


# ---------------------------------------------------------------------------- no reliable estimate
def test_static_camera(tmp_path):
    rng = np.random.default_rng(0)
    t = T0_POSE + np.arange(0, 6_000_000, 4000, dtype=np.int64)
    traj = Trajectory(t, np.zeros((len(t), 3)), np.tile([0, 0, 0, 1.0], (len(t), 1)))
    ev = rate_events(traj, ClockModel(0, 0, T0_POSE + 1_000_000), T0_POSE + 1_000_000, T0_POSE + 5_000_000, rng)
    folder = write_scene(tmp_path / "static", traj, ev)
    with _Open(folder) as scene:
        res = sync_scene(scene)
        base = sync_minima_baseline(scene)
    assert not res.reliable and res.offset_us is None and res.skew_ppm is None
    assert "static" in res.reason
    assert res.confidence == 0.0
    assert not base.reliable


def test_periodic_motion_is_ambiguous(tmp_path):
    rng = np.random.default_rng(1)
    t_s = np.arange(0, 8.0, 0.004)
    P = np.zeros((len(t_s), 3))
    P[:, 0] = 0.05 * np.sin(2 * np.pi * t_s / 0.36)      # period 360 ms: speed repeats every 180 ms
    traj = Trajectory(T0_POSE + np.rint(t_s * 1e6).astype(np.int64), P, np.tile([1.0, 0, 0, 0], (len(t_s), 1)))
    clock = ClockModel(-37_000, 0.0, T0_POSE + 1_500_000)
    ev = rate_events(traj, clock, clock.t_ref_us, clock.t_ref_us + 5_000_000, rng)
    folder = write_scene(tmp_path / "periodic", traj, ev)
    with _Open(folder) as scene:
        res = sync_scene(scene)
    assert not res.reliable and res.offset_us is None
    assert "ambiguous" in res.reason or "periodic" in res.reason
    assert len(res.correlation) > 0   # the curve is still returned for display


def test_empty_single_event_constant_rate_and_short(tmp_path):
    rng = np.random.default_rng(2)
    traj = stop_go_trajectory(5.0, rng)
    t_ref = T0_POSE + 1_000_000
    cases = {
        "empty": None,
        "single": EventArray([3], [4], [t_ref], [1]),
        # exactly 5 events in every ms for 3 s
        "constant": EventArray(np.zeros(15000, np.uint16), np.zeros(15000, np.uint16),
                               t_ref + np.repeat(np.arange(3000) * 1000, 5) + np.tile(np.arange(5) * 100, 3000),
                               np.zeros(15000, np.uint8)),
        "short": rate_events(traj, ClockModel(0, 0, t_ref), t_ref, t_ref + 150_000, rng),
    }
    expect = {"empty": "no events", "single": "too short", "constant": "constant", "short": "too short"}
    for name, ev in cases.items():
        folder = write_scene(tmp_path / name, traj, ev)
        with _Open(folder) as scene:
            res = sync_scene(scene)
            base = sync_minima_baseline(scene)
        assert not res.reliable and res.offset_us is None, name
        assert expect[name] in res.reason, (name, res.reason)
        assert not base.reliable, name
        json.dumps(res.to_json(curve=True))   # serialisable, NaN mapped to null


def test_estimate_clock_rejects_bad_arguments():
    proxy = MotionProxy(0, np.array([0.0, 1e6]), np.array([1.0]))
    with pytest.raises(ValueError):
        estimate_clock([0, 1000], [1], 1000, proxy, ClockModel())
    with pytest.raises(ValueError):
        estimate_clock([0], [1], 0, proxy, ClockModel())


def test_180_degree_turn_between_samples():
    t = T0_POSE + np.array([0, 4000, 8000, 12000, 16000], np.int64)
    q = Rotation.from_euler("z", np.array([0, 0, 180, 0, 90.0])[:, None], degrees=True).as_quat()
    traj = Trajectory(t, np.zeros((5, 3)), q)
    rays = np.array([[0.0, 0.0], [0.3, -0.2]])
    raw = motion_proxy(traj, FX, rays_xy=rays, smooth=False)
    assert np.all(np.isfinite(raw.value))
    w = np.pi / 4e-3   # 180 degrees in 4 ms: the relative rotation's angle is pi, never NaN
    assert 0 < raw.value[1] < 2 * FX * w
    speed = motion_proxy(traj, FX, kind="speed", smooth=False)
    assert speed.value[1] == pytest.approx(FX * w)
    # the smoothed curve (default) runs linearly through the interval means at the midpoints:
    # on interval 1, between its neighbours' means, and within 125 us of slope of its own mean
    proxy = motion_proxy(traj, FX, rays_xy=rays)
    assert np.all(np.isfinite(proxy.value)) and len(proxy.value) == 4 * 16
    sub = proxy.value[16:32]
    assert raw.value[:3].min() - 1e-9 <= sub.min() and sub.max() <= raw.value[:3].max() + 1e-9
    assert sub[7] == pytest.approx(raw.value[1] - (raw.value[1] - raw.value[0]) * 125 / 4000, rel=1e-9)
    m, ok = proxy.mean_over(np.array([0.0, 2000.0]), np.array([16000.0, 20000.0]))
    assert ok.tolist() == [True, False] and np.isfinite(m).all()


def test_masked_ncc_matches_direct_computation():
    rng = np.random.default_rng(4)
    a = rng.normal(size=50)
    b = rng.normal(size=70)
    ma = rng.random(50) > 0.1
    mb = rng.random(70) > 0.2
    ncc, n = _masked_ncc(a, ma, b, mb, 5)
    for j in range(21):
        m = ma & mb[j:j + 50]
        x, y = a[m], b[j:j + 50][m]
        ref = np.corrcoef(x, y)[0, 1]
        assert ncc[j] == pytest.approx(ref, abs=1e-9)
        assert n[j] == m.sum()


# ---------------------------------------------------------------------------- rendered scene + baseline + CLI
@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A low-resolution (87x65) rendered scene: for synchronisation only the event rate matters."""
    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    cam = CameraModel.davis346()
    s = 87 / 346
    K = cam.K.copy()
    K[:2] *= s
    K[0, 2] = (cam.K[0, 2] + 0.5) * s - 0.5
    K[1, 2] = (cam.K[1, 2] + 0.5) * s - 0.5
    out = tmp_path_factory.mktemp("sync") / "rendered"
    # -116.5 ms: the largest shift of the published E-POSE table (block, r_01_gl)
    generate(out, SynthConfig(objects=("box", "flatbox"), trajectory="B", speed_mps=0.5, duration_s=5.0,
                              offset_us=-116_500, seed=4, max_px_per_frame=2,
                              camera={"width": 87, "height": 65, "K": K.tolist(), "dist": cam.dist.tolist()}))
    return out


def test_rendered_scene_offset_and_baseline(rendered):
    from evpose.core.sim.synth import load_ground_truth

    true_off = load_ground_truth(rendered)["clock"]["offset_us"]
    with _Open(rendered) as scene:
        res = sync_scene(scene)
        base = sync_minima_baseline(scene)
    assert res.reliable, res.reason
    # the simulated event rate lags the image motion by ~1 ms (see docs/sync.md, Accuracy)
    assert abs(res.offset_us - true_off) < 3000
    assert res.skew_ppm is None        # 5 s: too short for a skew
    assert base.method == "minima-baseline"
    if base.reliable:
        assert abs(base.offset_us - true_off) > abs(res.offset_us - true_off)


def test_apply_through_history_and_undo(rendered, tmp_path):
    folder = tmp_path / "scene"
    shutil.copytree(rendered, folder)
    with _Open(folder) as scene:
        res = sync_scene(scene)
        h = History(scene.corrections)
        assert apply_sync(h, scene, res)
        assert scene.clock.offset_us == res.offset_us
        assert len(h) == 1 and h.undo_text == "clock sync"
        h.undo()
        assert scene.clock.offset_us == scene.manifest.clock_offset_us
        bad = SyncResult(None, None, 0.0, False, "static", np.zeros(0), np.zeros(0))
        assert not apply_sync(h, scene, bad) and len(h) == 1 and h.index == 0


def _cli(argv) -> tuple[int, str]:
    from evpose.app.cli.align import add_align_parsers

    p = argparse.ArgumentParser(prog="evpose")
    add_align_parsers(p.add_subparsers(dest="command", required=True))
    args = p.parse_args(argv)
    buf = io.StringIO()
    with redirect_stdout(buf):
        rc = args.func(args)
    return rc, buf.getvalue()


def test_cli_sync_json_apply_baseline(rendered, tmp_path):
    folder = tmp_path / "scene"
    shutil.copytree(rendered, folder)
    rc, out = _cli(["sync", str(folder), "--json", "--apply", "--baseline", "--range-ms", "400"])
    assert rc == 0
    data = json.loads(out)       # exactly one JSON document
    for key in ("offset_us", "skew_ppm", "confidence", "reliable", "runtime_s", "baseline", "correction"):
        assert key in data
    assert data["reliable"] and data["applied"]
    with _Open(folder) as scene:
        assert scene.corrections.offset_us == data["correction"]["offset_us"]
        assert scene.clock.offset_us == data["offset_us"]
    rc, text = _cli(["sync", str(folder)])
    assert rc == 0 and "offset" in text
    assert math.isfinite(data["confidence"])


# ---------------------------------------------------------------------------- second stage: edges
# (the edge stage itself, the clock fitted jointly with the poses, is tested in tests/core/test_joint.py)
def test_edge_stage_search_range_follows_the_rate_uncertainty(rendered):
    from evpose.core.align import sync_edges

    with _Open(rendered) as scene:
        res = sync_scene(scene)
    unreliable = SyncResult(None, None, 0.0, False, "static", np.zeros(0), np.zeros(0))
    assert sync_edges.sync_edge_half_range_us(res) == pytest.approx(
        np.clip(4 * res.offset_std_us, sync_edges.SYNC_EDGE_MIN_RANGE_US, sync_edges.SYNC_EDGE_MAX_RANGE_US))
    assert sync_edges.sync_edge_half_range_us(unreliable) == sync_edges.SYNC_EDGE_MAX_RANGE_US
