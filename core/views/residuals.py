"""The residual view: how far each event of a window lies from the edges its labels predict (issue 25.2).

A silhouette drawn over the events hides the errors a user most needs to see: an object off along the line of
sight, or tilted, hardly moves its outline. Its *edges* move, though, by a fraction of a pixel that is consistent
around the object: every event near an edge has a signed distance ``s`` to it (px, along the edge's normal;
positive outside the predicted silhouette). A shift shows as opposite signs on opposite sides, a depth error as one
sign all around, a tilt as opposite signs on the near and far sides.

* :func:`residuals`: for one event window under the corrections of a scene snapshot, every event near an object's
  visible edges with its signed distance (the association of the edge fits,
  :meth:`evpose.core.align.contours.Contours.associate`: each event at its own camera pose), and per object the
  events counted, the mean and RMS signed distance on its silhouette and the outline's image shift that fits them
  (px). A growth of the outline is fitted with the shift but not reported: on textured objects the events inside the
  outline pull it inwards (about 0.3 px with the true poses on the test scene), so it does not measure depth.
* What the view does not do: suggest the nudge to make. Tried on the test scene (a box 5 mm / 3 deg off): the
  residuals of one window put its depth ~10 mm off (the growth above), and a walk that took, of the pose panel's
  twelve nudges, the one that raised the refinement's edge objective most over 6-24 windows (halving the step when
  none did) stalled at 1.4-3.1 mm / 2.6-3.1 deg, while Refine, which moves all six together coarse to fine, reached
  0.09 mm / 0.08 deg. A hint that stalls or points the wrong way is worse than none: the view shows the evidence.
* :func:`residual_rgb`: the events coloured by their signed distance for the widget.

Pure functions, no Qt.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["DEFAULT_BAND_PX", "ObjectResidual", "ResidualData", "residual_rgb", "residuals"]

#: Events within this many pixels of an edge are associated with it (the colour scale's full range).
DEFAULT_BAND_PX = 4.0
#: The colours are full at this signed distance (px): a label off by a pixel shows clearly.
COLOUR_FULL_PX = 1.5
#: Huber threshold of the robust step, px: events further from their edge count linearly (texture, clutter).
HUBER_PX = 1.0
#: Width of the redescending weights of the robust step, px.
RIDGE_PX = 0.7
#: The shift's standard error is a jackknife over this many sectors of the outline's normal direction ...
N_SECTORS = 8
#: ... with this floor (px). With the true poses on the test scene (tests/evpose_testing.TINY_SCENE, 16 windows,
#: 54 shift components): |shift| / sigma <= 2 for 83 % without the floor, 93 % with it; <= 4 for 93 % / 94 %; the
#: worst (8 sigma, 0.6-1.1 px) in windows where the events lag the moving edges. Not the 100 % within 4 sigma of the
#: estimators: the view is evidence to look at, not a number to store.
SHIFT_FLOOR_PX = 0.1


@dataclass
class ObjectResidual:
    """One object's residuals in a window (see the module docstring): events near its edges, the mean and RMS signed
    distance on its silhouette (px; + outside the drawn outline), and the image shift of the outline that fits its
    silhouette events best (px, x right, y down) with its standard error (:func:`_sector_jackknife`)."""

    name: str
    n_events: int
    mean_px: float | None
    rms_px: float | None
    shift_px: np.ndarray
    shift_std_px: np.ndarray


@dataclass
class ResidualData:
    """The residuals of one window: associated events (raw pixel coordinates ``uv``, signed distance ``signed_px``,
    object index ``obj`` into ``names``, ``outer``: on a silhouette rather than an inner edge), every event of the
    window drawn (``all_uv``), per-object summaries, the camera's image size and the band."""

    t0_us: int
    t1_us: int
    names: list
    uv: np.ndarray
    signed_px: np.ndarray
    obj: np.ndarray
    outer: np.ndarray
    all_uv: np.ndarray
    objects: dict = field(default_factory=dict)
    size: tuple = (0, 0)
    band_px: float = DEFAULT_BAND_PX
    reason: str = ""                 # why nothing was computed ("" when something was)


def _empty(scene, t0_us, t1_us, names, band_px, reason, all_uv=None) -> ResidualData:
    z2, z = np.zeros((0, 2)), np.zeros(0)
    cam = scene.camera
    return ResidualData(int(t0_us), int(t1_us), list(names), z2, z, z.astype(np.int64), z.astype(bool),
                        z2 if all_uv is None else all_uv, {}, (cam.width, cam.height), band_px, reason)


