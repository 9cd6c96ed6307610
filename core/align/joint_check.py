"""The held-out check of a joint edge fit: does what it found also align the events of windows it never saw?

The joint fit (:mod:`evpose.core.align.joint_fit`) maximises its own edge objective on its own windows, so a false
optimum -- an object pulled onto texture edges, onto another object's silhouette, or into a twin at the same pose --
raises that objective too. The check scores every fitted object with the alignment score of the timeline
(:func:`evpose.core.align.score_table.score_windows`: a different measure, on other windows interleaved with the
fit's) at the start and at the end: an object whose score falls there by more than its noise is put back at its
start and named among the held objects, with both scores; and when the kept result as a whole scores lower on those
windows than the start, the fit is not accepted. A fit may end no worse than where it started.
"""
from __future__ import annotations

import math

import numpy as np

from evpose.core.align.event_windows import choose_windows

__all__ = ["HELD_OUT_WINDOWS", "HELD_OUT_SIGMAS", "held_out_windows", "check_held_out"]

#: Windows scored by the check (interleaved with the fit's, never overlapping them).
HELD_OUT_WINDOWS = 16
#: A fall of the mean score counts when it exceeds this many standard errors of the paired differences
#: (window by window, end minus start) and :data:`MIN_DROP` in score units.
HELD_OUT_SIGMAS = 2.0
MIN_DROP = 0.01


def held_out_windows(scene, fit_windows, n: int, window_us: int, clock, names) -> list:
    """Up to ``n`` windows of ``window_us`` spread over the moving part of the recording that overlap none of
    ``fit_windows`` (list of ``(t0_us, t1_us)``)."""
    cand = choose_windows(scene, 3 * max(len(fit_windows), n), window_us, names, clock)
    taken = np.array(fit_windows, np.int64).reshape(-1, 2)
    free = [w for w in cand if not np.any((taken[:, 0] < w[1]) & (w[0] < taken[:, 1]))]
    if len(free) <= n:
        return free
    pick = np.unique(np.linspace(0, len(free) - 1, n).round().astype(int))
    return [free[i] for i in pick]


def _paired_drop(before, after) -> tuple[float, float, int]:
    """Mean of ``after - before`` over windows where both are informative, its standard error, and the count."""
    ok = ~(np.ma.getmaskarray(before) | np.ma.getmaskarray(after))
    d = np.asarray(after, dtype=np.float64)[ok] - np.asarray(before, dtype=np.float64)[ok]
    if len(d) < 2:
        return 0.0, math.inf, int(len(d))
    return float(d.mean()), float(d.std(ddof=1) / math.sqrt(len(d))), int(len(d))


def _falls(mean: float, se: float) -> bool:
    return mean < -MIN_DROP and mean < -HELD_OUT_SIGMAS * se


def check_held_out(scene, result, fit_windows, clock0, T_start: dict, window_us: int) -> None:
    """Check an accepted :class:`~evpose.core.align.joint_result.JointResult` on held-out windows (in place; see
    the module docstring). ``clock0`` and ``T_start`` (name -> ``T_base_obj``) are the fit's start."""
    from evpose.core.align.score_table import score_windows
    from evpose.core.data.clock import ClockModel

    if not result.accepted:
        return
    names = list(scene.object_names)
    windows = held_out_windows(scene, fit_windows, HELD_OUT_WINDOWS, window_us, clock0, names)
    if len(windows) < 4:
        return
    end_clock = ClockModel(result.offset_us, result.skew_ppm, clock0.t_ref_us)
    end = dict(T_start)
    for name, o in result.objects.items():
        end[name] = o.dT_base @ scene.manifest.object(name).T_base_obj
    before = score_windows(scene, windows, names, clock=clock0, poses=T_start)
    after = score_windows(scene, windows, names, clock=end_clock, poses=end)
    result.held_out = {}
    for name in list(result.objects):
        mean, se, n = _paired_drop(_informative(before, name), _informative(after, name))
        result.held_out[name] = {"windows": n, "score_change": mean, "score_change_std": se}
        if _falls(mean, se):
            del result.objects[name]
            end[name] = T_start[name]
            result.held[name] = (f"its alignment score on {n} windows the fit did not use fell by {-mean:.3f} "
                                 f"(± {se:.3f}): a false optimum; pose kept")
    if len(result.held_out) and any(n in result.held for n in result.held_out):
        after = score_windows(scene, windows, names, clock=end_clock, poses=end)
    b = np.ma.concatenate([_informative(before, n) for n in names])
    a = np.ma.concatenate([_informative(after, n) for n in names])
    mean, se, n = _paired_drop(b, a)
    if _falls(mean, se):
        result.accepted = False
        result.reason = (f"the fit made the alignment score on {n} object-windows it did not use fall by {-mean:.3f} "
                         f"(± {se:.3f}); start kept")


def _informative(table, name: str):
    """The object's scores, masked where undefined or without evidence."""
    s = table.score[name]
    return np.ma.masked_array(np.ma.getdata(s), mask=~table.informative(name))
