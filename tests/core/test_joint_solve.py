"""The inner Newton step of the joint edge fit (core/align/joint_solve.py): it climbs the objective, stays within its
trust region on the predicted edge motion and within the parameter bounds, and keeps fixed parameters at zero."""
import numpy as np

from evpose.core.align.joint_solve import Layout, kernel_derivs, solve_step


def _problem(seed=0, n=4000, shift_sigmas=2.5, sigma=1.0):
    """Events of one object whose distances are all ``shift_sigmas`` kernel widths off, explained by a step."""
    rng = np.random.default_rng(seed)
    lay = Layout(1, clock=True, skew=False, hand_eye=False, objects=[True])
    J = rng.normal(size=(n, 14))
    true = np.zeros(lay.n)
    true[lay.free] = rng.normal(size=int(lay.free.sum()))
    s_true = rng.normal(scale=0.2 * sigma, size=n)
    cols = lay.cols(0)
    s0 = s_true - J @ true[cols]                       # the step ``true`` brings them back onto the edge
    s0 *= shift_sigmas * sigma / np.sqrt(np.mean(s0 ** 2))
    return s0, J, [slice(0, n)], np.zeros(n, bool), sigma, lay


def _objective(s, outer, sigma):
    return float(kernel_derivs(s, outer, sigma, 0.0)[0].sum())


def test_the_step_climbs_and_respects_the_trust_region():
    s0, J, rows, outer, sigma, lay = _problem()
    free_move = solve_step(s0, J, rows, outer, sigma, 0.0, lay, max_move_px=1e9)
    for limit in (0.3, 1.0):
        delta, f0, f, move = solve_step(s0, J, rows, outer, sigma, 0.0, lay, max_move_px=limit)
        assert f > f0 and f0 == _objective(s0, outer, sigma)
        assert move <= limit * (1 + 1e-6), (move, limit)             # predicted RMS edge motion within the region
        assert np.all(delta[~lay.free] == 0)                         # fixed parameters (skew, hand-eye) untouched
    assert free_move[3] > 1.0                                        # without the region the step moves further


def test_the_step_stays_within_the_parameter_bounds():
    s0, J, rows, outer, sigma, lay = _problem(seed=1)
    bounds = np.full(lay.n, 0.05)
    delta, f0, f, _ = solve_step(s0, J, rows, outer, sigma, 0.0, lay, max_move_px=1e9, bounds=bounds)
    assert f >= f0 and np.all(np.abs(delta) <= bounds + 1e-12)
