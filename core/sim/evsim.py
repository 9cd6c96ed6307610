"""Event-camera simulation from a sequence of log-intensity frames (ESIM-like).

Between two rendered frames the log intensity of each pixel is assumed to change linearly in
time; an event is emitted each time it crosses the pixel's reference level by the contrast
threshold, with the timestamp interpolated to the crossing. Modelled sensor effects:

* per-pixel contrast thresholds (normal around ``C`` with spread ``sigma_C``, separately for
  ON and OFF);
* a refractory period per pixel;
* background activity noise (Poisson, uniform over the sensor) and a few hot pixels firing at a
  high rate.

Everything is vectorised over pixels and events; the only loop is over frames.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evpose.core.data.events import EventArray


@dataclass(frozen=True)
class SensorParams:
    """Event sensor parameters.

    Attributes
    ----------
    contrast : float
        Mean contrast threshold on log intensity (ON and OFF).
    contrast_sigma : float
        Per-pixel standard deviation of the thresholds.
    refractory_us : int
        Minimum time between two events of one pixel.
    noise_rate_hz : float
        Background activity per pixel (events per second).
    hot_pixels : int
        Number of hot pixels.
    hot_rate_hz : float
        Event rate of each hot pixel.
    """

    contrast: float = 0.2
    contrast_sigma: float = 0.03
    refractory_us: int = 100
    noise_rate_hz: float = 0.1
    hot_pixels: int = 4
    hot_rate_hz: float = 300.0


class EventSimulator:
    """Stateful simulator for one sensor; feed frames in time order with :meth:`step`.

    Parameters
    ----------
    width, height : int
        Sensor size in pixels.
    params : SensorParams
    rng : numpy.random.Generator
    """

    def __init__(self, width: int, height: int, params: SensorParams = SensorParams(),
                 rng: np.random.Generator | None = None):
        self.width, self.height = width, height
        self.params = params
        self.rng = rng if rng is not None else np.random.default_rng()
        n = width * height
        c_min = max(0.25 * params.contrast, 0.01)
        self.c_on = np.clip(self.rng.normal(params.contrast, params.contrast_sigma, n), c_min, None).astype(np.float32)
        self.c_off = np.clip(self.rng.normal(params.contrast, params.contrast_sigma, n), c_min, None).astype(np.float32)
        self.hot = self.rng.choice(n, size=min(params.hot_pixels, n), replace=False)
        self.l_ref: np.ndarray | None = None
        self.l_prev: np.ndarray | None = None
        self.t_prev_us: int | None = None
        self.t_last = np.full(n, np.iinfo(np.int64).min // 2, dtype=np.int64)

    def reset(self, log_frame: np.ndarray, t_us: int) -> None:
        """Start from a frame without emitting events (the sensor's initial state)."""
        self.l_ref = np.asarray(log_frame, dtype=np.float32).ravel().copy()
        self.l_prev = self.l_ref.copy()
        self.t_prev_us = int(t_us)

    def step(self, log_frame: np.ndarray | None, t_us: int) -> EventArray:
        """Advance to ``t_us`` with the new log-intensity frame and return the events in
        ``(t_prev, t_us]``, sorted by time. ``log_frame=None`` means "unchanged" (a static
        camera), which produces only noise."""
        if self.t_prev_us is None:
            raise RuntimeError("call reset() with the first frame before step()")
        t0, t1 = self.t_prev_us, int(t_us)
        if t1 <= t0:
            raise ValueError(f"frames must be in increasing time order ({t0} -> {t1})")
        parts = [self._noise(t0, t1)]
        if log_frame is not None:
            l1 = np.asarray(log_frame, dtype=np.float32).ravel()
            parts.append(self._crossings(self.l_prev, l1, t0, t1))
            self.l_prev = l1.copy()
        self.t_prev_us = t1
        ev = _merge(parts)
        return self._refractory(ev)

    # ------------------------------------------------------------------ internals
    def _crossings(self, l0: np.ndarray, l1: np.ndarray, t0: int, t1: int) -> tuple:
        d = l1 - self.l_ref
        n_on = np.floor(d / self.c_on).astype(np.int64)
        n_off = np.floor(-d / self.c_off).astype(np.int64)
        n_on[n_on < 0] = 0
        n_off[n_off < 0] = 0
        out = []
        for n, c, sign, pol in ((n_on, self.c_on, 1.0, 1), (n_off, self.c_off, -1.0, 0)):
            pix = np.flatnonzero(n)
            if len(pix) == 0:
                continue
            counts = n[pix]
            rep = np.repeat(pix, counts)
            k = np.arange(len(rep)) - np.repeat(np.cumsum(counts) - counts, counts) + 1
            level = self.l_ref[rep] + sign * k * c[rep]
            slope = l1[rep] - l0[rep]
            with np.errstate(divide="ignore", invalid="ignore"):
                frac = np.where(np.abs(slope) > 1e-12, (level - l0[rep]) / slope, 1.0)
            frac = np.clip(frac, 0.0, 1.0)
            t = t0 + np.maximum(1, np.rint(frac * (t1 - t0))).astype(np.int64)
            np.minimum(t, t1, out=t)
            out.append((rep, t, np.full(len(rep), pol, np.uint8)))
            self.l_ref[pix] += sign * counts * c[pix]
        return _concat(out)

    def _noise(self, t0: int, t1: int) -> tuple:
        p = self.params
        dt_s = (t1 - t0) * 1e-6
        n_px = self.width * self.height
        n_bg = self.rng.poisson(p.noise_rate_hz * n_px * dt_s)
        pix = [self.rng.integers(0, n_px, n_bg)]
        n_hot = self.rng.poisson(p.hot_rate_hz * dt_s, size=len(self.hot))
        pix.append(np.repeat(self.hot, n_hot))
        pix = np.concatenate(pix).astype(np.int64)
        t = self.rng.integers(t0 + 1, t1 + 1, len(pix)).astype(np.int64)
        pol = self.rng.integers(0, 2, len(pix)).astype(np.uint8)
        return pix, t, pol

    def _refractory(self, ev: tuple) -> EventArray:
        pix, t, pol = ev
        if len(pix) == 0:
            return EventArray.empty()
        order = np.lexsort((t, pix))  # by pixel, then time
        pix, t, pol = pix[order], t[order], pol[order]
        prev_t = np.empty_like(t)
        prev_t[1:] = t[:-1]
        first = np.ones(len(pix), dtype=bool)
        first[1:] = pix[1:] != pix[:-1]
        prev_t[first] = self.t_last[pix[first]]
        keep = (t - prev_t) >= self.params.refractory_us
        pix, t, pol = pix[keep], t[keep], pol[keep]
        if len(pix):
            last = np.ones(len(pix), dtype=bool)
            last[:-1] = pix[1:] != pix[:-1]
            self.t_last[pix[last]] = t[last]
        order = np.argsort(t, kind="stable")
        pix, t, pol = pix[order], t[order], pol[order]
        y, x = np.divmod(pix, self.width)
        return EventArray(x.astype(np.uint16), y.astype(np.uint16), t, pol)


def _concat(parts: list[tuple]) -> tuple:
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.uint8)
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))


def _merge(parts: list[tuple]) -> tuple:
    return _concat([p for p in parts if len(p[0])])
