"""The triage report as one self-contained HTML file: the document of :func:`evpose.core.dataset.triage.triage`
drawn as a header, the scenes to fix first (with what changed since the last report), every flag ranked, an overview of every scene (table, clock and
unlabeled-share plots) and one section per scene (facts, flags, score distributions, worst windows).

No network: the CSS is inline, the plots are inline SVG (:mod:`evpose.core.dataset.svg_plots`), the thumbnails
inline PNG, the only script sorts and filters the overview table. Every text from the document is escaped.
"""
from __future__ import annotations

import math
from html import escape
from pathlib import Path

from evpose.core.data.atomic import write_atomic
from evpose.core.dataset import svg_plots
from evpose.core.dataset.report_style import CSS, SORT_JS

__all__ = ["render_report", "write_report"]


def write_report(doc: dict, path) -> Path:
    """Write the report of the triage document ``doc`` to ``path`` (atomically) and return the path."""
    return write_atomic(Path(path), render_report(doc).encode("utf-8"))


def render_report(doc: dict) -> str:
    """The report's HTML text."""
    ids = {r["name"]: f"scene-{k}" for k, r in enumerate(doc["scenes"])}
    title = f"evpose triage: {doc['dataset']}"
    parts = [f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{escape(title)}</title>',
             f"<style>{CSS}</style></head><body><main>", _header(doc), _scenes_first(doc, ids), _ranked(doc, ids),
             _overview(doc, ids)]
    parts += [_scene_section(r, ids[r["name"]], doc["thresholds"]) for r in doc["scenes"]]
    parts.append(_footer(doc))
    parts.append(f"</main><script>{SORT_JS}</script></body></html>\n")
    return "".join(parts)


# ----------------------------------------------------------------------------------------- formatting
def _e(x) -> str:
    return escape(str(x))


def _count(n) -> str:
    if n is None:
        return "–"
    for div, unit in ((1e9, " G"), (1e6, " M"), (1e3, " k")):
        if abs(n) >= div:
            return f"{n / div:.3g}{unit}"
    return str(n)


def _pct(x, digits=0) -> str:
    return "–" if x is None else f"{100 * x:.{digits}f} %"


def _ms(us, sign=True) -> str:
    return "–" if us is None else (f"{us / 1000:+.1f} ms" if sign else f"{us / 1000:.1f} ms")


def _sev_class(kind: str, sev: float) -> str:
    return "sev fail" if kind == "failed" else ("sev hi" if sev >= 10 else "sev mid" if sev >= 3 else "sev lo")


def _t_rel(rec: dict, t_us) -> str:
    return "" if t_us is None or rec.get("t0_us") is None else f"t = {(t_us - rec['t0_us']) * 1e-6:.3f} s"


# ----------------------------------------------------------------------------------------- sections
def _header(doc: dict) -> str:
    s = doc["summary"]
    facts = [f"{s['n_scenes']} scenes", f"{s['n_failed']} failed", f"{s['n_flagged']} flagged",
             f"{_count(s['n_events'])} events", f"{s['duration_s']:.1f} s recorded", f"{s['n_windows']} windows",
             f"{_pct(s['verified_windows'] / s['n_windows'] if s['n_windows'] else None)} verified",
             f"runtime {doc['runtime_s']:.1f} s"]
    cls = ' class="bad"' if s["n_failed"] else ""
    items = "".join(f"<li{cls if 'failed' in f else ''}>{_e(f)}</li>" for f in facts)
    return (f'<header><h1>Triage report <span class="ds">{_e(doc["dataset"])}</span></h1>'
            f'<ul class="facts" id="summary">{items}</ul></header>')


