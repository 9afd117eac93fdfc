"""Physics of the component laws: motor (ch. 3), spring mechanism and tendon (ch. 4)."""

import math

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd, InitializeAutoDiff
import pydrake.symbolic as sym

from _fd import assert_jacobians_close, autodiff_jacobian, fd_jacobian

from awiwi_drake.components import (
    LeverSpringMechanism, LinearSpring, AntagonisticPairSpring, PolynomialSpring, capstan_friction_force,
    guide_friction_force, hysteresis_rate, motor_friction_torque, motor_ripple_torque, reflected_inertia,
    saturate_torque, series_stiffness, tendon_spring, tendon_stiffness)
from awiwi_drake.parameters import (
    GuideFrictionParams, HysteresisParams, MotorParams, PolynomialSpringParams, SpringMechanismGeometry,
    SpringModelParams, TendonParams)


# ---------------------------------------------------------------- motor (ch. 3)
def test_reflected_inertia_closed_form():
    # (3.1): B = B_motor alpha^-2 + B_gearbox with alpha = 1/100.
    assert reflected_inertia(2e-7, 0.0, 100.0) == pytest.approx(2e-3)  # Table 16.1 writes 2e-7 * ratio^2
    assert reflected_inertia(1e-7, 5e-4, 100.0) == pytest.approx(1.5e-3)
    with pytest.raises(ValueError, match="gear_ratio"):
        reflected_inertia(1e-7, 0.0, 0.0)


def test_friction_matches_table_3_3_closed_form():
    p = MotorParams()
    for w in (-15.0, -1.0, 0.3, 15.0):
        expected = -(0.5586 * math.atan(10 * w) + 0.0356 * w)
        assert motor_friction_torque(np.array([w]), p)[0] == pytest.approx(expected, rel=1e-12)
    # Fig 3.3b scale: about 1.4 Nm at 15 rad/s.
    assert -motor_friction_torque(np.array([15.0]), p)[0] == pytest.approx(1.408, abs=0.01)


def test_friction_is_dissipative_and_odd():
    p = MotorParams(damping=0.01)
    w = np.linspace(-20, 20, 401)
    tau = motor_friction_torque(w, p)
    assert np.all(w * tau <= 0.0)
    np.testing.assert_allclose(tau, -motor_friction_torque(-w, p), atol=1e-14)
    assert np.all(motor_friction_torque(w, MotorParams(friction=False)) == 0.0)


def test_ripple_periods_and_switch():
    p = MotorParams(ripple=True)
    th = np.linspace(0, 2 * np.pi, 50)
    # The motor-shaft component repeats every 2 pi / 100 at the output, the output bearing every 2 pi.
    mot = MotorParams(ripple=True, ripple_output_amplitude=0.0)
    np.testing.assert_allclose(motor_ripple_torque(th, mot), motor_ripple_torque(th + 2 * np.pi / 100, mot), atol=1e-12)
    np.testing.assert_allclose(motor_ripple_torque(th, p), motor_ripple_torque(th + 2 * np.pi, p), atol=1e-12)
    peak = np.max(np.abs(motor_ripple_torque(np.linspace(0, 2 * np.pi, 20001), p)))
    assert peak == pytest.approx(p.ripple_motor_amplitude + p.ripple_output_amplitude, rel=1e-3)
    assert np.all(motor_ripple_torque(th, MotorParams(ripple=False)) == 0.0)


def test_saturation_clips_only_when_enabled():
    u = np.array([-5.0, 0.5, 5.0])
    np.testing.assert_allclose(saturate_torque(u, MotorParams(torque_limit=2.0)), [-2.0, 0.5, 2.0])
    np.testing.assert_allclose(saturate_torque(u, MotorParams(saturation=False)), u)


