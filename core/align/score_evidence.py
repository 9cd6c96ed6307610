"""The evidence behind a window's alignment score: could a pose error show in this window at all?

A score is computed from the events near the object. In a window where the object hardly moves in the
image, or where few events fall near its edges, or where most of it is outside the image, the score is
dominated by sensor noise and texture, and its value says nothing about the pose: such a window may have
the lowest score of the sequence without anything wrong being visible in it. Such windows are **low
evidence**: they keep their score (it is reported), but "worst window" never lands on them.

The evidence of one object in one window:

* ``n_edge_events``: events within ``near_px`` of the object's projected edges (silhouette and depth
  discontinuities), counted over the whole window (the score subsamples long windows; the count is scaled
  back by the stride), from :func:`evpose.core.align.score.score_window`;
* ``motion_px_s``: image motion of the object, px/s: the mean displacement of its bounding-box corners and
  centre between the poses at the window's two ends, over its length (pinhole pixels of the scene camera:
  ``K`` without the distortion, which is not monotonic far outside the image);
* ``in_view_fraction``: share of the projected bounding box (its corners' bounding rectangle) inside
  the image at the window's label time (the undistorted image's inscribed rectangle, :func:`view_rect`).

The thresholds (:class:`EvidenceParams`) and the measurement behind them are in ``docs/refine.md``
("Alignment score").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["EvidenceParams", "STATE_LOW", "STATE_OK", "STATE_UNDEFINED", "box_points", "image_motion_px_s",
           "in_view_fraction", "low_evidence_reason", "view_rect"]

#: Per window and object: the score is defined and backed by evidence / defined but low evidence / undefined.
STATE_OK, STATE_LOW, STATE_UNDEFINED = "ok", "low_evidence", "undefined"


@dataclass(frozen=True)
class EvidenceParams:
    """When a defined score counts as low evidence (any one condition suffices).

    The defaults come from the measurement in ``docs/refine.md`` ("Alignment score"): windows scored at
    the true poses and at random 5 mm / 3 degree errors, on synthetic scenes at 0.1-1.0 m/s (half
    DAVIS346, with dwells, one with 10x sensor noise) and a 5-object YCB scene (full DAVIS346).

    Attributes
    ----------
    min_edge_events : int
        Fewer events than this within ``near_px`` of the object's edges (whole window). Below 25 the true
        pose beat the error in about half the draws (chance) and scored below most erroneous windows;
        from 100 on it never did.
    min_motion_px : float
        The object moves less than this in the image over the window, pixels at ``fx = 146`` (half
        DAVIS346; scaled by ``fx / 146``), i.e. 5 px/s for 10 ms windows at half and 10 px/s at full
        DAVIS346 resolution. Reported as a speed, px/s. Windows below it are the robot's dwells: their
        events are sensor noise.
    min_in_view : float
        Less than this share of the object's projected bounding box is inside the image: on the YCB
        scene, 50-72 % of such windows showed the error, against 97-99 % above.
    """

    min_edge_events: int = 100
    min_motion_px: float = 0.05
    min_in_view: float = 0.5

    def min_motion_px_s(self, fx: float, window_us) -> np.ndarray:
        """The motion threshold as a speed (px/s) for windows of ``window_us`` µs in a camera of focal ``fx`` px."""
        w = np.asarray(window_us, np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(w > 0, self.min_motion_px * (fx / 146.0) / (w * 1e-6), np.inf)


def box_points(model) -> np.ndarray:
    """The 8 bounding-box corners and the centre ``(9, 3)`` of an object model, object frame, metres."""
    return np.vstack([model.bbox_corners(), model.bbox_center_m[None]])


def _project(camera, T_cam_obj: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole pixels ``(N, P, 2)`` (``K`` only, no distortion) and validity ``(N, P)`` (in front of the near
    plane) of object points ``pts (P, 3)`` under poses ``(N, 4, 4)``. The distortion model is not used: far
    outside the image it is not monotonic and would throw points to absurd pixels."""
    T = np.asarray(T_cam_obj, np.float64).reshape(-1, 4, 4)
    P = np.einsum("nij,pj->npi", T[:, :3, :3], pts) + T[:, None, :3, 3]
    z = P[..., 2]
    ok = z > camera.near_m
    zs = np.where(ok, z, 1.0)
    K = camera.K
    uv = np.stack([K[0, 0] * P[..., 0] / zs + K[0, 2], K[1, 1] * P[..., 1] / zs + K[1, 2]], axis=-1)
    return np.where(ok[..., None], uv, np.nan), ok


