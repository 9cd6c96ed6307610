"""How the score row shows what its scores are worth: low-evidence windows in their own style, and a stale row.

A **low-evidence** window (:mod:`evpose.core.align.score_evidence`: too few events near the object's edges,
no image motion, the object mostly out of view) keeps its score, drawn as a small grey ring off the object's
curve, so it never reads as a bad score; runs of windows where no object has evidence are shaded grey and
hatched. A **stale** row (the clock or a pose changed since it was computed) is dimmed, with a label, until
fresh scores replace it.
"""
from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore

from evpose.widgets.timeline.marks import merge_runs
from evpose.widgets.timeline.style import LOW_EVIDENCE_COLOR

__all__ = ["STALE_TEXT", "StaleLabel", "low_evidence_bands", "low_evidence_points", "no_evidence_windows"]

STALE_TEXT = "stale — recomputing"
STALE_ALPHA = 70                 # curves of a stale row (of 255)


def no_evidence_windows(scores: dict, low: dict) -> np.ndarray:
    """(N,) bool: some object has a low-evidence score there and no object has a score with evidence."""
    if not low:
        return np.zeros(0, bool)
    any_low = np.any([low[n] & np.isfinite(scores[n]) for n in low], axis=0)
    any_ok = np.any([np.isfinite(s) & ~low.get(n, np.zeros(len(s), bool)) for n, s in scores.items()], axis=0)
    return any_low & ~any_ok


def low_evidence_bands(t_s: np.ndarray, where: np.ndarray) -> list[pg.LinearRegionItem]:
    """Grey hatched full-height bands over the runs of ``where`` (window centres ``t_s``, s; each band
    reaches half-way to the neighbouring windows)."""
    if len(t_s) == 0 or not where.any():
        return []
    if len(t_s) > 1:
        half = np.diff(t_s) / 2
        lo, hi = t_s - np.concatenate([[half[0]], half]), t_s + np.concatenate([half, [half[-1]]])
    else:
        lo, hi = t_s - 0.005, t_s + 0.005
    brush = pg.mkBrush(*LOW_EVIDENCE_COLOR, 110)
    brush.setStyle(QtCore.Qt.BDiagPattern)
    items = []
    for a, b in merge_runs([(float(lo[i]), float(hi[i])) for i in np.flatnonzero(where)]):
        item = pg.LinearRegionItem((a, b), movable=False, brush=brush, pen=pg.mkPen(None))
        item.setZValue(-15)
        item.setAcceptedMouseButtons(QtCore.Qt.NoButton)
        for line in item.lines:
            line.setAcceptedMouseButtons(QtCore.Qt.NoButton)
        item.setToolTip("low evidence: no object has enough events near its edges, image motion or share in "
                        "view here; its scores say little about the pose")
        items.append(item)
    return items


def low_evidence_points(t_s: np.ndarray, scores: dict, low: dict) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` of every object's low-evidence scores (drawn as grey rings)."""
    xs, ys = [], []
    for n, s in scores.items():
        m = low.get(n)
        if m is not None:
            m = m & np.isfinite(s)
            xs.append(t_s[m])
            ys.append(s[m])
    return (np.concatenate(xs), np.concatenate(ys)) if xs else (np.zeros(0), np.zeros(0))


class StaleLabel:
    """"stale — recomputing" in the score row's top-right corner, clear of the legend (ViewBox pixels: it
    stays put on pan and zoom)."""

    def __init__(self, vb: pg.ViewBox):
        self.vb = vb
        self.item = pg.TextItem(STALE_TEXT, color=(150, 60, 0), fill=pg.mkBrush(255, 255, 255, 220), anchor=(1, 0))
        self.item.setParentItem(vb)
        self.item.setZValue(30)
        self.item.setVisible(False)
        vb.sigResized.connect(self._place)
        self._place()

    def _place(self, *_) -> None:
        self.item.setPos(self.vb.width() - 4, 2)

    def show(self, on: bool, text: str = STALE_TEXT) -> None:
        self.item.setText(text)
        self.item.setVisible(on)

    @property
    def text(self) -> str:
        return self.item.textItem.toPlainText()
