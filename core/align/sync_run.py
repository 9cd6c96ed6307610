"""One ``sync`` run on a scene, as ``evpose sync`` and ``evpose dataset sync`` both do it: the rate stage,
optionally the E-POSE minima baseline and the edge stage, and with ``apply`` the reliable estimate stored
as one undo step and saved. The result's :attr:`SyncRun.data` is the command's JSON document (DESIGN
section 5), so the dataset layer reports exactly what the single-scene command prints.

The document's top level is the **final** estimate (``offset_us``, ``skew_ppm``, ``offset_std_us``,
``skew_std_ppm``, ``offset_pinned``, ``reliable``, ``reason``, ``confidence``, ``method`` = ``"rate"`` or
``"rate+edges"``, ``runtime_s`` of the whole run, ``correction``), and each stage's own document is nested
under ``stages``: ``stages.rate`` (:meth:`~evpose.core.align.sync_result.SyncResult.to_json`) and, with
``edges``, ``stages.edges`` (:meth:`~evpose.core.align.joint_result.JointResult.to_json`: the clock fitted
jointly with the object poses, which are reported there but not applied by ``sync``)."""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field

from evpose.core.align.apply import APPLY_SIGMAS, plan_joint_result, plan_sync, save_applied, store_changes
from evpose.core.document.estimates import clock_correction_for

__all__ = ["EDGE_MIN_RANGE_US", "MOUNTING_MIN_OBJECTS", "MOUNTING_SIGMAS", "MOUNTING_TRIGGER_STD_US", "SyncOptions",
           "SyncRun", "edge_stage", "final_estimate", "mounting_check", "mounting_suspected", "run_sync"]


@dataclass(frozen=True)
class SyncOptions:
    """The options of a sync run (the CLI's flags; defaults are the CLI's)."""

    range_ms: float = 500.0      # search range around the clock in effect (ms)
    bin_us: int = 1000           # event-rate bin (multiple of 1000 us)
    edges: bool = False          # then fit clock and object poses jointly from event/edge alignment
    windows: int = 24            # event windows used by the edge stage
    apply: bool = False          # store a reliable estimate as corrections and save corrections.json
    baseline: bool = False       # also run the E-POSE minima-matching method
    curve: bool = False          # include the correlation curve in the document


@dataclass
class SyncRun:
    """What a sync run produced: the JSON document and the objects its text summary is made from."""

    data: dict = field(default_factory=dict)
    result: object = None               # SyncResult of the rate stage
    correction: tuple | None = None     # (offset_us, skew_ppm) on top of the prior, or None
    edges: object = None                # JointResult of the edge stage, or None
    saved_line: str = ""                # "applied and saved to ..." when --apply saved


def run_sync(scene, opts: SyncOptions, *, progress=None, edge_progress=None, cancel=None) -> SyncRun:
    """Run the rate stage (and the edge stage with ``opts.edges``), apply with ``opts.apply``.

    ``edge_progress(fraction, message)`` reports the edge stage (the rate stage takes a fraction of a second).
    A rate estimate that is not reliable is never applied (the reason goes to stderr and ``data["applied"]``
    is False); the edge stage runs only after a reliable one, and its clock is taken when the fit improved the
    objective and stayed within :func:`~evpose.core.align.sync_edges.sync_edge_half_range_us` of the rate
    estimate."""
    import time

    from evpose.core.align.estimate import sync_scene
    from evpose.core.document.history import History

    t_start = time.perf_counter()
    run = SyncRun()
    data = run.data
    res = run.result = sync_scene(scene, range_ms=opts.range_ms, bin_us=opts.bin_us)
    stages = {"rate": res.to_json(curve=opts.curve)}
    if opts.baseline:
        from evpose.core.align.minima_baseline import sync_minima_baseline     # scipy.signal: only when asked

        data["baseline"] = sync_minima_baseline(scene, range_ms=opts.range_ms).to_json()
    if opts.edges and res.reliable:
        run.edges = edge_stage(scene, res, opts.windows, progress=edge_progress, cancel=cancel)
        stages["edges"] = run.edges.to_json()
    data.update(final_estimate(res, run.edges))
    data["stages"] = stages
    corr = run.correction = (None if data["offset_us"] is None else
                             clock_correction_for(scene, data["offset_us"], data["skew_ppm"]))
    data["correction"] = None if corr is None else {"offset_us": corr[0], "skew_ppm": corr[1]}
    edges = run.edges if run.edges is not None and run.edges.accepted else None
    if not res.reliable:
        changes, kept = [], [f"no reliable estimate: {res.reason}"]
    elif edges is not None:
        changes, kept = plan_joint_result(scene, edges, poses=False)
    else:
        changes = plan_sync(scene, res)
        kept = [] if changes else [f"clock: within {APPLY_SIGMAS:g} sigma of the clock in effect"]
    data["changes"] = [c.to_json() for c in changes]        # what --apply stores (or stored): the dry run's diff
    data["kept"] = kept
    applied = False
    if opts.apply:
        if res.reliable:
            text = "clock sync (rate, then edges)" if edges is not None else "clock sync"
            applied = store_changes(History(scene.corrections), changes, text)
            if applied:
                run.saved_line = save_applied(scene, data)
        else:
            print(f"evpose sync: {scene.name}: not applied: {res.reason}", file=sys.stderr)
    data["applied"] = applied
    data["runtime_s"] = time.perf_counter() - t_start
    return run


