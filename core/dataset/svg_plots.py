"""Small inline SVG plots drawn from numbers, for the triage report (:mod:`evpose.core.dataset.report_html`).

Every function returns one ``<svg>`` element as text: no scripts, no external resources, every label
escaped. Colours come from the report's CSS classes (``svg .bar``, ``svg .warn`` ...), so the plots follow
the page's style.
"""
from __future__ import annotations

import math
from html import escape

__all__ = ["box_plot", "clock_plot", "histogram", "share_bars"]

_FONT = 11


def _svg(width: int, height: int, body: list, label: str) -> str:
    return (f'<svg width="{width}" height="{height}" '
            f'viewBox="0 0 {width} {height}" role="img" aria-label="{escape(label)}">'
            f'<title>{escape(label)}</title>{"".join(body)}</svg>')


def _text(x, y, s, anchor="start", cls="lbl") -> str:
    return f'<text x="{x:.1f}" y="{y:.1f}" class="{cls}" text-anchor="{anchor}">{escape(str(s))}</text>'


def _line(x0, y0, x1, y1, cls="axis") -> str:
    return f'<line x1="{x0:.1f}" y1="{y0:.1f}" x2="{x1:.1f}" y2="{y1:.1f}" class="{cls}"/>'


def _rect(x, y, w, h, cls="bar", tip: str | None = None) -> str:
    tip_el = f"<title>{escape(tip)}</title>" if tip else ""
    return f'<rect x="{x:.1f}" y="{y:.1f}" width="{max(w, 0):.1f}" height="{max(h, 0):.1f}" class="{cls}">{tip_el}</rect>'


def histogram(edges, counts, *, threshold: float | None = None, median: float | None = None,
              width: int = 220, height: int = 70, label: str = "score histogram") -> str:
    """Vertical bars of ``counts`` over the bins ``edges``, with a dashed line at ``threshold`` (the
    flag's limit) and a solid one at ``median``."""
    lo, hi = float(edges[0]), float(edges[-1])
    top, bottom, left, right = 4, height - 14, 4, width - 4
    sx = (right - left) / (hi - lo)
    cmax = max(max(counts), 1)
    body = [_line(left, bottom, right, bottom)]
    for a, b, c in zip(edges[:-1], edges[1:], counts):
        h = (bottom - top) * c / cmax
        cls = "bar warnbar" if threshold is not None and b <= threshold + 1e-9 else "bar"
        body.append(_rect(left + (a - lo) * sx + 0.5, bottom - h, (b - a) * sx - 1, h, cls, f"[{a:g}, {b:g}): {c}"))
    for v, cls in ((threshold, "limit"), (median, "median")):
        if v is not None:
            x = left + (min(max(v, lo), hi) - lo) * sx
            body.append(_line(x, top, x, bottom, cls))
    body += [_text(left, height - 2, f"{lo:g}"), _text(right, height - 2, f"{hi:g}", "end"),
             _text((left + right) / 2, height - 2, "score", "middle", "lbl dim")]
    return _svg(width, height, body, label)


def box_plot(rows, *, lo: float, hi: float, threshold: float | None = None, width: int = 480,
             label: str = "score distribution") -> str:
    """One horizontal box per row ``(name, quantiles)``: whiskers p10-p90, box p25-p75, a mark at the
    median, dots at min and max (quantiles None: "no score"), on a shared axis ``[lo, hi]``."""
    row_h, left, right, top = 22, 110, width - 14, 6
    height = top + row_h * len(rows) + 22
    sx = (right - left) / (hi - lo)

    def x(v):
        return left + (min(max(v, lo), hi) - lo) * sx

    body = []
    step = 0.1 if hi - lo <= 1.0 + 1e-9 else 0.2
    for k in range(math.floor(lo / step + 1e-9), math.ceil(hi / step - 1e-9) + 1):
        v = round(k * step, 1)
        body.append(_line(x(v), top, x(v), height - 18, "grid"))
        body.append(_text(x(v), height - 5, f"{v:g}", "middle"))
    if threshold is not None:
        body.append(_line(x(threshold), top, x(threshold), height - 18, "limit"))
    for i, (name, q) in enumerate(rows):
        yc = top + row_h * i + row_h / 2
        body.append(_text(left - 8, yc + 4, name, "end"))
        if q is None:
            body.append(_text(left + 4, yc + 4, "no score", "start", "lbl dim"))
            continue
        cls = "box warnbox" if threshold is not None and q["p50"] < threshold else "box"
        tip = "  ".join(f"{k} {v:.3f}" for k, v in q.items())
        body += [_line(x(q["p10"]), yc, x(q["p90"]), yc, "whisker"),
                 _rect(x(q["p25"]), yc - 7, x(q["p75"]) - x(q["p25"]), 14, cls, tip),
                 _line(x(q["p50"]), yc - 8, x(q["p50"]), yc + 8, "median"),
                 f'<circle cx="{x(q["min"]):.1f}" cy="{yc:.1f}" r="2" class="dot"/>',
                 f'<circle cx="{x(q["max"]):.1f}" cy="{yc:.1f}" r="2" class="dot"/>']
    return _svg(width, height, body, label)


