"""The model of the joint edge fit: its parameters, and each associated event's signed edge distance with its
derivatives in all of them at once.

Parameters (the increments the fit solves for, around the current state):

* ``offset_us`` and ``skew_ppm`` of the clock (``t_pose = t_event + offset + skew * 1e-6 * (t_event - t_ref)``);
* a hand-eye increment ``dT_cam`` in the camera frame (``T_base_cam' = T_base_cam @ H @ exp(d)``): translation in
  mm, rotation scaled to mm of displacement at :data:`HAND_EYE_RADIUS_M` (1 unit = 2 mrad = 0.115 degrees);
* per object, a base-frame increment about its centre (translation in mm, rotation scaled to mm at the object's
  radius), as :func:`evpose.core.align.pose_refine.delta_T`.

An event ``e`` associated with an edge sample ``P`` (object frame, object ``i``) has the signed distance
``s = n . (x_e - pi(P_c))`` (undistorted pixels, ``n`` the sample's 2D normal) with
``P_c = H^-1 T_cb(tau_e) D_i T_bo_i P``. Its derivatives, with ``a = ds/dP_c = -n^T dpi/dP_c``:

* clock: ``a . v_e`` per µs of offset (``v_e = dP_c/dtau``, the point's velocity in the camera) and
  ``a . v_e * 1e-6 (t_e - t_ref)`` per ppm of skew;
* hand-eye: ``-1e-3 a`` per mm of translation and ``1e-3 / rho * (a x P_c)`` per unit of rotation;
* object ``i``: ``1e-3 R_cb^T a`` per mm and ``-1e-3 / r_i * (R_cb^T a) x (P_b - c_i)`` per unit of rotation.

A row has 14 non-zero entries (clock 2, hand-eye 6, its object 6), so the normal equations are assembled per
object block without forming the dense Jacobian.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from evpose.core.data.clock import ClockModel
from evpose.core.data.geometry import inv_T, make_T

__all__ = ["HAND_EYE_RADIUS_M", "N_CLOCK", "N_HAND_EYE", "EdgeData", "HandEyeScene", "JointState", "gather",
           "jacobian", "he_delta", "KNOT_SPACING_US", "KnotPoses", "set_window_clock"]

#: Scale of the hand-eye rotation parameter: one unit moves a point this far away by 1 mm.
HAND_EYE_RADIUS_M = 0.5
N_CLOCK, N_HAND_EYE = 2, 6
#: Spacing of the knots where a window's camera poses are evaluated exactly (linear in between), µs.
KNOT_SPACING_US = 100


def he_delta(x6: np.ndarray) -> np.ndarray:
    """``exp(d)`` of a hand-eye increment ``x6 = (t_mm (3), r (3))``: translation ``t_mm`` mm and rotation vector
    ``r * 1e-3 / HAND_EYE_RADIUS_M`` (camera frame)."""
    x6 = np.asarray(x6, np.float64)
    return make_T(Rotation.from_rotvec(x6[3:] * 1e-3 / HAND_EYE_RADIUS_M).as_matrix(), x6[:3] * 1e-3)


class HandEyeScene:
    """The scene seen through a trial hand-eye correction ``H`` (camera frame, on top of the scene's own):
    :meth:`T_base_cam` returns ``T_base_cam @ H``; everything else is the scene's."""

    def __init__(self, scene, H: np.ndarray):
        self._scene = scene
        self.H = np.asarray(H, np.float64)

    def __getattr__(self, name):
        return getattr(self._scene, name)

    def T_base_cam(self, t_event_us, clock=None):
        T, ok = self._scene.T_base_cam(t_event_us, clock)
        return T @ self.H, ok


@dataclass
class JointState:
    """The current estimate: clock (float offset, µs), hand-eye ``H`` (4x4, camera frame, on top of the scene's
    correction) and each object's base-frame pose ``T_bo`` (list of 4x4)."""

    offset_us: float
    skew_ppm: float
    t_ref_us: int
    H: np.ndarray
    T_bo: list

    def clock(self) -> ClockModel:
        return ClockModel(int(round(self.offset_us)), float(self.skew_ppm), int(self.t_ref_us))

    def copy(self) -> "JointState":
        return JointState(self.offset_us, self.skew_ppm, self.t_ref_us, self.H.copy(), [T.copy() for T in self.T_bo])


@dataclass
class EdgeData:
    """The associated events of one level (fixed association), with everything :func:`jacobian` needs.

    Arrays of length N (associated events): ``s`` signed distance (px) at the state they were gathered at,
    ``obj`` object index, ``win`` window index, ``outer`` silhouette flag, ``t_rel_us`` event time minus the
    clock's reference (float), ``P_b`` the edge sample in the base frame, ``P_c`` in the camera, ``R_cb`` (N, 3, 3)
    and ``v`` (N, 3) the camera's rotation and the sample's velocity in the camera (m/µs), ``normal`` (N, 2).
    ``n_events`` is the number of valid events in the windows (the objective's fixed normaliser)."""

    s: np.ndarray
    obj: np.ndarray
    win: np.ndarray
    outer: np.ndarray
    t_rel_us: np.ndarray
    P_b: np.ndarray
    P_c: np.ndarray
    R_cb: np.ndarray
    v: np.ndarray
    normal: np.ndarray
    n_events: int

    def slices(self, n_objects: int) -> list[slice]:
        """The rows of each object (the data are sorted by object)."""
        b = np.searchsorted(self.obj, np.arange(n_objects + 1))
        return [slice(int(b[i]), int(b[i + 1])) for i in range(n_objects)]


class KnotPoses:
    """A window's per-event camera poses (camera <- base, ``(3, 4)``: rotation and translation), linearly
    interpolated between poses at knots, computed when indexed: ``poses[e]`` (an event or an index array),
    ``poses[e, :3, :3]``, ``poses[e, :3, 3]``; :meth:`rate` the time derivative (per µs). Per event only the knot
    and the fraction are kept (16 bytes instead of 2 x 96 for the poses and their rates: ~40 MB less during Auto's
    edge fit, tracker issue 25.4); every value is computed with the same operations as for all events at once."""

    def __init__(self, T_knots: np.ndarray, j: np.ndarray, f: np.ndarray, spacing_us: int):
        self.T_knots, self.j, self.f, self.spacing_us = T_knots, j, f, float(spacing_us)

    def __len__(self) -> int:
        return len(self.j)

    @property
    def shape(self) -> tuple:
        return len(self.j), 3, 4

    def __getitem__(self, key):
        first, rest = (key[0], key[1:]) if isinstance(key, tuple) else (key, ())
        j, f = self.j[first], np.asarray(self.f[first])[..., None, None]
        out = self.T_knots[j] * (1.0 - f) + self.T_knots[j + 1] * f
        return out[(Ellipsis,) + rest] if rest else out

    def rate(self, index) -> np.ndarray:
        """The poses' time derivative at events ``index``, ``(..., 3, 4)`` per µs."""
        j = self.j[index]
        return (self.T_knots[j + 1] - self.T_knots[j]) / self.spacing_us


def set_window_clock(view, w, clock, spacing_us: int = KNOT_SPACING_US) -> None:
    """Per-event camera poses of window ``w`` under ``clock`` (``w.T_cb``, a :class:`KnotPoses`: camera <- base,
    ``(3, 4)`` per event, and its :meth:`~KnotPoses.rate` per µs; ``w.ok``), linearly interpolated between knots
    every ``spacing_us`` where the trajectory is evaluated exactly (its slerp). Cheap enough to redo at every trial
    clock: a window needs ~100 trajectory evaluations instead of one per event, and the interpolation error is below
    1e-8 rad at 1 rad/s."""
    t = w.ev_t
    knots = np.arange(w.t0 - spacing_us, w.t1 + 2 * spacing_us, spacing_us, dtype=np.int64)
    T_bc, ok_k = view.T_base_cam(knots, clock)
    T_cb = np.ascontiguousarray(inv_T(T_bc)[:, :3, :])               # (k, 3, 4)
    j = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, len(knots) - 2)
    w.T_cb = KnotPoses(T_cb, j, (t - knots[j]) / float(spacing_us), spacing_us)
    w.ok = ok_k[j] & ok_k[j + 1] & np.all(np.isfinite(w.xy), axis=1)
    w.clock = clock