def _since_last(doc: dict) -> str:
    s = doc.get("since_last")
    if not s:
        return ""
    parts = [("newly flagged", ", ".join(s["new"])), ("no longer flagged", ", ".join(s["resolved"])),
             ("flagged for another cause", ", ".join(f"{c['scene']} ({c['was']} → {c['now']})" for c in s["changed"]))]
    if s.get("options_changed"):
        parts.append(("made with other options than the last", f"{s['options_changed']['was']} → "
                                                               f"{s['options_changed']['now']}"))
    items = "".join(f"<li><b>{_e(k)}</b>: {_e(v)}</li>" for k, v in parts if v)
    return f'<p class="since" id="since-last">Since the last report: {"<ul>" + items + "</ul>" if items else "nothing changed."}</p>'


def _scenes_first(doc: dict, ids: dict) -> str:
    """The scenes to fix, worst first: each with its cause, its reasons, the worst window of its first flagged
    object drawn small, and the command to run next."""
    rows = []
    recs = {r["name"]: r for r in doc["scenes"]}
    for e in doc.get("scenes_ranked", []):
        reasons = "".join(f"<li>{_e(x)}</li>" for x in e["reasons"])
        thumbs = {n: th for n, th in (recs[e["scene"]].get("thumbnails") or {}).items() if "png_b64" in th}
        mini = ""
        if thumbs:
            name, th = next(iter(thumbs.items()))
            mini = (f'<img class="mini" alt="{_e(name)}: window {th["window"]}" title="{_e(name)}: its worst window '
                    f'({th["window"]})" src="data:image/png;base64,{th["png_b64"]}">')
        rows.append(f'<li><span class="{_sev_class(e["cause"], e["severity"])}" title="severity">'
                    f'{e["severity"]:.1f}</span><a href="#{ids[e["scene"]]}" class="scene">{_e(e["scene"])}</a>'
                    f'<span class="tag">{_e(e["cause"])}</span><ul class="reasons">{reasons}</ul>{mini}'
                    f'<code class="next" title="the next command">{_e(e["next"])}</code></li>')
    body = f'<ol class="scenes-first">{"".join(rows)}</ol>' if rows else '<p class="ok">Nothing flagged.</p>'
    return f'<section id="scenes-first"><h2>Fix these scenes first</h2>{_since_last(doc)}{body}</section>'


def _ranked(doc: dict, ids: dict) -> str:
    rows = []
    for e in doc["ranked"]:
        rec = next(r for r in doc["scenes"] if r["name"] == e["scene"])
        where = "".join(f'<span class="tag">{_e(t)}</span>' for t in
                        ([e["object"]] if e["object"] else []) +
                        ([f"window {e['window']}", _t_rel(rec, e["t_label_us"])] if e["window"] is not None else [])
                        if t)
        rows.append(f'<li><span class="{_sev_class(e["kind"], e["severity"])}" title="severity">'
                    f'{e["severity"]:.1f}</span><a href="#{ids[e["scene"]]}" class="scene">{_e(e["scene"])}</a>'
                    f'{where}<span class="reason">{_e(e["reason"])}</span></li>')
    body = f'<ol class="ranked">{"".join(rows)}</ol>' if rows else '<p class="ok">Nothing flagged.</p>'
    return f'<section id="ranked"><h2>Every flag, worst first</h2>{body}</section>'


def _overview(doc: dict, ids: dict) -> str:
    heads = ["Scene", "Events", "Duration", "Unlabeled", "Clock Δ", "σ", "n σ", "Lowest median score",
             "Verified", "Flags"]
    th = "".join(f'<th class="{"num" if k else "name"}">{_e(h)}</th>' for k, h in enumerate(heads))
    rows = "".join(_overview_row(r, ids[r["name"]]) for r in doc["scenes"])
    t = doc["thresholds"]
    ok = [r for r in doc["scenes"] if r["status"] == "ok"]
    clock_rows = [_clock_row(r) for r in ok]
    share_rows = [(r["name"], r["windows"]["holes_share"], r["windows"]["outside_share"]) for r in ok]
    plots = ""
    if ok:
        plots = (f'<div class="plots"><figure><figcaption>Clock estimate − clock in effect (● ±1 σ, thin: '
                 f'±{t["clock_k_sigma"]:g} σ, σ including the model-error floor; red: flagged, '
                 f'hollow: σ loose)</figcaption>'
                 f'{svg_plots.clock_plot(clock_rows, k_sigma=t["clock_k_sigma"])}</figure>'
                 f'<figure><figcaption>Windows without a label (<span class="key holes"></span> trajectory holes, '
                 f'<span class="key outside"></span> outside the trajectory; dashed: '
                 f'{_pct(t["max_unlabeled_share"])})</figcaption>'
                 f'{svg_plots.share_bars(share_rows, threshold=t["max_unlabeled_share"])}</figure></div>')
    tools = ('<div class="filter"><input type="search" id="scene-filter" placeholder="filter: scene name or flag text '
             '(clock, pose, mounting, …)" aria-label="filter the scenes"><label><input type="checkbox" '
             'id="flagged-only"> flagged only</label><span id="shown"></span></div>')
    return (f'<section id="overview"><h2>Scenes</h2>{tools}<table class="scenes sortable filterable"><thead><tr>{th}'
            f'</tr></thead><tbody>{rows}</tbody></table>{plots}</section>')


