"""Section 5.5: the fifth finger's HMC revolute as the four-bar's instantaneous axis, and its error."""

import numpy as np
import pytest

from awiwi_drake.reproductions.ch05_fifth_hmc import hmc_revolute_error


def test_revolute_is_exact_to_first_order_and_exact_for_a_degenerate_four_bar():
    """Second order with a closed-form coefficient: the revolute about the initial instantaneous centre IC0 and the
    coupler agree in velocity; their second derivatives (in phi) differ by the acceleration of the coupler point at
    IC0, the pole's transfer speed |dIC/dphi|, the same for every coupler point: e = |dIC/dphi| phi^2 / 2 + O(phi^4)
    (the four-bar is mirror-symmetric, so e is even in phi).  Each rocker turns r_c / (r_c - r_g) times the
    coupler about its ground pivot, which shifts its line by r_g times that at IC0, and the two lines (at +-alpha
    from the axis) then meet r_g r_c / ((r_c - r_g) cos alpha) per radian off IC0, across the axis.  Checked by
    Richardson extrapolation of e / phi^2 over phi, 2 phi, 4 phi, 8 phi (removing the phi^2 and phi^4 terms); the
    a-posteriori error bound of the last level is the change it made."""
    phi = np.radians([1.25, 2.5, 5.0, 10.0])
    for rg, rc, alpha, dist in ((0.010, 0.022, np.radians(20.0), 0.030), (0.005, 0.020, 0.3, 0.030),
                                (0.015, 0.025, 0.5, 0.045)):
        g = hmc_revolute_error(phi, alpha=alpha, r_ground=rg, r_coupler=rc, distance=dist) / phi ** 2
        c = rg * rc / (2.0 * (rc - rg) * np.cos(alpha))
        r1 = (4.0 * g[:-1] - g[1:]) / 3.0
        r2 = (16.0 * r1[:-1] - r1[1:]) / 15.0
        assert abs(r2[0] - c) <= abs(r2[0] - r1[0]), (rg, rc, alpha, r2[0], c)
    # even in phi (mirror symmetry), to fsolve's xtol 1e-13 on the ~2 rad rocker angles times the 12 mm rockers
    np.testing.assert_allclose(hmc_revolute_error(-phi), hmc_revolute_error(phi), rtol=0, atol=3e-15)
    # ground pivots at the instantaneous centre: the four-bar is a revolute about it
    assert np.max(hmc_revolute_error(phi, r_ground=0.0)) < 1e-12


def test_error_of_representative_four_bars_over_the_hmc_range():
    """Representative four-bars (IC 30 mm from the MCP base): 0.1-0.6 mm at 10 deg, 0.4-2.1 mm at
    20 deg (docs/REPRODUCTIONS.md); the error grows with the ground pivots' distance from the IC."""
    e = [hmc_revolute_error(np.radians(20.0), r_ground=rg, r_coupler=rc)[0]
         for rg, rc in ((0.005, 0.020), (0.010, 0.022), (0.015, 0.025))]
    assert e[0] < e[1] < e[2]
    with pytest.raises(ValueError, match="r_ground"):
        hmc_revolute_error(0.1, r_ground=0.03, r_coupler=0.02)
