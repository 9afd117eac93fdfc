"""Section 12.3: the pole-placement design of Table 12.1 under a stiffness error ((12.19), Fig 12.4), checked
against the thesis's closed-form characteristic polynomial (12.12) written out here from Table 12.1."""

from __future__ import annotations

import numpy as np
import pytest

from awiwi_drake.parameters import FlexibleJointParams
from awiwi_drake.parameters.control import PolePlacementParams
from awiwi_drake.reproductions.ch12_pole_placement import PRINTED_12_18, stiffness_robustness

# Table 12.1
B_M, M_L, D_Q, D_TH = 2e-3, 4e-7, 0.0012, 0.0012


def _sorted(ev):
    ev = np.asarray(ev)
    return ev[np.lexsort((ev.imag, ev.real))]


def _poly_12_12(k, alpha):
    """Monic characteristic polynomial of (12.8) under u = alpha^T x, coefficients (12.12) as printed."""
    a1, a2, a3, a4 = np.ravel(alpha)
    m, b, dq, dth = M_L, B_M, D_Q, D_TH
    return np.array([1.0,
                     (m * dth - m * a4 + dq * b) / (m * b),
                     (dq * dth - m * a3 + k * (m + b) - dq * a4) / (m * b),
                     (-dq * a3 - k * (a2 + a4 - dq - dth)) / (m * b),
                     -k * (a1 + a3) / (m * b)])


def _A_12_10(k):
    m, b, dq, dth = M_L, B_M, D_Q, D_TH
    return np.array([[0, 1, 0, 0], [-k / m, -dq / m, k / m, 0], [0, 0, 0, 1], [k / b, 0, -k / b, -dth / b]])


@pytest.fixture(scope="module")
def study():
    return stiffness_robustness(num=9)


def test_table_12_1_is_what_the_study_uses():
    p = FlexibleJointParams()
    assert (p.motor_inertia, p.link_inertia, p.link_damping, p.motor_damping, p.stiffness) == \
        (B_M, M_L, D_Q, D_TH, 0.605)
    assert PolePlacementParams().perturbed_stiffness == 0.600


def test_12_19_perturbed_poles_are_the_roots_of_12_12_with_the_perturbed_stiffness(study):
    """The design k = 0.605 places (12.13) exactly; the same gains on k = 0.600 give the roots of (12.12) with
    k = 0.600 (alpha = -K): an unstable pair, a fast real pole and a slow real pole, as the thesis's (12.19)."""
    alpha = -study.K
    p = PolePlacementParams()
    target = np.polymul([1, 2 * p.xi1 * p.omega1, p.omega1 ** 2], [1, 2 * p.xi2 * p.omega2, p.omega2 ** 2])
    np.testing.assert_allclose(_poly_12_12(0.605, alpha), target, rtol=1e-6)
    np.testing.assert_allclose(study.nominal_poles, _sorted(np.roots(target)), rtol=1e-6)
    perturbed = _sorted(np.roots(_poly_12_12(0.600, alpha)))
    np.testing.assert_allclose(study.perturbed_poles, perturbed, rtol=1e-6)
    unstable = study.perturbed_poles[study.perturbed_poles.real > 0]
    assert len(unstable) == 2 and abs(unstable[0].imag) > 0          # printed: 53.27 +- 225.14i
    real = study.perturbed_poles[np.abs(study.perturbed_poles.imag) < 1e-9]
    assert len(real) == 2 and np.all(real.real < 0)                   # printed: -318.78 and -0.058


