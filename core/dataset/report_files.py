"""The triage report's files: ``REPORT.html`` (:mod:`~evpose.core.dataset.report_html`) and beside it
``REPORT.csv`` (the scenes to fix, ranked: for a spreadsheet or a script) and ``REPORT.json`` (the whole triage
document: what the next report compares with).

A rerun reads the previous ``REPORT.json`` and records in the document's ``since_last`` what changed: scenes newly
flagged, no longer flagged, or flagged for another cause. The two siblings are replaced only when evpose wrote
them (the JSON's ``format``, the CSV's header row); another program's file of that name is refused, before any
work, with one line naming it.
"""
from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from evpose.core.data.atomic import AtomicBatch
from evpose.core.data.json_values import to_jsonable
from evpose.core.errors import NotOursError

__all__ = ["CSV_HEADER", "FIXABLE", "check_report_siblings", "flagged_scenes", "ranked_for", "ranking_csv", "since_last", "sibling_paths",
           "write_report_files"]

CSV_HEADER = ["rank", "scene", "severity", "cause", "reasons", "next"]
#: The worst causes of a report's scenes that each dataset command can deal with (``--only-flagged``, the dataset
#: view's Refine).
FIXABLE = {"sync": ("clock", "skew", "clock_uncertain", "object"),
           "refine": ("clock", "skew", "clock_uncertain", "object", "pose", "mounting")}


def sibling_paths(html) -> tuple[Path, Path]:
    """``(REPORT.csv, REPORT.json)`` beside ``html``."""
    html = Path(html)
    return html.with_suffix(".csv"), html.with_suffix(".json")


def _ours_json(path: Path):
    """The previous triage document at ``path``: None when absent; refused when it is not evpose's."""
    from evpose.core.dataset.triage import TRIAGE_FORMAT

    if not path.exists():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None
    except (OSError, UnicodeDecodeError, ValueError):
        doc = None
    if not isinstance(doc, dict) or doc.get("format") != TRIAGE_FORMAT:
        raise NotOursError(f"{path}: not a triage document evpose wrote (format {TRIAGE_FORMAT!r}); evpose writes "
                           "the report's JSON there and never replaces another file: move it or choose another --out")
    return doc


def _check_ours_csv(path: Path) -> None:
    if not path.exists():
        return
    try:
        first = path.read_text(encoding="utf-8").splitlines()[:1] if path.is_file() else None
    except (OSError, UnicodeDecodeError):
        first = None
    if first is None or next(csv.reader(first), None) != CSV_HEADER:
        raise NotOursError(f"{path}: not a triage ranking evpose wrote (header {','.join(CSV_HEADER)}); evpose writes "
                           "the report's CSV there and never replaces another file: move it or choose another --out")


def check_report_siblings(html):
    """Refuse before any work when ``REPORT.csv`` or ``REPORT.json`` exists and is not evpose's; returns the
    previous triage document (or None)."""
    csv_path, json_path = sibling_paths(html)
    _check_ours_csv(csv_path)
    return _ours_json(json_path)


def since_last(previous: dict | None, doc: dict) -> dict | None:
    """What changed against the previous report: ``new`` (scenes flagged now, not then), ``resolved`` (flagged
    then, not now), ``changed`` (flagged for another cause: ``{scene, was, now}``) and, when the two reports were made
    with other options (``doc["options"]``, e.g. ``--edges``), ``options_changed``: then flags differ for that too."""
    if previous is None:
        return None
    was = {e["scene"]: e["cause"] for e in previous.get("scenes_ranked") or []}
    now = {e["scene"]: e["cause"] for e in doc.get("scenes_ranked") or []}
    out = {"new": [s for s in now if s not in was], "resolved": [s for s in was if s not in now],
           "changed": [{"scene": s, "was": was[s], "now": now[s]} for s in now if s in was and was[s] != now[s]]}
    if previous.get("options") != doc.get("options"):     # e.g. one with --edges, one without: not like for like
        out["options_changed"] = {"was": previous.get("options"), "now": doc.get("options")}
    return out


def ranking_csv(doc: dict) -> str:
    """The scenes to fix, ranked, as CSV (``reasons`` joined by " | ")."""
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(CSV_HEADER)
    for e in doc.get("scenes_ranked") or []:
        w.writerow([e["rank"], e["scene"], f"{e['severity']:.3f}", e["cause"], " | ".join(e["reasons"]), e["next"]])
    return out.getvalue()


def write_report_files(doc: dict, html, previous: dict | None = None) -> Path:
    """Write ``REPORT.html``, ``.csv`` and ``.json`` of the triage document ``doc`` (``doc["since_last"]`` set from
    ``previous``) as one atomic batch; returns the HTML's path."""
    from evpose.core.dataset.report_html import render_report

    html = Path(html)
    doc["since_last"] = since_last(previous, doc)
    csv_path, json_path = sibling_paths(html)
    with AtomicBatch(True, None) as batch:
        batch.add(html, render_report(doc).encode("utf-8"))
        batch.add(csv_path, ranking_csv(doc).encode("utf-8"))
        batch.add(json_path, (json.dumps(doc, indent=1, sort_keys=True, default=to_jsonable) + "\n").encode("utf-8"))
    return html


def flagged_scenes(report_json, causes=None) -> list[str]:
    """The scenes a previous report (its ``REPORT.json``, which evpose wrote) ranks to fix, worst first; with
    ``causes`` only those whose worst cause is one of them. A missing or foreign file is refused in one line."""
    path = Path(report_json)
    if not path.is_file():
        raise NotOursError(f"{path}: --only-flagged: no such report (the REPORT.json that evpose dataset report wrote "
                           "beside its HTML)")
    return ranked_for(_ours_json(path), causes)


def ranked_for(doc: dict, causes=None) -> list[str]:
    """The scenes triage document ``doc`` ranks, worst first; with ``causes`` only those whose worst cause is one of
    them."""
    return [e["scene"] for e in doc.get("scenes_ranked") or [] if causes is None or e["cause"] in causes]