def _cell(text, sort=None, cls="") -> str:
    key = "" if sort is None else f' data-sort="{_e(sort)}"'
    c = f' class="{cls}"' if cls else ""
    return f"<td{key}{c}>{_e(text)}</td>"


def _overview_row(r: dict, sid: str) -> str:
    name = f'<td data-sort="{_e(r["name"])}"><a href="#{sid}">{_e(r["name"])}</a></td>'
    nflags = len(r["flags"])
    flags = _cell(nflags, nflags, "num bad" if nflags else "num")
    why = " | ".join(f'{f["kind"]}: {f["reason"]}' for f in r["flags"])
    tr = f'<tr data-flags="{nflags}" data-reasons="{_e(why)}"'
    if r["status"] == "failed":
        return f'{tr} class="failed">{name}<td colspan="8" class="err">failed: {_e(r["error"])}</td>{flags}</tr>'
    w, c, rv = r["windows"], r["clock"], r["review"]
    medians = [(s["quantiles"]["p50"], n) for n, s in r["scores"].items() if s["quantiles"]]
    low = min(medians) if medians else None
    verified = rv.get("verified_fraction")
    nsig = c["n_sigma"]
    cells = [_cell(_count(r["n_events"]), r["n_events"], "num"), _cell(f"{r['duration_s']:.2f} s", r["duration_s"], "num"),
             _cell(_pct(w["unlabeled_share"], 1), w["unlabeled_share"], "num"),
             _cell(_ms(c["delta_effect_us"]) if c["reliable"] else "unreliable", c["delta_effect_us"], "num"),
             _cell("∞" if c["offset_pinned"] is False else _ms(c["offset_std_us"], False),
                   1e12 if c["offset_pinned"] is False else c["offset_std_us"], "num"),
             _cell("–" if nsig is None else f"{nsig:.1f}", nsig, "num"),
             _cell("–" if low is None else f"{low[0]:.2f} ({low[1]})", None if low is None else low[0], "num"),
             _cell(_pct(verified), verified, "num")]
    return f'{tr}>{name}{"".join(cells)}{flags}</tr>'


def _clock_row(r: dict) -> tuple:
    c = r["clock"]
    if not c["reliable"] or c["delta_effect_us"] is None:
        return r["name"], None, None, None, "warn", f"not reliable: {c['reason']}"
    std = None if c["offset_std_us"] is None else c["offset_std_us"] / 1000
    st = None if c["sigma_total_us"] is None else c["sigma_total_us"] / 1000
    kinds = {f["kind"] for f in r["flags"]}
    status = "warn" if kinds & {"clock", "skew"} else "unsure" if "clock_uncertain" in kinds else "ok"
    sigma = "σ unbounded" if c["offset_pinned"] is False else f"± {_ms(c['offset_std_us'], False)}"
    return r["name"], c["delta_effect_us"] / 1000, std, st, status, f"{_ms(c['delta_effect_us'])} {sigma}"


