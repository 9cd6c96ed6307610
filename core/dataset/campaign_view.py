"""The dataset view's summary of ``campaign_fit.json``, the record of ``evpose dataset refine --joint --shared …
--apply`` (:func:`~evpose.core.dataset.campaign.record_campaign`), as plain text lines (no Qt: the dataset window's
:class:`~evpose.widgets.campaign_panel.CampaignPanel` shows them).

Per group of ``dataset.toml``: one line per shared term, its change from the start with one standard error
(``day1 (3 scenes): hand-eye 1.15 mm ± 0.80, 0.268° ± 0.167``; ``day1: box 0.86 mm ± 0.58, 0.28° ± 0.17``; or why
it was kept), then which of the group's scenes stored it (the revision of their corrections); then the fit's notes.
A scene's own terms (units ``scene:<name>``) are in its row's refine columns, not here.

A missing record is a hint how to make one; a record that cannot be read or is not evpose's is one line naming the
file and the field (:class:`CampaignRecordError`), never a traceback.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

from evpose.core.data.input_files import InputFileError, open_regular
from evpose.core.dataset.campaign import CAMPAIGN_FILENAME, CAMPAIGN_FORMAT
from evpose.core.errors import InputError

__all__ = ["CAMPAIGN_HINT", "MAX_RECORD_BYTES", "CampaignRecordError", "campaign_lines", "read_record",
           "record_lines"]

CAMPAIGN_HINT = "No campaign fit recorded (evpose dataset refine --joint --shared … --apply)"
#: A record is a few kB per unit and trial step; anything far larger is not one (and is never read whole).
MAX_RECORD_BYTES = 16 * 2**20
_NUMBER = (int, float)
_KINDS = {dict: "an object", list: "a list", str: "a string", _NUMBER: "a number", int: "an integer",
          bool: "true or false"}
_REQUIRED = object()


class CampaignRecordError(InputError):
    """A ``campaign_fit.json`` that cannot be shown; the message names the file and the field."""


def read_record(root) -> dict | None:
    """The campaign record beside dataset ``root``'s ``dataset.toml`` (None when there is none)."""
    path = Path(root) / CAMPAIGN_FILENAME
    if not os.path.lexists(path):
        return None
    try:
        with open_regular(path, "r", max_bytes=MAX_RECORD_BYTES, encoding="utf-8") as f:
            doc = json.load(f)
    except InputFileError as exc:
        raise CampaignRecordError(str(exc)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CampaignRecordError(f"{path}: cannot read ({exc})") from None
    except (ValueError, RecursionError) as exc:
        raise CampaignRecordError(f"{path}: not JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise CampaignRecordError(f"{path}: expected a JSON object (an evpose campaign fit, {CAMPAIGN_FORMAT}), "
                                  f"got a JSON {type(doc).__name__}")
    if doc.get("format") != CAMPAIGN_FORMAT:
        raise CampaignRecordError(f"{path}: format: expected {CAMPAIGN_FORMAT!r} (an evpose campaign fit), "
                                  f"got {doc.get('format')!r:.40}")
    return doc


def campaign_lines(root) -> tuple[str, list[str]]:
    """``(state, lines)`` of dataset ``root``'s record: ``("absent", [hint])``, ``("error", [one line])`` or
    ``("ok", record_lines(...))``."""
    try:
        doc = read_record(root)
        if doc is None:
            return "absent", [CAMPAIGN_HINT]
        return "ok", record_lines(doc, Path(root) / CAMPAIGN_FILENAME)
    except CampaignRecordError as exc:
        return "error", [str(exc)]


def _get(obj: dict, key: str, kind, where: str, path, default=_REQUIRED):
    """``obj[key]`` checked to be of ``kind`` (``default`` when absent, if one is given); ``where``: the field's
    prefix in the record (``fit.hand_eye.group:day1.``)."""
    if key not in obj and default is not _REQUIRED:
        return default
    value = obj.get(key)
    if not isinstance(value, kind) or (kind in (_NUMBER, int) and isinstance(value, bool)):
        got = "nothing" if key not in obj else f"{value!r:.40}"
        raise CampaignRecordError(f"{path}: {where}{key}: expected {_KINDS[kind]}, got {got}")
    return value


def _sigma(value, where: str, path, digits: int) -> str:
    """A standard error as text; null (how the record writes an infinite one) is "∞"."""
    if value is None:
        return "∞"
    if isinstance(value, bool) or not isinstance(value, _NUMBER):
        raise CampaignRecordError(f"{path}: {where}: expected a number or null, got {value!r:.40}")
    return f"{value:.{digits}f}" if math.isfinite(value) else "∞"


def _term(name: str, fit: dict, where: str, path, deg_digits: int) -> str:
    """``name``'s change from its start ± one standard error (mm, degrees), or why it kept its start."""
    if not _get(fit, "fitted", bool, where, path):
        return f"{name} not fitted: {_get(fit, 'reason', str, where, path, '') or 'not pinned'}"
    dt_mm, dr_deg = (_get(fit, k, _NUMBER, where, path) for k in ("dt_mm", "dR_deg"))
    std_mm = _sigma(fit.get("dt_std_mm"), where + "dt_std_mm", path, 2)
    std_deg = _sigma(fit.get("dR_std_deg"), where + "dR_std_deg", path, deg_digits)
    return f"{name} {dt_mm:.2f} mm ± {std_mm}, {dr_deg:.{deg_digits}f}° ± {std_deg}"


def _stored(scenes: list, stored: dict, failed: dict) -> str:
    """Which of ``scenes`` stored the fit (their corrections' revision), which only stored the sigma of values the
    fit confirmed, which stored nothing and which failed (a record without ``values`` counts a store as values)."""
    done, sigma_only, kept, bad = [], [], [], []
    for s in scenes:
        entry = stored.get(s)
        if s in failed:
            bad.append(f"{s} failed: {failed[s]}")
        elif isinstance(entry, dict) and entry.get("applied"):
            (done if entry.get("values", True) else sigma_only).append(f"{s} rev {entry.get('revision')}")
        else:
            kept.append(s if isinstance(entry, dict) else f"{s} (not in the record)")
    parts = [f"stored in {len(done)} of {len(scenes)} scenes" + (f" ({', '.join(done)})" if done else "")]
    parts += [f"values confirmed, only their sigma stored: {', '.join(sigma_only)}"] if sigma_only else []
    parts += [f"nothing stored: {', '.join(kept)}"] if kept else []
    return "; ".join(parts + bad)


def _group_terms(name: str, shared: list, fit: dict, path) -> list[str]:
    """The terms of group ``name`` in the fit: its hand-eye, then each object of its placement (a kind it
    ``shared`` in dataset.toml that the fit did not share says so)."""
    unit = f"group:{name}"
    he = _get(fit, "hand_eye", dict, "fit.", path, {})
    placements = _get(fit, "placements", dict, "fit.", path, {})
    out = []
    if unit in he:
        out.append(_term("hand-eye", _get(he, unit, dict, "fit.hand_eye.", path), f"fit.hand_eye.{unit}.", path, 3))
    elif "hand-eye" in shared:
        out.append("hand-eye not shared in this fit (each scene its own)")
    objects = _get(placements, unit, dict, "fit.placements.", path, {})
    for obj in objects:
        fit_obj = _get(objects, obj, dict, f"fit.placements.{unit}.", path)
        out.append(_term(obj, fit_obj, f"fit.placements.{unit}.{obj}.", path, 2))
    if unit not in placements and "placement" in shared:
        out.append("placement not shared in this fit (each scene its own)")
    return out


def _headline(fit: dict, path) -> str:
    """What the lines are, and whether the fit was accepted."""
    n = len(_get(fit, "scenes", list, "fit.", path, []))
    head = f"Campaign fit of {n} scenes: "
    if not _get(fit, "accepted", bool, "fit.", path):
        return head + f"not accepted: {fit.get('reason') or '?'} (every shared term kept its start)"
    steps, runtime_s = _get(fit, "steps", int, "fit.", path, 0), _get(fit, "runtime_s", _NUMBER, "fit.", path, 0.0)
    return head + f"accepted ({steps} steps, {runtime_s:.1f} s); change ± 1 sigma"


def record_lines(doc: dict, path="campaign_fit.json") -> list[str]:
    """The text lines of campaign record ``doc`` (read from ``path``, which errors name): a headline, per group its
    terms and what its scenes stored, then the fit's notes and the scenes outside any group that failed."""
    fit = _get(doc, "fit", dict, "", path)
    stored = _get(doc, "stored", dict, "", path, {})
    failed = _get(doc, "failed", dict, "", path, {})
    lines, grouped = [_headline(fit, path)], set()
    for k, g in enumerate(_get(doc, "groups", list, "", path)):
        if not isinstance(g, dict):
            raise CampaignRecordError(f"{path}: groups[{k}]: expected an object, got {g!r:.40}")
        name = _get(g, "name", str, f"groups[{k}].", path)
        scenes = [str(s) for s in _get(g, "scenes", list, f"groups[{k}].", path)]
        grouped.update(scenes)
        shared = _get(g, "shared", list, f"groups[{k}].", path, [])
        terms = _group_terms(name, shared, fit, path) or ["no term of this group in the fit"]
        lines.append(f"{name} ({len(scenes)} scenes): {terms[0]}")
        lines += [f"{name}: {t}" for t in terms[1:]]
        lines.append(f"{name}: {_stored(scenes, stored, failed)}")
    lines += [f"note: {note}" for note in _get(fit, "notes", list, "fit.", path, [])]
    lines += [f"{s} failed: {e}" for s, e in failed.items() if s not in grouped]
    return lines
