"""The motion proxy of a scene: its camera trajectory (hand-eye applied) seen over a grid of
pixel rays at the distance of its objects.

Both the clock estimate (:mod:`evpose.core.align.estimate`) and the windows of the edge
refinement (:mod:`evpose.core.align.event_windows`) need the image speed of a scene, so it is
built here once from the scene's own data: the flow is averaged over an 8 x 6 grid of pixel rays
(the image, not the optical axis alone) at the median depth of the objects' box centres.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from evpose.core.align.proxy import DEFAULT_DEPTH_M, MotionProxy, motion_proxy
from evpose.core.data.trajectory import Trajectory

__all__ = ["camera_trajectory", "scene_motion_proxy"]


def _ray_grid(camera, n_u: int = 8, n_v: int = 6) -> np.ndarray:
    """Normalised rays ``(G, 2)`` of an ``n_u x n_v`` grid of pixel centres (valid ones)."""
    xy, ok = camera.pixel_rays()
    H, W = ok.shape
    us = np.linspace(0.5 * W / n_u, W - 0.5 * W / n_u, n_u).astype(int)
    vs = np.linspace(0.5 * H / n_v, H - 0.5 * H / n_v, n_v).astype(int)
    g = xy[np.ix_(vs, us)].reshape(-1, 2)
    good = ok[np.ix_(vs, us)].ravel()
    return g[good] if good.any() else np.zeros((1, 2))


def camera_trajectory(scene) -> Trajectory:
    """The scene's trajectory as camera poses (hand-eye applied for ``tcp`` trajectories).

    Composed as rotations and positions (``T_base_tcp @ hand_eye @ delta``), without (N, 4, 4) arrays: 128 bytes
    a pose each, 350 MB for 3 hours of poses at 250 Hz."""
    traj = scene.trajectory
    he = scene.manifest.hand_eye if scene.manifest.trajectory_frame == "tcp" else None
    dT = scene.corrections.hand_eye_delta
    if he is None and np.array_equal(dT, np.eye(4)):
        return traj
    M = (np.eye(4) if he is None else np.asarray(he, dtype=np.float64)) @ dT
    rot = Rotation.from_quat(traj.quats_xyzw)
    pos = traj.positions_m + rot.apply(M[:3, 3])
    quat = (rot * Rotation.from_matrix(M[:3, :3])).as_quat()
    return Trajectory(traj.t_us, pos, quat, source=traj.source, max_gap_us=traj.max_gap_us)


def _object_depths(traj: Trajectory, centres: np.ndarray, chunk: int = 100_000) -> np.ndarray:
    """Median camera-frame depth (m) of the base-frame points ``centres`` (K, 3) per pose, over those more
    than 5 cm in front; :data:`DEFAULT_DEPTH_M` where none is. Computed in chunks of poses."""
    depth = np.empty(len(traj))
    for i in range(0, len(traj), chunk):
        s = slice(i, i + chunk)
        rot = Rotation.from_quat(traj.quats_xyzw[s])
        z_axis = rot.apply([0.0, 0.0, 1.0])                               # camera z in the base frame, (n, 3)
        d = centres[None, :, :] - traj.positions_m[s][:, None, :]        # (n, K, 3)
        z = np.einsum("nkj,nj->nk", d, z_axis)
        z = np.where(z > 0.05, z, np.nan)
        with np.errstate(all="ignore"):
            depth[s] = np.nanmedian(np.where(np.isnan(z).all(axis=1, keepdims=True), DEFAULT_DEPTH_M, z), axis=1)
    return depth


def scene_motion_proxy(scene, kind: str = "flow", grid=(8, 6)) -> MotionProxy:
    """:func:`motion_proxy` of a scene's camera, with the depth of the objects' box centres
    (median over objects, per pose sample; :data:`DEFAULT_DEPTH_M` where none is in front)."""
    traj = camera_trajectory(scene)
    centres = []
    for name in scene.object_names:
        try:
            c = scene.model(name).bbox_center_m
        except Exception:  # a missing mesh must not prevent synchronisation: use the origin
            c = np.zeros(3)
        Tb = scene.T_base_obj(name)
        centres.append(Tb[:3, :3] @ c + Tb[:3, 3])
    depth = _object_depths(traj, np.asarray(centres)) if centres else DEFAULT_DEPTH_M
    K = scene.camera.K
    return motion_proxy(traj, K[0, 0], K[1, 1], rays_xy=_ray_grid(scene.camera, *grid), depth_m=depth, kind=kind)
