"""The per-scene tasks of the dataset commands, run on Dask workers.

Each task opens its scene from a path (with the dataset's shared defaults), does what the single-scene
command does through the same core function, closes the scene and returns the same JSON document
(plain values): ``dataset sync`` equals ``evpose sync`` scene by scene because both call
:func:`evpose.core.align.sync_run.run_sync`.
"""
from __future__ import annotations

from contextlib import contextmanager

from evpose.core.data.json_values import plain
from evpose.core.label.windows import DEFAULT_WINDOW_US

__all__ = ["info_task", "sync_task", "refine_task", "score_task", "review_progress", "looked_at", "triage_task",
           "TRIAGE_WINDOW_US"]

#: Window length of the triage scores and review progress (the export default).
TRIAGE_WINDOW_US = DEFAULT_WINDOW_US


@contextmanager
def _scene(path: str, defaults):
    from evpose.core.data.scene import Scene

    scene = Scene.open(path, defaults=defaults)
    try:
        yield scene
    finally:
        scene.close()


def info_task(path: str, defaults) -> dict:
    """``evpose info SCENE --json``."""
    from evpose.core.data.scene_summary import scene_info

    with _scene(path, defaults) as scene:
        return plain(scene_info(scene))


def sync_task(path: str, defaults, opts) -> dict:
    """``evpose sync SCENE --json`` with the options ``opts`` (:class:`~evpose.core.align.sync_run.SyncOptions`)."""
    from evpose.core.align.sync_run import run_sync

    with _scene(path, defaults) as scene:
        return plain(run_sync(scene, opts).data)


def refine_task(path: str, defaults, opts) -> dict:
    """``evpose refine SCENE --joint --json`` with the options ``opts``
    (:class:`~evpose.core.align.refine_run.JointRunOptions`): the fit, ``changes`` (what ``--apply`` stores or would
    store, each beyond its sigma of what is in effect), ``kept``, ``applied``."""
    from evpose.core.align.refine_run import run_refine_joint

    with _scene(path, defaults) as scene:
        return plain(run_refine_joint(scene, opts).data)


def score_task(path: str, defaults, window_us: int = TRIAGE_WINDOW_US) -> dict:
    """``evpose score SCENE --json --window-ms window_us/1000``."""
    from evpose.core.align.score_table import score_windows

    with _scene(path, defaults) as scene:
        return plain(score_windows(scene, window_us=window_us).to_json())


def review_progress(scene, window_us: int = TRIAGE_WINDOW_US, windows=None) -> dict:
    """How far the review of ``scene`` is: the windows ``export --only-verified`` would export (every
    object verified by a mark that is not stale), the windows marked otherwise, and the marks by status.
    ``windows``: the ``window_us`` tiling when the caller has built it already."""
    import numpy as np

    from evpose.core.export.windows import build_windows, review_usage, scene_staleness

    reviews = scene.corrections.reviews
    if windows is None:
        windows = build_windows(scene.events, window_us=window_us)
    keep, touched, _ = review_usage(windows, reviews, scene.object_names, scene_staleness(scene))
    statuses: dict = {}
    for m in reviews:
        statuses[m.status] = statuses.get(m.status, 0) + 1
    n = len(windows)
    return {"n_windows": n, "verified_windows": int(np.count_nonzero(keep)),
            "verified_fraction": float(np.count_nonzero(keep) / n) if n else 0.0,
            "touched_not_verified": int(np.count_nonzero(touched & ~keep)), "marks": statuses}


def looked_at(scene, score: dict, window_us: int = TRIAGE_WINDOW_US) -> dict:
    """Objects whose worst window (:func:`evpose.core.dataset.triage_scores.object_scores`) a person verified in
    review with a mark that is still fresh (made on the poses and clock in effect now): ``{name: {"window", "note"}}``.
    The triage reports them as "looked at, fine" instead of flagging their low scores again; a correction stored
    since makes the mark stale and the flag comes back."""
    from evpose.core.dataset.triage_scores import object_scores
    from evpose.core.export.windows import build_windows, review_usage, scene_staleness

    reviews = scene.corrections.reviews
    if not reviews:
        return {}
    windows = build_windows(scene.events, window_us=window_us)
    stale = scene_staleness(scene)
    out = {}
    for name in scene.object_names:
        worst = object_scores(score, name)["worst"]
        if not worst:
            continue
        idx = int(worst[0]["index"])
        keep, _, _ = review_usage(windows[idx:idx + 1], reviews, [name], stale)
        if keep[0]:
            w = windows[idx]
            notes = [m.note for m in reviews if m.note and m.status == "verified" and m.object in (None, name)
                     and m.t0_us < w.t1_us and m.t1_us > w.t0_us]
            out[name] = {"window": idx, "note": "; ".join(notes)}
    return out


def triage_task(path: str, defaults, sync_opts, window_us: int = TRIAGE_WINDOW_US) -> dict:
    """What the triage report needs of one scene: ``info``, ``sync`` (the rate estimate, never applied),
    ``score`` (per-object summary and per-window scores), ``review`` (:func:`review_progress`) and ``thumbnails``
    (each object's worst window drawn: :func:`evpose.core.dataset.thumbnails.worst_window_thumbnails`)."""
    from dataclasses import replace

    from evpose.core.align.score_table import score_windows
    from evpose.core.align.sync_run import run_sync
    from evpose.core.data.scene_summary import scene_info

    from evpose.core.dataset.thumbnails import worst_window_thumbnails

    with _scene(path, defaults) as scene:
        score = plain(score_windows(scene, window_us=window_us).to_json())
        doc = {"info": scene_info(scene), "sync": run_sync(scene, replace(sync_opts, apply=False)).data,
               "score": score, "review": review_progress(scene, window_us),
               "thumbnails": worst_window_thumbnails(scene, score), "looked_at": looked_at(scene, score, window_us)}
    return plain(doc)
