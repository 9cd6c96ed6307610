"""The silhouette sweep (issue 25.2): the selected object's silhouette swept over a span of time, seen from the top
(x against t) and from the side (y against t), against its events.

A pose error along the line of sight or a tilt hardly moves the outline in one frame, but over a span in which the
camera moves it shows: the predicted silhouette's extent (its leftmost and rightmost column, its top and bottom row,
at each slice time) no longer follows the streaks its edges' events draw in (x, t) and (y, t). A lateral error moves
both predicted lines of a view the same way, a depth error the two apart or together (the object drawn too big or
too small), a tilt one side more than the other and differently as the view changes.

* :func:`silhouette_sweep`: for one object and a span of time, the event counts in (t, x) and (t, y) of the events
  near the silhouette's outline (within :data:`SWEEP_EDGE_PX` of the outline of the slice nearest in time: the
  object's texture and other objects do not fill the view), and the silhouette's extent at each slice time, from
  one label-map render per slice (the space-time view's slices:
  :data:`~evpose.core.views.spacetime_slices.SLICE_REQUEST`).

Pure functions, no Qt. Nothing is estimated here: the view shows the evidence (see :mod:`.residuals` for why no
nudge is suggested).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evpose.core.label.annotate import Annotator
from evpose.core.label.windows import Window
from evpose.core.views.spacetime_band import FIELD_SCALE, signed_field
from evpose.core.views.spacetime_slices import SLICE_REQUEST, slice_times

__all__ = ["SweepData", "silhouette_sweep", "DEFAULT_SWEEP_SPAN_US", "SWEEP_SLICES", "SWEEP_EDGE_PX"]

#: The span swept by default, µs: long enough for the camera to move the view of the object.
DEFAULT_SWEEP_SPAN_US = 200_000
#: Silhouette slices over the span.
SWEEP_SLICES = 24
#: Events at most this far from the outline (px, either side) count in the views.
SWEEP_EDGE_PX = 3.0
#: Time bins of the event images over the span.
SWEEP_TIME_BINS = 100


@dataclass
class SweepData:
    """One object's sweep over ``[t0_us, t1_us)``. Times are ms relative to ``t_center_us``.

    ``top`` (T, W) and ``side`` (T, H) are event counts per time bin (rows, centres ``t_ms``) and column / row;
    ``extent`` (S, 5) holds, per slice time, ``t_ms, x_min, x_max, y_min, y_max`` of the visible silhouette (px,
    pixel centres; NaN where the object is out of view or has no pose)."""

    name: str
    t_center_us: int
    t0_us: int
    t1_us: int
    t_ms: np.ndarray
    top: np.ndarray
    side: np.ndarray
    extent: np.ndarray
    n_events: int = 0
    reason: str = ""


def _empty(name, tc, t0, t1, w, h, reason) -> SweepData:
    return SweepData(name, tc, t0, t1, np.zeros(0), np.zeros((0, w), np.uint16), np.zeros((0, h), np.uint16),
                     np.zeros((0, 5)), 0, reason)


def silhouette_sweep(scene, name: str, t_center_us: int, span_us: int = DEFAULT_SWEEP_SPAN_US, *,
                     n_slices: int = SWEEP_SLICES, n_bins: int = SWEEP_TIME_BINS, edge_px: float = SWEEP_EDGE_PX,
                     annotator: Annotator | None = None, events=None) -> SweepData:
    """The sweep of object ``name`` over ``span_us`` centred on ``t_center_us`` under the scene's corrections.

    ``annotator`` (made with :data:`SLICE_REQUEST` for ``scene``) may be passed to reuse its geometry; ``events``
    (the span's :class:`~evpose.core.data.events.EventArray`) when already read."""
    cam = scene.camera
    W, H = int(cam.width), int(cam.height)
    t0 = int(t_center_us) - int(span_us) // 2
    t1 = t0 + int(span_us)
    if not scene.has_poses or name not in scene.object_names:
        why = "no poses: an event-only scene" if not scene.has_poses else f"no object {name!r}"
        return _empty(name, int(t_center_us), t0, t1, W, H, why)
    k = list(scene.object_names).index(name)
    ann = annotator or Annotator(scene, SLICE_REQUEST)
    times = slice_times(t0, int(span_us), n_slices)
    T_co, T_bc, valid = ann.poses(times)
    extent = np.full((len(times), 5), np.nan)
    extent[:, 0] = (times - int(t_center_us)) * 1e-3
    fields = [None] * len(times)
    for i, t in enumerate(times):
        if not valid[i]:
            continue
        lab = ann.annotate(Window(-1, int(t), int(t) + 1, int(t)), pose=(T_co[i], T_bc[i], True))
        if lab.label_map is None:
            continue
        mask = lab.label_map == k
        cols, rows = np.flatnonzero(mask.any(axis=0)), np.flatnonzero(mask.any(axis=1))
        if len(cols):
            extent[i, 1:] = cols[0], cols[-1], rows[0], rows[-1]
            fields[i] = signed_field(mask, clip_px=edge_px + 1)
    seen = np.isfinite(extent[:, 1])
    if not seen.any():
        return _empty(name, int(t_center_us), t0, t1, W, H, f"{name} is out of view over this span")
    ev = events if events is not None else scene.events.window(t0, t1)
    t_ms = (np.arange(n_bins) + 0.5) * (span_us / n_bins) * 1e-3 - 0.5 * span_us * 1e-3
    if len(ev) == 0:
        z = (np.zeros((n_bins, W), np.uint16), np.zeros((n_bins, H), np.uint16))
        return SweepData(name, int(t_center_us), t0, t1, t_ms, *z, extent, 0, "no events over this span")
    # each event against the outline of the slice nearest its time (slices with the object in view)
    ts = times[seen]
    flds = [f for f, ok in zip(fields, seen) if ok]
    j = np.zeros(len(ev), np.intp)
    if len(ts) > 1:
        j = np.clip(np.searchsorted(ts, ev.t), 1, len(ts) - 1)
        j = np.where(np.abs(ev.t - ts[j - 1]) <= np.abs(ev.t - ts[j]), j - 1, j)
    x, y = ev.x.astype(np.int64), ev.y.astype(np.int64)
    near = np.zeros(len(ev), bool)
    bounds = np.searchsorted(j, np.arange(len(flds) + 1))   # events are time-sorted: each slice's are one run
    for i, f in enumerate(flds):
        sel = slice(bounds[i], bounds[i + 1])
        r, c = y[sel] - f.y0, x[sel] - f.x0
        inside = (r >= 0) & (r < f.sd.shape[0]) & (c >= 0) & (c < f.sd.shape[1])
        sd = np.full(len(r), np.inf)
        sd[inside] = np.abs(f.sd[r[inside], c[inside]].astype(np.float64)) / FIELD_SCALE
        near[sel] = sd <= edge_px
    b = np.clip(((ev.t - t0) * n_bins) // int(span_us), 0, n_bins - 1).astype(np.int64)
    top = np.bincount(b[near] * W + x[near], minlength=n_bins * W).reshape(n_bins, W)
    side = np.bincount(b[near] * H + y[near], minlength=n_bins * H).reshape(n_bins, H)
    cap = np.iinfo(np.uint16).max
    return SweepData(name, int(t_center_us), t0, t1, t_ms, np.minimum(top, cap).astype(np.uint16),
                     np.minimum(side, cap).astype(np.uint16), extent, int(near.sum()))
