"""The binned event rate and the motion proxy on the same bins, at any candidate clock.

Every stage of the clock estimate compares the event counts with the proxy read at a clock
(offset, skew): :class:`RateSeries` holds the counts, their smoothed and transformed series,
and reads the proxy's exact bin means at any clock, so the stages differ only in how they score
the match. The same Gaussian smoothing and a fixed monotone transform (``log(x + c)`` by
default) are applied to both series; why the log map is the default is in ``docs/sync.md``.

Long recordings are estimated coarse-to-fine in time (:func:`evpose.core.align.estimate.estimate_long`): the
counts come from a :class:`BinnedCounts` or :class:`StoreCounts` source, which give the whole recording at a
coarse bin width and any window at the fine one without holding the fine counts of the whole recording.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from evpose.core.align.proxy import MotionProxy
from evpose.core.data.clock import ClockModel
from evpose.core.data.events import Cancelled

__all__ = ["BinnedCounts", "RateSeries", "StoreCounts", "check_cancel"]


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
        """Full NCC at a clock over the fixed bin selection ``sel``.

        Once the transform is fitted, the proxy is read only over the span of ``sel`` and the smoothing kernel's
        reach either side: the same numbers as over the whole series (each smoothed bin sums the same values), at
        a cost that follows the selection (a segment of a long series) instead of the series."""
        idx = np.flatnonzero(sel)
        if len(idx) < 10:
            return float("nan")
        if self.p_tf is None:
            lo, hi = 0, len(self.e)
            p, ok = self.prepared_proxy(offset_us, skew_ppm)
        else:
            reach = int(3.0 * self.sigma + 0.5) + 1                 # gaussian_filter1d's radius at truncate=3
            lo, hi = max(0, int(idx[0]) - reach), min(len(self.e), int(idx[-1]) + 1 + reach)
            p, ok = self._prepared_span(offset_us, skew_ppm, lo, hi)
        use = sel[lo:hi] & ok
        if use.sum() < 10:
            return float("nan")
        return _ncc_1d(self.e[lo:hi][use], p[use])

    def _prepared_span(self, offset_us, skew_ppm, lo: int, hi: int):
        """:meth:`prepared_proxy` of the bins ``lo:hi`` alone (the transform already fitted)."""
        k = 1.0 + skew_ppm * 1e-6
        a = self.d0[lo:hi] + offset_us + skew_ppm * 1e-6 * self.dr[lo:hi]
        p, mp = self.proxy.mean_over(a, a + self.bin_us * k)
        ps, ok = _gauss(p, mp, self.sigma)
        return self.p_tf(ps), ok


class BinnedCounts:
    """Event counts already binned (``starts_us``, ``counts`` at ``bin_us``, partial first and last bins
    dropped), as a source for the coarse-to-fine estimate of a long recording."""

    def __init__(self, starts_us: np.ndarray, counts: np.ndarray, bin_us: int):
        self.starts, self.counts, self.bin_us = np.asarray(starts_us, np.int64), np.asarray(counts), int(bin_us)

    @property
    def span_us(self) -> tuple[int, int]:
        """``[t0, t1)`` µs covered by whole bins."""
        return int(self.starts[0]), int(self.starts[-1]) + self.bin_us

    @property
    def n_bins(self) -> int:
        """Whole bins in :attr:`span_us` (0 when there are none)."""
        t0, t1 = self.span_us
        return max(0, (t1 - t0) // self.bin_us)

    def coarse(self, factor: int) -> tuple[np.ndarray, np.ndarray]:
        """Bins of ``factor x bin_us`` over the whole recording (the first and last may be partial)."""
        i = np.arange(0, len(self.counts), factor)
        return self.starts[i], np.add.reduceat(self.counts, i)

    def window(self, t0_us: int, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
        """``n_bins`` bins of ``bin_us`` from the bin start ``t0_us`` (inside the span)."""
        i0 = (int(t0_us) - int(self.starts[0])) // self.bin_us
        return self.starts[i0:i0 + n_bins].copy(), self.counts[i0:i0 + n_bins].copy()


class StoreCounts(BinnedCounts):
    """Event counts of an :class:`~evpose.core.data.event_store.EventStore`, binned on demand from its ms index
    (``ms_to_idx``; no event is read), the same bins as :class:`BinnedCounts` of its ``rate(bin_us)``: the whole
    recording at a coarse bin and any window at ``bin_us``, without holding the fine counts of the whole
    recording (16 bytes a bin: 170 MB for 3 hours at 1 ms). Bins lie on the store's grid
    ``t_offset_us + j * bin_us``, partial first and last bins dropped."""

    def __init__(self, events, bin_us: int):
        if not isinstance(bin_us, (int, np.integer)) or bin_us <= 0 or bin_us % 1000:
            raise ValueError(f"rate: bin_us must be a positive multiple of 1000 µs, got {bin_us!r}")
        self.events, self.bin_us = events, int(bin_us)
        off = int(events.t_offset_us)
        j0 = (int(events.t_first_us) - off) // self.bin_us
        j1 = (int(events.t_last_us) - off) // self.bin_us
        self._span = (off + (j0 + 1) * self.bin_us, off + j1 * self.bin_us)

    @property
    def span_us(self) -> tuple[int, int]:
        return self._span

    def _first_index(self, t_us: np.ndarray) -> np.ndarray:
        """Index of the first event at or after each whole-ms time ``t_us`` (``EventStore.index_of``, vectorised)."""
        ev = self.events
        k = (t_us - int(ev.ms_index_t0_us)) // 1000
        idx = ev.ms_to_idx[np.clip(k, 0, len(ev.ms_to_idx) - 1)]
        return np.where(k < 0, 0, np.where(k >= len(ev.ms_to_idx), ev.n_events, idx))

    def _binned(self, t0_us: int, bin_us: int, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
        edges = np.minimum(int(t0_us) + bin_us * np.arange(n_bins + 1, dtype=np.int64), self._span[1])
        return edges[:-1], np.diff(self._first_index(edges))

    def coarse(self, factor: int) -> tuple[np.ndarray, np.ndarray]:
        n = -(-(self._span[1] - self._span[0]) // (self.bin_us * factor))
        return self._binned(self._span[0], self.bin_us * factor, n)

    def window(self, t0_us: int, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
        return self._binned(t0_us, self.bin_us, n_bins)
