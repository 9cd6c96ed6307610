"""Clock sync of long recordings (tracker issue 23.7b): hours of events and ±1000 ppm of skew, in bounded time
and memory, and a reason that says what happened when there is no estimate.

Before, every stage read the motion proxy over every 1 ms bin of the whole recording, hundreds of times, and the
proxy held 16 pieces per pose interval: a 3-minute recording took 75 s, a 1-hour one more than 35 minutes and
1.4 GB, 3 hours at 250 Hz poses held 4.8 GB for the proxy alone. Now a recording of more than ``LONG_BINS`` bins
runs coarse-to-fine in time (``estimate_long``): the whole recording at ``COARSE_BINS`` coarse bins at most,
then ``FINE_WINDOWS`` windows at 1 ms; when the whole recording does not correlate at the prior's skew, a search
over the skew first.

The recordings here are 10-minute rate-only scenes (``write_long_rate_scene``): a camera translating through
minimum-jerk moves and stops, and a sparse event stream whose rate follows its speed at the pose time of each
1 ms bin (the clock under test), no rendering. They take the same path as hours do; what keeps that bounded is
checked on what the sync reads (never the fine counts of the whole recording, at most ``COARSE_BINS`` coarse
bins and the windows' fine bins) and on the size of the proxy (one piece per pose interval beyond 2**20). Both
passes run on fewer bins than in production (``use_test_passes``) to keep the tests fast;
``bench/bench_long_sync.py`` measures 1 and 3 hours with the real settings.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import evpose.core.align.estimate as estimate_module
from evpose.core.align import proxy as proxy_module
from evpose.core.align.estimate import LONG_BINS, estimate_clock, sync_scene
from evpose.core.align.proxy import motion_proxy
from evpose.core.align.rate_refine import _window_line, fine_windows
from evpose.core.align.rate_series import BinnedCounts, StoreCounts
from evpose.core.align.sync_result import ClockEstimate, SegmentOffset, unreliable
from evpose.core.data.camera import CameraModel
from evpose.core.data.clock import ClockModel
from evpose.core.data.event_store import EventStore
from evpose.core.data.event_writer import EventWriter
from evpose.core.data.manifest import SceneManifest
from evpose.core.data.scene import Scene
from evpose.core.data.trajectory import Trajectory

T0_POSE = 1_700_000_000_000_000          # epoch pose clock
FX = 60.0
DEPTH_M = 0.5
DURATION_S = 600.0
#: The passes of the tests: 20,000 coarse bins (30 ms for 10 minutes) and 6 fine windows of 5 s (production: at most
#: COARSE_BINS, 32,000; FINE_WINDOWS x FINE_WINDOW_US, 12 of 10 s).
TEST_COARSE_BINS, TEST_WINDOWS, TEST_WINDOW_US = 20_000, 6, 5_000_000
#: The prior skew of the tests' scene, 20 ppm off the truth: the whole recording still correlates (12 ms of drift),
#: but a segment's parabolic peak on the coarse lags leans towards the lag grid, which follows the start skew (the
#: skew found was 0.7 ppm off, 0.4 ms over the recording), unless refined by the NCC (``COARSE_REFINE``).
PRIOR_SKEW_PPM = 1020.0
#: Moves of the tests' scene (see :func:`long_scene`).
BRISK = dict(move_s=(0.1, 0.3), stop_s=(0.05, 0.3), dist_m=(0.02, 0.05))


class MinJerkMoves:
    """A camera looking down, translating through random minimum-jerk moves (``move_s``, default 0.3-1 s;
    ``dist_m``, 5-15 cm) separated by stops (``stop_s``, 0.1-0.5 s), from ``t = 0`` (s) on; :meth:`at` gives
    position (m) and speed (m/s) at any times."""

    def __init__(self, duration_s: float, rng, move_s=(0.3, 1.0), stop_s=(0.1, 0.5), dist_m=(0.05, 0.15)):
        n = int(duration_s / (move_s[0] + stop_s[0])) + 10
        self.T = rng.uniform(*move_s, n)
        self.start = np.concatenate([[0.0], np.cumsum(self.T + rng.uniform(*stop_s, n))[:-1]])
        d = rng.normal(size=(n, 3))
        d[:, 2] *= 0.3
        self.d = d * (rng.uniform(*dist_m, n) / np.linalg.norm(d, axis=1))[:, None]
        self.p0 = np.concatenate([np.zeros((1, 3)), np.cumsum(self.d, axis=0)[:-1]])

    def at(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = np.clip(np.searchsorted(self.start, t_s, side="right") - 1, 0, len(self.T) - 1)
        tau = np.clip((t_s - self.start[k]) / self.T[k], 0.0, 1.0)
        s = tau ** 3 * (10 - 15 * tau + 6 * tau ** 2)
        ds = 30 * tau ** 2 * (1 - tau) ** 2 / self.T[k]
        return self.p0[k] + s[:, None] * self.d[k], np.linalg.norm(self.d[k], axis=1) * ds


def write_long_rate_scene(folder, duration_s: float, offset_us: int, skew_ppm: float, *, seed: int = 0,
                          pose_hz: float = 50.0, gain: float = 0.3, noise_per_ms: float = 0.5,
                          pose_cover: float = 1.0, margin_s: float = 2.0,
                          prior_skew_ppm: float | None = None, moves: dict | None = None) -> ClockModel:
    """A rate-only scene of ``duration_s`` of events whose true clock is ``(offset_us, skew_ppm)``, also the
    scene's prior (with the skew ``prior_skew_ppm`` if given); returns the true clock.

    Events per 1 ms bin: Poisson with mean ``gain * fx * speed / depth`` (speed in m/s at the bin's pose time, so
    ~10 per ms at 0.3 m/s) plus ``noise_per_ms``, written in 10-minute blocks. Poses at ``pose_hz`` cover the
    events' pose times (skew included) with ``margin_s`` either side, or only the first ``pose_cover`` share of
    them. ``moves``: keyword arguments of :class:`MinJerkMoves`."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    pose_span_s = duration_s * (1 + skew_ppm * 1e-6)
    moves = MinJerkMoves(pose_span_s + 2 * margin_s, rng, **(moves or {}))
    tp = np.arange(0.0, pose_cover * pose_span_s + 2 * margin_s, 1.0 / pose_hz)
    down = Rotation.from_matrix(np.diag([1.0, -1.0, -1.0])).as_quat()
    Trajectory(T0_POSE + np.rint(tp * 1e6).astype(np.int64), moves.at(tp)[0],
               np.tile(down, (len(tp), 1))).save_csv(folder / "trajectory.csv")
    t0_ev = T0_POSE + int(margin_s * 1e6) - int(offset_us)
    clock = ClockModel(int(offset_us), float(skew_ppm), t0_ev)
    n_bins = int(round(duration_s * 1000))
    with EventWriter(folder / "events.h5") as w:
        for b0 in range(0, n_bins, 600_000):
            bins = t0_ev + 1000 * np.arange(b0, min(n_bins, b0 + 600_000), dtype=np.int64)
            _, v = moves.at((clock.pose_time(bins + 500) - T0_POSE) * 1e-6)
            n = rng.poisson(gain * FX * v / DEPTH_M + noise_per_ms)
            t = np.sort(np.repeat(bins, n) + rng.integers(0, 1000, int(n.sum())))
            w.append(rng.integers(0, 64, len(t), dtype=np.uint16), rng.integers(0, 48, len(t), dtype=np.uint16), t,
                     rng.integers(0, 2, len(t), dtype=np.uint8))
    cam = CameraModel([[FX, 0, 31.5], [0, FX, 23.5], [0, 0, 1]], [], 64, 48)
    SceneManifest(folder / "scene.toml", folder.name, cam, folder / "events.h5", folder / "trajectory.csv", "cam",
                  None, int(offset_us), float(skew_ppm if prior_skew_ppm is None else prior_skew_ppm), []).save()
    return clock


