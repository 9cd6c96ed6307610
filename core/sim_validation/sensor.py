"""Level-crossing event generation: a DVS pixel model driven by log-intensity frames.

Between two frames a pixel's log intensity ``L`` is taken to change linearly in time. A pixel fires when
``L`` has moved by its threshold from the *reference* level stored at its last event (ON: ``+C_on``, OFF:
``-C_off``; both drawn per pixel around ``C`` with spread ``sigma``); the event's time is the crossing time
interpolated between the frames (stamped with the next µs tick). After an event the pixel is blind for the
refractory period, and its reference is reset to the level at the moment it fires (a crossing delayed by the
refractory period fires at its end, from the level reached then: the threshold is not simply added to the old
reference). The reference leaks downwards, so a static pixel fires ON *leak* events at ``leak_rate_hz``;
*shot noise* events (either polarity, Poisson at ``noise_rate_hz``, a few hot pixels much faster) fire and reset
the pixel like any other event. With both, a static pixel emits ``n / (1 - exp(-n / r))`` events per second
(n: noise rate, r: leak rate): every event restarts the leak's climb.

The per-pixel work is one numba kernel over all pixels of a frame interval (:func:`_fire`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from evpose.core.data.events import EventArray
from evpose.core.sim_validation.config import SensorModel


@njit(cache=True, nogil=True)
def _fire(L0, L1, t0, t1, ref, tset, tlast, c_on, c_off, leak, refr, npix, nt, npol, out_pix, out_t, out_p):
    """Events of all pixels in ``(t0, t1]`` (µs, float64 relative to the sensor's origin). ``ref``/``tset``
    (reference level and when it was set), ``tlast`` (last event) are updated in place; noise events
    ``npix/nt/npol`` are sorted by pixel, then time. Returns the number of events, or -1 when the output
    buffers are full (the state is then partly updated: the caller restores it)."""
    n_out, k, cap = 0, 0, len(out_t)
    span = t1 - t0
    for i in range(len(L0)):
        slope = (L1[i] - L0[i]) / span
        b = slope + leak[i]
        r, ts_, tl = ref[i], tset[i], tlast[i]
        tc = t0
        while True:
            while k < len(npix) and npix[k] < i:
                k += 1
            tn = math.inf
            while k < len(npix) and npix[k] == i:
                if nt[k] >= tl + refr:
                    tn = nt[k]
                    break
                k += 1                                    # noise inside the refractory period: lost
            ta = max(tc, tl + refr)
            te, pol = math.inf, 0
            if ta <= t1:
                f0 = L0[i] - r + leak[i] * (t0 - ts_)     # f(t) = L(t) - (ref - leak (t - tset)) = f0 + b (t - t0)
                fa = f0 + b * (ta - t0)
                if fa >= c_on[i]:
                    te, pol = ta, 1
                elif fa <= -c_off[i]:
                    te, pol = ta, 0
                elif b > 0.0:
                    te, pol = t0 + (c_on[i] - f0) / b, 1
                elif b < 0.0:
                    te, pol = t0 + (-c_off[i] - f0) / b, 0
                if te > t1:
                    te = math.inf
            if tn < te:
                te, pol = tn, npol[k]
                k += 1
            if te == math.inf:
                break
            if n_out >= cap:
                return -1
            out_pix[n_out] = i
            out_t[n_out] = te
            out_p[n_out] = pol
            n_out += 1
            r = L0[i] + slope * (te - t0)                 # reset to the level at the moment of firing
            ts_ = te
            tl = te
            tc = te
        ref[i], tset[i], tlast[i] = r, ts_, tl
    return n_out


class LevelCrossingSensor:
    """A sensor of ``width x height`` pixels with parameters drawn once from ``rng``.

    Attributes ``c_on``, ``c_off`` (thresholds), ``leak_hz`` and ``noise_hz`` (per-pixel rates) are the drawn
    values. Times passed to :meth:`reset` and :meth:`step` are int64 µs of the event clock.
    """

    def __init__(self, width: int, height: int, params: SensorModel, rng: np.random.Generator):
        self.width, self.height, self.params, self.rng = width, height, params, rng
        n = width * height
        c, s = params.contrast, params.contrast_sigma
        floor = max(0.2 * c, 0.005)
        self.c_on = np.maximum(rng.normal(c, s, n), floor)
        self.c_off = np.maximum(rng.normal(c, s, n), floor)
        sp = params.rate_spread
        self.leak_hz = params.leak_rate_hz * np.exp(rng.normal(-0.5 * sp * sp, sp, n))
        self.noise_hz = params.noise_rate_hz * np.exp(rng.normal(-0.5 * sp * sp, sp, n))
        self.hot = rng.choice(n, size=min(params.hot_pixels, n), replace=False)
        self.noise_hz[self.hot] = params.hot_rate_hz
        self._cum = np.cumsum(self.noise_hz)
        self._leak = self.leak_hz * self.c_on * 1e-6          # reference drift, log units per µs
        self.origin_us = 0
        self.ref = self.tset = self.tlast = None
        self._cap = 1 << 16

    def reset(self, log_frame: np.ndarray, t_us: int) -> None:
        """Start at ``t_us`` with each pixel at a random point between its thresholds (no events)."""
        L = np.asarray(log_frame, dtype=np.float64).ravel()
        self.origin_us = int(t_us)
        u = self.rng.uniform(0.0, 1.0, len(L))
        self.ref = L - (-self.c_off + u * (self.c_on + self.c_off)) * 0.999
        self.tset = np.zeros(len(L))
        self.tlast = np.full(len(L), -1e18)

    def _noise(self, a: float, b: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        total = float(self._cum[-1]) if len(self._cum) else 0.0
        count = self.rng.poisson(total * (b - a) * 1e-6)
        pix = np.searchsorted(self._cum, self.rng.uniform(0.0, total, count), side="right")
        t = np.floor(self.rng.uniform(a, b, count)) + 1.0          # whole µs in (a, b]
        pol = self.rng.integers(0, 2, count).astype(np.uint8)
        order = np.lexsort((t, pix))
        return pix[order].astype(np.int64), t[order], pol[order]

    def step(self, L0: np.ndarray, L1: np.ndarray, t0_us: int, t1_us: int) -> EventArray:
        """Events in ``(t0_us, t1_us]`` while the log intensity goes linearly from frame ``L0`` to ``L1``
        (``(H, W)``, same frame for a static interval), sorted by time."""
        if self.ref is None:
            raise RuntimeError("call reset() before step()")
        a, b = float(t0_us - self.origin_us), float(t1_us - self.origin_us)
        if b <= a:
            raise ValueError(f"step: t1 must follow t0 ({t0_us} -> {t1_us})")
        L0 = np.asarray(L0, dtype=np.float64).ravel()
        L1 = np.asarray(L1, dtype=np.float64).ravel()
        npix, nt, npol = self._noise(a, b)
        saved = (self.ref.copy(), self.tset.copy(), self.tlast.copy())
        while True:
            out_pix, out_t = np.empty(self._cap, np.int64), np.empty(self._cap)
            out_p = np.empty(self._cap, np.uint8)
            n = _fire(L0, L1, a, b, self.ref, self.tset, self.tlast, self.c_on, self.c_off, self._leak,
                      float(self.params.refractory_us), npix, nt, npol, out_pix, out_t, out_p)
            if n >= 0:
                break
            self.ref, self.tset, self.tlast = (s.copy() for s in saved)
            self._cap *= 4
        t = np.clip(np.ceil(out_t[:n] - 1e-9), a + 1, b).astype(np.int64) + self.origin_us   # the next µs tick
        order = np.argsort(t, kind="stable")
        pix = out_pix[:n][order]
        y, x = np.divmod(pix, self.width)
        return EventArray(x.astype(np.uint16), y.astype(np.uint16), t[order], out_p[:n][order])

    def expected_static_rates(self) -> tuple[np.ndarray, np.ndarray]:
        """Per pixel, the expected ON and OFF event rates (Hz) of a static scene, refractory period aside:
        OFF = n/2, ON = n/2 + leak, with leak = n e^(-n/r) / (1 - e^(-n/r)) (every event restarts the climb)."""
        n, r = self.noise_hz, self.leak_hz
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            q = np.exp(-n / r)
            leak = np.where(n > 0, n * q / (1.0 - q), r)
        leak = np.where(r > 0, leak, 0.0)
        return n / 2 + leak, n / 2
