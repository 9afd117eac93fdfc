"""Optimal backstepping gains (ch. 16): K_bs(Omega) derived from the controller, ARE, gain search."""

import concurrent.futures as cf

import numpy as np
import pytest

from awiwi_drake.control.backstepping import ImpedanceBackstepping, joint_model
from awiwi_drake.control.optimal_gains import (
    backstepping_feedback, monte_carlo_gains, optimal_feedback, optimize_gains, system_feedback, torque_coordinates)
from awiwi_drake.reproductions.ch16_optimal_backstepping import printed_model_feedback, table_16_1_rig
from awiwi_drake.parameters.backstepping import ImpedanceBacksteppingGains, OptimalGainsCase


def test_state_feedback_matches_the_printed_structure_of_16_3():
    """K_bs from AutoDiff of the law = through the TemplateSystem = the closed forms of (15.70)/(16.3)."""
    rig = table_16_1_rig()
    c = OptimalGainsCase()
    model = joint_model(rig)
    g = ImpedanceBacksteppingGains(stiffness=0.7, damping=0.03, k3=40.0, k4=90.0)
    K_law = backstepping_feedback(model, g).ravel()
    K_sys = system_feedback(ImpedanceBackstepping(model, g, external_torque="none"), np.zeros(4)).ravel()
    np.testing.assert_allclose(K_sys, K_law, rtol=1e-12)
    K_tau = K_law @ np.linalg.inv(torque_coordinates(c.stiffness))
    bk = c.motor_inertia / c.stiffness                               # the 0.0033 of (16.3)
    Kp, Kd, K3, K4 = g.stiffness, g.damping, g.k3, g.k4
    np.testing.assert_allclose(K_tau[0], bk * (K4 * K3 * Kp + Kp), rtol=1e-9)
    np.testing.assert_allclose(K_tau[1], bk * (K3 * Kp + K4 * (K3 * Kd + Kp + 1) + Kd), rtol=1e-9)


def test_lqr_from_framework_and_the_printed_table():
    rig = table_16_1_rig()
    K_tau, K_rig = optimal_feedback(rig)
    # scalar closed form of the ARE's position gain for an integrator chain: sqrt(Q11/R)
    assert K_tau[0] == pytest.approx(np.sqrt(100.0 / 0.1), rel=1e-6)
    printed = np.array(OptimalGainsCase().printed_kdes)
    ours = printed_model_feedback()
    assert ours[0] == pytest.approx(-np.sqrt(1000.0), rel=1e-6)
    assert not np.allclose(ours, printed, rtol=0.1)        # Table 16.1's Kdes does not follow from its A, B, Q, R


def test_table_16_1_target_is_below_the_structural_floor():
    """Every Omega > 0 gives a tau-gain above the LQR's: the R = 0.1 target is unreachable."""
    rig = table_16_1_rig()
    c = OptimalGainsCase()
    model = joint_model(rig)
    target, _ = optimal_feedback(rig, c)
    Tinv = np.linalg.inv(torque_coordinates(c.stiffness))
    rng = np.random.default_rng(0)
    for _ in range(20):
        om = np.exp(rng.uniform(np.log(c.gain_low), np.log(c.gain_high)))
        g = ImpedanceBacksteppingGains(stiffness=om[0], damping=om[1], k3=om[2], k4=om[3])
        assert (backstepping_feedback(model, g) @ Tinv).ravel()[2] > target[2]


def test_reachable_case_optimizer_beats_monte_carlo():
    rig = table_16_1_rig()
    case = OptimalGainsCase(r_weight=1e-3)
    fit = optimize_gains(rig, case)
    assert fit.distance < 1e-8
    with cf.ThreadPoolExecutor(2) as ex:
        mc = monte_carlo_gains(rig, case, samples=300, executor=ex)
    assert mc.distance > fit.distance
    assert all(v > 0 for v in (fit.gains.stiffness, fit.gains.damping, fit.gains.k3, fit.gains.k4))
