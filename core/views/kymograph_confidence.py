"""How far to trust the kymograph's reading: the 1σ of the lag, or the reason it is too weak to read.

σ has three parts, added in quadrature:

* the spread of the events: the lag's score is a sum over the track times
  (:func:`~evpose.core.views.kymograph_lag.lag_parts`), so the track times are drawn again by a moving-block
  bootstrap (blocks of ``BLOCK`` consecutive times: neighbouring times see overlapping events), the peak is found
  again on each redrawn sum, and this part is the root mean square of those peaks about the reading. A peak that
  stands on a few track times, or that another peak nearly matches, moves between draws. The draws are seeded:
  the same data gives the same σ;
* what is common to all track times, which no redraw can show: the time bins (``FLOOR_MS``), and an offset of the
  events across the edge of ``SYSTEMATIC_PX`` (the silhouette rasterised at pixel centres, the events on the
  pixel grid, a texture streak beside the edge), a lag error of ``SYSTEMATIC_PX / speed`` at the speed the
  events see the edge move along the line (:func:`evidence_speed`).

The constants were chosen on the tuning scenes of ``bench/bench_kymograph.py`` and checked on its validation
scenes (|error| / σ at most 2 in over 90 % of the readings, at most 4 in all).

A reading is *too weak* (no value is shown, the reason is; checked in this order) when the edge crosses the line
too briefly, does not move across it long enough (``MIN_MOVING_TIMES``), has too few events near its track at
the peak (``MIN_NEAR_EVENTS``), when the peak is at the end of the search, when the edge moves so slowly that
the offset across it alone exceeds ``MAX_SIGMA_MS``, when σ does, or when another peak of the edge score,
farther than ``max(RIVAL_MS, 2σ)``, nearly matches the reading's (``MIN_PROMINENCE``): parallel streaks (texture
lines, a face's inner edge) move like the edge, so every track time agrees on the wrong one and no redraw shows
the doubt.
"""
from __future__ import annotations

import numpy as np

from evpose.core.views.kymograph_lag import (
    MOVING_PX_PER_MS,
    LagEstimate,
    TimeParts,
    curves,
    peak_lags,
    refine_window,
)

#: Reasons a reading is too weak to read (shown after "too weak to read: ").
NO_TRACK = "no object edge crosses the line"
FEW_TIMES = "the edge crosses the line too briefly"
NO_MOTION = "no motion across the line"
SLOW = "the edge moves too slowly across the line"
FEW_EVENTS = "too few events near the track"
AT_EDGE = "the peak is at the end of the search"
AMBIGUOUS = "flat or ambiguous lag curve"
RIVAL = "another lag fits nearly as well"
DISAGREE = "lines across the objects disagree"          # the default line only (kymograph_pick)
REASONS = (NO_TRACK, FEW_TIMES, NO_MOTION, SLOW, FEW_EVENTS, AT_EDGE, AMBIGUOUS, RIVAL, DISAGREE)
#: Bootstrap draws and block length (track times).
N_BOOT = 200
BLOCK = 2
#: Errors the bootstrap cannot see, being common to all track times: the time bins' (ms) ...
FLOOR_MS = 0.3
#: ... and an offset of the events across the edge (px), a lag error of ``SYSTEMATIC_PX / speed``.
SYSTEMATIC_PX = 0.5
#: A reading needs this many track times where the edge moves along the line ...
MIN_MOVING_TIMES = 12
#: ... this many events near the track at its lag ...
MIN_NEAR_EVENTS = 40
#: ... a σ of at most this much (ms) ...
MAX_SIGMA_MS = 5.0
#: ... and an edge score at the reading that stands above every rival peak of it farther than ``max(RIVAL_MS, 2σ)``
#: by at least this share of its height above the median (parallel streaks -- texture lines, a face's inner edge --
#: move like the edge: every track time agrees on the wrong one, so the bootstrap cannot see the doubt).
MIN_PROMINENCE = 0.25
RIVAL_MS = 5.0
#: The bootstrap's seed: the same data gives the same σ.
SEED = 23


