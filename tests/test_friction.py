"""One law, one place: the friction laws, springs in series (8.1) and the gains (10.11).

Each law is checked against closed forms written here from the thesis equations,
for dissipation, and in AutoDiffXd (derivatives against closed forms and central
differences) and symbolic arithmetic (same values as float).
"""

import numpy as np
import pytest
import pydrake.symbolic as sym
from pydrake.autodiffutils import AutoDiffXd

from _fd import assert_jacobians_close, autodiff_jacobian, fd_jacobian
from awiwi_drake.components import (
    atan_friction, capstan_friction_force, guide_friction, guide_friction_force, motor_friction_torque,
    regularized_sign, series_stiffness, stribeck_friction)
from awiwi_drake.parameters import GuideFrictionParams, MotorParams

V = np.linspace(-2.0, 2.0, 81)


def _symbolic_values(law, v, *args):
    """Evaluate ``law`` on a symbolic variable and substitute each velocity."""
    s = sym.Variable("v")
    with np.errstate(invalid="ignore"):   # numpy's float-error check on an object scalar
        expr = law(sym.Expression(s), *args)
    return np.array([expr.Evaluate({s: float(x)}) for x in v])


def test_atan_friction_is_3_8_and_the_motor_uses_it():
    g1, g2, g3 = 10.0, 0.5586, 0.0356                       # Table 3.3 (gamma1, gamma2, gamma3)
    tau = atan_friction(V, g2, g1, g3)
    np.testing.assert_allclose(tau, -(g2 * np.arctan(g1 * V) + g3 * V), rtol=0, atol=1e-15)
    assert np.all(tau * V <= 0)                                                  # dissipative
    # slope at rest: d tau/dv = -(g2 g1 + g3); far from rest: -(g2 (pi/2 - 1/(g1 v)) + g3 v)
    J = autodiff_jacobian(lambda v: atan_friction(v, g2, g1, g3), [0.0])
    assert J[0, 0] == pytest.approx(-(g2 * g1 + g3), rel=1e-14)
    # atan(z) = pi/2 - 1/z + O(z^-3)
    assert atan_friction(1e6, g2, g1, g3) == pytest.approx(-(g2 * (np.pi / 2 - 1e-7) + g3 * 1e6), rel=1e-14)
    np.testing.assert_allclose(_symbolic_values(atan_friction, V, g2, g1, g3), tau, rtol=1e-14, atol=1e-15)
    # the motor's torque is (3.8) with its Table 3.3 parameters plus its linear damping
    p = MotorParams()
    np.testing.assert_allclose(motor_friction_torque(V, p),
                               -(p.coulomb_torque * np.arctan(p.friction_slope * V) + p.viscous_friction * V)
                               - p.damping * V, rtol=1e-14, atol=1e-15)


def test_stribeck_friction_levels_slope_and_dissipation():
    fc, fs, vs, eps, d = 0.01, 0.015, 0.05, 0.01, 1e-4
    tau = stribeck_friction(V, fc, fs, vs, eps, d)
    assert np.all(tau * V <= 0)
    # far above the Stribeck velocity: Coulomb level plus viscous
    assert stribeck_friction(5.0, fc, fs, vs, eps, d) == pytest.approx(-(fc + d * 5.0), rel=1e-12)
    # slope at rest from the closed form: -(Fs / v_eps + d)
    J = autodiff_jacobian(lambda v: stribeck_friction(v, fc, fs, vs, eps, d), [0.0])
    assert J[0, 0] == pytest.approx(-(fs / eps + d), rel=1e-14)
    # the breakaway peak exceeds the Coulomb level near v_eps (stick-slip): |tau| > Fc somewhere
    assert np.max(np.abs(stribeck_friction(np.linspace(0, 0.2, 201), fc, fs, vs, eps, 0.0))) > 1.2 * fc
    # static == coulomb: regularised Coulomb friction -Fc tanh(v/eps)
    np.testing.assert_allclose(stribeck_friction(V, fc, fc, vs, eps), -fc * np.tanh(V / eps), rtol=1e-14)
    np.testing.assert_allclose(_symbolic_values(stribeck_friction, V, fc, fs, vs, eps, d), tau, rtol=1e-12,
                               atol=1e-16)
    v0 = np.array([-0.3, -0.02, 0.004, 0.07])
    assert_jacobians_close(np.diag(np.diag(autodiff_jacobian(lambda v: stribeck_friction(v, fc, fs, vs, eps, d),
                                                             v0))),
                           fd_jacobian(lambda v: stribeck_friction(v, fc, fs, vs, eps, d), v0), rtol=1e-6)


def test_regularized_sign_limits():
    assert regularized_sign(1.0, 1e-3) == pytest.approx(1.0, abs=1e-12)
    assert regularized_sign(-1.0, 1e-3) == pytest.approx(-1.0, abs=1e-12)
    assert autodiff_jacobian(lambda v: regularized_sign(v, 0.02), [0.0])[0, 0] == pytest.approx(50.0, rel=1e-14)


