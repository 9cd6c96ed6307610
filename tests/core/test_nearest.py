"""The edge stage's nearest-sample search (core/align/nearest.py) returns what scipy's k-d tree returns: the same
neighbour and distance within the radius, none beyond it, points far outside the image (samples behind the camera
project to ~1e9 px) ignored, and a bounded grid for a tiny radius."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from evpose.core.align.nearest import nearest_within


@pytest.mark.parametrize("radius", [0.25, 1.5, 3.2, 40.0])
def test_same_neighbours_as_the_kd_tree(radius):
    rng = np.random.default_rng(int(radius * 100))
    for _ in range(20):
        M, N = int(rng.integers(1, 3000)), int(rng.integers(1, 1500))
        P = rng.uniform(-30.0, 380.0, (M, 2))
        P[: M // 50] = rng.choice([-1e9, 1e9], (M // 50, 2))           # projected from behind the camera
        Q = rng.uniform(0.0, 346.0, (N, 2))
        d_ref, i_ref = cKDTree(P).query(Q, distance_upper_bound=radius)
        d, i = nearest_within(P, Q, radius)
        found = np.isfinite(d_ref)
        np.testing.assert_array_equal(np.isfinite(d), found)
        np.testing.assert_allclose(d[found], d_ref[found], rtol=1e-12)
        np.testing.assert_array_equal(i[found], i_ref[found])
        assert np.all(i[~found] == M) and d[found].max(initial=0.0) < radius


def test_ties_go_to_the_lower_index_and_empty_inputs():
    P = np.array([[10.0, 10.0], [12.0, 10.0], [11.0, 10.0], [11.0, 10.0]])
    d, i = nearest_within(P, np.array([[11.0, 10.4], [11.0, 9.0], [50.0, 50.0]]), 2.0)
    assert list(i) == [2, 2, 4] and d[0] == pytest.approx(0.4) and np.isinf(d[2])
    d, i = nearest_within(np.zeros((0, 2)), np.ones((3, 2)), 1.0)
    assert np.all(np.isinf(d)) and np.all(i == 0)
    d, i = nearest_within(P, np.zeros((0, 2)), 1.0)
    assert len(d) == 0 and len(i) == 0


def test_a_tiny_radius_over_a_wide_spread_is_exact_and_bounded():
    """1e-3 px over a 1e6 px spread would be 1e18 cells: the grid widens its cells and stays exact."""
    rng = np.random.default_rng(5)
    P = rng.uniform(0.0, 1e6, (2000, 2))
    Q = np.concatenate([P[:500] + 1e-4, rng.uniform(0.0, 1e6, (500, 2))])
    d, i = nearest_within(P, Q, 1e-3)
    assert np.all(i[:500] == np.arange(500)) and np.all(np.isinf(d[500:]))
