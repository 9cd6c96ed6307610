"""The kymograph's readout: by how much the events along the line lag an object's projected edge track.

The events near the line are binned into a density image ``D(t, s)`` (1 ms x 1 px), smoothed, minus each time
row's mean (busy moments must not win by their event rate alone). The object's silhouette along the line at
the track times gives, per track time and column, the signed distance ``d`` to its nearest edge crossing (> 0
inside the silhouette). For a lag ``tau`` two scores are read at the rows ``t + tau``:

* the *edge* score: the density weighted by a narrow Gaussian of ``d`` (events on the projected edge);
* the *region* score: the mean density in a band just inside the edges minus a band just outside (a textured
  object sweeps a family of parallel streaks whose boundary, not any one streak, is the silhouette's).

The lag is the maximum of ``edge + REGION_WEIGHT * |region|`` (which streak family), moved to the edge score's own
maximum within ``REFINE_MS`` of it (where exactly: a lone streak entering a region band would pull the sum) and
refined by a parabola through its neighbours; it is *clear* when no lag farther than a few ms scores nearly as
well on the sum (texture streaks, repeated edges).

Sign: ``lag > 0`` means the events happen *later* than the track says (the track runs ahead): the poses in
effect are taken ``lag`` too late on the pose clock, i.e. the clock offset in effect is ``lag`` too large. A
correct clock gives ``lag ~ 0``; a constant pose error moves the track in space, which a lag mimics only while
the edge keeps one speed.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evpose.core.align.correlation_peak import parabolic_offset

#: Lags are searched within +- this many ms (a 47 ms wrong clock must be found).
MAX_LAG_MS = 80.0
#: Lag grid step, ms.
LAG_STEP_MS = 0.25
#: A peak is *clear* when it stands above the best other peak (farther than ``SEPARATION_MS``) by at least this
#: share of its height above the median score.
MIN_PROMINENCE = 0.15
SEPARATION_MS = 5.0
#: At least this many track times with a crossing, and this many events on the line, are needed.
MIN_TRACK_TIMES = 4
MIN_EVENTS = 50
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
#: The lag is refined on the edge score alone within this many ms of the combined score's peak.
REFINE_MS = 1.0


@dataclass
class LagEstimate:
    """The lag of the events behind a track (see the module docstring for the sign).

    Attributes
    ----------
    lag_ms : float or None
        The score's peak; None when the track is too short or does not move along the line, the line saw too
        few events, or the peak sits at the end of the search.
    lags_ms, score : np.ndarray
        The searched lags and the combined score at each (empty when nothing was searched).
    edge_score : np.ndarray
        The edge score alone at each lag.
    prominence : float
        The peak's height above the best other peak (farther than ``SEPARATION_MS``), as a share of its height
        above the median score: near 0 when another lag fits about as well.
    n_times : int
        Track times with at least one crossing.
    """

    lag_ms: float | None
    lags_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    score: np.ndarray = field(default_factory=lambda: np.zeros(0))
    edge_score: np.ndarray = field(default_factory=lambda: np.zeros(0))
    prominence: float = 0.0
    n_times: int = 0

    @property
    def clear(self) -> bool:
        """A lag whose peak stands out (see :data:`MIN_PROMINENCE`)."""
        return self.lag_ms is not None and self.prominence >= MIN_PROMINENCE


def contrast_density(counts: np.ndarray, sigma=SMOOTH_SIGMA) -> np.ndarray:
    """``counts`` (n_t, n_s) smoothed and minus each time row's mean (float32)."""
    from scipy.ndimage import gaussian_filter

    d = gaussian_filter(np.asarray(counts, np.float32), sigma=sigma, mode="constant")
    return d - d.mean(axis=1, keepdims=True)


def signed_edge_distance(inside: np.ndarray, crossings: np.ndarray, n_cols: int) -> np.ndarray:
    """Per column ``c`` (s = c px): the distance to the nearest crossing, > 0 where ``inside`` (bool per column);
    +-inf without crossings."""
    c = np.arange(n_cols, dtype=np.float64)
    if len(crossings) == 0:
        return np.where(inside, np.inf, -np.inf)
    d = np.abs(c[:, None] - np.asarray(crossings, np.float64)[None, :]).min(axis=1)
    return np.where(inside, d, -d)


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


