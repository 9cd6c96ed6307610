"""The kymograph's readout: by how much the events along the line lag an object's projected edge track.

The events near the line are binned into a density image ``D(t, s)`` (1 ms x 1 px), smoothed, minus each time
row's mean (busy moments must not win by their event rate alone). The object's silhouette along the line at
the track times gives, per track time and column, the signed distance ``d`` to its nearest edge crossing (> 0
inside the silhouette). For a lag ``tau`` two scores are read at the rows ``t + tau``:

* the *edge* score: the density weighted by a narrow Gaussian of ``d`` (events on the projected edge);
* the *region* score: the mean density in a band just inside the edges minus a band just outside (a textured
  object sweeps a family of parallel streaks whose boundary, not any one streak, is the silhouette's).

The lag is the maximum of ``edge + REGION_WEIGHT * |region|`` (which streak family), moved to the edge score's own
maximum within ``REFINE_PX`` of motion of it (where exactly: a lone streak entering a region band would pull the
sum) and refined by a parabola through the edge score one time bin either side (the scores are linear between
the bins' centres: a parabola through closer samples would lock the lag to those). Only track times whose
crossings move along the line count in full (``MOVING_PX_PER_MS``): a still edge tells nothing about the lag,
yet shifted onto a busy moment it would score. How far to trust the lag (its 1σ, or why it is too weak to read) is
:mod:`~evpose.core.views.kymograph_confidence`'s.

Sign: ``lag > 0`` means the events happen *later* than the track says (the track runs ahead): the poses in
effect are taken ``lag`` too late on the pose clock, i.e. the clock offset in effect is ``lag`` too large. A
correct clock gives ``lag ~ 0``; a constant pose error moves the track in space, which a lag mimics only while
the edge keeps one speed.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Lags are searched within +- this many ms (a 47 ms wrong clock must be found).
MAX_LAG_MS = 80.0
#: Lag grid step, ms.
LAG_STEP_MS = 0.25
#: At least this many track times with a crossing are needed.
MIN_TRACK_TIMES = 4
#: Track times count in full where their crossings move at least this fast along the line (px/ms), less in
#: proportion below: a still edge at a busy moment would pull the lag to that moment.
MOVING_PX_PER_MS = 0.05
#: A crossing's speed is measured over this long before and after a track time (ms) ...
SPEED_BASE_MS = 8.0
#: ... and a crossing moving farther than this between two track times (px) is another edge, not motion.
MAX_STEP_PX = 8.0
#: Events within this distance (px) of a crossing count as near the track.
NEAR_PX = 2.0
#: A track must move at least this far along the line over the span (px).
MIN_TRAVEL_PX = 3.0
#: Smoothing of the density before the search: (time bins, px).
SMOOTH_SIGMA = (1.0, 1.0)
#: Edge weight: a Gaussian of this width (px) around each crossing.
EDGE_SIGMA_PX = 1.0
#: Region bands: from ``REGION_GAP_PX`` to ``REGION_GAP_PX + REGION_WIDTH_PX`` on each side of a crossing.
REGION_GAP_PX, REGION_WIDTH_PX = 1.0, 5.0
#: Weight of the region score against the edge score.
REGION_WEIGHT = 3.0
#: The lag is refined on the edge score alone within the time the edge takes to move this far (px) from the
#: combined score's peak, at least ``REFINE_MS`` and at most ``REFINE_MAX_MS``.
REFINE_PX, REFINE_MS, REFINE_MAX_MS = 1.5, 1.0, 5.0


def contrast_density(counts: np.ndarray, sigma=SMOOTH_SIGMA) -> np.ndarray:
    """``counts`` (n_t, n_s) smoothed and minus each time row's mean (float32)."""
    from scipy.ndimage import gaussian_filter

    d = gaussian_filter(np.asarray(counts, np.float32), sigma=sigma, mode="constant")
    return d - d.mean(axis=1, keepdims=True)