def clock_plot(rows, *, k_sigma: float, width: int = 520, label: str = "clock estimate") -> str:
    """Clock estimate minus the clock in effect (ms) per scene, with error bars of ±1 σ (thick) and
    ±``k_sigma`` σ_total (thin); the zero line is the clock in effect. ``rows``: ``(name, delta_ms or None,
    std_ms or None, sigma_total_ms or None, status, note)`` with ``status`` "ok", "warn" (disagrees) or
    "unsure" (loose or unbounded σ)."""
    row_h, left, right, top = 22, 130, width - 60, 6
    height = top + row_h * len(rows) + 22
    span = 5.0
    for _, d, s, st, _, _ in rows:
        if d is not None:
            span = max(span, abs(d) + k_sigma * (st or 0.0), abs(d) + (s or 0.0))
    span = _nice(span * 1.05)
    sx = (right - left) / (2 * span)

    def x(v):
        return left + (min(max(v, -span), span) + span) * sx

    body = [_line(x(0), top, x(0), height - 18, "zero")]
    for v in (-span, -span / 2, span / 2, span):
        body += [_line(x(v), top, x(v), height - 18, "grid"), _text(x(v), height - 5, f"{v:+g}", "middle")]
    body.append(_text(x(0), height - 5, "0 ms", "middle"))
    for i, (name, d, s, st, status, note) in enumerate(rows):
        yc = top + row_h * i + row_h / 2
        body.append(_text(left - 8, yc + 4, name, "end"))
        if d is None:
            body.append(_text(x(0) + 6, yc + 4, note, "start", "lbl dim"))
            continue
        if st is not None:
            body.append(_line(x(d - k_sigma * st), yc, x(d + k_sigma * st), yc, "errk"))
        if s is not None:
            body.append(_line(x(d - s), yc, x(d + s), yc, "err1"))
        body.append(f'<circle cx="{x(d):.1f}" cy="{yc:.1f}" r="4" class="dot {status}"><title>{escape(note)}</title></circle>')
        body.append(_text(right + 6, yc + 4, f"{d:+.1f} ms", "start", "lbl num"))
    return _svg(width, height, body, label)


def share_bars(rows, *, threshold: float, width: int = 520, label: str = "unlabeled windows") -> str:
    """Stacked horizontal bars per scene of the shares (0-1) ``(name, holes, outside)`` of windows without
    a label, with a dashed line at ``threshold``; the axis ends at the larger of 2 x threshold and the
    largest share."""
    row_h, left, right, top = 22, 130, width - 60, 6
    height = top + row_h * len(rows) + 22
    vmax = max([2 * threshold] + [h + o for _, h, o in rows if h is not None])
    sx = (right - left) / vmax
    body = []
    for k in range(5):
        v = vmax * k / 4
        body += [_line(left + v * sx, top, left + v * sx, height - 18, "grid"),
                 _text(left + v * sx, height - 5, f"{100 * v:.0f} %", "middle")]
    body.append(_line(left + threshold * sx, top, left + threshold * sx, height - 18, "limit"))
    for i, (name, holes, outside) in enumerate(rows):
        yc = top + row_h * i + row_h / 2
        body.append(_text(left - 8, yc + 4, name, "end"))
        if holes is None:
            body.append(_text(left + 4, yc + 4, "no data", "start", "lbl dim"))
            continue
        body += [_rect(left, yc - 7, holes * sx, 14, "bar holes", f"trajectory holes {100 * holes:.1f} %"),
                 _rect(left + holes * sx, yc - 7, outside * sx, 14, "bar outside",
                       f"outside the trajectory {100 * outside:.1f} %"),
                 _text(right + 6, yc + 4, f"{100 * (holes + outside):.1f} %", "start", "lbl num")]
    return _svg(width, height, body, label)


def _nice(v: float) -> float:
    """The smallest 1, 2, 2.5 or 5 times a power of ten that is >= v."""
    p = 10 ** math.floor(math.log10(v))
    return next(m * p for m in (1, 2, 2.5, 5, 10) if m * p >= v)