def test_laws_accept_autodiff_and_symbolic():
    p = MotorParams(ripple=True)
    w = InitializeAutoDiff(np.array([0.7])).ravel()
    d_ad = motor_friction_torque(w, p)[0].derivatives()[0]
    d_fd = fd_jacobian(lambda v: motor_friction_torque(v, p), [0.7], h=1e-6)[0, 0]
    assert d_ad == pytest.approx(d_fd, rel=1e-6)
    x = sym.Variable("w")
    with np.errstate(invalid="ignore"):  # numpy inspects FPU flags after object-array ufuncs
        expr = motor_friction_torque(np.array([sym.Expression(x)]), p)[0]
    assert expr.Evaluate({x: 0.7}) == pytest.approx(motor_friction_torque(np.array([0.7]), p)[0])


# ---------------------------------------------------------------- spring mechanism (ch. 4)
@pytest.fixture(scope="module")
def lever():
    return LeverSpringMechanism()


def test_lever_spring_constant_is_fitted_to_fig_4_8b(lever):
    # A *fit*, not a reproduction: the spring constant K is tuned so that f(48 deg) = 175 N
    # (SpringMechanismGeometry.spring_constant); this only guards the fit.
    assert lever.force_at_angle(math.radians(48)) == pytest.approx(175.0, abs=1.0)


def test_lever_curve_unfitted_shape_of_fig_4_8b(lever):
    # Properties of Fig 4.8b that no parameter was tuned for (the geometry lengths are chosen, K
    # scales the force only): zero force at 0 deg, monotonic, convex (progressive) with a large
    # stiffness ratio over 0-180 N, dL of a few millimetres (Fig 4.7), force rising steeply
    # between 45 and 50 deg as in the figure.
    assert lever.force_at_angle(0.0) == 0.0
    f45, f50 = lever.force_at_angle(math.radians(45)), lever.force_at_angle(math.radians(50))
    assert 130 < f45 < 175 < f50 < 220
    th, x, f, k = lever.sample_curve(max_force=180.0)
    assert np.all(np.diff(f) > 0) and np.all(np.diff(x) > 0)       # monotonic
    assert np.all(np.diff(k[1:]) > 0)                               # convex: stiffness rises with force
    assert k[-1] / k[1] > 20.0                                      # strongly progressive (2.3 -> 149 kN/m)
    assert 0.004 < x[-1] < 0.008                                    # dL of a few millimetres (Fig 4.7)


def test_lever_force_is_virtual_work_of_the_spring(lever):
    # Energy: int_0^x f dx' equals the energy stored in the linear spring at the same lever angle.
    th = np.linspace(0.0, math.radians(48), 2001)
    x = lever.elongation_at_angle(th)
    f = lever.force_at_angle(th)
    work = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(x))])
    stored = lever.spring_energy_at_angle(th)
    np.testing.assert_allclose(work, stored, atol=2e-4 * stored[-1])


def test_lever_autodiff_equals_finite_difference(lever):
    x = np.array([0.0005, 0.003, 0.006])
    J_ad = autodiff_jacobian(lever.force, x)
    J_fd = fd_jacobian(lever.force, x, h=1e-9)
    assert_jacobians_close(J_ad, J_fd, rtol=1e-5)
    np.testing.assert_allclose(np.diag(J_ad), lever.stiffness(x), rtol=1e-9)   # stiffness = d force / dx
    assert lever.force(-1e-3) == 0.0 and lever.stiffness(-1e-3) == 0.0  # slack
    # the inverse lands on the force and the elongation grows with the force
    f = np.array([1.0, 50.0, 100.0, 150.0])
    x_f = np.array([lever.inverse_force(fi) for fi in f])
    np.testing.assert_allclose(lever.force(x_f), f, rtol=1e-9)
    assert np.all(np.diff(x_f) > 0)


def test_lever_rejects_symbolic_with_clear_message(lever):
    with pytest.raises(ValueError, match="to_polynomial"):
        lever.force(np.array([sym.Expression(sym.Variable("x"))]))


