"""core/align computes the clock estimate's Theil-Sen line, the small-sample factor of the joint fit's sigmas, the NCC
scan's correlations and its peaks without scipy.stats and scipy.signal (tracker issue 25.4: importing them kept
~23 MB resident in the app after the first Auto), and gets scipy's results bit for bit."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from scipy import signal, stats

from evpose.core.align.correlation import correlate_valid
from evpose.core.align.correlation_peak import local_maxima
from evpose.core.align.joint_solve import small_sample_factor
from evpose.core.align.segments import theil_sen


def same(a, b) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))


@pytest.mark.filterwarnings("ignore::RuntimeWarning")   # ties making every x equal: scipy warns
@pytest.mark.filterwarnings("ignore::RuntimeWarning")   # ties making every x equal: scipy warns
@pytest.mark.parametrize("n", [2, 3, 4, 5, 7, 12, 40])
@pytest.mark.parametrize("alpha", [0.9, 0.95, 0.1])
def test_theil_sen_is_scipy_s_theilslopes(n, alpha):
    rng = np.random.default_rng(n)
    for trial in range(20):
        x = np.sort(rng.uniform(-3, 3, n))
        y = 40.0 * x + rng.normal(0, 5, n)
        if trial % 4 == 1:
            x = np.round(x)                              # ties in x
        if trial % 4 == 2:
            y = np.round(y / 20) * 20                    # ties in y
        if trial % 4 == 3 and n > 2:
            y[rng.integers(n)] += 500.0                  # an outlier
        assert same(theil_sen(y, x, alpha), tuple(stats.theilslopes(y, x, alpha))), (n, alpha, trial)


def test_theil_sen_with_nan_or_one_x_is_scipy_s():
    with np.errstate(all="ignore"):
        x = np.array([0.0, 1.0, 2.0, 3.0])
        y = np.array([1.0, np.nan, 2.0, 3.0])
        assert same(theil_sen(y, x, 0.9), tuple(stats.theilslopes(y, x, 0.9)))
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert same(theil_sen([1.0, 2.0, 3.0], [1.0, 1.0, 1.0], 0.9),
                        tuple(stats.theilslopes([1.0, 2.0, 3.0], [1.0, 1.0, 1.0], 0.9)))


def test_small_sample_factor_is_scipy_stats_quantiles():
    for n in range(2, 300):
        assert small_sample_factor(n) == float((stats.t.ppf(0.975, n - 1) / stats.norm.ppf(0.975)) ** 2)
    assert small_sample_factor(1) == float("inf")


@pytest.mark.parametrize("k, lags", [(1, 7), (5, 1), (30, 41), (200, 801), (1500, 401), (4000, 2001), (9000, 4001),
                                     (20000, 121)])
def test_correlate_valid_is_scipy_signal_correlate(k, lags):
    """Sizes on both sides of scipy's direct / FFT choice (the NCC scan: a segment's K bins against K + 2L)."""
    rng = np.random.default_rng(k)
    x = rng.normal(size=k) * (rng.uniform(size=k) > 0.2)
    y = rng.poisson(3.0, size=k + lags - 1).astype(float)
    method = signal.choose_conv_method(y, x[::-1], mode="valid")
    got, want = correlate_valid(y, x), signal.correlate(y, x, mode="valid", method="auto")
    assert np.array_equal(got, want), (k, lags, method, np.abs(got - want).max())


def test_both_methods_are_exercised():
    assert signal.choose_conv_method(np.ones(4000 + 2000), np.ones(4000), mode="valid") == "fft"
    assert signal.choose_conv_method(np.ones(200 + 800), np.ones(200), mode="valid") == "direct"


def test_local_maxima_are_scipy_s_find_peaks():
    rng = np.random.default_rng(3)
    for n in (0, 1, 2, 3, 4, 10, 101, 1000):
        for levels in (3, 10, 1000):
            x = rng.integers(0, levels, n).astype(float)       # plateaus when there are few levels
            if n > 5:
                x[rng.integers(n, size=2)] = -2.0
            assert np.array_equal(local_maxima(x), signal.find_peaks(x)[0]), (n, levels)
    x = np.array([0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 2.0, 2.0, 3.0, 3.0, 1.0, 5.0, 5.0])
    assert np.array_equal(local_maxima(x), signal.find_peaks(x)[0]) and list(local_maxima(x)) == [2, 8]


_AUTO_CHILD = r"""
import sys
from evpose.core.align import estimate, joint_fit, joint_solve, segments, correlation, correlation_peak, rate_refine
from evpose.core.align import sync_run
bad = [m for m in ("scipy.stats", "scipy.signal") if m in sys.modules]
print(",".join(bad) or "none")
"""


def test_the_clock_and_edge_estimates_import_neither_scipy_stats_nor_scipy_signal():
    out = subprocess.run([sys.executable, "-c", _AUTO_CHILD], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "QT_QPA_PLATFORM": "offscreen"})
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "none"