def expected_offset_us(truth: ClockModel, t_ref_us: int) -> float:
    """The true clock's offset at ``t_ref_us`` (the scene's prior refers to its first event)."""
    return truth.offset_us + truth.skew_ppm * 1e-6 * (t_ref_us - truth.t_ref_us)


def data_std_us(res) -> float:
    """The offset's standard error from the data alone (``sync_scene`` adds a model-error floor measured on other
    scenes to ``offset_std_us``; the windows' scatter is what these scenes can check)."""
    std = getattr(res, "offset_std_data_us", None)
    return res.offset_std_us if std is None else std


def use_test_passes(mp) -> None:
    """The tests' coarse bins and fine windows (:data:`TEST_COARSE_BINS`, ...) on the MonkeyPatch ``mp``."""
    mp.setattr(estimate_module, "COARSE_BINS", TEST_COARSE_BINS)
    mp.setattr(estimate_module, "FINE_WINDOWS", TEST_WINDOWS)
    mp.setattr(estimate_module, "FINE_WINDOW_US", TEST_WINDOW_US)


@pytest.fixture
def test_passes(monkeypatch):
    use_test_passes(monkeypatch)


@pytest.fixture(scope="module")
def long_scene(tmp_path_factory):
    """Ten minutes of events at +1000 ppm (0.6 s of drift), offset -45 ms; the prior has the offset and a skew
    20 ppm off (:data:`PRIOR_SKEW_PPM`). Short, brisk moves and poses at 100 Hz: the rate pins each 5 s window's
    offset to ~0.6 ms (~2 ms with the default moves)."""
    folder = tmp_path_factory.mktemp("long") / "ten_minutes"
    return folder, write_long_rate_scene(folder, DURATION_S, -45_000, 1000.0, seed=4, pose_hz=100.0, moves=BRISK,
                                         prior_skew_ppm=PRIOR_SKEW_PPM)


