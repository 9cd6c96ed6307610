"""Which unit (s, ms, µs, ns) a column of times is in, decided from the numbers and reported.

Published formats rarely state their time unit, and a wrong unit silently stretches a recording by 1000x.
:func:`guess_time_unit` scores each unit by how plausible the event rate or pose period it implies is;
:func:`resolve_time_unit` combines that guess with ``--time-unit`` and the format's declared unit, and writes
the decision (and any doubt) into the import report.
"""
from __future__ import annotations

import math

import numpy as np

from evpose.core.importers.report import ImportContext

_UNIT_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
_UNIT_NAMES = {"s": "seconds", "ms": "milliseconds", "us": "microseconds", "ns": "nanoseconds"}


def guess_time_unit(sample, *, kind: str = "events") -> tuple[str, str, dict]:
    """Guess the unit of a column of times from the numbers alone.

    Each unit gets a score (lower is better, ``inf`` = implausible): for events the event rate ``(n-1)/span``
    must lie in 10 .. 2e9 ev/s and the score is its distance (decades) from 1 M ev/s; for poses the median positive
    step must be a sampling period of 10 µs .. 2 s and the score is its distance from 5 ms. Values that read as an
    epoch date (years 1998..2100) in a unit get a bonus of one decade there; fractional values add two decades to
    ms/µs/ns. Units differ by 1000x, so real data is far from ties. With too few values for a rate or a period,
    a unique epoch reading decides, else seconds for fractional and µs for integer values.

    Returns
    -------
    unit : str
        ``"s"``, ``"ms"``, ``"us"`` or ``"ns"``.
    reason : str
        Human-readable justification (goes into the report).
    scores : dict
        Per-unit score.
    """
    v = np.asarray(sample, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return "us", "no finite sample; assumed microseconds", {}
    has_frac = bool(np.any(v != np.round(v)))
    vmin, vmax = float(v.min()), float(v.max())
    epoch = {u for u, f in _UNIT_S.items() if 8.8e8 <= vmin * f and vmax * f <= 4.1e9}
    scores = {}
    if kind == "events":
        span = vmax - vmin
        for u, f in _UNIT_S.items():
            if span <= 0 or len(v) < 2:
                scores[u] = math.inf
                continue
            rate = (len(v) - 1) / (span * f)
            scores[u] = abs(math.log10(rate / 1e6)) if 10 <= rate <= 2e9 else math.inf
        what = "event rate"
    else:
        d = np.diff(v)
        pos = d[d > 0]
        for u, f in _UNIT_S.items():
            if len(pos) == 0:
                scores[u] = math.inf
                continue
            step = float(np.median(pos)) * f
            scores[u] = abs(math.log10(step / 5e-3)) if 1e-5 <= step <= 2.0 else math.inf
        what = "sampling period"
    for u in scores:
        if u in epoch:
            scores[u] -= 1.0
        if has_frac and u != "s":
            scores[u] += 2.0
    finite = {u: sc for u, sc in scores.items() if math.isfinite(sc)}
    if not finite:
        if len(epoch) == 1:
            u = next(iter(epoch))
            return u, f"values look like epoch time in {_UNIT_NAMES[u]} (first {v[0]:.17g})", scores
        u = "s" if has_frac else "us"
        return u, f"too few distinct values to measure the {what}; assumed {_UNIT_NAMES[u]}", scores
    u = min(finite, key=finite.get)
    f = _UNIT_S[u]
    if kind == "events":
        val = f"{(len(v) - 1) / ((vmax - vmin) * f):.3g} ev/s"
    else:
        d = np.diff(v)
        val = f"{float(np.median(d[d > 0])) * f * 1e3:.3g} ms period"
    others = ", ".join(k for k in finite if k != u)
    reason = (f"{what} is plausible in {_UNIT_NAMES[u]} ({val}" + (", epoch-like values" if u in epoch else "") + ")"
              + (f"; also possible: {others}" if others else ""))
    return u, reason, scores


#: A forced unit is questioned when its plausibility score (decades from a typical event rate / pose period, see
#: :func:`guess_time_unit`) is this much worse than the best unit's: 2 decades = a 100x odd rate or period.
FORCED_UNIT_MARGIN_DECADES = 2.0


def _forced_unit_implausible(sample, forced: str, kind: str) -> str | None:
    """Why the numbers do not look like ``forced`` (None when they plausibly do): e.g. ``--time-unit ns`` on
    µs data gives 1834 M events/s."""
    unit, _reason, scores = guess_time_unit(sample, kind=kind)
    sc, best = scores.get(forced, math.inf), scores.get(unit, math.inf)
    if not scores or (math.isfinite(sc) and not (sc - best >= FORCED_UNIT_MARGIN_DECADES)):
        return None
    v = np.asarray(sample, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if len(v) < 2:
        return None
    f = _UNIT_S[forced]
    if kind == "events":
        span = float(v.max() - v.min()) * f
        if span <= 0:
            return None
        val = f"an event rate of {(len(v) - 1) / span / 1e6:.4g} M events/s"
    else:
        d = np.diff(v)
        pos = d[d > 0]
        if len(pos) == 0:
            return None
        val = f"a pose period of {float(np.median(pos)) * f * 1e3:.4g} ms"
    better = f"; the values look like {_UNIT_NAMES[unit]}" if unit != forced else ""
    return f"{_UNIT_NAMES[forced]} give {val}, which is implausible{better} (check --time-unit)"


def resolve_time_unit(ctx: ImportContext, sample, *, what: str, kind: str, declared: str | None = None) -> str:
    """Decide the unit of a time column: ``--time-unit`` wins; else the format's ``declared`` unit if the
    numbers are plausible in it; else the guess. The decision goes into the report (and stderr)."""
    forced = ctx.options.time_unit
    if forced:
        ctx.report.assume(f"{what}: times in {_UNIT_NAMES[forced]} (--time-unit)")
        ctx.report.details.setdefault("time_units", {})[what] = {"unit": forced, "why": "--time-unit"}
        implausible = _forced_unit_implausible(sample, forced, kind)
        if implausible:
            ctx.report.warn(f"{what}: --time-unit {forced}: {implausible}")
        return forced
    unit, reason, scores = guess_time_unit(sample, kind=kind)
    if declared is not None:
        if declared == unit or math.isfinite(scores.get(declared, math.inf)) or not scores:
            ctx.report.details.setdefault("time_units", {})[what] = {"unit": declared, "why": "format specification"}
            return declared
        ctx.report.warn(f"{what}: the format specifies {_UNIT_NAMES[declared]}, but the values are implausible in "
                        f"that unit; {reason}: using {_UNIT_NAMES[unit]} (override with --time-unit)")
    else:
        ctx.report.assume(f"{what}: times in {_UNIT_NAMES[unit]} ({reason}; override with --time-unit)")
    ctx.report.details.setdefault("time_units", {})[what] = {"unit": unit, "why": reason}
    return unit
