"""Undistortion by Newton's method (tracker issue 23.7a): converges at every pixel that has a ray.

Oracle: the *forward* map, ``cv2.projectPoints`` of normalised points ``(x, y, 1)``, which needs no
iteration. A dense grid of normalised points is distorted and undistorted again (< 1e-9 normalised,
< 1e-6 px back); which pixel centres have a ray is decided by the forward image of the rim ``r = r_max``
(a pixel centre inside it has one, outside none), and every such pixel must be valid in
``CameraModel.pixel_rays``. Before, ``cv2.undistortPoints`` left 23 (fx = 20) to 134 (k1 = -0.6, k3 = 0.4)
of them invalid. Run with ``-s`` for the counts and timings.
"""
import time

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from evpose.core.data.camera import DAVIS346_DIST, DAVIS346_K, CameraModel
from evpose.core.data.undistort_newton import R_SEARCH, distort_xy, split_coefficients

K = np.array(DAVIS346_K)
CX, CY = K[0, 2], K[1, 2]
CASES = {
    "davis346": lambda: CameraModel.davis346(),
    "strong k1=-0.6 k3=+0.4": lambda: CameraModel(K, [-0.6, 0.0, 0.0, 0.0, 0.4]),
    "fold-back k1=-0.6": lambda: CameraModel(K, [-0.6, 0.0, 0.0, 0.0]),
    "wide fx=fy=20": lambda: CameraModel([[20.0, 0, CX], [0, 20.0, CY], [0, 0, 1]], DAVIS346_DIST),
    "wide fx=20": lambda: CameraModel([[20.0, 0, CX], [0, K[1, 1], CY], [0, 0, 1]], DAVIS346_DIST),
    "none": lambda: CameraModel(K, []),
    "rational+prism": lambda: CameraModel(K, [-0.3, 0.1, 0.001, 0.002, 0.01, 0.05, 0.01, 0.002,
                                              0.001, -0.002, 0.0005, 0.001]),
    "tilted": lambda: CameraModel(K, [-0.3, 0.1, 0.001, 0.002, 0.01, 0, 0, 0, 0, 0, 0, 0, 0.01, -0.02]),
}


@pytest.fixture(params=list(CASES) + ["davis346 json"])
def camera(request):
    if request.param == "davis346 json":
        return CameraModel.from_json(request.getfixturevalue("assets_dir") / "camera_davis346.json")
    return CASES[request.param]()


def forward_px(cam, xy):
    """The oracle: ``cv2.projectPoints`` of ``(x, y, 1)``, pixels."""
    pts = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    return cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K, cam.dist)[0].reshape(-1, 2)


def rim_radius(cam):
    """``r_max``, or when the distortion is monotonic everywhere the smallest of 0.5, 1, 2, ... 20 whose
    forward image encloses the sensor (farther out, prism and tangential terms can twist the rim's image)."""
    if np.isfinite(cam.r_max):
        return cam.r_max
    th = np.linspace(0.0, 2 * np.pi, 3600, endpoint=False)
    corners = np.array([[-0.5, -0.5], [cam.width - 0.5, cam.height - 0.5], [-0.5, cam.height - 0.5],
                        [cam.width - 0.5, -0.5]])
    reach = np.hypot(*(corners - cam.K[:2, 2]).T).max()
    for r in (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, R_SEARCH):
        rim = forward_px(cam, r * np.stack([np.cos(th), np.sin(th)], axis=1))
        if np.hypot(*(rim - cam.K[:2, 2]).T).min() > reach:
            return r
    return R_SEARCH


