"""The binned event rate and the motion proxy on the same bins, at any candidate clock.

Every stage of the clock estimate compares the event counts with the proxy read at a clock
(offset, skew): :class:`RateSeries` holds the counts, their smoothed and transformed series,
and reads the proxy's exact bin means at any clock, so the stages differ only in how they score
the match. The same Gaussian smoothing and a fixed monotone transform (``log(x + c)`` by
default) are applied to both series; why the log map is the default is in ``docs/sync.md``.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from evpose.core.align.proxy import MotionProxy
from evpose.core.data.clock import ClockModel
from evpose.core.data.events import Cancelled

__all__ = ["RateSeries", "check_cancel"]


def _gauss(x: np.ndarray, mask: np.ndarray, sigma_bins: float) -> tuple[np.ndarray, np.ndarray]:
    """Normalised (masked) Gaussian smoothing; returns ``(smoothed, still_valid)``."""
    if sigma_bins <= 0:
        return np.where(mask, x, 0.0), mask.copy()
    m = mask.astype(np.float64)
    num = ndimage.gaussian_filter1d(np.where(mask, x, 0.0), sigma_bins, mode="constant", truncate=3.0)
    den = ndimage.gaussian_filter1d(m, sigma_bins, mode="constant", truncate=3.0)
    ok = mask & (den > 0.999)  # bins whose whole kernel lies on valid data
    return np.where(den > 1e-12, num / np.maximum(den, 1e-12), 0.0), ok


class _Transform:
    """A fixed monotone map fitted on reference values (so it stays continuous when re-applied)."""

    def __init__(self, kind: str, ref: np.ndarray):
        self.kind = kind
        ref = ref[np.isfinite(ref)]
        if kind == "log":
            med = float(np.median(ref)) if len(ref) else 0.0
            top = float(np.max(ref)) if len(ref) else 0.0
            self.c = max(0.5 * med, 1e-3 * top, 1e-12)
        elif kind != "linear":
            raise ValueError(f"transform must be 'log' or 'linear', got {kind!r}")

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if self.kind == "log":
            return np.log(np.maximum(x, 0.0) + self.c)
        return x


def _ncc_1d(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    d = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / d if d > 0 else float("nan")


def check_cancel(cancel):
    """Raise :class:`evpose.core.data.events.Cancelled` when ``cancel()`` says so."""
    if cancel is not None and cancel():
        raise Cancelled("clock synchronisation cancelled")


class RateSeries:
    """The event series and the proxy, prepared for evaluations at arbitrary clocks.

    ``e`` is the smoothed, transformed event rate and ``me`` the bins whose whole smoothing
    kernel lies on data; ``counts`` the raw counts (for the likelihood); ``d0`` / ``dr`` the bin
    starts relative to the proxy's origin and to the prior's ``t_ref_us`` (µs, float).
    """

    def __init__(self, starts_us, counts, bin_us, proxy: MotionProxy, prior: ClockModel, sigma_bins, transform):
        self.bin_us = int(bin_us)
        self.starts = np.asarray(starts_us, dtype=np.int64)
        self.proxy = proxy
        self.prior = prior
        self.sigma = sigma_bins
        self.transform_kind = transform
        c = np.asarray(counts, dtype=np.float64)
        self.counts = c
        m = np.ones(len(c), bool)
        e, ok = _gauss(c, m, sigma_bins)
        self.e = _Transform(transform, e[ok])(e)
        self.me = ok
        # float offsets of the bin starts relative to the trajectory origin and to t_ref
        self.d0 = (self.starts - np.int64(proxy.t0_us)).astype(np.float64)
        self.dr = (self.starts - np.int64(prior.t_ref_us)).astype(np.float64)
        self.p_tf = None

    def proxy_bins(self, offset_us: float, skew_ppm: float, shift_bins: np.ndarray | None = None):
        """Bin means of the proxy for event bins (optionally shifted by whole bins)."""
        d0, dr = self.d0, self.dr
        if shift_bins is not None:
            d0 = d0[0] + shift_bins * float(self.bin_us)
            dr = dr[0] + shift_bins * float(self.bin_us)
        k = 1.0 + skew_ppm * 1e-6
        a = d0 + offset_us + skew_ppm * 1e-6 * dr
        return self.proxy.mean_over(a, a + self.bin_us * k)

    def prepared_proxy(self, offset_us, skew_ppm, shift_bins=None):
        """The proxy's bin means at a clock, smoothed and transformed like the event rate:
        ``(series, valid)``. The transform is fitted on the first call and then kept fixed."""
        p, mp = self.proxy_bins(offset_us, skew_ppm, shift_bins)
        ps, ok = _gauss(p, mp, self.sigma)
        if self.p_tf is None:
            self.p_tf = _Transform(self.transform_kind, ps[ok])
        return self.p_tf(ps), ok

    def ncc_at(self, offset_us, skew_ppm, sel: np.ndarray) -> float:
        """Full NCC at a clock over the fixed bin selection ``sel``."""
        p, ok = self.prepared_proxy(offset_us, skew_ppm)
        use = sel & ok
        if use.sum() < 10:
            return float("nan")
        return _ncc_1d(self.e[use], p[use])