#: The edge stage's clock may move at least this far from the rate estimate (µs), whatever the rate's standard
#: error says (inert while that carries its 4.75 ms model-error floor: 4 sigma are >= 19 ms).
EDGE_MIN_RANGE_US = 5000.0


#: A mounting error is concluded only when at least this many objects were fitted with it: it moves every object's
#: edges in one camera-frame pattern, while one object's own pose error moves its edges much as a hand-eye error does
#: (on a 1-object calibration scene the hand-eye fit took a 6 mm object error for a mounting error).
MOUNTING_MIN_OBJECTS = 2
#: The mounting check runs when the clock-and-poses fit was refused, dropped an implausible skew, or its windows
#: disagree on the clock by more than this (its data-only standard error, µs): well-aligned scenes at 0.5-1 m/s give
#: 20-50 µs, a 3 mm / 0.8 deg mounting error ~300 µs (slow scenes, texture and clutter also raise it: those pay the
#: second fit, which then decides).
MOUNTING_TRIGGER_STD_US = 120.0
#: The hand-eye the mounting check finds counts as a camera-mounting error when its translation or rotation exceeds
#: this many of its standard errors (each is the root sum of three axes' variances, so 3 is far in the tail: under no
#: error ``|d|^2 / std^2`` is about chi-square(3) / 3, beyond 9 with probability ~6e-6).
MOUNTING_SIGMAS = 3.0
#: A mounting *shift* is judged only when the camera turns by at least this much (degrees) over the recording: a
#: camera that keeps its orientation sees a shifted mounting exactly as every object shifted alike (only the prior on
#: the objects decides between them), so only the mounting's rotation is judged then (a false alarm on a
#: translating validation scene had the hand-eye take up the objects' own pose errors).
MOUNTING_MIN_TURN_DEG = 5.0