@pytest.fixture(scope="module")
def long_sync(long_scene):
    """``sync_scene`` of :func:`long_scene` with the tests' passes, and what it read: ``(result, reads)`` with
    ``reads`` the (kind, bin_us, bins) of every count read. (Its memory is measured by the bench: tracing it here
    tripled the sync's time. What grows with the length is the proxy, bounded per pose below, and the coarse
    series, bounded by COARSE_BINS; the fine counts of the whole recording are never read.)"""
    folder, _ = long_scene
    reads = []
    with pytest.MonkeyPatch.context() as mp:
        use_test_passes(mp)
        coarse, window = StoreCounts.coarse, StoreCounts.window

        def spy_coarse(self, factor):
            out = coarse(self, factor)
            reads.append(("coarse", self.bin_us * factor, len(out[1])))
            return out

        def spy_window(self, t0_us, n_bins):
            out = window(self, t0_us, n_bins)
            reads.append(("window", self.bin_us, len(out[1])))
            return out

        def no_rate(self, bin_us=1000):
            raise AssertionError("the long path read the fine counts of the whole recording")

        mp.setattr(StoreCounts, "coarse", spy_coarse)
        mp.setattr(StoreCounts, "window", spy_window)
        mp.setattr(EventStore, "rate", no_rate)
        with Scene.open(folder) as scene:
            scene.trajectory, scene.events.n_events
            t = time.perf_counter()
            res = sync_scene(scene, kind="speed")
            dt = time.perf_counter() - t
    print(f"\n10 min, +1000 ppm (prior {PRIOR_SKEW_PPM:+.0f}): sync {dt:.1f} s\n  " + "\n  ".join(res.notes))
    return res, reads