def gather(setup, contours, state: JointState, band_px: float, n_sub: int) -> EdgeData | None:
    """The events within ``band_px`` of the contours' samples (nearest sample at the event's own time, as
    :meth:`evpose.core.align.contours.Contours.associate`) at ``state`` (the windows' poses set for it by
    :func:`set_window_clock`); sorted by object; None when there are none."""
    parts = []
    for k, (w, c) in enumerate(zip(setup.wins, contours)):
        ei, si, sd = c.associate(w, state.T_bo, band_px, n_sub)
        if len(ei) == 0:
            continue
        obj = c.obj[si]
        P_b = np.empty((len(si), 3))
        for i in np.unique(obj):
            m = obj == i
            T = state.T_bo[i]
            P_b[m] = c.P[si[m]] @ T[:3, :3].T + T[:3, 3]
        A = w.T_cb[ei]
        R_cb = A[:, :3, :3]
        P_c = np.einsum("nij,nj->ni", R_cb, P_b) + A[:, :3, 3]
        A = w.T_cb.rate(ei)
        v = np.einsum("nij,nj->ni", A[:, :, :3], P_b) + A[:, :, 3]
        del A
        parts.append([sd, obj, np.full(len(ei), k), c.outer[si], (w.ev_t[ei] - state.t_ref_us).astype(np.float64),
                      P_b, P_c, R_cb, v, c.normal[si]])
    if not parts:
        return None
    order = np.argsort(np.concatenate([p[1] for p in parts]), kind="stable")   # by object: its rows are a slice
    cols = []
    for j in range(10):                 # one column at a time, the windows' parts of it dropped once joined
        cols.append(np.concatenate([p[j] for p in parts])[order])
        for p in parts:
            p[j] = None
    n_all = max(sum(int(w.ok.sum()) for w in setup.wins), 1)
    return EdgeData(*cols, n_events=n_all)