def edge_stage(scene, rate, n_windows: int, *, progress=None, cancel=None, mounting: bool = True):
    """The joint edge fit (clock and every object's pose, :func:`~evpose.core.align.joint_fit.refine_joint`)
    started at the rate estimate ``rate``; not accepted (``reason`` says why) when its clock moves further from the
    rate estimate than :func:`~evpose.core.align.sync_edges.sync_edge_half_range_us` or :data:`EDGE_MIN_RANGE_US`,
    whichever is larger (a far-off local optimum).

    With ``mounting``, when :func:`mounting_suspected`, the fit runs a second time with the hand-eye free
    (:func:`mounting_check`): a camera-mounting error moves the projected edges with the camera's *pose*, a clock
    error with its *velocity*; a clock-and-poses fit can absorb the first only into the clock (and skew), so a right
    clock would be made wrong. When the freed hand-eye is beyond :data:`MOUNTING_SIGMAS` of its standard errors and
    that fit is accepted, its result (clock, hand-eye and poses) is returned, with a note that says so; otherwise
    the first fit's."""
    from evpose.core.align.joint_fit import refine_joint
    from evpose.core.align.joint_result import JointParams

    halves = _halves(progress) if mounting else (progress, None)
    res = refine_joint(scene, params=JointParams(n_windows=n_windows), clock=rate.clock(), progress=halves[0],
                       cancel=cancel)
    _check_range(res, rate)
    if not (mounting and mounting_suspected(res)):
        if progress is not None and mounting:
            progress(1.0, "done (no sign of a camera-mounting error)")
        return res
    alt = refine_joint(scene, params=JointParams(n_windows=n_windows, hand_eye=True), clock=rate.clock(),
                       progress=halves[1], cancel=cancel)
    _check_range(alt, rate)
    return mounting_check(res, alt, turns=camera_turn_deg(scene, rate.clock()) >= MOUNTING_MIN_TURN_DEG)


def camera_turn_deg(scene, clock=None, n: int = 200) -> float:
    """How far the camera turns over the recording (degrees): the largest angle between its orientation at ``n``
    times over the events and their mean orientation."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    ev = scene.events
    if ev.t_first_us is None or ev.t_last_us <= ev.t_first_us:
        return 0.0
    t = np.linspace(ev.t_first_us, ev.t_last_us, n).astype(np.int64)
    T, ok = scene.T_base_cam(t, clock=clock)
    if not np.any(ok):
        return 0.0
    R = Rotation.from_matrix(np.asarray(T)[ok][:, :3, :3])
    return float(np.degrees(np.max((R.mean().inv() * R).magnitude())))


def mounting_suspected(res) -> bool:
    """Whether a clock-and-poses fit ``res`` shows what a camera-mounting error does to it: refused, an implausible
    skew dropped, or windows that disagree on the clock (:data:`MOUNTING_TRIGGER_STD_US`)."""
    if not res.accepted or res.skew_implausible:
        return True
    std = res.offset_std_data_us
    return std is not None and (not math.isfinite(std) or std > MOUNTING_TRIGGER_STD_US)


def mounting_check(res, alt, turns: bool = True):
    """Of a clock-and-poses fit ``res`` and the same fit with the hand-eye free ``alt``, the one to believe: ``alt``
    when it was accepted and its hand-eye change is beyond :data:`MOUNTING_SIGMAS` of its standard errors (a note on
    it says by how much the mounting looks off, and what the first fit made of it), else ``res`` (with a note when
    ``alt`` saw no mounting error). ``turns``: the camera turns over the recording
    (:data:`MOUNTING_MIN_TURN_DEG`); when it does not, only the hand-eye's rotation is judged."""
    def ratio(change, std):
        return change / std if std and math.isfinite(std) and std > 0 else 0.0

    # tested against the events' own standard errors: the object prior's pull (in the sigmas stored) says how far a
    # start pose may be off, not whether the events ask for a mounting change (the check's 3 sigma and its false
    # alarms were set against these)
    std_mm = alt.hand_eye_std_events_mm if alt.hand_eye_std_events_mm is not None else alt.hand_eye_std_mm
    std_deg = alt.hand_eye_std_events_deg if alt.hand_eye_std_events_deg is not None else alt.hand_eye_std_deg
    z_rot = ratio(alt.hand_eye_dR_deg, std_deg)
    z = max(ratio(alt.hand_eye_dt_mm, std_mm), z_rot) if turns else z_rot
    caveat = ([] if turns else ["mounting check: the camera does not turn over the recording, so a mounting shift "
                                "looks exactly like every object shifted alike; only the mounting's rotation is judged"])
    seen = (f"{alt.hand_eye_dt_mm:.2f} +- {std_mm or float('nan'):.2f} mm, "
            f"{alt.hand_eye_dR_deg:.3f} +- {std_deg or float('nan'):.3f} deg from the events")
    if (std_mm, std_deg) != (alt.hand_eye_std_mm, alt.hand_eye_std_deg):
        seen += (f" (+- {alt.hand_eye_std_mm or float('nan'):.2f} mm, {alt.hand_eye_std_deg or float('nan'):.3f} deg "
                 "with the start poses' own uncertainty)")
    if alt.accepted:          # kept with the fit that keeps the mounting: how far the mounting in effect may be off
        res.mounting_check = {"dt_mm": alt.hand_eye_dt_mm, "dt_std_mm": alt.hand_eye_std_mm,
                              "dR_deg": alt.hand_eye_dR_deg, "dR_std_deg": alt.hand_eye_std_deg}
    if alt.accepted and z > MOUNTING_SIGMAS and len(alt.objects) < MOUNTING_MIN_OBJECTS:
        res.notes.append(f"mounting check: a hand-eye change of {seen} would explain the events, but with "
                         f"{len(alt.objects)} object fitted a camera-mounting error and that object's pose error move "
                         "its edges alike; nothing concluded (the mounting shows on two or more objects)")
        res.notes.extend(caveat)
        return res
    if alt.accepted and z > MOUNTING_SIGMAS:
        first = (f"clock {res.offset_us / 1000:+.3f} ms" + (f", skew {res.skew_ppm:+.0f} ppm" if res.skew_estimated
                                                             else "")) if res.accepted else f"refused: {res.reason}"
        alt.notes.insert(0, f"the camera mounting (hand-eye) looks off by {seen} ({z:.1f} sigma): clock, hand-eye "
                            f"and poses were fitted together (without the hand-eye the fit gave {first}); "
                            "store the hand-eye with Accept in the app or `evpose refine --joint --hand-eye --apply`")
        alt.notes.extend(caveat)
        return alt
    res.notes.append(f"mounting check: no camera-mounting error seen (hand-eye {seen}, {z:.1f} sigma)"
                     if alt.accepted else f"mounting check: the fit with the hand-eye free was refused ({alt.reason})")
    res.notes.extend(caveat)
    return res