def test_guide_friction_4_1_capstan_and_the_directional_law():
    p = GuideFrictionParams()
    a = np.array([0.0, 0.1, 1.0, 3.5])
    np.testing.assert_allclose(guide_friction_force(a, p), p.c0 * (1 - np.exp(-p.c1 * a)), rtol=1e-15)
    # capstan (Euler-Eytelwein): the tension after the guides is f e^(-mu alpha)
    f = 30.0
    assert f - capstan_friction_force(f, 2.0, p) == pytest.approx(f * np.exp(-p.mu * 2.0), rel=1e-14)
    # directional law: far from rest the pulling end carries f e^(+-mu alpha) +- C
    mu_a, c, vs = 0.35, 0.8, 1e-4
    up = guide_friction(1.0, f, c, mu_a, vs)
    down = guide_friction(-1.0, f, c, mu_a, vs)
    assert f + up == pytest.approx(f * np.exp(mu_a) + c, rel=1e-12)
    assert f + down == pytest.approx(f * np.exp(-mu_a) - c, rel=1e-12)
    # releasing loses exactly the capstan loss of the same wrap
    assert -down - c == pytest.approx(capstan_friction_force(f, mu_a / p.mu, p), rel=1e-12)
    v = np.linspace(-1e-3, 1e-3, 101)
    assert np.all(guide_friction(v, f, c, mu_a, vs) * v >= 0)                   # opposes sliding
    # AutoDiff derivative w.r.t. sliding speed and tension (closed forms)
    J = autodiff_jacobian(lambda z: guide_friction(z[0], z[1], c, mu_a, vs), [0.0, f])
    np.testing.assert_allclose(J[0], [(c + f * mu_a) / vs, 0.0], rtol=1e-14, atol=1e-12)
    with pytest.raises(ValueError, match="bending_angle"):
        guide_friction_force(-0.1, p)


def test_series_stiffness_8_1_scalar_array_matrix_and_autodiff():
    assert series_stiffness(3.0, 6.0) == pytest.approx(2.0, rel=1e-15)       # 1/(1/3 + 1/6)
    np.testing.assert_allclose(series_stiffness(np.array([0.0, 2e4, 1e6]), 1e5),
                               [0.0, 1.0 / (1 / 2e4 + 1 / 1e5), 1.0 / (1 / 1e6 + 1 / 1e5)], rtol=1e-14)
    rng = np.random.default_rng(4)
    A, B = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    Ka, Kb = A @ A.T + 0.3 * np.eye(3), B @ B.T + 0.3 * np.eye(3)
    np.testing.assert_allclose(series_stiffness(Ka, Kb), np.linalg.inv(np.linalg.inv(Ka) + np.linalg.inv(Kb)),
                               rtol=1e-10, atol=1e-12)
    # derivative: d/dk_a [k_a k_b/(k_a + k_b)] = (k_b/(k_a + k_b))^2
    J = autodiff_jacobian(lambda k: np.array([series_stiffness(k[0], k[1])]), [3.0, 6.0])
    np.testing.assert_allclose(J[0], [(6.0 / 9.0) ** 2, (3.0 / 9.0) ** 2], rtol=1e-14)
    assert isinstance(series_stiffness(AutoDiffXd(3.0), AutoDiffXd(6.0)), AutoDiffXd)
    with pytest.raises(ValueError, match="series_stiffness"):
        series_stiffness(-1.0, 2.0)
    with pytest.raises(ValueError, match="series_stiffness"):
        series_stiffness(np.eye(2), np.eye(3))


def test_identified_gains_10_11_place_the_force_loop_poles():
    """(10.11) makes B s^2 + alpha Kd s + alpha Kp have natural frequency w and damping xi (10.10)."""
    from awiwi_drake.control.tendon_force import identified_gains
    B, w, xi = 1.3e-4 * 1e4, 60.0, 0.8
    alphas = np.array([50.0, 400.0, 3000.0])
    kp, kd = identified_gains(alphas, B, w, xi)
    for a, p_, d_ in zip(alphas, kp, kd):
        poles = np.roots([B, a * d_, a * p_])
        assert np.abs(poles) == pytest.approx([w, w], rel=1e-12)
        assert -poles.real / np.abs(poles) == pytest.approx([xi, xi], rel=1e-12)
    assert identified_gains(400.0, B, w, xi) == pytest.approx((kp[1], kd[1]), rel=1e-15)
    with pytest.raises(ValueError, match="alpha"):
        identified_gains(np.array([1.0, 0.0]), B, w, xi)