def _scene_section(r: dict, sid: str, t: dict) -> str:
    head = f'<h2>{_e(r["name"])} ' + ('<span class="badge fail">failed</span>' if r["status"] == "failed" else
                                       f'<span class="badge{" warn" if r["flags"] else " ok"}">'
                                       f'{len(r["flags"])} flag{"s" if len(r["flags"]) != 1 else ""}</span>') + "</h2>"
    if r["status"] == "failed":
        return f'<section class="scene" id="{sid}">{head}<p class="errbox">{_e(r["error"])}</p></section>'
    flags = "".join(f'<li><span class="{_sev_class(f["kind"], f["severity"])}">{f["severity"]:.1f}</span>'
                    f'{_e(f["reason"])}</li>' for f in r["flags"])
    flags = f'<ul class="flags">{flags}</ul>' if flags else ""
    path = f'<p class="path">{_e(r["path"])}</p>' if r.get("path") else ""
    box, table = _objects(r, t)
    return (f'<section class="scene" id="{sid}">{head}{path}<div class="top"><div>{_facts(r)}{flags}</div>{box}</div>'
            f'{_thumbs(r)}{table}</section>')


def _thumbs(r: dict) -> str:
    """The flagged objects' worst windows: event frame (ON red, OFF blue) with every object's contour."""
    figs = []
    for name, th in (r.get("thumbnails") or {}).items():
        if "png_b64" not in th:
            figs.append(f'<p class="thumb-missing">{_e(name)}: no picture of window {th["window"]} '
                        f'({_e(th.get("error", ""))})</p>')
            continue
        figs.append(f'<figure class="thumb"><img alt="{_e(name)}: window {th["window"]}" '
                    f'src="data:image/png;base64,{th["png_b64"]}"><figcaption>{_e(name)}: window {th["window"]}, '
                    f'{_e(_t_rel(r, th["t_label_us"]))} (its worst; events ON red, OFF blue; contours of the labels, '
                    f'{_e(name)} thick)</figcaption></figure>')
    return f'<div class="thumbs">{"".join(figs)}</div>' if figs else ""


def _facts(r: dict) -> str:
    w, c, rv = r["windows"], r["clock"], r["review"]
    win = f"{w['n_windows']} × {w['window_us'] / 1000:g} ms" if w["window_us"] else str(w["n_windows"])
    if c["reliable"]:
        std = (", σ unbounded" if c["offset_pinned"] is False else
               "" if c["offset_std_us"] is None else f" ± {_ms(c['offset_std_us'], False)}")
        nsig = "" if c["n_sigma"] is None else f" ({c['n_sigma']:.1f} σ)"
        clock = f"{_ms(c['delta_effect_us'])}{std} from the clock in effect{nsig}"
    else:
        clock = f"not reliable: {c['reason']}"
    skew = ("not estimated" if c["estimate_skew_ppm"] is None else
            f"estimate {c['estimate_skew_ppm']:+.1f} ppm (drift {_ms(c['skew_drift_us'])} over the scene)")
    marks = ", ".join(f"{k} {v}" for k, v in sorted((rv.get("marks") or {}).items())) or "none"
    frac = rv.get("verified_fraction") or 0.0
    items = [("Events", f"{_count(r['n_events'])} ({r['duration_s']:.2f} s)"), ("Windows", win),
             ("Unlabeled", f"{_pct(w['unlabeled_share'], 1)}: {w['in_holes']} in {w['n_holes']} trajectory holes, "
                           f"{w['outside_trajectory']} outside the trajectory"),
             ("Clock estimate", clock),
             ("Clock", f"in effect {_ms(c['effect_offset_us'])}, prior {_ms(c['prior_offset_us'])}, "
                       f"estimate {_ms(c['estimate_offset_us'])}"),
             ("Skew", f"{skew}; in effect {c['effect_skew_ppm']:+.1f} ppm"),
             ("Review", f"{rv.get('verified_windows', 0)} of {rv.get('n_windows', 0)} windows verified "
                        f"({_pct(frac)}), {rv.get('touched_not_verified', 0)} partly verified, mixed or stale; "
                        f"marks: {marks}")]
    for name, la in (r.get("looked_at") or {}).items():
        items.append(("Looked at, fine", f"{name}: its worst window {la['window']} verified in review"
                                          + (f" ({la['note']})" if la.get("note") else "")))
    dl = "".join(f"<dt>{_e(k)}</dt><dd>{_e(v)}</dd>" for k, v in items)
    bar = f'<div class="progress" title="verified"><div style="width:{100 * frac:.1f}%"></div></div>'
    return f'<dl class="facts">{dl}</dl>{bar}'


