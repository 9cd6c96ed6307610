"""Triage of a dataset: which scenes, objects and windows to look at first, and why.

:func:`triage` reads the document ``dataset report`` collects (a
:class:`~evpose.core.dataset.batch.BatchResult` of :func:`evpose.core.dataset.tasks.triage_task`: per scene
``info``, ``sync`` (the rate estimate, never applied), ``score`` (10 ms windows) and ``review``) and
returns the report's document (``dataset report --json``): per scene the facts and its flags, and on top
one ranked list of everything flagged, worst first. The HTML report (:mod:`evpose.core.dataset.report_html`)
draws this document and nothing else.

What is flagged (thresholds are the module constants, echoed in the document's ``thresholds``):

* a scene that failed (always first);
* the clock: the estimate disagrees with the clock in effect by more than :data:`CLOCK_K_SIGMA` of its standard
  errors (``offset_std_us`` as the sync printed it: it holds the model-error floor of
  :mod:`evpose.core.align.uncertainty`, so nothing is widened here); the estimate is not reliable; its standard error is above :data:`CLOCK_LOOSE_STD_US` or unbounded; the
  estimated skew drifts more than :data:`MAX_SKEW_DRIFT_US` from the clock in effect over the scene;
* more than :data:`MAX_UNLABELED_SHARE` of the windows without a label (trajectory holes, outside it);
* an object whose median alignment score is below :data:`MIN_MEDIAN_SCORE` (0 is "no better than noise";
  on the synthetic scenes the true poses score ~0.35-0.45 and a 5 mm / 3 degree error or a 20 ms clock
  error 0.01-0.3), or that no window scores;
* with the edge stage (``dataset report --edges``: clock and poses fitted together, with the mounting check), a
  **pose verdict** per object: the fit moves it by more than :data:`VERDICT_SIGMAS` of its standard errors *and*
  by at least :data:`POSE_MATTERS_MM` / :data:`POSE_MATTERS_DEG` (what moves a DAVIS346 label by about half a pixel
  at 0.5 m); a **mounting verdict** when the mounting check found the hand-eye off. A pose verdict explains its
  object's low scores (the score flag folds under it); the scores of every object fold under a flagged clock or
  mounting (they rank below it and say to fix that first).

An object whose worst window a person verified in review (a mark still fresh: made on the poses and clock in
effect) is "looked at, fine" (``looked_at``, with the mark's note): its low scores are not flagged again until a
correction makes the mark stale.

Besides the flat list of flags, ``scenes_ranked`` ranks the scenes (worst flag first), each with its reasons in
order and the next command to run.

The clock is judged against the clock in effect (the manifest prior plus any stored correction: what the
labels use now), so a scene whose estimate was applied leaves the list; the distance to the prior is
reported beside it.
"""
from __future__ import annotations

import math

from evpose.core.dataset.triage_scores import (
    HIST_EDGES,
    MIN_EVENTS_NEAR,
    WORST_WINDOWS,
    object_scores,
    unlabeled_counts,
)
from evpose.core.errors import InputError

__all__ = [
    "CLOCK_K_SIGMA",
    "CLOCK_LOOSE_STD_US",
    "MAX_SKEW_DRIFT_US",
    "MAX_UNLABELED_SHARE",
    "MIN_MEDIAN_SCORE",
    "POSE_MATTERS_DEG",
    "POSE_MATTERS_MM",
    "SEVERITY_FAILED",
    "VERDICT_SIGMAS",
    "TRIAGE_FORMAT",
    "TriageError",
    "triage",
]