def view_rect(camera, n: int = 16) -> tuple[float, float, float, float]:
    """``(u0, v0, u1, v1)``: the rectangle of the undistorted (pinhole) image inscribed in what the sensor
    sees (its border pixels undistorted; without distortion the sensor's own ``[-0.5, W - 0.5)``)."""
    W, H = camera.width, camera.height
    s_u, s_v = np.linspace(-0.5, W - 0.5, n), np.linspace(-0.5, H - 0.5, n)
    sides = [np.stack([np.full(n, -0.5), s_v], 1), np.stack([np.full(n, W - 0.5), s_v], 1),
             np.stack([s_u, np.full(n, -0.5)], 1), np.stack([s_u, np.full(n, H - 0.5)], 1)]
    K = camera.K
    ideal = [camera.undistort_points(b) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]] for b in sides]
    # border pixels without a ray (a lens folding back within the sensor: NaN) bound nothing; a side with none
    # left is bounded by the sensor's own edge
    bound = [(np.nanmax, 0, -0.5), (np.nanmax, 1, -0.5), (np.nanmin, 0, W - 0.5), (np.nanmin, 1, H - 0.5)]
    out = []
    for side, (pick, axis, edge) in zip((ideal[0], ideal[2], ideal[1], ideal[3]), bound):
        v = side[:, axis]
        out.append(float(pick(v)) if np.isfinite(v).any() else float(edge))
    return tuple(out)


def image_motion_px_s(camera, pts: np.ndarray, T_co_start: np.ndarray, T_co_end: np.ndarray,
                      window_us) -> np.ndarray:
    """Image speed of an object over each window, px/s.

    Parameters
    ----------
    camera : CameraModel
    pts : (P, 3) float
        Object points (e.g. :func:`box_points`), object frame, metres.
    T_co_start, T_co_end : (N, 4, 4) float
        ``T_cam_obj`` at each window's start and end.
    window_us : (N,) int
        Window lengths, µs.

    Returns
    -------
    (N,) float64
        Mean displacement (pinhole px) of the points in front of the camera at both ends, over the window
        length (s); NaN for empty windows and where no point is in front at both ends.
    """
    a, oka = _project(camera, T_co_start, pts)
    b, okb = _project(camera, T_co_end, pts)
    ok = oka & okb
    d = np.where(ok, np.linalg.norm(b - a, axis=-1), 0.0).sum(axis=1)
    n = ok.sum(axis=1)
    w = np.asarray(window_us, np.float64).reshape(-1) * 1e-6
    with np.errstate(divide="ignore", invalid="ignore"):
        v = d / n / w
    return np.where((n > 0) & (w > 0), v, np.nan)


def in_view_fraction(camera, pts: np.ndarray, T_cam_obj: np.ndarray) -> np.ndarray:
    """Share of each pose's projected bounding rectangle that lies inside the image (:func:`view_rect`).

    The rectangle spans the points in front of the camera (pinhole pixels); points behind it count as
    outside, so the share is scaled by the fraction of points in front.

    Returns
    -------
    (N,) float64 in [0, 1]
    """
    uv, ok = _project(camera, T_cam_obj, pts)
    u0, v0, u1, v1 = view_rect(camera)
    uv = np.where(ok[..., None], uv, 0.0)
    any_ok = ok.any(axis=1)
    lo = np.where(any_ok[:, None], np.where(ok[..., None], uv, np.inf).min(axis=1), 0.0)
    hi = np.where(any_ok[:, None], np.where(ok[..., None], uv, -np.inf).max(axis=1), 0.0)
    size = np.maximum(hi - lo, 1.0)                                   # (N, 2), at least a pixel
    mid = 0.5 * (lo + hi)
    lo, hi = mid - 0.5 * size, mid + 0.5 * size
    inter = (np.clip(np.minimum(hi[:, 0], u1) - np.maximum(lo[:, 0], u0), 0, None)
             * np.clip(np.minimum(hi[:, 1], v1) - np.maximum(lo[:, 1], v0), 0, None))
    frac = np.where(any_ok, inter / (size[:, 0] * size[:, 1]), 0.0)
    return np.clip(frac, 0.0, 1.0) * ok.mean(axis=1)


def low_evidence_reason(n_edge_events: int, motion_px_s: float, in_view: float, min_motion_px_s: float,
                        params: EvidenceParams) -> str:
    """Why a defined score is low evidence ('' when it is not): the failing conditions, joined by '; '.

    ``motion_px_s`` NaN (unknown: a window end outside the trajectory) is not a reason by itself."""
    why = []
    if n_edge_events < params.min_edge_events:
        why.append(f"too few events near the edges ({n_edge_events} < {params.min_edge_events})")
    if np.isfinite(motion_px_s) and motion_px_s < min_motion_px_s:
        why.append(f"no image motion ({motion_px_s:.1f} < {min_motion_px_s:.1f} px/s)")
    if in_view < params.min_in_view:
        why.append(f"object mostly out of view ({100 * in_view:.0f} % of its box in the image)")
    return "; ".join(why)
