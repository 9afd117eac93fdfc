"""Invented-parameter table: one-at-a-time +-20 % sensitivity of the reproduced headline numbers."""

import math

import numpy as np
import pytest

from awiwi_drake.reproductions.invented_parameters import (INVENTED, fig_6_10_length_scale,
                                                            invented_parameter_sensitivity, sensitivity_markdown)


def test_closed_form_sensitivities_and_unreachable_wrist_reported():
    rows = invented_parameter_sensitivity(parameters=("ring.dip_radius", "ring.coupling_stiffness",
                                                      "wrist.link_length", "fifth.hmc_radius"))
    by = {(r.parameter, r.headline): r for r in rows}
    r2, r3 = 0.007, 0.005
    arm = lambda a, b: a + b * b / a                                         # (5.16) reduced moment arm
    r = by[("ring.dip_radius", "ring_pip_moment_arm")]
    assert r.minus == pytest.approx(arm(r2, 0.8 * r3) / arm(r2, r3) - 1, rel=1e-9)
    assert r.plus == pytest.approx(arm(r2, 1.2 * r3) / arm(r2, r3) - 1, rel=1e-9)
    # the coupling compliance tau / (k_c (1 + c^2)) (hand.plant.coupling_compliance) scales as 1/k_c
    r = by[("ring.coupling_stiffness", "ring_coupling_compliance")]
    assert r.minus == pytest.approx(1 / 0.8 - 1, rel=1e-6) and r.plus == pytest.approx(1 / 1.2 - 1, rel=1e-6)
    # a longer |AA0| makes the neutral wrist unreachable: reported, not dropped
    r = by[("wrist.link_length", "fig6_10_abduction_peak")]
    assert np.isfinite(r.minus) and math.isnan(r.plus)
    table = sensitivity_markdown(rows)
    assert "unreachable" in table and "none: no reproduced figure uses it" in table
    assert len(table.splitlines()) == 2 + 4


def test_fig_6_10_factor_two_needs_a_longer_link_length():
    """Of the four reconstructed linkage lengths only |AA0| reaches twice our Fig 6.10 abduction peak
    (at 1.19x, at the edge of the reachable range); the others stop below 2 before the wrist can no
    longer reach the motion."""
    assert fig_6_10_length_scale("link_length", 1.19) == pytest.approx(2.0, abs=0.1)
    assert math.isnan(fig_6_10_length_scale("link_length", 1.2))
    assert fig_6_10_length_scale("crank_length", 0.775) < 1.9 and math.isnan(fig_6_10_length_scale("crank_length", 0.75))
    assert fig_6_10_length_scale("coupler_length", 1.65) < 1.95 and math.isnan(fig_6_10_length_scale("coupler_length", 1.7))


def test_every_invented_parameter_has_a_source():
    rows = invented_parameter_sensitivity(parameters=[p.name for p in INVENTED if not p.headlines])
    assert rows and all(r.source for r in rows)