TRIAGE_FORMAT = "evpose-triage/1"
#: A clock estimate further than this many standard errors from the clock in effect is flagged.
CLOCK_K_SIGMA = 3.0
#: A clock estimate whose standard error is above this (µs) pins the clock too loosely to check it (the event rate
#: alone gives ~5 ms with its model-error floor: it still tells a 30 ms error).
CLOCK_LOOSE_STD_US = 10_000.0
#: An estimated skew whose drift against the clock in effect over the scene exceeds this (µs) is flagged.
MAX_SKEW_DRIFT_US = 2000.0
#: A scene with more than this share of its windows without a label is flagged.
MAX_UNLABELED_SHARE = 0.10
#: An object whose median score over its scored windows is below this is flagged.
MIN_MEDIAN_SCORE = 0.15
#: A fitted pose change is a verdict when beyond this many standard errors (the ``--apply`` rule) and at least
#: POSE_MATTERS_MM (displacement of the object's centre) or POSE_MATTERS_DEG.
VERDICT_SIGMAS = 2.0
POSE_MATTERS_MM = 1.0
POSE_MATTERS_DEG = 0.5
#: Severity of a failed scene (above any other flag's, which are capped well below it).
SEVERITY_FAILED = 100.0
#: Category weights of the severities (a flag's severity is its weight times how far past its threshold).
_W_CLOCK, _W_OBJECT, _W_UNLABELED, _W_LOOSE, _W_POSE, _W_MOUNT = 3.0, 2.0, 1.0, 1.0, 2.5, 3.5
_CAP = 10.0


class TriageError(InputError):
    """A triage input document lacks a field the report needs; the message names the scene and the field."""


def triage(batch_json: dict, order: list | None = None, paths: dict | None = None) -> dict:
    """The triage report's document of a dataset.

    Parameters
    ----------
    batch_json : dict
        ``{"dataset", "scenes": {name: triage_task document}, "failed": {name: error}, "runtime_s"}``.
    order : list of str, optional
        Scene names in dataset order (default: the scenes, then the failed ones, as they come).
    paths : dict, optional
        Scene name -> folder (for the failed scenes' records and commands; the others carry their own).

    Returns
    -------
    dict
        JSON-able: ``format``, ``dataset``, ``runtime_s``, ``summary``, ``thresholds``, ``ranked`` (every
        flag, worst first: ``rank``, ``scene``, ``object``, ``window``, ``t_label_us``, ``kind``,
        ``severity``, ``reason``) and ``scenes`` (one record per scene, in dataset order).
    """
    scenes_in = batch_json.get("scenes") or {}
    failed_in = batch_json.get("failed") or {}
    names = list(order) if order is not None else [*scenes_in, *(n for n in failed_in if n not in scenes_in)]
    names += [n for n in [*scenes_in, *failed_in] if n not in names]
    records = []
    for name in names:
        if name in failed_in:
            records.append(_failed_record(name, str(failed_in[name]), (paths or {}).get(name)))
        else:
            records.append(_scene_record(name, scenes_in[name]))
    position = {r["name"]: k for k, r in enumerate(records)}
    ranked = [dict(f, scene=r["name"]) for r in records for f in r["flags"]]
    ranked.sort(key=lambda e: (-e["severity"], position[e["scene"]], e["object"] or "", _num(e["window"], -1),
                               e["kind"]))
    ranked = [{"rank": k + 1, "scene": e["scene"], **{f: e[f] for f in _FLAG_FIELDS}} for k, e in enumerate(ranked)]
    return {"format": TRIAGE_FORMAT, "dataset": str(batch_json.get("dataset", "")),
            "runtime_s": float(batch_json.get("runtime_s") or 0.0), "summary": _summary(records),
            "thresholds": _thresholds(), "scenes_ranked": _scenes_ranked(records, position), "ranked": ranked,
            "scenes": records}


def _scenes_ranked(records: list, position: dict) -> list:
    """The flagged scenes, worst first (their worst flag, then dataset order): ``rank``, ``scene``, ``severity``,
    ``cause`` (the worst flag's kind), ``reasons`` (every flag's reason, worst first) and ``next`` (the command
    that deals with the worst cause)."""
    out = []
    for r in records:
        if not r["flags"]:
            continue
        flags = sorted(r["flags"], key=lambda f: -f["severity"])
        out.append({"scene": r["name"], "severity": flags[0]["severity"], "cause": flags[0]["kind"],
                    "reasons": [f["reason"] for f in flags], "next": _next_command(r, flags[0])})
    out.sort(key=lambda e: (-e["severity"], position[e["scene"]]))
    return [{"rank": k + 1, **e} for k, e in enumerate(out)]