def pixels_with_a_ray(cam, n_rim=200_000, band_px=0.005):
    """``(has_ray (H, W), ambiguous (H, W))`` by the forward map: a pixel centre has a ray when it lies inside
    the forward image of the rim :func:`rim_radius` (even-odd rule along each row); centres within
    ``band_px`` of the curve's samples are ambiguous (the polygon's own error is ~1e-7 px)."""
    th = np.linspace(0.0, 2 * np.pi, n_rim, endpoint=False)
    rim = forward_px(cam, rim_radius(cam) * np.stack([np.cos(th), np.sin(th)], axis=1))
    a, b = rim, np.roll(rim, -1, axis=0)
    H, W = cam.height, cam.width
    # every (segment, row v) with min(y) <= v < max(y), rows 0 .. H-1 only (half-open: each crossing counted once)
    lo, hi = np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 1], b[:, 1])
    first = np.clip(np.ceil(lo), 0, H)
    n_rows = np.maximum(np.clip(np.ceil(hi), 0, H) - first, 0).astype(np.int64)
    seg = np.repeat(np.arange(len(a)), n_rows)
    v = first[seg] + (np.arange(len(seg)) - np.repeat(np.cumsum(n_rows) - n_rows, n_rows))
    pa, pb = a[seg], b[seg]
    uc = pa[:, 0] + (v - pa[:, 1]) * (pb[:, 0] - pa[:, 0]) / (pb[:, 1] - pa[:, 1])
    # crossings left of each pixel centre, row by row: odd = inside
    order = np.lexsort((uc, v))
    key = v[order] * (W + 1.0) + np.clip(uc[order], -1.0, W)       # rows never overlap: uc clipped to [-1, W]
    u = np.arange(W, dtype=np.float64)
    centres = (np.arange(H, dtype=np.float64)[:, None] * (W + 1.0) + u[None, :]).ravel()
    row_start = np.searchsorted(v[order], np.arange(H), side="left")
    has = ((np.searchsorted(key, centres) - np.repeat(row_start, W)) % 2 == 1).reshape(H, W)
    vv, uu = np.mgrid[0:H, 0:W]
    near = cKDTree(rim).query(np.stack([uu.ravel(), vv.ravel()], 1), distance_upper_bound=band_px)[0]
    return has, np.isfinite(near).reshape(H, W)


def opencv_valid(cam):
    """The old validity: ``cv2.undistortPoints`` (100 iterations, eps 1e-12) round-tripped to 1e-4 px."""
    vv, uu = np.mgrid[0:cam.height, 0:cam.width]
    uv = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, cam.dist, criteria=crit).reshape(-1, 2)
    ok = (np.abs(cam.distort_normalized(xy) - uv).max(axis=1) < 1e-4) & ((xy ** 2).sum(1) <= cam.r_max ** 2)
    return ok.reshape(cam.height, cam.width)


def test_every_pixel_with_a_ray_is_valid_and_no_other(camera):
    has, ambiguous = pixels_with_a_ray(camera)
    t = time.perf_counter()
    xy, ok = camera.pixel_rays()
    dt = time.perf_counter() - t
    sure = ~ambiguous
    missed = int(np.count_nonzero(has & ~ok & sure))
    print(f"\n{camera!r}: {int(has.sum())} pixels have a ray, {int((has & ~sure).sum())} ambiguous; "
          f"Newton: {missed} missed, {dt * 1e3:.0f} ms; OpenCV missed {int((has & ~opencv_valid(camera)).sum())}")
    assert missed == 0
    assert not np.any(ok & ~has & sure)                       # no ray invented beyond the fold
    assert np.isnan(xy[~ok]).all() and np.isfinite(xy[ok]).all()
    # every valid ray lies in the monotonic disk and distorts back onto its pixel centre
    vv, uu = np.mgrid[0:camera.height, 0:camera.width]
    back = forward_px(camera, xy[ok])
    assert np.abs(back - np.stack([uu[ok], vv[ok]], axis=1)).max() < 1e-6
    assert ((xy[ok] ** 2).sum(axis=1) <= camera.r_max ** 2).all()