def test_long_recording_runs_coarse_to_fine_on_bounded_reads(long_scene, long_sync):
    folder, truth = long_scene
    res, reads = long_sync
    assert res.reliable, res.reason
    err = res.offset_us - expected_offset_us(truth, res.t_ref_us)
    print(f"offset error {err:+.0f} us (std {data_std_us(res):.0f} from the data), skew error "
          f"{res.skew_ppm - truth.skew_ppm:+.2f} ppm")
    # ~0.6 ms a window, 0.25 ms for six (a wrong window time or skew would be off by up to 0.6 s)
    assert 0 < data_std_us(res) < 600 and abs(err) <= 3 * data_std_us(res) + 200
    assert abs(res.skew_ppm - truth.skew_ppm) < 0.15                # 0.09 ms over the recording
    assert res.prior_skew_ppm == PRIOR_SKEW_PPM and not any(n.startswith("skew search") for n in res.notes)
    assert res.notes[0].startswith("long recording (0.17 h): the whole of it at 30 ms bins")
    assert any(n.startswith("fine: skew of the") for n in res.notes)
    # what it read: the whole recording once at the coarse bin, then the windows at 1 ms; nothing else
    n_bins = int(DURATION_S * 1000)
    kinds = [r[0] for r in reads]
    assert kinds == ["coarse"] + ["window"] * TEST_WINDOWS
    assert reads[0][1] == 1000 * int(np.ceil(n_bins / TEST_COARSE_BINS))
    assert reads[0][2] <= TEST_COARSE_BINS + 1
    assert all(r[1] == 1000 and r[2] == TEST_WINDOW_US // 1000 for r in reads[1:])
    # the windows, one offset each (the robust line may drop one), spread over the recording
    assert len(res.segments) == TEST_WINDOWS and all(s.used for s in res.segments)
    t_c = [s.t_center_us for s in res.segments]
    assert t_c[-1] - t_c[0] > 0.9 * DURATION_S * 1e6


def test_long_arrays_take_the_same_path(long_scene, monkeypatch):
    """``estimate_clock`` on the counts of a long recording goes coarse-to-fine too, with ``sync_scene``'s
    settings and the same bins (BinnedCounts of the array, StoreCounts of the store: equal, see below)."""
    folder, _ = long_scene
    calls = []

    def record(source, proxy, prior, **kw):
        calls.append((source, prior, {k: v for k, v in kw.items() if k not in ("t_start", "progress", "cancel")}))
        return unreliable("estimate_long", time.perf_counter(), prior)

    monkeypatch.setattr(estimate_module, "estimate_long", record)
    monkeypatch.setattr(estimate_module, "_rate_stages", lambda *a, **kw: unreliable("direct", 0.0, a[4]))
    with Scene.open(folder) as scene:
        from evpose.core.align.scene_proxy import scene_motion_proxy

        proxy = scene_motion_proxy(scene, kind="speed")
        starts, counts = scene.events.rate(1000)
        assert len(counts) - 2 > LONG_BINS
        assert estimate_clock(starts, counts, 1000, proxy, scene.clock, max_skew_ppm=1200.0).reason == "estimate_long"
        assert sync_scene(scene, kind="speed", max_skew_ppm=1200.0).reason == "estimate_long"
        # LONG_BINS whole bins (and the partial first and last) are still estimated directly
        res = estimate_clock(starts[:LONG_BINS + 2], counts[:LONG_BINS + 2], 1000, proxy, scene.clock)
    assert len(calls) == 2 and res.reason == "direct"
    (a, prior_a, kw_a), (b, prior_b, kw_b) = calls
    assert isinstance(a, BinnedCounts) and isinstance(b, StoreCounts)
    assert (a.span_us, a.n_bins, a.bin_us) == (b.span_us, b.n_bins, b.bin_us) and prior_a == prior_b
    assert kw_a == kw_b and kw_a["max_skew_ppm"] == 1200.0 and kw_a["range_us"] == 500_000
    assert kw_a["refine"] == "ml" and kw_a["estimate_skew"] == "auto"


def view_of(folder: Path, events_of: Path, *, prior_skew_ppm: float, trajectory: Trajectory | None = None) -> Path:
    """A scene in ``folder`` with the events (and trajectory, unless given) of the scene ``events_of`` and the
    prior skew ``prior_skew_ppm``."""
    folder.mkdir(parents=True)
    traj_path = events_of / "trajectory.csv"
    if trajectory is not None:
        traj_path = folder / "trajectory.csv"
        trajectory.save_csv(traj_path)
    with Scene.open(events_of) as scene:
        src = scene.manifest
    SceneManifest(folder / "scene.toml", folder.name, src.camera, events_of / "events.h5", traj_path, "cam", None,
                  int(src.clock_offset_us), float(prior_skew_ppm), []).save()
    return folder


def test_wrong_prior_skew_is_found_by_a_skew_search(long_scene, tmp_path, test_passes, monkeypatch):
    """True +1000 ppm, prior -500 ppm: 0.9 s of drift over the recording, so it does not correlate at the prior's
    skew; a search over the skew finds it and says so. (Coarse bins of 60 ms here, 29 skews; in production 32,000
    bins, 31 ppm steps.)"""
    monkeypatch.setattr(estimate_module, "COARSE_BINS", 10_000)
    folder, truth = long_scene
    with Scene.open(view_of(tmp_path / "wrong_prior", folder, prior_skew_ppm=-500.0)) as scene:
        res = sync_scene(scene, kind="speed", refine="ncc")        # the windows by NCC: quicker than the likelihood
    print("\n  " + "\n  ".join(res.notes))
    assert res.reliable, res.reason
    assert res.notes[1].startswith("skew search: at the prior skew -500.0 ppm the whole recording does not "
                                   "correlate"), res.notes
    assert "over 29 skews within ±1500 ppm (100.0 ppm steps), the best is +1000 ppm" in res.notes[1]
    assert abs(res.skew_ppm - truth.skew_ppm) < 2.0                 # 1.2 ms over the recording
    # the windows' NCC peaks lean ~0.4 ms on this scene (the likelihood's do not: see the first test)
    assert abs(res.offset_us - expected_offset_us(truth, res.t_ref_us)) < 1000
    assert res.prior_skew_ppm == -500.0


def test_too_little_overlap_is_said_with_the_skew(long_scene, tmp_path, monkeypatch):
    """The trajectory covers the first 40 % of the events (at +1000 ppm): no correlation at any skew, and the
    reason says how much it covers and where the events land on it, skew included (it said "does not overlap")."""
    monkeypatch.setattr(estimate_module, "COARSE_BINS", 10_000)
    folder, truth = long_scene
    with Scene.open(folder) as scene:
        traj = scene.trajectory
        keep = traj.t_us <= traj.t_us[0] + 2_000_000 + 0.4 * DURATION_S * 1e6
        cut = Trajectory(traj.t_us[keep], traj.positions_m[keep], traj.quats_xyzw[keep])
    with Scene.open(view_of(tmp_path / "short_trajectory", folder, prior_skew_ppm=truth.skew_ppm,
                            trajectory=cut)) as scene:
        res = sync_scene(scene, kind="speed")
    assert not res.reliable
    assert "the trajectory covers" in res.reason and "needs at least half" in res.reason, res.reason
    share = float(res.reason.split("covers ")[1].split(" %")[0])
    assert abs(share - 40.0) < 1.0, res.reason
    lo, hi = (float(x) for x in res.reason.split("map to pose times ")[1].split(" s from")[0].split(" to "))
    # the coarse series (60 ms bins, partial first and last dropped) spans 599.88 s of events: 600.48 s of poses
    # (599.88 without the skew); the message gives both ends to 0.1 s
    assert hi - lo == pytest.approx((DURATION_S - 0.12) * (1 + truth.skew_ppm * 1e-6), abs=0.11)
    assert "no skew within ±1500 ppm makes the whole recording correlate either" in res.reason, res.reason
    assert res.notes[-1].startswith("long recording (0.17 h)") and res.prior_skew_ppm == truth.skew_ppm


def test_store_counts_are_the_rate_binned_on_demand(long_scene):
    folder, _ = long_scene
    with Scene.open(folder) as scene:
        starts, counts = scene.events.rate(1000)
        src = StoreCounts(scene.events, 1000)
        assert src.span_us == (int(starts[1]), int(starts[-1])) and src.n_bins == len(counts) - 2
        i = 234_567
        t0 = int(starts[i])
        ws, wc = src.window(t0, 5000)
        np.testing.assert_array_equal(ws, starts[i:i + 5000])
        np.testing.assert_array_equal(wc, counts[i:i + 5000])
        b = BinnedCounts(starts[1:-1], counts[1:-1], 1000)      # what estimate_clock makes of the same counts
        assert b.span_us == src.span_us and b.n_bins == src.n_bins
        np.testing.assert_array_equal(b.window(t0, 5000)[1], wc)
        for k in (1, 18, 7):
            for got, ref in zip(src.coarse(k), b.coarse(k)):
                np.testing.assert_array_equal(got, ref)
        assert src.coarse(18)[1].sum() == counts[1:-1].sum()
        with pytest.raises(ValueError, match="multiple of 1000"):
            StoreCounts(scene.events, 1500)


def _windows(t_ref_us: int, icpt_us: float, skew_ppm: float, resid_us) -> list[SegmentOffset]:
    """Window offsets 100 s apart (local offsets, as ``segment_offset`` gives them) on the line
    ``icpt_us + skew_ppm * x`` plus ``resid_us``."""
    out = []
    for j, r in enumerate(resid_us):
        tc = t_ref_us + 5_000_000 + j * 100_000_000
        off = icpt_us + skew_ppm * 1e-6 * (tc - t_ref_us) + r
        out.append(SegmentOffset(tc - 5_000_000, tc + 5_000_000, tc, off, 0.9, True))
    return out


def test_window_line_offset_and_its_standard_error():
    """The fine pass's offset at t_ref and its standard error from the windows' scatter (what the rate pins over
    the whole recording): exact on constructed window offsets; a window 20 ms off is dropped and marked."""
    t_ref = 1_700_000_000_000_000
    resid = [600.0, -600.0] * 4 + [20_000.0]
    # the skew in effect (not estimated): offsets at t_ref along it, their mean and scatter
    est = ClockEstimate(-44_000.0, 1000.0, [])
    segs = _windows(t_ref, -45_000.0, 1000.0, resid)
    _window_line(est, segs, t_ref, 1000, None, False, 1500.0)
    assert [g.used for g in segs] == [True] * 8 + [False]
    assert est.offset_us == pytest.approx(-45_000.0, abs=1e-6) and est.skew_ppm == 1000.0
    assert est.offset_std_us == pytest.approx(600.0 / np.sqrt(7), rel=1e-9)     # sqrt(8 a^2 / 7 / 8)
    assert not est.skew_estimated and "skew 1000.00 ppm kept (not estimated)" in est.notes[-1]
    # a coarse segment line better determined than the windows' own: its skew, and its uncertainty in the sigma
    est = ClockEstimate(-44_000.0, 1000.3, [])
    segs = _windows(t_ref, -45_000.0, 1000.0, resid)
    _window_line(est, segs, t_ref, 1000, (1000.0, -45_010.0, 0.05, 16), True, 1500.0)
    assert not segs[-1].used and est.skew_ppm == 1000.0 and est.skew_estimated
    x_mean = np.mean([(g.t_center_us - t_ref) * 1e-6 for g in segs[:8]])
    assert est.offset_us == pytest.approx(-45_000.0, abs=1e-6)
    assert est.offset_std_us == pytest.approx(np.sqrt(600.0 ** 2 * 8 / 7 / 8 + (0.05 / 1.645) ** 2 * x_mean ** 2))
    assert est.notes[-1].startswith("fine: skew of the coarse segments 1000.00 ppm (90% CI ±0.05), offset ±")
    # fewer than 3 windows: no standard error, said so
    est = ClockEstimate(-44_000.0, 1000.0, [])
    _window_line(est, _windows(t_ref, -45_000.0, 1000.0, [100.0, -100.0]), t_ref, 1000, None, False, 1500.0)
    assert est.offset_std_us == np.inf and "no standard error: 2 window offset(s), at least 3 needed" in est.notes[-1]


class _Span:
    """A counts source of ``n`` 1 ms bins from 0 (only what :func:`fine_windows` reads)."""

    def __init__(self, n):
        self.bin_us, self.span_us = 1000, (0, 1000 * n)


def test_fine_windows_spread_over_the_covered_part():
    proxy = motion_proxy(Trajectory(np.array([0, 100_000_000]), np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1))),
                         FX, kind="speed")
    est = ClockEstimate(2_000_000.0, 0.0, [])          # pose = event + 2 s: events 0..98 s lie on the trajectory
    prior = ClockModel(0, 0.0, 0)
    # long enough: 4 windows of 10 s, first and last at the covered part's ends (margin 1 s)
    w = fine_windows(_Span(200_000), proxy, prior, est, 4, 10_000_000, 1_000_000)
    assert w == [(0, 10_000), (29_000_000, 10_000), (58_000_000, 10_000), (87_000_000, 10_000)]
    # shorter than the windows together: cut into 4 consecutive windows
    w = fine_windows(_Span(30_000), proxy, prior, est, 4, 10_000_000, 1_000_000)
    assert w == [(0, 7500), (7_500_000, 7500), (15_000_000, 7500), (22_500_000, 7500)]
    # shorter still (pieces below a tenth of a window): one window; nothing below a tenth
    assert fine_windows(_Span(3_000), proxy, prior, est, 4, 10_000_000, 1_000_000) == [(0, 3000)]
    assert fine_windows(_Span(900), proxy, prior, est, 4, 10_000_000, 1_000_000) == []
    # the clock decides what is covered: at 1000 ppm pose 100 s is event 97.902 s, so the last window ends 0.098 s
    # earlier, at 96.902 s (margin 1 s)
    est.skew_ppm = 1000.0
    w = fine_windows(_Span(200_000), proxy, prior, est, 4, 10_000_000, 1_000_000)
    assert w[0] == (0, 10_000) and w[-1] == (86_902_000, 10_000)