def _next_command(rec: dict, flag: dict) -> str:
    """The command for a scene's worst flag (paths as the report knows them)."""
    path = rec.get("path") or rec["name"]
    kind = flag["kind"]
    if kind == "failed":
        return f"evpose info {path}"
    if kind in ("clock", "skew", "clock_uncertain"):
        return f"evpose sync {path} --edges --apply"
    if kind == "mounting":
        return f"evpose refine {path} --joint --hand-eye --apply"
    if kind == "pose":
        return f"evpose refine {path} --joint --apply"
    if flag.get("t_label_us") is not None and rec.get("t0_us") is not None:
        return f"evpose gui {path} --at {(flag['t_label_us'] - rec['t0_us']) * 1e-6:.3f}"
    return f"evpose gui {path}"


_FLAG_FIELDS = ("object", "window", "t_label_us", "kind", "severity", "reason")


def _flag(kind: str, severity: float, reason: str, obj=None, window=None, t_label_us=None) -> dict:
    return {"object": obj, "window": window, "t_label_us": t_label_us, "kind": kind,
            "severity": round(float(severity), 3), "reason": reason}


def _num(x, default):
    return default if x is None else x


def _failed_record(name: str, error: str, path: str | None = None) -> dict:
    return {"name": name, "status": "failed", "error": error, "path": path, "n_events": None, "duration_s": None,
            "t0_us": None,
            "objects": [], "windows": None, "clock": None, "scores": {}, "review": None, "verdicts": {},
            "thumbnails": {}, "looked_at": {},
            "flags": [_flag("failed", SEVERITY_FAILED, f"failed: {error}")]}


def _scene_record(name: str, doc: dict) -> dict:
    try:
        info, sync, score, review = doc["info"], doc["sync"], doc["score"], doc["review"]
        objects = list(info["objects"])
        windows = _windows(info, score)
        clock = _clock(info, sync)
        scores = {n: object_scores(score, n) for n in objects}
        rec = {"name": name, "status": "ok", "error": None, "path": info.get("path"),
               "n_events": int(info["n_events"]), "duration_s": float(info["duration_s"]), "t0_us": info["t0_us"],
               "objects": objects, "windows": windows, "clock": clock, "scores": scores,
               "review": dict(review)}
    except KeyError as exc:
        raise TriageError(f"scenes.{name}: missing field {exc.args[0]!r} in its triage document") from None
    except (TypeError, ValueError, AttributeError) as exc:
        raise TriageError(f"scenes.{name}: malformed triage document ({exc})") from None
    clock_flags = _clock_flags(clock)
    verdicts = _verdict_flags(sync)
    rec["verdicts"] = {f["object"]: f["reason"] for f in verdicts if f["kind"] == "pose"}
    cause_sev = [f["severity"] for f in clock_flags + verdicts if f["kind"] in ("clock", "skew", "mounting")]
    rec["looked_at"] = dict(doc.get("looked_at") or {})          # worst windows a person verified: not flagged again
    score_flags = [f for f in _object_flags(scores, max(cause_sev, default=None))
                   if f["object"] not in rec["verdicts"] and f["object"] not in rec["looked_at"]]
    rec["flags"] = clock_flags + verdicts + _unlabeled_flags(windows) + score_flags
    flagged = {f["object"] for f in rec["flags"] if f["object"]}
    rec["thumbnails"] = {n: th for n, th in (doc.get("thumbnails") or {}).items() if n in flagged}
    return rec


def _verdict_flags(sync: dict) -> list:
    """Pose and mounting verdicts of the edge stage (none without it, or when it was not accepted)."""
    edges = (sync.get("stages") or {}).get("edges")
    if not edges or not edges.get("accepted"):
        return []
    flags = []
    he = edges.get("hand_eye")
    if he and _significant(he):
        flags.append(_flag("mounting", _W_MOUNT * min(_n_sigma(he) / VERDICT_SIGMAS, _CAP),
                           f"camera mounting (hand-eye) off by {he['dt_mm']:.2f} mm ± {he['dt_std_mm']:.2f}, "
                           f"{he['dR_deg']:.2f}° ± {he['dR_std_deg']:.2f} (the edges' fit, with the clock and poses)"))
    for name, o in (edges.get("objects") or {}).items():
        if _significant(o):
            flags.append(_flag("pose", _W_POSE * min(_n_sigma(o) / VERDICT_SIGMAS, _CAP),
                               f"{name}: pose off by {o['dt_mm']:.2f} mm ± {o['dt_std_mm']:.2f}, {o['dR_deg']:.2f}° "
                               f"± {o['dR_std_deg']:.2f} (the edges' fit, with the clock)", obj=name))
    return flags