def test_joint_friction_bound_is_the_largest_torque_of_the_unmeasured_frictions():
    """``joint_friction_bound`` (ch. 9's bound of the observer's estimate, one law for the chain and the 15.5
    backstepping): per joint ``B_j = sum_i |A_ij| (W_i(f_i + w_i) + w_i)`` against its closed form, at random
    couplings ``A`` (signs mixed, as P S), forces and levels.  The unmeasured frictions are the guides' Dahl force
    ``|g_i| <= W_i`` at the tension it passes (pulled: ``C + t (e^{mu alpha} - 1)``, released: ``C + t (1 -
    e^{-mu alpha})``) and the lever's hysteresis ``|z_i| <= w_i``, the tension being ``f_i + z_i``.  Over every
    corner of that set (each tendon's z and g at +-, g at its own tension and direction) the joint torque
    ``|A^T (z + g)|`` never exceeds B; for the constant (4.1) law the bound is attained (the corner z, g = +-w, +-C
    with the signs of A's column), with the capstan law at the corner of a one-signed column pulled everywhere.
    Slack (negative) forces count as 0; w = 0 (the measured force holds the hysteresis: the chain) leaves the guides
    alone; AutoDiffXd passes through.  The joints' own stick-slip (``|tau_l| <= Fs_l``, :func:`stick_slip_rate`)
    adds ``|S|^T Fs`` on the DoF ``q = S w`` (a joint torque ``tau`` is ``S^T tau`` there, as the tendons' ``-(P S)^T
    f``; :func:`joint_breakaway_bound`, computed once), attained at ``tau_l = Fs_l`` with the signs of S's column;
    Fs = 0 is no joint term (None), the bound bit-identical."""
    from itertools import product
    from awiwi_drake.components.friction import joint_breakaway_bound, joint_friction_bound
    rng = np.random.default_rng(3)
    m, k = 6, 3
    A = rng.normal(0.0, 5e-3, (m, k))
    A[:, 2] = np.abs(A[:, 2])                                     # one one-signed column
    f = rng.uniform(5.0, 40.0, m)
    C, mu, w = rng.uniform(0.5, 2.0, m), rng.uniform(0.1, 0.6, m), rng.uniform(0.5, 4.0, m)
    for capstan in (False, True):
        mu_a = mu if capstan else np.zeros(m)
        B = joint_friction_bound(A, f, C, mu_a, w)
        np.testing.assert_allclose(B, np.abs(A).T @ (C + (f + w) * np.expm1(mu_a) + w), rtol=1e-14)
        worst = np.zeros(k)
        for sz, sg in product(product((-1.0, 1.0), repeat=m), repeat=2):
            sz, sg = np.array(sz), np.array(sg)
            t = f + sz * w
            level = C + t * np.where(sg > 0, np.expm1(mu_a), -np.expm1(-mu_a))
            worst = np.maximum(worst, np.abs(A.T @ (sz * w + sg * level)))
        assert np.all(worst <= B * (1 + 1e-12)), (capstan, worst / B)
        tight = [0, 1, 2] if not capstan else [2]
        np.testing.assert_allclose(worst[tight], B[tight], rtol=1e-12)
    np.testing.assert_allclose(joint_friction_bound(A, -f, C, mu, 0.0), np.abs(A).T @ C, rtol=1e-14)
    np.testing.assert_allclose(joint_friction_bound(A, f, C, mu), np.abs(A).T @ (C + f * np.expm1(mu)), rtol=1e-14)
    fa = np.array([AutoDiffXd(x, np.eye(m)[i]) for i, x in enumerate(f)], dtype=object)
    Ba = joint_friction_bound(A, fa, C, mu, w)
    np.testing.assert_allclose([b.value() for b in Ba], joint_friction_bound(A, f, C, mu, w), rtol=1e-14)
    np.testing.assert_allclose(np.array([b.derivatives() for b in Ba]), (np.abs(A) * np.expm1(mu)[:, None]).T,
                               rtol=1e-12)
    # the joints' friction on the DoF: P (m x n) and S (n x k), a coupled joint (row 3: two DoF, mixed signs)
    P = rng.normal(0.0, 5e-3, (m, 4))
    S = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, -0.4, 0.8]])
    Fs = rng.uniform(0.005, 0.03, 4)
    Bj = joint_friction_bound(P, f, C, mu, w, joint_breakaway_bound(Fs, S), S)
    worst = np.max([np.abs(S.T @ (Fs * np.array(sj))) for sj in product((-1.0, 1.0), repeat=4)], axis=0)
    np.testing.assert_allclose(Bj - joint_friction_bound(P @ S, f, C, mu, w), worst, rtol=1e-12)
    np.testing.assert_allclose(worst, [Fs[0], Fs[1] + 0.4 * Fs[3], Fs[2] + 0.8 * Fs[3]], rtol=1e-14)
    assert joint_breakaway_bound(np.zeros(4), S) is None and joint_breakaway_bound(None, S) is None
    assert np.array_equal(joint_friction_bound(P, f, C, mu, w, None, S), joint_friction_bound(P @ S, f, C, mu, w))