def residuals(scene, t0_us: int, t1_us: int, *, names=None, band_px: float = DEFAULT_BAND_PX,
              max_events: int = 40_000) -> ResidualData:
    """The residuals of window ``[t0_us, t1_us)`` of ``scene`` (a snapshot: its corrections are the labels') for the
    objects ``names`` (default: all)."""
    from evpose.core.align.edges import EdgeSetup
    from evpose.core.align.refine_result import RefineParams

    names = list(scene.object_names if names is None else names)
    clock = scene.clock
    if not names:
        return _empty(scene, t0_us, t1_us, names, band_px, "no object shown")
    setup = EdgeSetup(scene, names, [(int(t0_us), int(t1_us))], clock,
                      RefineParams(max_events=max_events, spacing_px=0.5, n_sub=3))
    w = setup.wins[0]
    cam = scene.camera
    all_uv = _raw(cam, w.xy[np.all(np.isfinite(w.xy), axis=1)])
    if not w.ok.any():
        return _empty(scene, t0_us, t1_us, names, band_px, "no camera pose for these events", all_uv)
    T_bo = [scene.T_base_obj(n) for n in names]
    contours = setup.contours(T_bo, clock)
    c = contours[0]
    if not c.valid or len(c.P) == 0:
        return _empty(scene, t0_us, t1_us, names, band_px, "no object edge in view", all_uv)
    ei, si, sd = c.associate(w, T_bo, band_px, setup.p.n_sub)
    out = ResidualData(int(t0_us), int(t1_us), names, _raw(cam, w.xy[ei]), sd, c.obj[si], c.outer[si], all_uv,
                       {}, (cam.width, cam.height), band_px)
    # the outline's image shift that fits the silhouette's events: s = n . d + g (n the outward normal, g a growth
    # that takes up what a shift cannot: depth, and texture events inside the outline)
    nrm = c.normal[si]
    for i, name in enumerate(names):
        on = out.obj == i
        sil = on & out.outer
        mean = float(out.signed_px[sil].mean()) if sil.any() else None
        rms = float(np.sqrt(np.mean(out.signed_px[sil] ** 2))) if sil.any() else None
        shift, shift_sd = np.zeros(2), np.full(2, np.inf)
        if sil.sum() >= 12:
            A = np.column_stack([nrm[sil], np.ones(int(sil.sum()))])
            shift = _robust_step(A, -out.signed_px[sil])[0][:2]
            shift_sd = _sector_jackknife(A, out.signed_px[sil], nrm[sil])
        out.objects[name] = ObjectResidual(name, int(on.sum()), mean, rms, shift, shift_sd)
    return out


def _sector_jackknife(A: np.ndarray, s: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Standard errors of the shift by a jackknife over :data:`N_SECTORS` sectors of the outline's normal direction:
    events on one stretch of edge share its errors (texture beside it, a model edge that is not where the object's
    is), so the sectors, not the events, are the independent evidence. inf with fewer than 3 sectors holding events."""
    ang = np.arctan2(normals[:, 1], normals[:, 0])
    sector = np.minimum(((ang + np.pi) / (2 * np.pi) * N_SECTORS).astype(np.int64), N_SECTORS - 1)
    present = [k for k in range(N_SECTORS) if np.count_nonzero(sector == k) >= 3]
    if len(present) < 3:
        return np.full(2, np.inf)
    est = []
    for k in present:
        keep = sector != k
        est.append(_robust_step(A[keep], -s[keep])[0][:2])
    est = np.array(est)
    n = len(est)
    return np.hypot(np.sqrt((n - 1) / n * np.sum((est - est.mean(axis=0)) ** 2, axis=0)), SHIFT_FLOOR_PX)


def _raw(cam, xy_und: np.ndarray) -> np.ndarray:
    """Undistorted pixels (of ``cam.K``) back to the sensor's pixels, where the frame view draws them."""
    if len(xy_und) == 0:
        return np.zeros((0, 2))
    K = cam.K
    n = np.stack([(xy_und[:, 0] - K[0, 2]) / K[0, 0], (xy_und[:, 1] - K[1, 2]) / K[1, 1]], axis=1)
    return cam.distort_normalized(n)


def _robust_step(J: np.ndarray, s: np.ndarray, iterations: int = 12):
    """The step ``x`` with ``s + J x ~ 0`` and its covariance (events taken as independent: a lower bound).

    Redescending weights (Gaussian of width :data:`RIDGE_PX`, after a least-squares start): the events *on* an edge
    decide, not the ones a textured object fires all over its inside (with Huber weights those pulled every outline
    ~1 px inwards on the test scene, i.e. ~10 mm of depth)."""
    x = np.zeros(J.shape[1])
    w = np.ones(len(s))
    for k in range(iterations):
        A = J.T @ (J * w[:, None])
        A += np.eye(len(x)) * 1e-9 * max(np.trace(A), 1e-12)
        x = np.linalg.solve(A, -J.T @ (w * s))
        r = s + J @ x
        w = np.exp(-0.5 * (r / RIDGE_PX) ** 2) if k else np.minimum(1.0, HUBER_PX / np.maximum(np.abs(r), 1e-12))
    dof = max(len(s) - len(x), 1)
    sigma2 = float(np.sum(w * r * r) / dof)
    return x, np.linalg.inv(A) * sigma2


def residual_rgb(data: ResidualData, background: str = "white") -> np.ndarray:
    """The window's events as ``uint8 (H, W, 3)``: events near no edge light grey; events near a silhouette by
    their mean signed distance per pixel, red outside the drawn outline and blue inside (full colour from
    :data:`COLOUR_FULL_PX`, pale near 0); events near an inner edge green."""
    W, H = data.size
    bg = 255 if background == "white" else 0
    img = np.full((H, W, 3), bg, np.uint8)

    def pix(uv):
        u = np.rint(uv[:, 0]).astype(np.int64)
        v = np.rint(uv[:, 1]).astype(np.int64)
        ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        return v[ok] * W + u[ok], ok

    flat = img.reshape(-1, 3)
    p, _ = pix(data.all_uv)
    flat[p] = (222, 222, 222) if bg == 255 else (60, 60, 60)
    inner = ~data.outer
    p, ok = pix(data.uv[inner])
    flat[p] = (40, 160, 60)
    sil = data.outer
    p, ok = pix(data.uv[sil])
    if len(p):
        s = data.signed_px[sil][ok]
        total = np.bincount(p, weights=s, minlength=W * H)
        count = np.bincount(p, minlength=W * H)
        idx = np.flatnonzero(count)
        m = np.clip(total[idx] / count[idx] / COLOUR_FULL_PX, -1.0, 1.0)
        a = np.abs(m)[:, None]
        red, blue, white = np.array([220, 30, 30]), np.array([30, 70, 220]), np.array([190, 190, 190])
        col = np.where((m > 0)[:, None], white + a * (red - white), white + a * (blue - white))
        flat[idx] = np.clip(np.rint(col), 0, 255).astype(np.uint8)
    return img