def test_fig_12_4_loci_are_the_roots_of_12_12_for_both_gain_sets(study):
    """Each row of both loci (the gains placing (12.13), and the printed (12.18) as u = -alpha x) is the root set
    of (12.12) at that k.  The printed gains never give a pole in the right half plane over [0.43, 1.15] (the
    thesis: 'does not lead to an unstable system'); the gains that realise (12.13) do, except within 1e-4 of k0."""
    for k, row, row_printed in zip(study.stiffness, study.poles_vs_stiffness, study.printed_gain_poles_vs_stiffness):
        np.testing.assert_allclose(row, _sorted(np.roots(_poly_12_12(k, -study.K))), rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(row_printed, _sorted(np.roots(_poly_12_12(k, -PRINTED_12_18))),
                                   rtol=1e-6, atol=1e-6)
    # the printed gains: alpha1 + alpha3 = 0 leaves the rigid-body pole at 0, the rest in the left half plane
    assert np.all(study.printed_gain_poles_vs_stiffness.real <= 1e-6)
    lo, hi = study.stable_interval
    assert lo < 0.605 < hi and hi - lo < 2e-4
    off = (study.stiffness < lo) | (study.stiffness > hi)
    assert np.all(np.max(study.poles_vs_stiffness[off].real, axis=1) > 0)   # unstable outside the interval


def test_stable_interval_ends_are_where_12_12_gains_a_root_in_the_right_half_plane(study):
    """Each end of each stable interval is a root of the largest real part of (12.12)'s roots (or the end of the
    searched range), and the tolerated stiffness error grows with faster targets (section 12.4)."""
    from awiwi_drake.control.pole_placement import design_pole_placement
    from awiwi_drake.rigs import flexible_joint_rig
    rig = flexible_joint_rig()
    p = PolePlacementParams()
    widths = []
    for (w1, w2), (lo, hi) in zip(study.targets, study.target_intervals):
        alpha = -design_pole_placement(rig, p.replace(omega1=float(w1), omega2=float(w2))).K
        growth = lambda k: np.max(np.roots(_poly_12_12(k, alpha)).real)
        assert growth(0.605) < 0
        for edge, outward, end in ((lo, -1.0, study.search_range[0]), (hi, 1.0, study.search_range[1])):
            if edge == pytest.approx(end, abs=1e-12):
                assert growth(edge) < 0
            else:
                assert growth(edge - outward * 1e-7) < 0 < growth(edge + outward * 1e-7)
        widths.append(hi - lo)
    assert np.all(np.diff(widths) > 0)
    assert study.stable_interval == pytest.approx(tuple(study.target_intervals[0]), abs=1e-9)


def test_simulated_perturbed_step_grows_at_the_unstable_pole_of_12_10(study):
    """The perturbed loop's simulated state, projected on the left eigenvector of its closed-loop matrix
    ((12.10) at k = 0.600 minus B K), grows exactly as e^(Re s t); the run is stopped and reported as diverged.
    The difference x(t) - x(t - h) removes the (unknown) equilibrium from the projection."""
    A = _A_12_10(0.600) - np.array([[0], [0], [0], [1 / B_M]]) @ study.K
    ev, W = np.linalg.eig(A.T)                    # left eigenvectors of A
    i = int(np.argmax(ev.real))
    w = W[:, i]
    x, t = study.state["perturbed"], study.t["perturbed"]
    d = np.abs((x[1:] - x[:-1]) @ w)
    n1, n2 = np.searchsorted(t, 0.02), np.searchsorted(t, 0.9 * t[-1])   # (the last sample ends a short step)
    rate = np.log(d[n2] / d[n1]) / (t[n2] - t[n1])
    assert rate == pytest.approx(ev[i].real, rel=1e-4)
    assert study.diverged_at["perturbed"] is not None and t[-1] < study.diverged_at["perturbed"]
    assert study.diverged_at["nominal"] is None
    q_nom = study.state["nominal"][:, 0]
    assert abs(q_nom[-1] - study.step) < 0.01 * study.step          # the nominal loop settles (5 time constants)


def test_plot_has_the_five_panels(study):
    fig, axes = study.plot()
    titles = [a.get_title() for a in axes.ravel()]
    assert titles[0].startswith("Fig 12.4") and titles[1].startswith("Fig 12.4") and "(12.19)" in titles[2]
    assert len(axes[0, 2].get_lines()) >= 3
    import matplotlib.pyplot as plt
    plt.close(fig)


@pytest.mark.parametrize("kw, match", [(dict(num=1), "num = 1 must be an integer >= 2"),
                                       (dict(num=9.5), "num = 9.5 must be an integer"),
                                       (dict(window=0.0), "window = 0.0 s must be finite and > 0")])
def test_bad_arguments_are_refused_with_one_line_naming_them(kw, match):
    with pytest.raises(ValueError, match=match):
        stiffness_robustness(**kw)
