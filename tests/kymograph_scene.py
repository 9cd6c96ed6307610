"""A synthetic scene for the kymograph and the space-time band (a uniquely named module, like occlusion_scene.py):
three objects, the camera translating (trajectory A) at 2 m/s so that edges sweep the half-resolution image at
about 0.5 px/ms, a clock offset of 20 ms injected and no pose error, so that a clock error is the only thing
that moves the projected edges off the events. Built once per test session (about 4 s).

Also hand-made kymograph inputs with a known lag and no renderer: :func:`edge_events` (one edge moving along a
line, its events binned) and :func:`two_object_span` (label maps of two moving rectangles and the events of
only one of them)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from evpose_testing import half_davis_camera

#: The injected clock offset (µs): the true clock is a correction of this much (the prior is 0).
TRUE_OFFSET_US = 20_000
KYMO_SCENE = dict(objects=("box", "cylinder", "flatbox"), trajectory="A", speed_mps=2.0, duration_s=1.0,
                  offset_us=TRUE_OFFSET_US, skew_ppm=0.0, pose_error_mm=0.0, pose_error_deg=0.0, seed=3)
#: Half-span of the kymograph plus its largest lag (ms): the chosen time keeps this far from the recording's ends.
MARGIN_US = 180_000

_BUILT: dict = {}


def kymograph_scene(tmp_path_factory) -> Path:
    """The scene folder (built on first use in this test session; never modify it)."""
    if "path" not in _BUILT:
        from evpose.core.sim.synth import generate
        from evpose.core.sim.synth_config import SynthConfig

        out = tmp_path_factory.mktemp("kymograph") / "scene"
        generate(out, SynthConfig(**KYMO_SCENE, camera=half_davis_camera()))
        _BUILT["path"] = out
    return _BUILT["path"]


def moves_us(scene_dir: Path, t_first_us: int, t_last_us: int) -> list[tuple[int, int]]:
    """``(length, middle)`` (µs; the middle on the event clock) of every camera move whose middle keeps
    ``MARGIN_US`` from both ends of the recording, the longest first."""
    gt = json.loads((Path(scene_dir) / "ground_truth.json").read_text())
    off = int(gt["clock"]["offset_us"])
    out = [(b - a, (a + b) // 2 - off) for a, b in gt["moving_segments_pose_us"]]    # pose clock -> event clock
    return sorted([m for m in out if t_first_us + MARGIN_US <= m[1] <= t_last_us - MARGIN_US], reverse=True)


def moving_time_us(scene_dir: Path, t_first_us: int, t_last_us: int) -> int:
    """The event-clock time in the middle of the longest camera move that keeps ``MARGIN_US`` from both ends."""
    moves = moves_us(scene_dir, t_first_us, t_last_us)
    assert moves, "no camera move far enough from the recording's ends"
    return int(moves[0][1])


def still_time_us(scene_dir: Path, t_first_us: int, t_last_us: int, span_us: int = 200_000) -> int:
    """An event-clock time in the middle of a pause between camera moves longer than ``span_us`` plus the clock
    offset either way (the camera is still over the whole span, whatever clock is in effect)."""
    gt = json.loads((Path(scene_dir) / "ground_truth.json").read_text())
    off = int(gt["clock"]["offset_us"])
    segs = gt["moving_segments_pose_us"]
    for (_, a), (b, _) in zip(segs[:-1], segs[1:]):
        mid = (a + b) // 2 - off
        if b - a > span_us + 2 * abs(off) and t_first_us + span_us <= mid <= t_last_us - span_us:
            return int(mid)
    raise AssertionError("no pause long enough between the camera moves")


def edge_events(seed: int, speed_px_ms: float, lag_ms: float, rate: float = 1.0, noise: float = 0.02,
                jitter_px: float = 0.5, n_cols: int = 100, moving_ms: tuple = (-np.inf, np.inf),
                twin_px: float | None = None):
    """One edge moving along a line at ``speed_px_ms`` through column 50 at t = 0 (only within ``moving_ms``, still
    before and after), its events ``lag_ms`` later than its track: Poisson ``rate`` events per ms while it moves,
    spread ``jitter_px`` across it, background noise ``noise`` per pixel and ms; ``twin_px``: a second streak as
    strong, that far beside the edge, moving with it (a texture line parallel to the edge). Returns
    ``(LineEvents, track_t_ms, distances, travel_px)`` for ``estimate_lag`` (rows from -180 ms, 1 ms bins; the
    silhouette right of the edge)."""
    from evpose.core.views.kymograph_lag import LineEvents

    def edge(t):
        return 50 + speed_px_ms * np.clip(t, *moving_ms)

    rng = np.random.default_rng(seed)
    n_rows, t_first = 360, -180.0
    t = t_first + np.arange(n_rows) + 0.5
    counts = rng.poisson(noise, (n_rows, n_cols)).astype(np.float64)
    moves = (t - lag_ms >= moving_ms[0]) & (t - lag_ms <= moving_ms[1])
    for shift in (0.0,) if twin_px is None else (0.0, twin_px):
        for i, k in enumerate(rng.poisson(rate, n_rows) * moves):
            c = np.rint(edge(t[i] - lag_ms) + shift + rng.normal(0.0, jitter_px, k)).astype(int)
            np.add.at(counts[i], c[(c >= 0) & (c < n_cols)], 1)
    track_t = np.arange(-100.0, 100.0, 4.0)
    d = np.arange(n_cols)[None, :] - edge(track_t)[:, None]
    return LineEvents(counts, t_first, 1.0), track_t, d, float(np.ptp(edge(track_t)))


def two_object_span(seed: int = 0, dark_lag_ms: float | None = None):
    """A hand-made :class:`~evpose.core.views.kymograph_read.SpanData` (160x120 px, the clock right): object
    0 ("dark") moves right at 0.8 px/ms but is as bright as the background, so makes no events; object 1 ("lit")
    moves down at 0.25 px/ms and its top and bottom edges fire; plus background noise. The fastest-moving
    object, which the default line used to cross, has no evidence at all. ``dark_lag_ms``: the dark object's left
    and right edges fire too, that much later than its track says (as a pose error or a texture line beside
    the edge would make them seem)."""
    from evpose.core.data.events import EventArray
    from evpose.core.views.kymograph_read import BIN_US, SpanData

    rng = np.random.default_rng(seed)
    H, W, tc = 120, 160, 1_000_000
    times = tc + np.arange(-100_000, 100_001, 4_000)

    def boxes(t_us):
        dt_ms = (t_us - tc) / 1e3
        return [(20 + 0.8 * dt_ms, 20.0, 24, 20), (110.0, 50 + 0.25 * dt_ms, 30, 20)]   # (u0, v0, w, h)

    maps = []
    uu, vv = np.meshgrid(np.arange(W), np.arange(H))
    for t in times:
        m = np.full((H, W), -1, np.int8)
        for k, (u0, v0, w, h) in enumerate(boxes(t)):
            m[(uu >= u0) & (uu < u0 + w) & (vv >= v0) & (vv < v0 + h)] = k
        maps.append(m)
    t_ext0 = tc - 180_000
    ev = []                                                     # (x, y, t, p) arrays
    for t in range(t_ext0, tc + 180_000, 250):                  # the edges, every 0.25 ms
        u0, v0, w, h = boxes(t)[1]
        for row, pol in ((v0, 1), (v0 + h, 0)):                 # the lit object's top and bottom
            x = np.nonzero(rng.random(w) < 0.08)[0] + int(u0)
            ev.append((x, np.full(len(x), int(np.rint(row - 0.5))), np.full(len(x), t), np.full(len(x), pol)))
        if dark_lag_ms is not None:
            u0, v0, w, h = boxes(t - dark_lag_ms * 1e3)[0]
            for col, pol in ((u0, 0), (u0 + w, 1)):             # the dark object's left and right
                y = np.nonzero(rng.random(h) < 0.08)[0] + int(v0)
                ev.append((np.full(len(y), int(np.rint(col - 0.5))), y, np.full(len(y), t), np.full(len(y), pol)))
    n_noise = 20_000
    ev.append((rng.integers(0, W, n_noise), rng.integers(0, H, n_noise), rng.integers(t_ext0, tc + 180_000, n_noise),
               rng.integers(0, 2, n_noise)))
    x, y, t, p = (np.concatenate([e[i] for e in ev]) for i in range(4))
    inside = (x >= 0) & (x < W) & (y >= 0) & (y < H)
    x, y, t, p = x[inside], y[inside], t[inside], p[inside]
    order = np.argsort(t, kind="stable")
    return SpanData(EventArray(x[order], y[order], t[order], p[order]), t_ext0, 360_000 // BIN_US, tc, times, maps,
                    ["dark", "lit"], frozenset())


def moving_session(tmp_path_factory):
    """A :class:`~evpose.core.session.model.Session` on :func:`kymograph_scene`, at a time the object moves (close it)."""
    from evpose.core.session.model import Session

    path = kymograph_scene(tmp_path_factory)
    s = Session.open(path)
    s.set_time(moving_time_us(path, *s.time_range))
    return s
