"""The motion proxy of a scene: its camera trajectory (hand-eye applied) seen over a grid of
pixel rays at the distance of its objects.

Both the clock estimate (:mod:`evpose.core.align.estimate`) and the windows of the edge
refinement (:mod:`evpose.core.align.event_windows`) need the image speed of a scene, so it is
built here once from the scene's own data: the flow is averaged over an 8 x 6 grid of pixel rays
(the image, not the optical axis alone) at the median depth of the objects' box centres.
"""
from __future__ import annotations

import numpy as np

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
    """The scene's trajectory as camera poses (hand-eye applied for ``tcp`` trajectories)."""
    traj = scene.trajectory
    he = scene.manifest.hand_eye if scene.manifest.trajectory_frame == "tcp" else None
    dT = scene.corrections.hand_eye_delta
    if he is None and np.array_equal(dT, np.eye(4)):
        return traj
    T = traj.T()
    if he is not None:
        T = T @ he
    T = T @ dT
    return Trajectory.from_T(traj.t_us, T, source=traj.source, max_gap_us=traj.max_gap_us)


def scene_motion_proxy(scene, kind: str = "flow", grid=(8, 6)) -> MotionProxy:
    """:func:`motion_proxy` of a scene's camera, with the depth of the objects' box centres
    (median over objects, per pose sample; :data:`DEFAULT_DEPTH_M` where none is in front)."""
    traj = camera_trajectory(scene)
    T = traj.T()
    centres = []
    for name in scene.object_names:
        try:
            c = scene.model(name).bbox_center_m
        except Exception:  # a missing mesh must not prevent synchronisation: use the origin
            c = np.zeros(3)
        Tb = scene.T_base_obj(name)
        centres.append(Tb[:3, :3] @ c + Tb[:3, 3])
    if centres:
        C = np.asarray(centres)                                      # (K, 3) base frame
        d = C[None, :, :] - T[:, None, :3, 3]                       # (N, K, 3)
        z = np.einsum("nij,nki->nkj", T[:, :3, :3], d)[..., 2]     # camera-frame z
        z = np.where(z > 0.05, z, np.nan)
        with np.errstate(all="ignore"):
            depth = np.nanmedian(np.where(np.isnan(z).all(axis=1, keepdims=True), DEFAULT_DEPTH_M, z), axis=1)
    else:
        depth = DEFAULT_DEPTH_M
    K = scene.camera.K
    return motion_proxy(traj, K[0, 0], K[1, 1], rays_xy=_ray_grid(scene.camera, *grid), depth_m=depth, kind=kind)