def jacobian(d: EdgeData, K: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Derivatives of ``d.s`` in the 14 parameters each event depends on, ``(N, 14)``: offset (µs), skew (ppm),
    hand-eye (t mm (3), r (3)), its object (t mm (3), r (3)); ``centres`` (K, 3) base frame and ``radii`` (K,) of
    the objects at the state the data were gathered at."""
    X, Y, Z = d.P_c[:, 0], d.P_c[:, 1], np.maximum(d.P_c[:, 2], 1e-6)
    fx, fy = float(K[0, 0]), float(K[1, 1])
    nx, ny = d.normal[:, 0], d.normal[:, 1]
    a = -np.stack([nx * fx / Z, ny * fy / Z, -(nx * fx * X + ny * fy * Y) / (Z * Z)], axis=1)   # ds/dP_c
    J = np.empty((len(d.s), 14))
    J[:, 0] = np.einsum("ij,ij->i", a, d.v)
    J[:, 1] = J[:, 0] * 1e-6 * d.t_rel_us
    J[:, 2:5] = -1e-3 * a
    J[:, 5:8] = np.cross(a, d.P_c) * (1e-3 / HAND_EYE_RADIUS_M)
    b = np.einsum("nji,nj->ni", d.R_cb, a)                      # R_cb^T a
    J[:, 8:11] = 1e-3 * b
    J[:, 11:14] = -np.cross(b, d.P_b - centres[d.obj]) * (1e-3 / radii[d.obj])[:, None]
    return J
