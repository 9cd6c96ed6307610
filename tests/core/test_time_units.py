"""The time-unit guess (evpose.core.importers.time_guess.guess_time_unit): the fractional-seconds rule.

Units are scored by how plausible the event rate / pose period they imply is. Where the numbers alone
leave two units plausible, a column with fractional parts is read as seconds: integer-valued units
(ms, µs, ns) get a two-decade penalty for fractions, and with too few values for a rate or a period a
fractional column falls back to seconds (an integer one to µs). The cases below are the ones the rule
decides: without it they would be read as milliseconds (1000x too slow a recording) or microseconds.
(The importer-level case is ``test_importers.py::test_npz_fractional_seconds_at_a_low_event_rate``.)
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from evpose.core.importers.time_guess import guess_time_unit

#: The penalty of the rule, in decades of implausibility (see guess_time_unit).
FRACTION_PENALTY = 2.0


def low_rate_seconds(n: int = 801, rate_ev_s: float = 1e4, t0_s: float = 0.0) -> np.ndarray:
    """``n`` event times in float seconds at ``rate_ev_s`` (a quiet sensor), jittered so no two steps are equal."""
    rng = np.random.default_rng(4)
    steps = rng.uniform(0.5, 1.5, n - 1) / rate_ev_s
    return t0_s + np.r_[0.0, np.cumsum(steps)]


def test_fractional_seconds_at_a_low_event_rate_are_seconds():
    t_s = low_rate_seconds()                           # ~1e4 ev/s: 2 decades from 1 M ev/s in seconds,
    assert np.any(t_s != np.round(t_s))                # 1 decade from it in ms (1e7 ev/s) ...
    unit, reason, scores = guess_time_unit(t_s, kind="events")
    assert unit == "s", (reason, scores)
    # ... so it is the rule that decides: without the penalty ms would score better than s
    assert math.isfinite(scores["ms"])
    assert scores["ms"] - FRACTION_PENALTY < scores["s"] < scores["ms"], scores
    assert "seconds" in reason


def test_the_same_rate_in_whole_numbers_is_not_seconds():
    """The rule only applies to fractions: the same event column scaled to whole µs is an integer unit."""
    t_us = np.round(low_rate_seconds() * 1e6)
    assert np.all(t_us == np.round(t_us))
    unit, _, scores = guess_time_unit(t_us, kind="events")
    assert unit != "s"
    assert not math.isfinite(scores["s"]) or scores["s"] > scores[unit]


def test_fractional_epoch_seconds_at_a_low_event_rate_are_seconds():
    """Epoch seconds (a bonus of one decade for s) at ~3 k ev/s: without the rule ms still wins."""
    t_s = low_rate_seconds(n=401, rate_ev_s=10**3.5, t0_s=1_468_940_293.0)
    unit, reason, scores = guess_time_unit(t_s, kind="events")
    assert unit == "s", (reason, scores)
    assert scores["ms"] - FRACTION_PENALTY < scores["s"], scores


@pytest.mark.parametrize("t0_s", [0.25, 1_700_000_000.25])
def test_fractional_seconds_of_slow_poses_are_seconds(t0_s):
    """Poses every second (1 Hz) in float seconds: a period 2.3 decades from 5 ms in seconds (1.3 with the
    epoch bonus), 0.7 decades in ms."""
    t_s = t0_s + 1.0 * np.arange(40)
    unit, reason, scores = guess_time_unit(t_s, kind="poses")
    assert unit == "s", (reason, scores)
    assert scores["ms"] - FRACTION_PENALTY < scores["s"], scores
    # whole numbers with the same period in ms (1000 ms) are not read as seconds
    assert guess_time_unit(np.round(t_s * 1e3), kind="poses")[0] != "s"


@pytest.mark.parametrize("kind", ["events", "poses"])
def test_too_few_values_fall_back_to_seconds_when_fractional(kind):
    """One value, or only repeated values: no rate, no period. A fraction says seconds, a whole number µs."""
    for sample in ([12.5], [3.25, 3.25, 3.25]):
        unit, reason, scores = guess_time_unit(np.array(sample), kind=kind)
        assert unit == "s", (sample, reason)
        assert all(not math.isfinite(v) for v in scores.values())
        assert "too few" in reason and "seconds" in reason
    for sample in ([12.0], [3.0, 3.0]):
        unit, reason, _ = guess_time_unit(np.array(sample), kind=kind)
        assert unit == "us", (sample, reason)