def dense_grid(cam, step_px=0.7):
    """Normalised points (exact, by construction) whose images are ~``step_px`` apart over the sensor +-2 px:
    a pixel grid pulled back by the inverse of OpenCV's forward map along the x axis (a table, interpolated;
    accurate or not, the points are what they are), inside the rim."""
    R = rim_radius(cam)
    r = np.linspace(0.0, R, 20_001)
    rd = np.maximum.accumulate((forward_px(cam, np.stack([r, 0 * r], 1))[:, 0] - cam.K[0, 2]) / cam.K[0, 0])
    u = np.arange(-2.5, cam.width + 1.5, step_px)
    v = np.arange(-2.5, cam.height + 1.5, step_px)
    uu, vv = np.meshgrid(u, v)
    xd, yd = ((uu - cam.K[0, 2]) / cam.K[0, 0]).ravel(), ((vv - cam.K[1, 2]) / cam.K[1, 1]).ravel()
    rho = np.hypot(xd, yd)
    scale = np.interp(rho, rd, r) / np.where(rho > 0, rho, 1.0)
    grid = np.stack([xd * scale, yd * scale], axis=1)
    return grid[(grid ** 2).sum(axis=1) < (R * (1 - 1e-6)) ** 2]


def test_dense_forward_map_round_trips(camera):
    """A dense grid of normalised points (~0.7 px apart on the sensor, two per pixel) distorted by OpenCV and
    undistorted back: < 1e-9 in normalised coordinates, < 1e-6 px when distorted again."""
    grid = dense_grid(camera, step_px=0.7)
    uv = forward_px(camera, grid)
    on = camera.in_image(uv, margin_px=2.0)
    grid, uv = grid[on], uv[on]
    assert len(grid) > 0.5 * camera.width * camera.height / 0.7 ** 2
    back = camera.undistort_points(uv)
    assert np.isfinite(back).all()
    assert np.abs(back - grid).max() < 1e-9
    assert np.abs(forward_px(camera, back) - uv).max() < 1e-6


def test_matches_opencv_where_it_converges_and_applies_K_new():
    cam = CameraModel.davis346()
    rng = np.random.default_rng(1)
    uv = rng.uniform([-0.5, -0.5], [345.5, 259.5], size=(5000, 2))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    K_new = np.array([[150.0, 0, 90], [0, 151.0, 70], [0, 0, 1]])
    for P in (None, K_new):
        ref = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, cam.dist, P=P, criteria=crit).reshape(-1, 2)
        scale = 1.0 if P is None else 150.0
        assert np.abs(cam.undistort_points(uv, K_new=P) - ref).max() < 1e-9 * scale


def test_event_pixels_are_looked_up_in_the_cached_rays():
    cam = CameraModel(K, [-0.6, 0.0, 0.0, 0.0])
    rng = np.random.default_rng(2)
    uv = np.stack([rng.integers(0, 346, 30_000), rng.integers(0, 260, 30_000)], axis=1).astype(np.float64)
    t = time.perf_counter()
    direct = cam._undistorter.rays(uv)[0]
    t_direct = time.perf_counter() - t
    cam.pixel_rays()
    t = time.perf_counter()
    looked_up = cam.undistort_points(uv)
    t_lookup = time.perf_counter() - t
    print(f"\n30,000 event pixels: Newton {t_direct * 1e3:.1f} ms, lookup {t_lookup * 1e3:.1f} ms")
    np.testing.assert_array_equal(looked_up, direct)        # the same numbers, NaN where no ray
    assert np.isnan(looked_up).any()
    # fractional or off-sensor coordinates are not looked up
    off = np.array([[10.25, 20.0], [-3.0, 5.0]])
    np.testing.assert_array_equal(cam.undistort_points(off), cam._undistorter.rays(off)[0])


def test_analytic_jacobian_matches_finite_differences():
    d12, tilted = split_coefficients([-0.3, 0.1, 0.001, 0.002, 0.01, 0.05, 0.01, 0.002, 0.001, -0.002, 0.0005, 0.001])
    assert not tilted
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-0.8, 0.8, (2, 200))
    _, _, J = distort_xy(x, y, d12, jacobian=True)
    h = 1e-6
    for k, (dx, dy) in enumerate(((h, 0), (0, h))):
        p = distort_xy(x + dx, y + dy, d12)
        m = distort_xy(x - dx, y - dy, d12)
        np.testing.assert_allclose(J[k], (p[0] - m[0]) / (2 * h), atol=1e-8)       # d xd / d(x, y)
        np.testing.assert_allclose(J[2 + k], (p[1] - m[1]) / (2 * h), atol=1e-8)   # d yd / d(x, y)


