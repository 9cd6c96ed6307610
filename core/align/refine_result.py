"""The knobs and the outcome of a refinement from events (object pose or clock offset).

Shared by the pose refinement (:mod:`evpose.core.align.pose_refine`) and the clock refinement
(:mod:`evpose.core.align.clock_refine`), which fit the same edge objective
(:mod:`evpose.core.align.edges`), and read by the CLI, the app and the benchmarks.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from evpose.core.label.windows import DEFAULT_WINDOW_US

__all__ = ["DEFAULT_SIGMAS_PX", "RefineParams", "RefineResult", "json_number"]

#: Coarse-to-fine kernel widths (px at half DAVIS346 resolution, fx = 146; scaled by fx / 146).
DEFAULT_SIGMAS_PX = (1.5, 0.8, 0.5, 0.3, 0.2, 0.12, 0.08)



def json_number(x):
    """``x`` as a JSON number, None when missing or not finite (JSON has no inf / NaN)."""
    return None if x is None or not math.isfinite(x) else float(x)

@dataclass(frozen=True)
class RefineParams:
    """Knobs of the refinement (pixels are pixels of the scene camera).

    ``sigmas_px=None`` picks :data:`DEFAULT_SIGMAS_PX` = ``(1.5, 0.8, 0.5, 0.3, 0.2, 0.12, 0.08)``
    px scaled by ``fx / 146`` (half DAVIS346 focal length), i.e. ~3 px down to ~0.16 px at full
    DAVIS resolution. The fine levels matter: on textured objects the event density is much
    higher inside the silhouette than outside, and the edge kernel's optimum is then displaced
    from the true edge by an amount proportional to ``sigma`` (on the benchmark scenes, stopping
    at 0.5 px left ~1.5 mm of depth and ~1 degree of out-of-plane rotation; ``bench/accuracy.py``).
    Windows are motion-compensated per event, so they may be long (10 ms); more windows spread
    over the sequence give more viewpoints, which is what constrains the depth and the rotation.
    """

    n_windows: int = 24
    window_us: int = DEFAULT_WINDOW_US
    max_events: int = 20_000
    sigmas_px: tuple | None = None
    outer_per_level: int = 8
    step_sigmas: float = 1.0      # trust region of one outer step: edges move at most this many sigma
    band_sigmas: float = 3.0
    spacing_px: float = 0.5
    max_iter: int = 60
    n_sub: int = 3
    ridge_sigma_px: float = 10.0  # the ridge term is used at levels with sigma <= this (x fx/146)


@dataclass
class RefineResult:
    """Outcome of a refinement.

    Attributes
    ----------
    kind : "pose" or "offset"
    object : str or None
    dT_base : (4, 4) or None
        The object's **total** correction to store (``T_base_obj' = dT_base @ T_base_obj``
        of the manifest); the start value when not accepted.
    offset_us : int or None
        Total effective clock offset (offset refinement).
    offset_std_us : float or None
        Its standard error (jackknife over the windows) when accepted; ``inf`` when the windows
        do not pin it, NaN with fewer than 3 windows.
    skew_ppm : float or None
        Total skew of the accepted clock (the start's unless ``skew_estimated``).
    skew_std_ppm : float or None
        Standard error of the skew fitted from the windows (also when it was not taken).
    skew_estimated : bool
        The fitted skew was taken (see :func:`refine_offset`).
    dR_deg, dt_mm : float
        Size of the change found (rotation angle, translation of the object's centre).
    score_before, score_after : float or None
        Mean :mod:`evpose.core.align.score` alignment score over the refinement windows.
    objective_before, objective_after : float
        The fitted objective (mean kernel value per event, higher is better).
    n_windows, iterations : int
    runtime_s : float
    accepted : bool
    reason : str
    trace : list of dict
        Per outer iteration: ``iteration``, ``sigma_px``, ``objective``, ``T_base_obj`` or
        ``offset_us``, ``elapsed_s`` (for error-against-iterations benchmarks).
    """

    kind: str
    object: str | None
    dT_base: np.ndarray | None = None
    offset_us: int | None = None
    offset_std_us: float | None = None
    skew_ppm: float | None = None
    skew_std_ppm: float | None = None
    skew_estimated: bool = False
    dR_deg: float = 0.0
    dt_mm: float = 0.0
    score_before: float | None = None
    score_after: float | None = None
    objective_before: float = float("nan")
    objective_after: float = float("nan")
    n_windows: int = 0
    iterations: int = 0
    runtime_s: float = 0.0
    accepted: bool = False
    reason: str = ""
    trace: list = field(default_factory=list)

    def to_json(self) -> dict:
        num = json_number
        d = {"kind": self.kind, "object": self.object, "dR_deg": float(self.dR_deg), "dt_mm": float(self.dt_mm),
             "score_before": num(self.score_before), "score_after": num(self.score_after),
             "objective_before": num(self.objective_before), "objective_after": num(self.objective_after),
             "n_windows": int(self.n_windows), "iterations": int(self.iterations),
             "runtime_s": float(self.runtime_s), "accepted": bool(self.accepted), "reason": self.reason}
        if self.dT_base is not None:
            d["dT_base"] = np.asarray(self.dT_base).tolist()
        if self.offset_us is not None:
            d["offset_us"] = int(self.offset_us)
        if self.offset_std_us is not None:
            d["offset_std_us"] = num(self.offset_std_us)
        if self.kind == "offset":
            d["skew_ppm"] = num(self.skew_ppm)
            d["skew_std_ppm"] = num(self.skew_std_ppm)
            d["skew_estimated"] = bool(self.skew_estimated)
        return d

