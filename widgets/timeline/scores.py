"""The timeline's score row: per-object alignment scores over time, each in its object's colour, with
the worst window of each object marked (x), a cursor and the current window's span; it also keeps the
control row's "Scores" check box and "Worst ▾" menu in step with the scores shown. The legend is a line above the
row (never over the scores), and the y range holds every score, values above 1 included.

Low-evidence windows (their scores say little about the pose) are drawn apart, as grey rings, and are never
the worst; a stale row (computed before the clock or a pose changed) is dimmed with a label
(:mod:`~evpose.widgets.timeline.evidence`)."""
from __future__ import annotations

import numpy as np
import pyqtgraph as pg

from evpose.widgets.timeline.evidence import (
    STALE_ALPHA,
    STALE_TEXT,
    StaleLabel,
    low_evidence_bands,
    low_evidence_points,
    no_evidence_windows,
)
from evpose.widgets.timeline.style import (
    LEFT_AXIS_W,
    LOW_EVIDENCE_COLOR,
    RIGHT_AXIS_W,
    ScrubViewBox,
    label_style,
    long_curve,
    make_cursor,
    make_span,
    small_font,
    swatch,
    white_layout,
)

__all__ = ["ScoreRow"]

OTHER_COLOR = (80, 80, 80)      # a score series that names no object of the scene
LEGEND_H = 15                   # px of the legend line above the row


def legend_html(entries) -> str:
    """One line of ``(name, rgb, faint)`` legend entries: a line of the curve's colour, then the name."""
    parts = []
    for name, rgb, faint in entries:
        colour = pg.mkColor(*rgb).name()
        style = "color:#999" if faint else "color:#222"
        parts.append(f"<span style='color:{colour}'><b>&#8212;&#8212;</b></span>"
                     f"&nbsp;<span style='{style}'>{name}</span>")
    return "&nbsp;&nbsp;&nbsp; ".join(parts)


def score_range(scores: dict, lower_is_better: bool = False) -> tuple[float, float]:
    """The row's y range: every finite score (values above 1 too), with 0 and 1 always in view for scores (higher
    is better); a little margin so the extremes are not drawn on the border."""
    finite = [s[np.isfinite(s)] for s in scores.values()]
    finite = np.concatenate(finite) if finite else np.zeros(0)
    lo, hi = (0.0, 1.0) if not lower_is_better else (0.0, 0.0)
    if finite.size:
        lo, hi = min(lo, float(finite.min())), max(hi, float(finite.max()))
    if hi <= lo:
        hi = lo + 1.0
    pad = 0.06 * (hi - lo)
    return lo - pad, hi + pad