def row_scores(density: np.ndarray, weights: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``sum_c density[r, c] * weights[i, c]`` at fractional rows ``rows`` (n_lags, n_times) (linear between
    rows, 0 outside): (n_lags,) summed over the track times."""
    P = density @ weights.T                           # (n_rows, n_times): every row against every time's weights
    n_rows = P.shape[0]
    r0 = np.floor(rows).astype(np.int64)
    f = rows - r0
    cols = np.broadcast_to(np.arange(weights.shape[0]), rows.shape)
    v0 = np.where((r0 >= 0) & (r0 < n_rows), P[np.clip(r0, 0, n_rows - 1), cols], 0.0)
    v1 = np.where((r0 + 1 >= 0) & (r0 + 1 < n_rows), P[np.clip(r0 + 1, 0, n_rows - 1), cols], 0.0)
    return ((1 - f) * v0 + f * v1).sum(axis=1)


def parabolic(lags_ms: np.ndarray, score: np.ndarray, i: int) -> float:
    """The lag of sample ``i`` refined by a parabola through it and its neighbours."""
    lag = float(lags_ms[i])
    if 0 < i < len(score) - 1:
        lag += parabolic_offset(score[i - 1], score[i], score[i + 1]) * float(lags_ms[1] - lags_ms[0])
    return lag


def peak_lag(lags_ms: np.ndarray, score: np.ndarray, edge: np.ndarray | None = None) -> tuple[float, float]:
    """``(lag, prominence)``: the score's maximum (moved to ``edge``'s maximum within ``REFINE_MS`` when given),
    refined by a parabola, and the score's peak height above the best score farther than ``SEPARATION_MS`` as a
    share of its height above the median."""
    i = int(np.argmax(score))
    j = i
    if edge is not None:
        near = np.nonzero(np.abs(lags_ms - lags_ms[i]) <= REFINE_MS)[0]
        j = int(near[np.argmax(edge[near])])
    lag = parabolic(lags_ms, score if edge is None else edge, j)
    peak, med = float(score[i]), float(np.median(score))
    far = np.abs(lags_ms - lags_ms[i]) > SEPARATION_MS
    other = float(score[far].max()) if far.any() else med
    return lag, (peak - other) / max(peak - med, 1e-12)


def lag_curve(density: np.ndarray, t_first_ms: float, bin_ms: float, track_t_ms, distances,
              max_lag_ms: float = MAX_LAG_MS, step_ms: float = LAG_STEP_MS
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(lags, combined score, edge score)`` of one object: ``density`` from :func:`contrast_density` (rows:
    ``bin_ms`` bins from ``t_first_ms``), ``distances`` (n_times, n_cols) its signed edge distances at
    ``track_t_ms``."""
    lags = np.arange(-max_lag_ms, max_lag_ms + 0.5 * step_ms, step_ms)
    rows = (np.asarray(track_t_ms, np.float64)[None, :] + lags[:, None] - t_first_ms) / bin_ms - 0.5
    edge, region = edge_weights(np.asarray(distances, np.float64))
    n = max(len(track_t_ms), 1)
    e = row_scores(density, edge, rows) / n
    r = row_scores(density, region, rows) / n
    return lags, e + REGION_WEIGHT * np.abs(r), e


def estimate_lag(density: np.ndarray, t_first_ms: float, bin_ms: float, track_t_ms, distances,
                 n_events: int, travel_px: float) -> LagEstimate:
    """The lag of the events behind one object's track (see :func:`lag_curve` and :class:`LagEstimate`);
    ``travel_px``: how far the track moves along the line over the span (a still edge has no lag to measure)."""
    d = np.asarray(distances, np.float64)
    n_times = int(np.isfinite(d).any(axis=1).sum()) if d.size else 0
    if n_times < MIN_TRACK_TIMES or n_events < MIN_EVENTS or travel_px < MIN_TRAVEL_PX:
        return LagEstimate(None, n_times=n_times)
    lags, score, edge = lag_curve(density, t_first_ms, bin_ms, track_t_ms, d)
    return judged(lags, score, edge, n_times)


def judged(lags: np.ndarray, score: np.ndarray, edge: np.ndarray, n_times: int) -> LagEstimate:
    """The estimate of the score curves: their peak (None at the end of the search) and its prominence."""
    lag, prominence = peak_lag(lags, score, edge)
    inside = abs(lag) < lags[-1] - (lags[1] - lags[0])
    return LagEstimate(lag if inside else None, lags, score, edge, prominence, n_times)


def combine(estimates: list[LagEstimate]) -> LagEstimate:
    """One estimate from several objects' curves on the same lag grid: their sum weighted by track times."""
    used = [e for e in estimates if len(e.score) and e.n_times]
    if not used:
        return LagEstimate(None, n_times=sum(e.n_times for e in estimates))
    n = np.array([e.n_times for e in used], np.float64)
    score = np.sum([w * e.score for w, e in zip(n, used)], axis=0) / n.sum()
    edge = np.sum([w * e.edge_score for w, e in zip(n, used)], axis=0) / n.sum()
    return judged(used[0].lags_ms, score, edge, int(n.sum()))