def _n_sigma(o: dict) -> float:
    def r(x, s):
        return abs(x) / s if s is not None and math.isfinite(s) and s > 0 else 0.0
    return max(r(o["dt_mm"], o["dt_std_mm"]), r(o["dR_deg"], o["dR_std_deg"]))


def _significant(o: dict) -> bool:
    """A change beyond :data:`VERDICT_SIGMAS` of its standard error in a part that is also large enough to matter."""
    def beyond(x, s, matters):
        return s is not None and math.isfinite(s) and s > 0 and abs(x) > VERDICT_SIGMAS * s and abs(x) >= matters
    return beyond(o["dt_mm"], o["dt_std_mm"], POSE_MATTERS_MM) or beyond(o["dR_deg"], o["dR_std_deg"], POSE_MATTERS_DEG)


def _windows(info: dict, score: dict) -> dict:
    n = int(score["n_windows"])
    holes, outside = unlabeled_counts(score)
    unlabeled = int(score["unlabeled"])
    traj = info["trajectory"]
    first = score["windows"][0] if score["windows"] else None

    def share(k):
        return k / n if n else None

    return {"n_windows": n, "window_us": None if first is None else int(first["t1_us"]) - int(first["t0_us"]),
            "unlabeled": unlabeled, "in_holes": holes, "outside_trajectory": outside,
            "unlabeled_share": share(unlabeled), "holes_share": share(holes), "outside_share": share(outside),
            "n_holes": len(traj["holes"]), "info_windows_in_holes": int(traj["windows_in_holes"])}


def _clock(info: dict, sync: dict) -> dict:
    c = info["clock"]
    est, std, pinned = sync["offset_us"], sync["offset_std_us"], sync.get("offset_pinned")
    effect, prior = int(c["offset_us"]), int(c["prior_offset_us"])
    out = {"reliable": bool(sync["reliable"]), "reason": sync["reason"], "estimate_offset_us": est,
           "offset_std_us": std, "offset_pinned": pinned, "effect_offset_us": effect, "prior_offset_us": prior,
           "corrected": effect != prior or float(c["skew_ppm"]) != float(c["prior_skew_ppm"]),
           "delta_effect_us": None, "delta_prior_us": None, "sigma_total_us": None, "n_sigma": None,
           "estimate_skew_ppm": sync["skew_ppm"], "effect_skew_ppm": float(c["skew_ppm"]),
           "prior_skew_ppm": float(c["prior_skew_ppm"]), "skew_drift_us": None,
           "duration_s": float(info["duration_s"])}
    if est is None:
        return out
    out["delta_effect_us"], out["delta_prior_us"] = int(est) - effect, int(est) - prior
    if pinned is not False:
        sigma = float(std) if std else math.inf
        out["sigma_total_us"] = sigma
        out["n_sigma"] = abs(out["delta_effect_us"]) / sigma
    if sync["skew_ppm"] is not None:
        out["skew_drift_us"] = (float(sync["skew_ppm"]) - out["effect_skew_ppm"]) * out["duration_s"]
    return out


def _ms(us: float) -> str:
    return f"{us / 1000:+.1f} ms"