class ScoreRow:
    """Score curves of a :class:`~evpose.core.session.model.Session`'s objects, x-linked to the main row.

    Parameters
    ----------
    session : Session
        Read: object names, colours, the selected and hidden objects.
    scrub : callable(x_s, final)
        Left click / drag on the row.
    x_link : pg.ViewBox
        The main row's ViewBox (same x range).
    cursor_dragged, cursor_released : callable(line)
        The row's cursor line moved / let go.
    controls : ControlBar
        Its ``scores_check``, ``worst_button`` and ``worst_menu`` follow the scores.
    goto_worst : callable(name)
        A "Worst ▾" menu entry was chosen.
    axis : Timeline
        The time axis: ``axis.x_of(t_us)`` (plot x in s of an event time in µs) and ``axis.t_ref_us``
        (the event time of x = 0).
    """

    def __init__(self, session, scrub, x_link, cursor_dragged, cursor_released, *, controls, goto_worst, axis):
        self.session = session
        self.controls = controls
        self.goto_worst = goto_worst
        self.axis = axis
        self.t_s: np.ndarray | None = None
        self.scores: dict[str, np.ndarray] = {}
        #: name -> (N,) bool: the window's score has too little evidence (drawn apart, never the worst)
        self.low_evidence: dict[str, np.ndarray] = {}
        self.items: dict[str, pg.PlotDataItem] = {}
        self.lower_is_better = False
        #: True while the scores shown predate a change of the clock or a pose
        self.stale = False
        self.low_bands: list[pg.LinearRegionItem] = []
        self.glw = white_layout()
        self.vb = ScrubViewBox(scrub, enableMenu=False)
        # the legend: one line above the plot, never over the scores
        self.glw.ci.setSpacing(0)
        self.legend = self.glw.addLabel("", row=0, col=0, justify="left", size="8pt")
        self.legend.setMaximumHeight(LEGEND_H)
        self.plot: pg.PlotItem = self.glw.addPlot(row=1, col=0, viewBox=self.vb)
        sp = self.plot
        sp.setMenuEnabled(False)
        sp.hideButtons()
        sp.setMouseEnabled(x=True, y=False)
        sp.setXLink(x_link)
        sp.showGrid(x=True, y=True, alpha=0.15)
        sp.hideAxis("bottom")
        sp.getAxis("left").setWidth(LEFT_AXIS_W)
        sp.getAxis("left").setLabel("score", **label_style())
        small_font(sp.getAxis("left"))
        sp.showAxis("right")
        sp.getAxis("right").setWidth(2 * RIGHT_AXIS_W)
        sp.getAxis("right").setStyle(showValues=False)
        self.vb.enableAutoRange(x=False, y=False)     # every score in view, 0 and 1 always (set_scores)
        self.vb.setYRange(*score_range({}), padding=0)
        self.cursor = make_cursor(cursor_dragged, cursor_released)
        self.span = make_span()
        sp.addItem(self.span, ignoreBounds=True)
        sp.addItem(self.cursor, ignoreBounds=True)
        self.worst_item = pg.ScatterPlotItem(size=9, symbol="x", pen=None)
        self.worst_item.setZValue(15)
        sp.addItem(self.worst_item, ignoreBounds=True)
        self.low_item = pg.ScatterPlotItem(size=5, symbol="o", pen=pg.mkPen(*LOW_EVIDENCE_COLOR, 200), brush=None)
        self.low_item.setZValue(-1)
        sp.addItem(self.low_item)
        self.stale_label = StaleLabel(self.vb)

    def set_scores(self, t_s, scores: dict, *, lower_is_better: bool = False, label: str = "score",
                   low_evidence: dict | None = None) -> None:
        """Per-object alignment scores over time, drawn in each object's colour; shown fresh (not stale).

        Parameters
        ----------
        t_s : (N,) array
            Window label times, seconds since the first event (the timeline's x).
        scores : dict name -> (N,) float
            NaN where undefined (object out of view, no events, no pose).
        lower_is_better : bool
            False (default) for :mod:`evpose.core.align.score`'s ``score`` (1 = every event on an edge, 0 =
            noise): the worst window is the minimum, as in ``evpose.core.align.score_table.worst_window``. True
            for distances (``distance_px``): the worst window is the maximum.
        label : str
            Left-axis label, with units.
        low_evidence : dict name -> (N,) bool, optional
            Windows whose score of that object has too little evidence
            (``evpose.core.align.score_table.ScoreTable.low_evidence``): drawn as grey rings off the curve,
            never the worst.
        """
        t_s = np.asarray(t_s, np.float64).ravel()
        clean, low = {}, {}
        for name, s in scores.items():
            s = np.asarray(s, np.float64).ravel()
            if s.shape != t_s.shape:
                raise ValueError(f"scores[{name!r}] has {s.size} values for {t_s.size} times")
            clean[name] = s
            m = np.zeros(s.shape, bool) if not low_evidence or name not in low_evidence else \
                np.asarray(low_evidence[name], bool).ravel()
            if m.shape != t_s.shape:
                raise ValueError(f"low_evidence[{name!r}] has {m.size} values for {t_s.size} times")
            low[name] = m
        self.clear_scores()
        self.t_s, self.scores, self.low_evidence, self.lower_is_better = t_s, clean, low, bool(lower_is_better)
        self.plot.getAxis("left").setLabel(label, **label_style())
        c = self.controls
        for name, s in clean.items():
            item = long_curve(pg.mkPen(self.color(name), width=1.5), name)
            self.plot.addItem(item)   # add before setData: clipping needs the ViewBox
            item.setData(t_s, np.where(low[name], np.nan, s))
            self.items[name] = item
            i = self.worst_index(name)
            if i is not None:          # the value and where: which object to look at first shows in the menu
                text = f"{name}: {s[i]:.3g} at {t_s[i]:.3f} s"
            else:
                text = name if not np.isfinite(s).any() else f"{name} — no window with enough evidence"
            has_worst = i is not None
            act = c.worst_menu.addAction(text)
            act.setIcon(swatch(self.color(name)))
            act.setEnabled(has_worst)
            act.triggered.connect(lambda _=False, n=name: self.goto_worst(n))
        self.low_item.setData(*low_evidence_points(t_s, clean, low))
        self.vb.setYRange(*score_range(clean, lower_is_better), padding=0)
        self.low_bands = low_evidence_bands(t_s, no_evidence_windows(clean, low))
        for band in self.low_bands:
            self.plot.addItem(band, ignoreBounds=True)
        self.set_stale(False)
        pts = [(self.axis.x_of(t), self.score_at(n, t), n) for n in clean if (t := self.worst_time(n)) is not None]
        self.worst_item.setData([p[0] for p in pts], [p[1] for p in pts],
                                brush=None, pen=[pg.mkPen(self.color(p[2]), width=2) for p in pts])
        has = bool(clean)
        c.scores_check.setEnabled(has)
        c.worst_button.setEnabled(has)
        c.scores_check.setChecked(has)
        self.glw.setVisible(has and c.scores_check.isChecked())

    def clear_scores(self) -> None:
        for item in list(self.items.values()) + self.low_bands:
            self.plot.removeItem(item)
        self.items.clear()
        self.low_bands = []
        self.scores, self.low_evidence = {}, {}
        self.t_s = None
        c = self.controls
        c.worst_menu.clear()
        self.worst_item.setData([], [])
        self.low_item.setData([], [])
        self.set_stale(False)
        c.scores_check.setEnabled(False)
        c.worst_button.setEnabled(False)
        self.glw.setVisible(False)

    def worst_time(self, name: str) -> int | None:
        """Event time (µs) of the window with the worst score of ``name`` (NaN ignored): the minimum, or the
        maximum when the scores were set with ``lower_is_better``; None if the object has no defined score."""
        i = self.worst_index(name)
        if i is None:
            return None
        return self.axis.t_ref_us + int(round(float(self.t_s[i]) * 1e6))

    def worst_index(self, name: str) -> int | None:
        """Index of the worst window of ``name`` (NaN and low-evidence windows ignored): the minimum, or the
        maximum when lower is better; None if the object has no defined score with evidence."""
        if name not in self.scores:
            raise KeyError(f"no scores for {name!r}")
        s = self.scores[name]
        finite = np.isfinite(s) & ~self.low_evidence.get(name, False)
        if not finite.any():
            return None
        masked = np.where(finite, s, -np.inf if self.lower_is_better else np.inf)
        return int(np.argmax(masked) if self.lower_is_better else np.argmin(masked))

    def score_at(self, name: str, t_us: int) -> float:
        """Score of ``name`` at the window nearest to event time ``t_us``."""
        i = int(np.argmin(np.abs(self.t_s - self.axis.x_of(t_us))))
        return float(self.scores[name][i])

    def color(self, name: str):
        return self.session.color(name) if name in self.session.object_names else OTHER_COLOR

    def style(self) -> None:
        """The selected object's curve wide and on top, hidden objects' faint; every curve dimmed while stale."""
        sel, hidden = self.session.view.selected, self.session.view.hidden
        for name, item in self.items.items():
            width = 2.5 if name == sel else 1.2
            alpha = STALE_ALPHA if self.stale else 90 if name in hidden else 255
            item.setPen(pg.mkPen(*self.color(name), alpha, width=width))
            item.setZValue(5 if name == sel else 0)
        self.legend.setText(legend_html([(n, self.color(n), n in hidden) for n in self.items]))

    def set_stale(self, stale: bool, text: str = STALE_TEXT) -> None:
        """Mark the scores shown as stale (dimmed, with ``text`` in the corner) or fresh."""
        self.stale = bool(stale) and bool(self.scores)
        self.stale_label.show(self.stale, text)
        for item in (self.worst_item, self.low_item, *self.low_bands):
            item.setOpacity(0.35 if self.stale else 1.0)
        self.style()