def block_weights(n: int, n_boot: int, block: int, rng: np.random.Generator) -> np.ndarray:
    """(n, n_boot) how often each of ``n`` items is drawn by a moving-block bootstrap (blocks of ``block``
    consecutive items, as many as cover ``n``)."""
    block = max(1, min(block, n))
    n_blocks = -(-n // block)
    starts = rng.integers(0, n - block + 1, size=(n_blocks, n_boot))
    idx = (starts[:, None, :] + np.arange(block)[None, :, None]).reshape(-1, n_boot)
    w = np.zeros((n, n_boot))
    np.add.at(w, (idx, np.broadcast_to(np.arange(n_boot), idx.shape)), 1.0)
    return w * (n / w.sum(axis=0, keepdims=True))


def bootstrap_sigma(lags: np.ndarray, parts: TimeParts, lag_ms: float, n_boot: int = N_BOOT,
                    block: int = BLOCK) -> float:
    """The root mean square (ms) about ``lag_ms`` of the peaks of ``n_boot`` block-bootstrap redraws of the
    track times (the columns of ``parts``)."""
    w = block_weights(parts.edge.shape[1], n_boot, block, np.random.default_rng(SEED))
    peaks = peak_lags(lags, *curves(parts.edge, parts.region, w), refine_window(parts), parts.bin_ms)
    return float(np.sqrt(np.mean((peaks - lag_ms) ** 2)))


def evidence_speed(parts: TimeParts, j: int) -> float:
    """The edge's speed along the line (px/ms) as the events near the track at lag index ``j`` see it: the
    least-squares ratio ``sum n v^2 / sum n |v|`` over the track times (``n`` events near the crossings, ``v``
    their speed), by which a constant offset across the line turns into a lag error (0 without events)."""
    n, v = np.maximum(parts.near[j], 0.0), np.abs(parts.speed)
    den = float(np.sum(n * v))
    return float(np.sum(n * v * v)) / den if den > 0 else 0.0


def evidence(parts: TimeParts, j: int) -> float:
    """How much a line's tracks tell about the lag: ``sum_i v_i^2 n_i`` over the track times, ``v_i`` the
    crossings' speed (px/ms) and ``n_i`` the events near them at lag index ``j`` beyond the median over all
    lags (noise and texture are near the track at any lag; the edge's own events only at the right one) -- the
    inverse square of the lag's spread, as far as it comes from the events' spread across the edge."""
    excess = parts.near[j] - np.median(parts.near, axis=0)
    return float(np.sum(parts.speed ** 2 * np.maximum(excess, 0.0)))


def prominence(lags_ms: np.ndarray, curve: np.ndarray, lag_ms: float, separation_ms: float) -> float:
    """How far ``curve`` at ``lag_ms`` stands above its best rival: its highest local maximum farther than
    ``separation_ms`` from ``lag_ms`` (the reading's own shoulders are no rivals), as a share of the height at
    ``lag_ms`` above the median (1: no rival; 0: a rival as high or higher)."""
    height, med = float(np.interp(lag_ms, lags_ms, curve)), float(np.median(curve))
    if height <= med:
        return 0.0
    inner = curve[1:-1]
    local = np.zeros(len(curve), bool)
    local[1:-1] = (inner >= curve[:-2]) & (inner >= curve[2:])
    rivals = local & (np.abs(lags_ms - lag_ms) > separation_ms)
    if not rivals.any():
        return 1.0
    return float(np.clip((height - float(curve[rivals].max())) / (height - med), 0.0, 1.0))


def measure(est: LagEstimate) -> LagEstimate:
    """``est`` (its peak, curves and parts set) with its events near the track, the speed they see, its moving
    track times and its evidence."""
    j = int(np.argmin(np.abs(est.lags_ms - est.peak_ms)))
    est.n_near = int(round(float(est.parts.near[j].sum())))
    est.speed = evidence_speed(est.parts, j)
    est.n_moving = float(np.clip(est.parts.speed / MOVING_PX_PER_MS, 0.0, 1.0).sum())
    est.evidence = evidence(est.parts, j)
    return est


def judge(est: LagEstimate) -> LagEstimate:
    """``est`` (measured, :func:`measure`) with its σ and, when too weak, the reason in ``weak`` and no
    ``lag_ms`` (idempotent)."""
    if est.judged or est.parts is None:
        return est
    est.judged = True
    lags, lag = est.lags_ms, est.peak_ms
    if est.n_moving < MIN_MOVING_TIMES:
        est.weak = NO_MOTION
    elif est.n_near < MIN_NEAR_EVENTS:
        est.weak = FEW_EVENTS
    elif abs(lag) >= lags[-1] - (lags[1] - lags[0]):
        est.weak = AT_EDGE
    else:
        sys_ms = SYSTEMATIC_PX / max(est.speed, 1e-9)
        est.spread_ms = bootstrap_sigma(lags, est.parts, lag)
        est.sigma_ms = float(np.sqrt(est.spread_ms ** 2 + FLOOR_MS ** 2 + sys_ms ** 2))
        est.prominence = prominence(lags, est.edge_score, lag, max(RIVAL_MS, 2.0 * est.sigma_ms))
        if sys_ms > MAX_SIGMA_MS:
            est.weak = SLOW
        elif est.sigma_ms > MAX_SIGMA_MS:
            est.weak = AMBIGUOUS
        elif est.prominence < MIN_PROMINENCE:
            est.weak = RIVAL
        else:
            est.lag_ms = lag
    return est
