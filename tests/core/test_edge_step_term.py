"""The edge kernel's density-step term at fine widths (JointParams.step_min_sigma_px, joint_fit.level_beta).

The term ``beta * (-u) g`` rewards a density contrast across a silhouette (texture events inside, few outside). Its
``beta`` is measured from the events within 3 kernel widths of the contour; once the width is below the events'
own spread about the edge, that count measures the contour's offset itself, and the term holds the contour where it
is. On bench/campaign.py's main-generator scenes this put the camera -0.6 to -1.8 mm along its optical axis in 5 of
6 campaigns (73 % of the estimates within 2 sigma; with the term at the two coarsest widths only: 100 %)."""
from types import SimpleNamespace

import numpy as np

from evpose.core.align.edges import kernel
from evpose.core.align.joint_fit import level_beta
from evpose.core.align.joint_result import JointParams


def _edge_offset_px(p: JointParams, fx=146.0, start_px=0.8) -> float:
    """Coarse to fine over the fit's widths, the contour offset (px) that maximises the kernel over 1-D events: an
    edge at 0 (spread 0.15 px) with 5x more background events inside (-3..0 px) than outside; ``beta`` from each
    width's first association, as the joint fit takes it."""
    rng = np.random.default_rng(3)
    ev = np.r_[rng.normal(0.0, 0.15, 3000), rng.uniform(-3, 0, 1500), rng.uniform(0, 3, 300)]
    d = start_px
    for sigma in p.sigmas(fx):
        band = 3 * sigma
        s = ev - d
        near = np.abs(s) <= band
        beta = level_beta(SimpleNamespace(s=s[near], outer=np.ones(int(near.sum()), bool)), sigma, p, fx)
        for _ in range(4):
            grid = d + np.linspace(-sigma, sigma, 401)
            vals = [kernel((ev - g)[np.abs(ev - g) <= band], True, sigma, beta).sum() for g in grid]
            d = float(grid[int(np.argmax(vals))])
    return d


def test_the_step_term_left_out_at_fine_widths_finds_the_edge_and_kept_everywhere_holds_it_off():
    assert abs(_edge_offset_px(JointParams())) < 0.01
    assert abs(_edge_offset_px(JointParams(step_min_sigma_px=0.0))) > 0.03      # 0.059 px: most of a fine width


def test_the_step_widths_scale_with_the_camera():
    p = JointParams()
    half, full = p.sigmas(146.0), p.sigmas(292.0)
    assert [p.step_at(s, 146.0) for s in half] == [p.step_at(s, 292.0) for s in full] == [True, True] + [False] * 4
    assert all(p.step_at(s, 146.0) for s in half) is False and all(
        JointParams(step_min_sigma_px=0.0).step_at(s, 146.0) for s in half)
