"""What a clock estimate returns: the total clock found, how sure it is, and why not when it is not.

:class:`SyncResult` is the one outcome of every clock estimate (the rate estimate and the
E-POSE baseline alike), so the CLI, the app and the benchmarks read one shape;
:class:`ClockEstimate` is the estimate while its stages (:mod:`evpose.core.align.estimate`)
build it.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from evpose.core.align.refine_result import json_number
from evpose.core.data.clock import ClockModel

__all__ = ["SLOW_STD_NOTE_US", "ClockEstimate", "SegmentOffset", "SyncResult", "unreliable"]

SLOW_STD_NOTE_US = 1000.0     # offset standard error above this: a note says how loosely the rate pins it


@dataclass
class SegmentOffset:
    """Offset estimated on one segment of the sequence (event clock)."""

    t0_us: int
    t1_us: int
    t_center_us: int
    offset_us: float | None
    peak: float
    used: bool

    def to_json(self) -> dict:
        return {"t0_us": self.t0_us, "t1_us": self.t1_us, "t_center_us": self.t_center_us,
                "offset_us": self.offset_us, "peak": self.peak, "used": self.used}


@dataclass
class SyncResult:
    """Outcome of a clock estimate.

    Attributes
    ----------
    offset_us : int or None
        Total effective offset (prior + correction) at ``t_ref_us``, µs; None when unreliable.
    skew_ppm : float or None
        Total effective skew, ppm; None when not estimated (too short for skew, or unreliable):
        the clock's skew in effect is then kept.
    confidence : float
        In [0, 1]: peak NCC times its margin over the second-best peak.
    reliable : bool
    reason : str
        Why the estimate is unreliable ("" when reliable).
    lags_us : (L,) float64
        Total offsets at which the correlation curve is evaluated (for plots and the GUI).
    correlation : (L,) float64
        NCC per lag; NaN where too few bins overlap.
    segments : list of SegmentOffset
        Per-segment offsets used for the skew (empty when skew was not estimated).
    runtime_s : float
    offset_std_us : float or None
        Standard error (1 sigma) of ``offset_us`` from the curvature of the Poisson likelihood
        (``refine="ml"`` only; at the skew in effect before the final 2-D refinement): how
        tightly the event rate pins the offset. ``inf`` when the likelihood is flat over its
        scan (±30 ms at 1 ms bins); None when not computed. Large for slow sequences with few
        moves - a property of the data, not a failure (``docs/sync.md``).
    """

    offset_us: int | None
    skew_ppm: float | None
    confidence: float
    reliable: bool
    reason: str
    lags_us: np.ndarray
    correlation: np.ndarray
    segments: list = field(default_factory=list)
    runtime_s: float = 0.0
    method: str = "xcorr"
    peak: float = float("nan")
    second_peak: float = float("nan")
    peak_hwhm_us: float = float("nan")
    prior_offset_us: int = 0
    prior_skew_ppm: float = 0.0
    t_ref_us: int = 0
    notes: list = field(default_factory=list)
    offset_std_us: float | None = None
    #: ``offset_std_us`` before the model-error floor (:data:`~evpose.core.align.uncertainty.RATE_OFFSET_FLOOR_US`)
    #: that :func:`~evpose.core.align.estimate.sync_scene` adds: what the rate's Poisson noise alone allows.
    offset_std_data_us: float | None = None

    def clock(self) -> ClockModel | None:
        """The estimated clock model (prior skew kept when skew was not estimated)."""
        if self.offset_us is None:
            return None
        return ClockModel(int(self.offset_us), self.prior_skew_ppm if self.skew_ppm is None else float(self.skew_ppm),
                          self.t_ref_us)

    def to_json(self, curve: bool = False) -> dict:
        num = json_number
        d = {"method": self.method, "offset_us": self.offset_us, "skew_ppm": num(self.skew_ppm),
             "confidence": float(self.confidence), "reliable": bool(self.reliable), "reason": self.reason,
             "runtime_s": float(self.runtime_s), "peak_ncc": num(self.peak), "second_peak_ncc": num(self.second_peak),
             "peak_hwhm_us": num(self.peak_hwhm_us), "prior_offset_us": int(self.prior_offset_us),
             "prior_skew_ppm": float(self.prior_skew_ppm), "t_ref_us": int(self.t_ref_us),
             "offset_std_us": None if self.offset_std_us is None else num(self.offset_std_us),
             "offset_std_data_us": None if self.offset_std_data_us is None else num(self.offset_std_data_us),
             "offset_pinned": None if self.offset_std_us is None else bool(math.isfinite(self.offset_std_us)),
             "segments": [s.to_json() for s in self.segments], "notes": list(self.notes)}
        if curve:
            d["lags_us"] = [float(x) for x in self.lags_us]
            d["correlation"] = [num(x) for x in self.correlation]
        return d


@dataclass
class ClockEstimate:
    """The clock estimate while the stages refine it (offset at ``t_ref`` µs, skew ppm).

    ``loose_line`` is a Theil-Sen line ``(slope ppm, offset µs, half CI ppm)`` too uncertain to
    accept alone; the likelihood stage may still confirm it on the whole sequence.
    """

    offset_us: float
    skew_ppm: float
    notes: list
    skew_estimated: bool = False
    offset_std_us: float | None = None
    segments: list = field(default_factory=list)
    loose_line: tuple | None = None


def unreliable(reason: str, t_start: float, prior: ClockModel, method="xcorr", lags=None, corr=None,
               **kw) -> SyncResult:
    """A result without an estimate (``reliable=False``) saying why, timed from ``t_start``."""
    return SyncResult(None, None, 0.0, False, reason, np.zeros(0) if lags is None else lags,
                      np.zeros(0) if corr is None else corr, runtime_s=time.perf_counter() - t_start,
                      method=method, prior_offset_us=int(prior.offset_us), prior_skew_ppm=float(prior.skew_ppm),
                      t_ref_us=int(prior.t_ref_us), **kw)

