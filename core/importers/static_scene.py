"""Camera poses of a static scene from per-frame object poses (formats that label objects, not the camera).

E-POSE exports and YCB-Ev give ``T_cam_obj`` per frame and object; a scene needs ``T_base_cam`` and one
``T_base_obj`` per object. With the scene static, every object seen in a frame gives an estimate of the
camera pose; they are averaged (chordal mean) and their disagreement is reported.
"""
from __future__ import annotations

import math

import numpy as np

from evpose.core.data.geometry import make_T, orthonormalize, rotation_angle
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.report import ImportContext


def chordal_mean(Ts: np.ndarray) -> np.ndarray:
    """Mean of rigid transforms: translations averaged, rotations by the chordal L2 mean (SVD projection)."""
    Ts = np.asarray(Ts, dtype=np.float64)
    if len(Ts) == 1:
        R, _ = orthonormalize(Ts[0, :3, :3])
        return make_T(R, Ts[0, :3, 3])
    R, _ = orthonormalize(Ts[:, :3, :3].mean(0))
    return make_T(R, Ts[:, :3, 3].mean(0))


def derive_camera_trajectory(ctx: ImportContext, file, t_us: np.ndarray, tracks: dict[str, dict[int, np.ndarray]],
                             known: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Camera poses from per-frame object poses in the camera, for a static scene.

    Parameters
    ----------
    t_us : (F,) int64
        Frame times.
    tracks : {object: {frame index: T_cam_obj (4, 4)}}
        As read (may be slightly non-orthonormal; inverted as general matrices so that labels made from a
        non-orthonormal ``T_base_obj`` give back the camera pose exactly).
    known : {object: T_base_obj (4, 4)}
        Object poses in the base frame, as given (raw). Without any, the base frame is the frame of the object
        seen in most frames (reported).

    Returns
    -------
    t_us : (M,) int64, T_base_cam : (M, 4, 4), T_base_obj : {object: (4, 4)} (known ones unchanged)
    """
    known = dict(known)
    if not known:
        anchor = max(tracks, key=lambda k: (len(tracks[k]), -list(tracks).index(k)))
        known[anchor] = np.eye(4)
        ctx.report.assume(f"no T_base_obj given: the base frame is the frame of object {anchor!r} "
                          f"(seen in {len(tracks[anchor])} of {len(t_us)} frames)")
    given = set(known)
    inv = _inverses(file, tracks)
    estimated: dict[str, np.ndarray] = {}

    def cam_at(k: int, objs) -> np.ndarray | None:
        ests = [known[o] @ inv[o, k] for o in objs if k in tracks[o]]
        return chordal_mean(np.stack(ests)) if ests else None

    # camera poses from the given objects, then estimate the others from those frames, repeat until stable
    cams: dict[int, np.ndarray] = {}
    for _ in range(len(tracks) + 1):
        for k in range(len(t_us)):
            if k not in cams:
                c = cam_at(k, [o for o in known if o in tracks])
                if c is not None:
                    cams[k] = c
        progress = False
        for o, tr in tracks.items():
            if o in known:
                continue
            ks = [k for k in tr if k in cams]
            if ks:
                estimated[o] = chordal_mean(np.stack([cams[k] @ tr[k] for k in ks]))
                known[o] = estimated[o]
                progress = True
        if not progress:
            break
    # consistency of the static-scene assumption: spread of the per-object camera estimates
    spread_t, spread_r = [], []
    for k, c in cams.items():
        for o in tracks:
            if k in tracks[o] and o in known:
                e = known[o] @ inv[o, k]
                spread_t.append(float(np.linalg.norm(e[:3, 3] - c[:3, 3])))
                Re, _ = orthonormalize(e[:3, :3])
                spread_r.append(float(rotation_angle(c[:3, :3].T @ Re)))
    missing = [k for k in range(len(t_us)) if k not in cams]
    if missing:
        ctx.report.warn(f"{file}: {len(missing)} frame(s) without any object pose give no camera pose "
                        f"(first: frame {missing[0]})")
    for o in estimated:
        ctx.report.assume(f"T_base_obj of {o!r} estimated as the mean over {len(tracks[o])} frame(s) (static scene)")
    if spread_t:
        ctx.report.details["camera_from_objects"] = {
            "max_disagreement_mm": 1e3 * max(spread_t), "max_disagreement_deg": math.degrees(max(spread_r)),
            "median_disagreement_mm": 1e3 * float(np.median(spread_t)), "objects_given": sorted(given)}
        if max(spread_t) > 2e-3 or math.degrees(max(spread_r)) > 0.5:
            ctx.report.warn(f"{file}: object poses disagree about the camera pose by up to {1e3 * max(spread_t):.2f} mm "
                            f"/ {math.degrees(max(spread_r)):.3f} deg (the scene is not static, or T_base_obj is off)")
    ks = sorted(cams)
    T = np.stack([cams[k] for k in ks]) if ks else np.zeros((0, 4, 4))
    return np.asarray(t_us, np.int64)[ks], T, known


def _inverses(file, tracks: dict[str, dict[int, np.ndarray]]) -> dict[tuple[str, int], np.ndarray]:
    """``inv(T_cam_obj)`` per (object, frame); a singular pose (possible after ``--repair``) is refused."""
    out = {}
    for o, tr in tracks.items():
        for k, T in tr.items():
            try:
                out[o, k] = np.linalg.inv(T)
            except np.linalg.LinAlgError:
                raise ImportFailure(file, f"frame {k}", f"T_cam_obj [{o}]", "singular matrix: no camera pose can "
                                    "be derived from it") from None
    return out