def test_undistortion_maps_never_sample_the_folded_back_image():
    cam = CameraModel(K, [-0.6, 0.0, 0.0, 0.0])
    K_wide = np.array([[150.0, 0, CX], [0, 150.0, CY], [0, 0, 1]])     # an undistorted view wider than r_max
    m1, m2 = cam.undistortion_maps(K_wide)
    vv, uu = np.mgrid[0:260, 0:346]
    beyond = ((uu - CX) / 150.0) ** 2 + ((vv - CY) / 150.0) ** 2 > cam.r_max ** 2
    assert beyond.any() and np.all(m1[beyond] == -1) and np.all(m2[beyond] == -1)
    assert cam.undistort_image(np.full((260, 346), 255, np.uint8), K_wide)[beyond].max() == 0
    # OpenCV's map samples the folded-back image there; inside, it is the same map
    r1, r2 = cv2.initUndistortRectifyMap(cam.K, cam.dist, None, K_wide, (346, 260), cv2.CV_32FC1)
    assert cam.in_image(np.stack([r1[beyond], r2[beyond]], axis=1)).any()
    assert max(np.abs(m1 - r1)[~beyond].max(), np.abs(m2 - r2)[~beyond].max()) < 1e-3
    davis = CameraModel.davis346()
    r1, r2 = cv2.initUndistortRectifyMap(davis.K, davis.dist, None, davis.K, (346, 260), cv2.CV_32FC1)
    m1, m2 = davis.undistortion_maps()
    assert max(np.abs(m1 - r1).max(), np.abs(m2 - r2).max()) < 1e-3


def test_r_max_is_the_fold_radius():
    cam = CameraModel(K, [-0.6, 0.0, 0.0, 0.0])          # r_d = r (1 - 0.6 r^2) peaks at r = 1 / sqrt(1.8)
    assert cam.r_max == pytest.approx(1 / np.sqrt(1.8), abs=1e-12)


def test_newton_never_leaves_the_monotonic_disk():
    """A step that would cross the fold radius goes halfway to the rim instead (beyond it lies a second,
    folded-back root onto which Newton could converge)."""
    cam = CameraModel(K, [-0.6, 0.0, 0.0, 0.0])
    und = cam._undistorter
    r0 = 0.9 * cam.r_max
    x, y = np.array([r0]), np.array([0.0])
    target_u = np.array([CX + K[0, 0] * 0.6])          # r_d = 0.6: beyond the largest r_d (0.497), no ray
    und._newton_step(x, y, target_u, np.array([CY]), np.array([0]))
    assert r0 < x[0] <= 0.5 * (r0 + cam.r_max) + 1e-15 and y[0] == 0.0
    xy, ok = und.rays(np.stack([target_u, [CY]], axis=1))
    assert not ok[0] and np.isnan(xy).all()


def test_pixels_without_a_ray_move_no_pose_and_bound_no_view():
    """Where the fold-back lens gives a corner pixel no ray (NaN), a drag from it moves nothing (never a NaN into
    a pose) and the inscribed view rectangle is bounded by the pixels that have one."""
    from evpose.core.align.score_evidence import view_rect
    from evpose.core.document.pose_edit import image_plane_shift

    cam = CASES["fold-back k1=-0.6"]()
    corner = np.array([0.0, 0.0])
    assert not np.all(np.isfinite(cam.undistort_points(corner[None])))       # the corner has no ray
    assert np.array_equal(image_plane_shift(cam, np.array([0, 0, 0.5]), corner, [CX, CY]), np.zeros(3))
    moved = image_plane_shift(cam, np.array([0, 0, 0.5]), [CX, CY], [CX + 10, CY])
    assert moved[0] > 0 and np.all(np.isfinite(moved))
    u0, v0, u1, v1 = view_rect(cam)
    assert all(np.isfinite([u0, v0, u1, v1])) and u0 < CX < u1 and v0 < CY < v1
