"""Event representations by name, for the views: one window's events -> ``uint8 (H, W, 3)`` RGB.

:data:`REPRESENTATIONS` maps a name to a function ``(ev, width, height, t0_us, t1_us, **opts) -> uint8 (H, W, 3)``
built from the event frames of :mod:`evpose.core.label.event_frames` (stateless: a pure function of the
window's events) and their display conversions (:mod:`evpose.core.label.event_frames.display`).
"""
from __future__ import annotations

import numpy as np

from evpose.core.data.events import EventArray
from evpose.core.label.event_frames.accumulate import check_size, check_window
from evpose.core.label.event_frames.counts import polarity_counts, spike
from evpose.core.label.event_frames.display import (
    check_background,
    gray_rgb,
    polarity_rgb,
    signed_rgb,
    three_channel_rgb,
    two_colour,
)
from evpose.core.label.event_frames.three_channel import three_channel
from evpose.core.label.event_frames.time_surface import time_surface
from evpose.core.label.event_frames.undistort import undistorter_for
from evpose.core.label.event_frames.voxel_grid import voxel_grid

__all__ = ["REPRESENTATIONS", "to_rgb"]


def _prepare(ev, width, height, t0_us, t1_us, camera, K_new):
    W, H = check_size(width, height)
    check_window(ev, t0_us, t1_us)
    if camera is not None:
        u = undistorter_for(camera, K_new, size=(W, H) if (W, H) != (camera.width, camera.height) else None)
        ev = u.apply(ev)
    return ev, W, H


def _r_polarity(ev, width, height, t0_us, t1_us, *, background="white", percentile=99.0,
                camera=None, K_new=None):
    ev, W, H = _prepare(ev, width, height, t0_us, t1_us, camera, K_new)
    return polarity_rgb(*polarity_counts(ev, W, H), background=background, percentile=percentile)


def _r_spike(ev, width, height, t0_us, t1_us, *, background="white", camera=None, K_new=None):
    check_background(background)
    ev, W, H = _prepare(ev, width, height, t0_us, t1_us, camera, K_new)
    return gray_rgb(spike(ev, W, H), invert=background == "white")


def _r_counts(ev, width, height, t0_us, t1_us, *, background="white", percentile=99.0,
              camera=None, K_new=None):
    check_background(background)
    ev, W, H = _prepare(ev, width, height, t0_us, t1_us, camera, K_new)
    pos, neg = polarity_counts(ev, W, H)
    return gray_rgb(pos + neg, percentile=percentile, invert=background == "white")


def _r_three_channel(ev, width, height, t0_us, t1_us, *, time_norm="max", background="white",
                     camera=None, K_new=None):
    check_background(background)    # accepted for a uniform option set; the image is the data itself
    ev, W, H = _prepare(ev, width, height, t0_us, t1_us, camera, K_new)
    return three_channel_rgb(three_channel(ev, W, H, t0_us, t1_us, time_norm=time_norm))


def _r_time_surface(ev, width, height, t0_us, t1_us, *, tau_us=None, polarity="merged", background="white",
                    camera=None, K_new=None):
    ev, W, H = _prepare(ev, width, height, t0_us, t1_us, camera, K_new)
    if tau_us is None:
        tau_us = max(1.0, (int(t1_us) - int(t0_us)) / 3.0)
    ts = time_surface(ev, W, H, int(t1_us), tau_us=tau_us, polarity=polarity)
    if polarity == "split":
        return two_colour(ts[0], ts[1], background)
    check_background(background)
    return gray_rgb(ts, vmax=1.0, invert=background == "white")


def _r_voxel(ev, width, height, t0_us, t1_us, *, bins=5, show="sum", background="white", percentile=99.0,
             camera=None, K_new=None):
    if show not in ("sum", "latest"):
        raise ValueError(f"show: expected 'sum' or 'latest', got {show!r}")
    ev, W, H = _prepare(ev, width, height, t0_us, t1_us, camera, K_new)
    vg = voxel_grid(ev, W, H, t0_us, t1_us, bins=bins)
    img = vg.sum(axis=0) if show == "sum" else vg[-1]
    return signed_rgb(img, background=background, percentile=percentile)


#: name -> ``f(ev, width, height, t0_us, t1_us, **opts) -> uint8 (H, W, 3)``, in display order.
#: Every entry checks the window (events in ``[t0_us, t1_us)``) and accepts ``camera=`` (a CameraModel;
#: events are first moved to undistorted pixels with :func:`undistorter_for`), ``K_new=`` and
#: ``background="white"|"black"``. Further options: polarity/counts ``percentile``; three_channel
#: ``time_norm``; time_surface ``tau_us`` (default a third of the window, so its oldest events fade to ~5 %,
#: reference time ``t1_us``) and ``polarity="merged"|"split"`` (split: ON red, OFF blue); voxel ``bins``,
#: ``show="sum"|"latest"`` (signed sum over bins or the latest bin; positive red, negative blue).
#: Unknown options raise TypeError.
REPRESENTATIONS = {
    "polarity": _r_polarity,
    "spike": _r_spike,
    "counts": _r_counts,
    "three_channel": _r_three_channel,
    "time_surface": _r_time_surface,
    "voxel": _r_voxel,
}


def to_rgb(kind: str, ev: EventArray, width: int, height: int, t0_us: int, t1_us: int, **opts) -> np.ndarray:
    """Render one window with the representation ``kind`` (a key of :data:`REPRESENTATIONS`) to
    ``uint8 (H, W, 3)`` RGB."""
    try:
        f = REPRESENTATIONS[kind]
    except KeyError:
        raise ValueError(f"kind: unknown representation {kind!r}; choose from {', '.join(REPRESENTATIONS)}") from None
    return f(ev, width, height, t0_us, t1_us, **opts)