def test_long_proxy_is_exact_piecewise_linear_with_one_piece_per_pose(monkeypatch):
    """5 minutes of poses at 250 Hz: the smoothed proxy holds one piece per pose interval (+1), linear between
    the intervals' midpoints, and its bin means are exact integrals of that curve; sampled on 16 pieces per
    interval (as for short trajectories; 16 x the memory) the bin means differ by < 0.1 % of the top speed."""
    rng = np.random.default_rng(1)
    moves = MinJerkMoves(300.0, rng)
    tp = np.arange(0.0, 300.0, 0.004)
    traj = Trajectory(np.rint(tp * 1e6).astype(np.int64), moves.at(tp)[0], np.tile([0, 0, 0, 1.0], (len(tp), 1)))
    proxy = motion_proxy(traj, FX, kind="speed")
    assert len(proxy.knots_us) == len(tp) + 1
    raw = motion_proxy(traj, FX, kind="speed", smooth=False)
    mids = 0.5 * (raw.knots_us[:-1] + raw.knots_us[1:])
    a = np.sort(rng.uniform(0, raw.knots_us[-1] - 2000, 500))
    b = a + rng.uniform(1, 2000, 500)
    fine = np.linspace(0, 1, 2001)
    quad = [np.trapezoid(np.interp(x0 + (x1 - x0) * fine, mids, raw.value), fine) for x0, x1 in zip(a, b)]
    got, ok = proxy.mean_over(a, b)
    assert ok.all()
    np.testing.assert_allclose(got, quad, rtol=1e-6, atol=1e-6)
    monkeypatch.setattr(proxy_module, "MAX_SAMPLED_PIECES", 10**9)
    sampled = motion_proxy(traj, FX, kind="speed")
    assert len(sampled.knots_us) == 16 * len(tp) - 15
    assert np.abs(sampled.mean_over(a, b)[0] - got).max() < 1e-3 * raw.value.max()