def _check_range(res, rate) -> None:
    from evpose.core.align.sync_edges import sync_edge_half_range_us

    half = max(sync_edge_half_range_us(rate), EDGE_MIN_RANGE_US)
    if res.accepted and abs(res.offset_us - rate.offset_us) > half:
        res.accepted = False
        res.reason = (f"the edges moved the clock {(res.offset_us - rate.offset_us) / 1000:+.1f} ms from the rate "
                      f"estimate, beyond its search range of ± {half / 1000:.1f} ms; rate estimate kept")


def _halves(progress):
    """Two progress callbacks ``(fraction, message)`` for two fits one after the other, on ``progress``'s 0..1."""
    if progress is None:
        return None, None

    def first(f, message=""):
        progress(None if f is None else 0.5 * float(f), message)

    def second(f, message=""):
        progress(None if f is None else 0.5 + 0.5 * float(f), f"mounting check: {message}")

    return first, second


def final_estimate(rate, edges) -> dict:
    """The top level of the sync document: the edge stage's clock when it was accepted, else the rate's."""
    import math

    from evpose.core.align.joint_result import json_number as num

    d = {"method": "rate", "offset_us": rate.offset_us, "skew_ppm": num(rate.skew_ppm),
         "offset_std_us": num(rate.offset_std_us) if rate.offset_std_us is not None else None,
         "skew_std_ppm": None,
         "offset_pinned": None if rate.offset_std_us is None else bool(math.isfinite(rate.offset_std_us)),
         "confidence": float(rate.confidence), "reliable": bool(rate.reliable), "reason": rate.reason,
         "prior_offset_us": int(rate.prior_offset_us), "prior_skew_ppm": float(rate.prior_skew_ppm),
         "t_ref_us": int(rate.t_ref_us)}
    if edges is not None and edges.accepted:
        std = edges.offset_std_us
        d.update(method="rate+edges", offset_us=int(edges.offset_us), offset_std_us=num(std),
                 offset_pinned=None if std is None else bool(math.isfinite(std)))
        if edges.skew_estimated:
            d.update(skew_ppm=float(edges.skew_ppm), skew_std_ppm=num(edges.skew_std_ppm))
    return d