def test_calibration_polynomial_fits_the_mechanism_in_series_with_the_tendon(lever):
    p = SpringModelParams()
    poly = tendon_spring(p)
    k_t = tendon_stiffness(p.tendon)
    th, x_mech, f, _ = lever.sample_curve(max_force=p.max_force)
    x_total = x_mech + f / k_t                       # series: elongations add at equal force
    err = poly.force(x_total) - f
    assert np.max(np.abs(err)) < 0.1                 # N, over 0-180 N (stated in SpringModelParams)
    # Series stiffness law 1/k = 1/k_mech + 1/k_t: the sampled curve's own slope df/dx_total (central differences,
    # truncation error <= h^2/6 max|f3| with f3 the third derivative from the third differences; round-off
    # 1e-15 |f| / h) is it.
    k_series = series_stiffness(np.array([lever.stiffness(x) for x in x_mech]).ravel(), k_t)
    h = np.diff(x_total)
    f3 = np.max(np.abs(np.diff(f, 3))) / np.min(h) ** 3
    slope = (f[2:] - f[:-2]) / (x_total[2:] - x_total[:-2])
    assert np.all(np.abs(slope - k_series[1:-1]) <= np.max(h) ** 2 / 6 * f3 + 1e-15 * np.max(f) / np.min(h))
    # The calibration polynomial's slope: its residual r = poly - curve stays under eps = 0.1 N on [a, b]; for r of
    # the fit's degree n Markov's inequality gives |r'| <= 2 n^2 eps / (b - a) (first order: r is smooth on the
    # polynomial's scale): 937 N/m, 5.5 % of the middle's 1.7e4 N/m (measured at most 521 N/m).
    n, eps = len(poly.coefficients), 0.1
    markov = 2 * n ** 2 * eps / (x_total[-1] - x_total[0])
    assert np.all(np.abs(np.ravel(poly.stiffness(x_total)) - k_series) <= markov)


@pytest.mark.parametrize("spring", [PolynomialSpring((2000.0, 3e6)), LinearSpring(1e4)])
def test_spring_stiffness_and_energy_are_derivative_and_integral_of_force(spring):
    x = np.linspace(-1e-3, 5e-3, 61)
    h = 1e-8
    fd = np.diag(fd_jacobian(spring.force, x, h=h))
    mask = np.abs(x) > 2 * h
    np.testing.assert_allclose(spring.stiffness(x)[mask], fd[mask], rtol=1e-6, atol=1e-6)
    e_fd = np.diag(fd_jacobian(spring.energy, x, h=h))
    np.testing.assert_allclose(e_fd[mask], spring.force(x)[mask], rtol=1e-6, atol=1e-6)
    assert np.all(spring.force(x[x <= 0]) == 0.0)   # tension only
    assert np.all(spring.stiffness(x[x <= 0]) == 0.0)
    f = np.array([1.0, 10.0, 50.0])
    np.testing.assert_allclose(spring.force(spring.inverse_force(f)), f, rtol=1e-10)


def test_antagonistic_pair_is_odd_stiffening_with_pretension_stiffness():
    base = PolynomialSpring((2000.0, 3e6))
    pair = AntagonisticPairSpring(base, pretension=20.0, radius=0.008)
    d = np.linspace(-0.3, 0.3, 61)
    np.testing.assert_allclose(pair.force(d), -pair.force(-d), atol=1e-12)
    assert pair.stiffness(np.array([0.0]))[0] == pytest.approx(2 * 0.008 ** 2 * base.stiffness(pair.x0), rel=1e-12)
    stiffer = AntagonisticPairSpring(base, pretension=40.0, radius=0.008)
    assert stiffer.stiffness(np.array([0.0]))[0] > pair.stiffness(np.array([0.0]))[0]


def test_polynomial_spring_params_validation_names_the_field():
    with pytest.raises(ValueError, match="not increasing"):
        PolynomialSpringParams(coefficients=(1000.0, -1e7))
    with pytest.raises(ValueError, match=r"coefficients\[1\].*not finite"):
        PolynomialSpringParams(coefficients=(1000.0, float("nan")))
    with pytest.raises(ValueError, match="coefficients"):
        PolynomialSpringParams(coefficients=(-5.0,))
    with pytest.raises(ValueError, match="max_lever_angle"):
        SpringMechanismGeometry(max_lever_angle=1.3)