def _clock_flags(c: dict) -> list:
    if not c["reliable"]:
        return [_flag("clock", _W_CLOCK * 2, f"clock estimate not reliable: {c['reason'] or 'no reason given'}")]
    flags = []
    against = "the clock in effect (prior + correction)" if c["corrected"] else "the prior"
    std = c["offset_std_us"]
    if c["n_sigma"] is not None and c["n_sigma"] > CLOCK_K_SIGMA:
        pm = "" if std is None else f" ± {std / 1000:.1f} ms"
        extra = f"; {_ms(c['delta_prior_us'])} from the prior" if c["corrected"] else ""
        flags.append(_flag("clock", _W_CLOCK * min(c["n_sigma"] / CLOCK_K_SIGMA, _CAP),
                           f"clock {_ms(c['delta_effect_us'])}{pm} from {against} ({c['n_sigma']:.0f} σ){extra}"))
    if c["offset_pinned"] is False:
        flags.append(_flag("clock_uncertain", _W_LOOSE * 5,
                           "clock not pinned by the event rate (σ unbounded): check it with sync --edges"))
    elif std is not None and std > CLOCK_LOOSE_STD_US:
        flags.append(_flag("clock_uncertain", _W_LOOSE * min(std / CLOCK_LOOSE_STD_US, 5),
                           f"clock estimate loose: σ {std / 1000:.1f} ms > {CLOCK_LOOSE_STD_US / 1000:g} ms"))
    drift = c["skew_drift_us"]
    if drift is not None and abs(drift) > MAX_SKEW_DRIFT_US:
        flags.append(_flag("skew", _W_CLOCK * min(abs(drift) / MAX_SKEW_DRIFT_US, _CAP),
                           f"skew {c['estimate_skew_ppm'] - c['effect_skew_ppm']:+.1f} ppm from {against}: "
                           f"{_ms(drift)} drift over the scene"))
    return flags


def _unlabeled_flags(w: dict) -> list:
    share = w["unlabeled_share"]
    if share is None or share <= MAX_UNLABELED_SHARE:
        return []
    parts = [p for p, k in (("trajectory holes", w["in_holes"]), ("outside the trajectory", w["outside_trajectory"]))
             if k]
    why = f" ({', '.join(parts)})" if parts else ""
    return [_flag("unlabeled", _W_UNLABELED * min(share / MAX_UNLABELED_SHARE, _CAP),
                  f"{100 * share:.0f} % of windows unlabeled{why}")]


def _object_flags(scores: dict, clock_severity: float | None) -> list:
    """Flags of objects scoring low; with the clock flagged (``clock_severity``) they say to fix that first and rank
    just below it (a wrong clock lowers every object's score)."""
    flags = []
    hint = " (the clock or the mounting is flagged too: fix that first)" if clock_severity is not None else ""
    for name, s in scores.items():
        if s["n_valid"] == 0:
            flags.append(_flag("object", _W_OBJECT, f"{name}: no window scored (out of view or too few events)",
                               obj=name))
            continue
        median = s["quantiles"]["p50"]
        if median >= MIN_MEDIAN_SCORE:
            continue
        worst = s["worst"][0] if s["worst"] else None
        where = f", worst window {worst['index']} ({worst['score']:.2f})" if worst else ""
        sev = _W_OBJECT * min(MIN_MEDIAN_SCORE / max(median, MIN_MEDIAN_SCORE / _CAP), _CAP)
        if clock_severity is not None:
            sev = min(sev, 0.999 * clock_severity)
        flags.append(_flag("object", sev, f"{name}: median score {median:.2f}{where}{hint}", obj=name,
                           window=worst and worst["index"], t_label_us=worst and worst["t_label_us"]))
    return flags


def _summary(records: list) -> dict:
    ok = [r for r in records if r["status"] == "ok"]
    return {"n_scenes": len(records), "n_failed": len(records) - len(ok),
            "n_flagged": sum(1 for r in records if r["flags"]),
            "n_events": sum(r["n_events"] for r in ok), "duration_s": sum(r["duration_s"] for r in ok),
            "n_windows": sum(r["windows"]["n_windows"] for r in ok),
            "verified_windows": sum(int(r["review"].get("verified_windows", 0)) for r in ok)}


def _thresholds() -> dict:
    return {"clock_k_sigma": CLOCK_K_SIGMA, "verdict_sigmas": VERDICT_SIGMAS, "pose_matters_mm": POSE_MATTERS_MM,
            "pose_matters_deg": POSE_MATTERS_DEG,
            "clock_loose_std_us": CLOCK_LOOSE_STD_US, "max_skew_drift_us": MAX_SKEW_DRIFT_US,
            "max_unlabeled_share": MAX_UNLABELED_SHARE, "min_median_score": MIN_MEDIAN_SCORE,
            "min_events_near": MIN_EVENTS_NEAR, "worst_windows": WORST_WINDOWS,
            "score_histogram_edges": list(HIST_EDGES)}