def edge_weights(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The edge weights (Gaussian of ``d``) and the region weights (+1 / -1 over the inside / outside band,
    each band normalised to sum 1 per row where present) of signed distances ``d`` (n_times, n_cols)."""
    edge = np.exp(-0.5 * (d / EDGE_SIGMA_PX) ** 2)
    a = np.abs(d)
    band = (a > REGION_GAP_PX) & (a <= REGION_GAP_PX + REGION_WIDTH_PX)
    inner, outer = band & (d > 0), band & (d < 0)
    n_in = np.maximum(inner.sum(axis=1, keepdims=True), 1)
    n_out = np.maximum(outer.sum(axis=1, keepdims=True), 1)
    both = (inner.any(axis=1) & outer.any(axis=1))[:, None]
    region = np.where(both, inner / n_in - outer / n_out, 0.0)
    return edge, region


def time_scores(image: np.ndarray, weights: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``sum_c image[r, c] * weights[i, c]`` at fractional rows ``rows`` (n_lags, n_times) (linear between rows,
    0 outside): (n_lags, n_times), one column per track time."""
    P = image @ weights.T                             # (n_rows, n_times): every row against every time's weights
    n_rows = P.shape[0]
    r0 = np.floor(rows).astype(np.int64)
    f = rows - r0
    cols = np.broadcast_to(np.arange(weights.shape[0]), rows.shape)
    v0 = np.where((r0 >= 0) & (r0 < n_rows), P[np.clip(r0, 0, n_rows - 1), cols], 0.0)
    v1 = np.where((r0 + 1 >= 0) & (r0 + 1 < n_rows), P[np.clip(r0 + 1, 0, n_rows - 1), cols], 0.0)
    return (1 - f) * v0 + f * v1


@dataclass
class LineEvents:
    """The events within reach of a line, binned: ``counts`` (n_rows, n_cols) per time bin and column (column ``c``
    at ``s = c`` px), row ``r`` from ``t_first_ms + r * bin_ms`` (ms, relative to the current time), and their
    :func:`contrast_density`."""

    counts: np.ndarray
    t_first_ms: float
    bin_ms: float
    density: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        self.counts = np.asarray(self.counts, np.float32)
        self.density = contrast_density(self.counts)

    def rows(self, t_ms: np.ndarray) -> np.ndarray:
        """Fractional rows of times ``t_ms`` (a row's centre at an integer)."""
        return (np.asarray(t_ms, np.float64) - self.t_first_ms) / self.bin_ms - 0.5

    def near_counts(self, window_ms: float) -> np.ndarray:
        """``counts`` summed over ``window_ms`` around each row: the events a track time stands for."""
        from scipy.ndimage import uniform_filter1d

        size = max(int(round(window_ms / self.bin_ms)), 1)
        return uniform_filter1d(self.counts, size, axis=0, mode="constant") * size


@dataclass
class TimeParts:
    """Per lag (rows) and track time (columns): the edge score, the region score and the events within
    ``NEAR_PX`` of the crossings; ``speed`` (n_times,) the crossings' speed along the line at each time (px/ms);
    ``bin_ms`` the time bins of the events they were read on."""

    edge: np.ndarray
    region: np.ndarray
    near: np.ndarray
    speed: np.ndarray
    bin_ms: float = 1.0

    @staticmethod
    def pooled(parts: list[TimeParts]) -> TimeParts:
        """The track times of all ``parts`` (read on the same time bins) side by side."""
        return TimeParts(*(np.concatenate([getattr(p, f) for p in parts], axis=-1)
                           for f in ("edge", "region", "near", "speed")), parts[0].bin_ms)


@dataclass
class LagEstimate:
    """The lag of the events behind one or more tracks (see the module docstring for the sign), with its 1σ or
    the reason it is too weak to read.

    Attributes
    ----------
    lag_ms, sigma_ms : float or None
        The reading and its standard deviation (ms); None when too weak to read (see ``weak``).
    weak : str or None
        Why the reading is too weak (one of :mod:`~evpose.core.views.kymograph_confidence`'s reasons); None
        when it is readable.
    peak_ms : float or None
        The score's peak, also when too weak (None: nothing was searched).
    lags_ms, score, edge_score : np.ndarray
        The searched lags, the combined score and the edge score alone at each (empty when nothing was searched).
    n_times : int
        Track times with at least one crossing.
    n_near : int
        Events within ``NEAR_PX`` of the track moved by the peak lag.
    n_moving : float
        Track times whose crossings move along the line (those slower than ``MOVING_PX_PER_MS`` in part).
    speed : float
        The edge's speed along the line where the events are (px/ms, see
        :func:`~evpose.core.views.kymograph_confidence.evidence_speed`).
    evidence : float
        How much the line tells about the lag (see :func:`~evpose.core.views.kymograph_confidence.evidence`):
        the default line is the one with the most.
    spread_ms : float or None
        The part of σ the block bootstrap sees (ms; None until judged that far).
    prominence : float or None
        The edge score at the reading above its best rival peak farther than ``max(RIVAL_MS, 2σ)``, as a share of
        its height above the median (see :func:`~evpose.core.views.kymograph_confidence.prominence`; None until
        judged that far).
    parts : TimeParts or None
        The per-time scores the estimate was made of (the bootstrap redraws them, :func:`combine` pools them).
    judged : bool
        Whether σ and the verdict (``lag_ms`` or ``weak``) are set; see :func:`judged`.
    """

    lag_ms: float | None
    sigma_ms: float | None = None
    weak: str | None = None
    peak_ms: float | None = None
    lags_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    score: np.ndarray = field(default_factory=lambda: np.zeros(0))
    edge_score: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_times: int = 0
    n_near: int = 0
    n_moving: float = 0.0
    speed: float = 0.0
    evidence: float = 0.0
    spread_ms: float | None = None
    prominence: float | None = None
    parts: TimeParts | None = field(default=None, repr=False)
    judged: bool = False

    @property
    def readable(self) -> bool:
        return self.lag_ms is not None


def lag_parts(events: LineEvents, track_t_ms, distances, max_lag_ms: float = MAX_LAG_MS,
              step_ms: float = LAG_STEP_MS) -> tuple[np.ndarray, TimeParts]:
    """``(lags, parts)`` of one object: per lag and track time its edge and region scores on ``events.density``,
    the events near its crossings, and its crossings' speed; ``distances`` (n_times, n_cols) its signed edge
    distances at ``track_t_ms``."""
    lags = np.arange(-max_lag_ms, max_lag_ms + 0.5 * step_ms, step_ms)
    t = np.asarray(track_t_ms, np.float64)
    rows = events.rows(t[None, :] + lags[:, None])
    d = np.asarray(distances, np.float64)
    speed = edge_speeds(d, t)
    gate = np.clip(speed / MOVING_PX_PER_MS, 0.0, 1.0)[:, None]      # a still edge says nothing about the lag
    edge, region = edge_weights(d)
    step = float(np.median(np.diff(t))) if len(t) > 1 else events.bin_ms
    near = (np.abs(d) <= NEAR_PX) * gate
    return lags, TimeParts(time_scores(events.density, edge * gate, rows),
                           time_scores(events.density, region * gate, rows),
                           time_scores(events.near_counts(step), near, rows), speed, events.bin_ms)


def edge_speeds(d: np.ndarray, t_ms: np.ndarray) -> np.ndarray:
    """(n_times,) how fast the crossings move along the line at each time (px/ms): over the columns within
    ``NEAR_PX`` of a crossing, the median of how fast their signed distance ``d`` (n_times, n_cols) changes over
    ``SPEED_BASE_MS`` before and after, the smaller of the two (where the nearest crossing changes, one of them
    jumps; the label maps move a slow edge in whole pixels, so a shorter base would often see no motion).
    Changes beyond ``MAX_STEP_PX`` per track step are jumps, not motion. 0 where no crossing is near or moves."""
    n = len(t_ms)
    if n < 2:
        return np.zeros(n)
    t = np.asarray(t_ms, np.float64)
    k = int(np.clip(round(SPEED_BASE_MS / float(np.median(np.diff(t)))), 1, n - 1))
    finite = np.where(np.isfinite(d), d, np.nan)
    change = np.abs(finite[k:] - finite[:-k])
    rate = np.where(change <= k * MAX_STEP_PX, change / (t[k:] - t[:-k])[:, None], np.nan)
    pad = np.full((k, d.shape[1]), np.nan)
    best = np.fmin(np.vstack([pad, rate]), np.vstack([rate, pad]))     # NaN only where neither side is known
    ok = (np.abs(d) <= NEAR_PX) & np.isfinite(best)
    near = np.where(ok, best, np.inf)
    m = ok.sum(axis=1)                                     # the median of each row's m near values
    srt = np.sort(near, axis=1)
    rows = np.arange(n)
    lo, hi = srt[rows, np.maximum((m - 1) // 2, 0)], srt[rows, np.maximum(m // 2, 0)]
    return np.where(m > 0, 0.5 * (lo + hi), 0.0)


def curves(edge_parts: np.ndarray, region_parts: np.ndarray, w: np.ndarray | None = None):
    """``(score, edge score)`` of per-time parts (n_lags, n_times) summed with weights ``w`` (n_times,) or
    (n_times, B) (default all 1) over the number of times: the region sum enters by its size."""
    n = max(edge_parts.shape[1], 1)
    if w is None:
        w = np.ones(edge_parts.shape[1])
    e = edge_parts @ w / n
    return e + REGION_WEIGHT * np.abs(region_parts @ w / n), e


def refine_window(parts: TimeParts) -> float:
    """How far (ms) from the combined score's peak the edge score's own maximum is looked for: the time the
    moving crossings take to move ``REFINE_PX`` at their median speed."""
    moving = parts.speed[parts.speed >= MOVING_PX_PER_MS]
    if not len(moving):
        return REFINE_MS
    return float(np.clip(REFINE_PX / np.median(moving), REFINE_MS, REFINE_MAX_MS))


def peak_lags(lags_ms: np.ndarray, score: np.ndarray, edge: np.ndarray, refine_ms: float = REFINE_MS,
              bin_ms: float = 1.0) -> np.ndarray:
    """The lags (B,) of curves (n_lags, B): each score's maximum moved to its edge score's maximum within
    ``refine_ms`` (which streak family, then where exactly) and refined by a parabola through it and the edge
    score one time bin (``bin_ms``) either side: the scores are linear between the bins' centres, so their
    maxima sit on those and a parabola through neighbouring grid samples would lock the lag to them."""
    n, B = score.shape
    step = float(lags_ms[1] - lags_ms[0])
    k = int(round(refine_ms / step))
    h = max(int(round(bin_ms / step)), 1)
    cols = np.arange(B)
    i = np.argmax(score, axis=0)
    cand = np.clip(i[None, :] + np.arange(-k, k + 1)[:, None], 0, n - 1)
    j = cand[np.argmax(edge[cand, cols], axis=0), cols]
    ym, y0, yp = edge[np.maximum(j - h, 0), cols], edge[j, cols], edge[np.minimum(j + h, n - 1), cols]
    den = ym - 2.0 * y0 + yp
    ok = (den < 0) & (j >= h) & (j < n - h)
    off = np.where(ok, np.clip(0.5 * (ym - yp) / np.where(ok, den, -1.0), -0.5, 0.5), 0.0)
    return lags_ms[j] + off * h * step


def estimate_lag(events: LineEvents, track_t_ms, distances, travel_px: float, judge: bool = True) -> LagEstimate:
    """The lag of the events behind one object's track (see :func:`lag_parts` and :class:`LagEstimate`);
    ``travel_px``: how far the track moves along the line over the span (a still edge has no lag to measure).
    ``judge`` False: the peak and its evidence only, no σ and no verdict yet (see :func:`judged`)."""
    from evpose.core.views.kymograph_confidence import FEW_TIMES, NO_MOTION

    d = np.asarray(distances, np.float64)
    n_times = int(np.isfinite(d).any(axis=1).sum()) if d.size else 0
    if n_times < MIN_TRACK_TIMES:
        return LagEstimate(None, weak=FEW_TIMES, n_times=n_times, judged=True)
    if travel_px < MIN_TRAVEL_PX:
        return LagEstimate(None, weak=NO_MOTION, n_times=n_times, judged=True)
    lags, parts = lag_parts(events, track_t_ms, d)
    return judged(lags, parts, n_times, judge)


def judged(lags: np.ndarray, parts: TimeParts, n_times: int, judge: bool = True) -> LagEstimate:
    """The estimate of pooled per-time parts: the peak and its evidence
    (:func:`~evpose.core.views.kymograph_confidence.measure`), and unless ``judge`` is False its 1σ and
    whether it is readable (:func:`~evpose.core.views.kymograph_confidence.judge`)."""
    from evpose.core.views import kymograph_confidence as conf

    score, edge = curves(parts.edge, parts.region)
    lag = peak_lags(lags, score[:, None], edge[:, None], refine_window(parts), parts.bin_ms)
    est = conf.measure(LagEstimate(None, None, None, float(lag[0]), lags, score, edge, n_times, parts=parts))
    return conf.judge(est) if judge else est


def combine(estimates: list[LagEstimate], judge: bool = True) -> LagEstimate:
    """One estimate from several objects' tracks on the same lag grid: their per-time parts pooled."""
    used = [e for e in estimates if e.parts is not None]
    if not used:
        weak = next((e.weak for e in estimates if e.weak), None)
        return LagEstimate(None, weak=weak, n_times=sum(e.n_times for e in estimates), judged=True)
    if len(used) == 1:
        return used[0]
    return judged(used[0].lags_ms, TimeParts.pooled([e.parts for e in used]), sum(e.n_times for e in used), judge)
