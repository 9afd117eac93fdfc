"""Section 5.5: the fifth finger's HMC revolute as the four-bar's instantaneous axis, and its error."""

import numpy as np
import pytest

from awiwi_drake.reproductions.ch05_fifth_hmc import hmc_revolute_error


def test_revolute_is_exact_to_first_order_and_exact_for_a_degenerate_four_bar():
    phi = np.radians([2.5, 5.0, 10.0])
    e = hmc_revolute_error(phi)
    # second order: halving the rotation quarters the error
    assert e[1] / e[0] == pytest.approx(4.0, rel=0.05) and e[2] / e[1] == pytest.approx(4.0, rel=0.1)
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
