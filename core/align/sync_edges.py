"""The second stage of the clock sync (``evpose sync --edges``): the clock from event/edge
alignment, started at the event-rate estimate and searched within its uncertainty.

The rate pins the offset only loosely on slow sequences (a slow move starts and stops
gradually, see ``docs/sync.md``); searching the edges within a few of the rate estimate's
standard errors keeps the edge fit from locking onto a far-off local optimum while letting it
take the error to where the events are.
"""
from __future__ import annotations

import math

import numpy as np

from evpose.core.align.clock_refine import refine_offset
from evpose.core.align.refine_result import RefineParams, RefineResult

__all__ = ["SYNC_EDGE_MAX_RANGE_US", "SYNC_EDGE_MIN_RANGE_US", "SYNC_EDGE_STDS", "refine_offset_from_sync",
           "sync_edge_half_range_us"]

#: Search range of :func:`refine_offset_from_sync`: this many of the rate estimate's standard
#: errors, clamped to [``SYNC_EDGE_MIN_RANGE_US``, ``SYNC_EDGE_MAX_RANGE_US``]. Four, because the rate's sigma
#: (model-error floor included, :mod:`~evpose.core.align.uncertainty`) is meant to cover every error within 4 of
#: it and >= 90 % within 2: with 3 a right edge answer 3.3 sigma from the rate was refused (issue 23).
SYNC_EDGE_STDS = 4.0
SYNC_EDGE_MIN_RANGE_US = 1000.0
SYNC_EDGE_MAX_RANGE_US = 50_000.0


def sync_edge_half_range_us(sync_result) -> float:
    """Search half range of :func:`refine_offset_from_sync` around a rate estimate:
    :data:`SYNC_EDGE_STDS` of its standard errors, clamped to [:data:`SYNC_EDGE_MIN_RANGE_US`,
    :data:`SYNC_EDGE_MAX_RANGE_US`] (the maximum when it has none)."""
    std = getattr(sync_result, "offset_std_us", None)
    span = SYNC_EDGE_STDS * std if std is not None and math.isfinite(std) else SYNC_EDGE_MAX_RANGE_US
    return float(np.clip(span, SYNC_EDGE_MIN_RANGE_US, SYNC_EDGE_MAX_RANGE_US))


def refine_offset_from_sync(scene, sync_result, *, params: RefineParams = RefineParams(), progress=None,
                            cancel=None) -> RefineResult:
    """Second stage of the clock sync: the offset (and skew) from event/edge alignment
    (:func:`~evpose.core.align.clock_refine.refine_offset`), started at a reliable event-rate
    estimate (:func:`evpose.core.align.estimate.sync_scene`; its clock, with the prior skew when it
    estimated none) and searched within :func:`sync_edge_half_range_us`.

    The rate pins the offset only loosely on slow sequences (a slow move starts and stops
    gradually); the edges pin it to where the events are, ~0.05-0.3 ms on the benchmark scenes
    at 0.1-1.0 m/s, provided the object poses are right. Not accepted (start kept) when the rate
    estimate is not reliable.
    """
    if sync_result.offset_us is None or not sync_result.reliable:
        return RefineResult("offset", None, offset_us=int(scene.clock.offset_us),
                            reason="no reliable event-rate estimate to start from")
    return refine_offset(scene, params=params, half_range_us=sync_edge_half_range_us(sync_result),
                         clock=sync_result.clock(), progress=progress, cancel=cancel)