def test_hysteresis_loop_width_and_dissipation():
    # Quasi-static cycle 40 -> 100 -> 40 N of elongation, integrate dz/dt on the path.
    poly = tendon_spring(SpringModelParams())
    hp = HysteresisParams(enabled=True)
    x_lo, x_hi = poly.inverse_force(40.0), poly.inverse_force(100.0)
    xs = np.concatenate([np.linspace(x_lo, x_hi, 4000), np.linspace(x_hi, x_lo, 4000),
                         np.linspace(x_lo, x_hi, 4000)])
    dt = 1e-4
    xdot = np.gradient(xs, dt)
    z = 0.0
    forces = []
    for x, v in zip(xs, xdot):
        z += dt * hysteresis_rate(z, x, v, poly.force(x), hp)
        forces.append(poly.force(x) + z)
    forces = np.array(forces)
    up = forces[8000:]                    # second loading branch (after the first reversal)
    down = forces[4000:8000][::-1]
    i = np.argmin(np.abs(xs[8000:] - poly.inverse_force(70.0)))
    width = up[i] - down[i]
    assert 10.0 <= width <= 20.0          # Fig 4.8b point A: 10-20 N at ~70 N
    work = np.trapezoid(up, xs[8000:]) - np.trapezoid(down, xs[8000:])
    assert work > 0                        # the loop dissipates energy


def test_dahl_path_is_the_exact_solution_of_the_rate_form():
    """:func:`dahl_path` (the Dahl law solved per sample on a piecewise-linear path) against (a) its closed form on
    a monotone path at constant level in the sign limit, ``F = W (1 - exp(-x/delta))``, and (b) a tight-tolerance
    integration of the rate form :func:`dahl_rate` along a random path with reversals, rests, segments slower than
    the smoothing velocity (where ``tanh(v/v_s)`` is far from +-1) and a level that varies along it (linear in
    time on each segment, as the exact form assumes)."""
    from scipy.integrate import solve_ivp
    from awiwi_drake.components.friction import dahl_path, dahl_rate
    delta, W = 1e-4, 3.0
    x = np.linspace(0.0, 5e-4, 11)
    np.testing.assert_allclose(dahl_path(x, W, delta), W * (1 - np.exp(-x / delta)), rtol=1e-13, atol=1e-15)
    rng = np.random.default_rng(7)
    dt, N, v_s = 1e-3, 80, 1e-4
    steps = rng.choice([-1.0, 1.0], N) * 10.0 ** rng.uniform(-8.5, -3.7, N)     # 3 um/s ... 0.2 m/s
    steps[rng.choice(N, 6, replace=False)] = 0.0                                 # rests
    xs = np.concatenate([[0.0], np.cumsum(steps)])
    Ws = rng.uniform(1.0, 5.0, N + 1)
    for smoothing in (v_s, 0.0):
        exact = dahl_path(xs, Ws, delta, smoothing, dt, initial_state=-0.5)
        F, ref = -0.5, [-0.5]
        for k in range(N):
            v, dW = (xs[k + 1] - xs[k]) / dt, (Ws[k + 1] - Ws[k]) / dt
            rate = (lambda t, y: [dahl_rate(y[0], v, Ws[k] + dW * t, delta, smoothing)]) if smoothing else (
                lambda t, y: [(v / delta) * (Ws[k] + dW * t - np.sign(v) * y[0])])
            F = solve_ivp(rate, (0.0, dt), [F], method="DOP853", rtol=1e-12, atol=1e-14).y[0, -1]
            ref.append(F)
        np.testing.assert_allclose(exact, ref, rtol=1e-9, atol=1e-11)
        assert np.ptp(exact) > 4.0   # the path reverses the state across most of its loop (not a trivial check)
    slow = np.abs(steps / dt) < v_s
    assert 10 < slow.sum() < N - 10  # both regimes of tanh(v/v_s) are exercised
    with pytest.raises(ValueError, match="presliding_length"):
        dahl_path(xs, 1.0, 0.0)
    with pytest.raises(ValueError, match="needs a sample period dt"):
        dahl_path(xs, 1.0, delta, v_s)


