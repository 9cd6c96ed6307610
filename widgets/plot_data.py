"""Polylines and segments as the x, y arrays one pyqtgraph ``PlotCurveItem`` draws them from."""
from __future__ import annotations

import numpy as np

__all__ = ["polylines_xy", "segments_xy"]


def polylines_xy(polys) -> tuple[np.ndarray, np.ndarray]:
    """Polylines (M, 2+) concatenated with NaN breaks, for one ``PlotCurveItem(connect='finite')``."""
    if not len(polys):
        return np.zeros(0), np.zeros(0)
    parts = []
    for p in polys:
        parts += [np.asarray(p, np.float64)[:, :2], np.full((1, 2), np.nan)]
    xy = np.concatenate(parts)
    return xy[:, 0], xy[:, 1]


def segments_xy(segments, dy: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(Q, 2, 2) segments -> x, y arrays for ``PlotCurveItem(connect='pairs')``, y moved by ``dy``."""
    seg = np.asarray(segments, np.float64).reshape(-1, 2)
    return seg[:, 0], seg[:, 1] + dy