def _objects(r: dict, t: dict) -> tuple[str, str]:
    """The box plot of the objects' scores and the table of their numbers, histograms and worst windows."""
    edges = t["score_histogram_edges"]
    rows = [(n, s["quantiles"]) for n, s in r["scores"].items()]
    if not rows:
        return "", ""
    qs = [q for _, q in rows if q]
    lo = math.floor(10 * min([edges[0]] + [q["min"] for q in qs]) + 1e-9) / 10      # the axis holds every score
    hi = math.ceil(10 * max([edges[-1]] + [q["max"] for q in qs]) - 1e-9) / 10
    box = svg_plots.box_plot(rows, lo=lo, hi=hi, threshold=t["min_median_score"],
                             label=f"{r['name']}: score distribution per object")
    trs = []
    for n, s in r["scores"].items():
        q = s["quantiles"] or {}
        hist = svg_plots.histogram(s["histogram"]["edges"], s["histogram"]["counts"],
                                   threshold=t["min_median_score"], median=q.get("p50"),
                                   label=f"{r['name']} / {n}: score histogram")
        worst = "".join(f'<li>window {w["index"]} <span class="dim">{_e(_t_rel(r, w["t_label_us"]))}</span> '
                        f'<b>{w["score"]:.2f}</b> <span class="dim">({w["n_events_near"]} ev)</span></li>'
                        for w in s["worst"]) or '<li class="dim">none with enough events</li>'
        p10, p50, p90 = ("–" if k not in q else f"{q[k]:.2f}" for k in ("p10", "p50", "p90"))
        bad = " bad" if q and q["p50"] < t["min_median_score"] else ""
        trs.append(f'<tr><th class="obj">{_e(n)}</th><td class="num">{s["n_valid"]} / {s["n_evidence"]}</td>'
                   f'<td class="num">{p10}</td><td class="num{bad}">{p50}</td><td class="num">{p90}</td>'
                   f'<td>{hist}</td><td><ol class="worst">{worst}</ol></td></tr>')
    head = ("<tr><th>Object</th><th>scored / evidence</th><th>p10</th><th>median</th><th>p90</th>"
            f"<th>histogram (dashed: {t['min_median_score']:g})</th>"
            f"<th>worst windows (≥ {t['min_events_near']} events near)</th></tr>")
    return (f'<figure class="boxes"><figcaption>Alignment score per object (box p25–p75, whiskers p10–p90, '
            f'dots min/max, dashed: flag below {t["min_median_score"]:g})</figcaption>{box}</figure>',
            f'<table class="objects"><thead>{head}</thead><tbody>{"".join(trs)}</tbody></table>')


def _footer(doc: dict) -> str:
    t = doc["thresholds"]
    items = [f"clock flagged beyond {t['clock_k_sigma']:g} σ (the estimate's own σ, model-error floor included) "
             f"or when σ > {t['clock_loose_std_us'] / 1000:g} ms",
             f"skew drift over a scene > {t['max_skew_drift_us'] / 1000:g} ms",
             f"unlabeled windows > {_pct(t['max_unlabeled_share'])}",
             f"median alignment score < {t['min_median_score']:g}",
             f"worst windows need ≥ {t['min_events_near']} events near the silhouette"]
    return (f'<footer><p>Thresholds: {_e("; ".join(items))}.</p>'
            f'<p>{_e(doc["format"])} · written by evpose dataset report</p></footer>')