# ---------------------------------------------------------------- tendon and guide friction
def test_tendon_elasticity_scales_and_stays_in_dyneema_range():
    p = TendonParams()
    k = tendon_stiffness(p)
    # Stiffness halves when the tendon doubles in length and quadruples with twice the diameter.
    assert tendon_stiffness(p.replace(rest_length=2 * p.rest_length)) == pytest.approx(k / 2)
    assert tendon_stiffness(p.replace(diameter=2 * p.diameter)) == pytest.approx(4 * k)
    # At the top of the calibrated range (180 N) the strain is well below Dyneema's ~3.5 % at break.
    strain = 180.0 / k / p.rest_length
    assert 1e-3 < strain < 0.01
    # Series with the mechanism: softer than either; a slack mechanism transmits nothing.
    ks = series_stiffness(np.array([0.0, 2e4, 1e6]), k)
    assert ks[0] == 0.0 and ks[1] < 2e4 and ks[2] < k
    assert series_stiffness(np.array([k]), k)[0] == pytest.approx(k / 2)


def test_guide_friction_law_4_1_and_fig_4_10_range():
    p = GuideFrictionParams()
    a = np.radians([0.0, 8.0, 100.0, 200.0])
    F = guide_friction_force(a, p)
    # Limits of (4.1): zero without bending, initial slope C0*C1, saturation at C0 for large angles.
    h = 1e-6
    assert guide_friction_force(h, p) / h == pytest.approx(p.c0 * p.c1, rel=1e-5)
    assert guide_friction_force(100.0, p) == pytest.approx(p.c0, rel=1e-12)
    assert F[0] == 0.0 and 0.15 < F[1] < 0.3 and 1.7 < F[3] < 2.1     # Fig 4.10: ~0.2-2 N over 0-200 deg
    assert np.all(np.diff(F) > 0)
    with pytest.raises(ValueError, match="bending_angle"):
        guide_friction_force(-1.0)


def test_capstan_friction_is_proportional_to_tension():
    a = math.radians(200)
    f1, f2 = capstan_friction_force(10.0, a), capstan_friction_force(20.0, a)
    assert f2 == pytest.approx(2 * f1)
    # Wrapping two guides in series (angles a1 + a2) loses the same as one guide of the total angle
    # (Euler-Eytelwein: tension ratios multiply).
    a1, a2, T = 0.7, 2.1, 30.0
    T_after_1 = T - capstan_friction_force(T, a1)
    T_after_2 = T_after_1 - capstan_friction_force(T_after_1, a2)
    assert T - T_after_2 == pytest.approx(capstan_friction_force(T, a1 + a2), rel=1e-12)
    assert 0.1 <= f1 / 10.0 <= 0.5        # ch. 9: routing friction 10-50 % of the force


def test_scalar_value_reads_every_scalar_type_and_refuses_none():
    """``_math.scalar_value``: the float value of a float, an int, a one-entry array, an AutoDiffXd (its value, not
    its derivatives), a Tangent (its value's value); None for a symbolic Expression, which has no value."""
    from pydrake.autodiffutils import AutoDiffXd
    from pydrake.symbolic import Expression, Variable

    from awiwi_drake._math import Tangent, scalar_value
    assert scalar_value(2) == 2.0 and isinstance(scalar_value(2), float)
    assert scalar_value(-1.5) == -1.5
    assert scalar_value(np.array([[0.25]])) == 0.25
    assert scalar_value(AutoDiffXd(0.7, np.array([3.0, 4.0]))) == 0.7
    assert scalar_value(Tangent(AutoDiffXd(-0.3, np.array([1.0])), 5.0)) == -0.3
    assert scalar_value(Expression(Variable("x"))) is None
    assert scalar_value(Expression(1.25)) is None          # even a constant Expression: the type decides, not the value
