"""Tendon force control (ch. 10, 14.2.1): closed forms (10.3)-(10.4), (10.11), gain scheduling, SDRE."""

from __future__ import annotations

import numpy as np
import pytest

from _fd import autodiff_vs_fd
from awiwi_drake.analysis import lqr
from awiwi_drake.control.base import closed_loop
from awiwi_drake.analysis import Samples, Step, simulate
from awiwi_drake.control.compare import fit_second_order_step
from awiwi_drake.control.sensors import force_sensor
from awiwi_drake.control.sdre import SDRE_GAIN, tendon_sdre_controller
from awiwi_drake.control.tendon_force import (TendonForceLaw, force_map, steady_state_force_without_feedforward,
                                              tendon_pd_controller, tendon_scheduled_controller)
from awiwi_drake.parameters import MotorParams, TendonRigParams
from awiwi_drake.parameters.control import ForceSensorParams, SdreTendonParams, TendonForceGains
from awiwi_drake.rigs import tendon_rig

DT = 1.0 / 3000.0


@pytest.fixture(scope="module")
def fmap():
    return force_map(tendon_rig())


def _step(controller_factory, fmap, f0, f1, *, t_final, ripple=False, noise=0.0, gains=None, delay=None):
    rig = tendon_rig(params=TendonRigParams(motor=MotorParams(ripple=ripple)))
    ctrl = controller_factory(rig, gains, fmap=fmap)
    sensors = {"tendon_force": force_sensor(ForceSensorParams(noise_std=noise))} if noise else None
    loop = closed_loop(rig, ctrl, rate_hz=3000.0, delay=delay, sensors=sensors)
    op = rig.operating_point(tendon_force=f0)
    ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque,
                              references={"tendon_force_reference": f0})
    t_step = 0.02
    log = simulate(loop, ctx, t_final, inputs={"tendon_force_reference": Step(t_step, f1, before=f0)},
                   log=("tendon_force", "motor_torque_command", "state"), log_period=DT)
    return log, t_step, ctrl


def test_force_map_and_identified_gains(fmap):
    rig = tendon_rig()
    r_m = rig.params.motor.pulley_radius
    for f in (10.0, 30.0, 45.0):
        op = rig.operating_point(tendon_force=f)
        assert fmap.theta_of_force(f) == pytest.approx(op.state[0], abs=2e-4)
        assert fmap.alpha_of_force(f) == pytest.approx(r_m * op.tendon_stiffness[0], rel=2e-3)
    # the slope table (r_m k_t from the rig's stiffness output) is the derivative of the tabulated force:
    # centred differences of the force column agree to O(h^2) away from the ends
    grad = np.gradient(fmap.force, fmap.theta)
    np.testing.assert_allclose(fmap.alpha[5:-5], grad[5:-5], rtol=2e-3)
    assert np.all(fmap.force > 0) and fmap.slack_angle < fmap.theta[0]  # taut rows only
    g = TendonForceGains()
    law = TendonForceLaw(fmap, rig.params.motor, g, scheduled=True)
    B, w, xi = rig.params.motor.inertia, g.natural_frequency, g.damping_ratio
    for f in (12.0, 33.0):
        kp, kd = law.gains_at(f)
        a = fmap.alpha_of_force(f)
        assert kp == pytest.approx(w ** 2 * B / a, rel=2e-3) and kd == pytest.approx(2 * xi * w * B / a, rel=2e-3)
    fixed = TendonForceLaw(fmap, rig.params.motor, g, scheduled=False)
    assert fixed.gains_at(12.0) == fixed.gains_at(40.0)
    np.testing.assert_allclose(fixed.gains_at(40.0), law.gains_at(g.design_force), rtol=1e-5)


def test_steady_state_error_with_and_without_feedforward(fmap):
    """(10.3): without the force feed-forward f_ss = f_des Kp / (Kp + r_m); (10.4): with it the error vanishes."""
    no_ff = TendonForceGains(force_feedforward=False)
    log, _, ctrl = _step(tendon_pd_controller, fmap, 20.0, 30.0, t_final=0.4, gains=no_ff)
    kp = ctrl.law.kp_fixed
    r_m = tendon_rig().params.motor.pulley_radius
    # at rest the smooth friction vanishes and the motor balances the tendon: Kp (f_des - f) = r_m f
    expected = 30.0 * kp / (kp + r_m)
    assert steady_state_force_without_feedforward(30.0, kp, r_m) == pytest.approx(expected, rel=1e-15)
    assert 30.0 - expected > 0.05  # a visible error ...
    assert log["tendon_force"][-1, 0] == pytest.approx(expected, abs=2e-3)  # ... exactly as (10.3) says
    log, _, _ = _step(tendon_pd_controller, fmap, 20.0, 30.0, t_final=0.4)
    assert log["tendon_force"][-1, 0] == pytest.approx(30.0, abs=1e-3)


def test_scheduled_gains_are_well_damped_everywhere_fixed_are_not(fmap):
    """Fig 10.2-10.3 with friction, ripple, 12-bit quantisation, noise and 333 us delay in the loop.

    The damping ratio is fitted to each simulated 5 N step (2nd-order model).
    Scheduled gains: within 0.10 of the design value 0.7 at 10, 20, 30, 40 N.
    Fixed gains (tuned at 30 N): under-damped at 10 N and spread at least twice as wide.
    """
    design = TendonForceGains().damping_ratio
    xi = {"fixed": [], "scheduled": []}
    for name, factory in (("fixed", tendon_pd_controller), ("scheduled", tendon_scheduled_controller)):
        for f0 in (10.0, 20.0, 30.0, 40.0):
            log, t_step, _ = _step(factory, fmap, f0, f0 + 5.0, t_final=0.15, ripple=True, noise=0.1, delay=333e-6)
            fit = fit_second_order_step(log.t, log["tendon_force"][:, 0], f0, f0 + 5.0, t_step)
            xi[name].append(fit["damping_ratio"])
    sched, fixed = np.array(xi["scheduled"]), np.array(xi["fixed"])
    assert np.all(np.abs(sched - design) < 0.10), sched
    assert fixed[0] < design - 0.12, fixed  # 10 N: visibly under-damped
    assert np.ptp(fixed) > 2.0 * np.ptp(sched), (fixed, sched)


def test_tendon_pd_near_slack_with_noisy_sensor_stays_bounded(fmap):
    """References 0-1 N with a 0.1 N noisy sensor: readings go below 0 N, the derivative term must stay damping.

    Before the fix the slope table was extrapolated below its slack row (alpha(-0.5 N) = -704 N/rad) and
    5 -> 0.3 N ran away to theta = -9 rad.  Now alpha is taken at max(f, min_schedule_force).
    """
    g = TendonForceGains()
    law = TendonForceLaw(fmap, tendon_rig().params.motor, g)
    a_floor = fmap.alpha_of_force(g.min_schedule_force)
    assert a_floor > 0 and fmap.alpha_of_force(-0.5, floor=g.min_schedule_force) == pytest.approx(a_floor)
    assert fmap.alpha_of_force(-0.5) == pytest.approx(fmap.alpha[0])  # no extrapolation below the table
    # derivative term alone (no friction feed-forward): d u / d motor_velocity = -Kd alpha(2 N) < 0 at any reading
    ctrl = tendon_pd_controller(tendon_rig(), g.replace(friction_compensation=False), fmap=fmap)
    for f in (-0.5, 0.0, 0.3, 1.9):
        J_ad, _ = autodiff_vs_fd(ctrl, {"tendon_force_reference": [0.3], "tendon_force": [f], "motor_velocity": [0.0]})
        assert J_ad[0, 2] == pytest.approx(-law.kd_fixed * a_floor, rel=1e-9)
    limit = MotorParams().torque_limit
    for factory in (tendon_pd_controller, tendon_scheduled_controller):
        for f1 in (0.0, 0.3, 1.0):
            log, _, _ = _step(factory, fmap, 5.0, f1, t_final=0.3, noise=0.1)
            th, f = log["state"][:, 0], log["tendon_force"][:, 0]
            assert np.min(th) > fmap.slack_angle - 0.15, (factory.__name__, f1, np.min(th))  # was -9 rad
            # after the step transient the noisy readings near slack do not drive the motor to its limit
            assert np.max(np.abs(log["motor_torque_command"][log.t > 0.1])) < 0.5 * limit
            if f1 > 0:
                assert np.mean(f[-300:]) == pytest.approx(f1, abs=0.1)


def test_tendon_force_references_outside_the_table_are_rejected(fmap):
    law = TendonForceLaw(fmap, tendon_rig().params.motor, TendonForceGains(), scheduled=True)
    meas = {"tendon_force": np.array([1.0]), "motor_velocity": np.array([0.0])}
    for bad in (-1.0, 1.5 * fmap.max_force, float("nan")):
        with pytest.raises(ValueError, match="tendon_force_reference"):
            law({"tendon_force_reference": np.array([bad]), **meas})
    with pytest.raises(ValueError, match="design_force"):
        TendonForceLaw(fmap, tendon_rig().params.motor, TendonForceGains(design_force=1e4))
    assert fmap.theta_of_force(0.0) == pytest.approx(fmap.slack_angle)
    law = tendon_sdre_controller(tendon_rig(), fmap=fmap).law
    with pytest.raises(ValueError, match="tendon_force_reference"):
        law({"tendon_force_reference": np.array([-2.0]), "motor_angle": np.array([0.5]),
             "motor_velocity": np.zeros(1), SDRE_GAIN: law.initial_gain})


def test_tendon_force_bank_equals_the_one_tendon_law_per_tendon_and_names_a_bad_entry(fmap):
    """The bank's vectorised float path (one table look-up for all tendons) equals the one-tendon law tendon by
    tendon to 1e-12 (also off the table's ends, where the slope and gains are held), and a bad reference in a
    bank is named by its index."""
    motor = MotorParams(ripple=True)
    n = 40
    rng = np.random.default_rng(5)
    fd = np.concatenate([[0.0, fmap.max_force], rng.uniform(0.0, fmap.max_force, n - 2)])
    u = {"tendon_force_reference": fd,
         "tendon_force": np.concatenate([[-3.0, 1.2 * fmap.max_force], rng.uniform(0.0, fmap.max_force, n - 2)]),
         "motor_velocity": rng.normal(0, 5, n), "motor_angle": rng.uniform(-3, 3, n),
         "tendon_path_velocity": rng.normal(0, 0.01, n)}
    for scheduled in (False, True):
        kw = dict(scheduled=scheduled, ripple_scale=0.8, path_velocity=True)
        bank = TendonForceLaw(fmap, motor, TendonForceGains(), size=n, **kw)(u)
        one = TendonForceLaw(fmap, motor, TendonForceGains(), **kw)
        each = [one({k: v[i:i + 1] for k, v in u.items()})[0] for i in range(n)]
        np.testing.assert_allclose(bank, each, rtol=1e-12, atol=1e-12)
    bad = dict(u, tendon_force_reference=np.where(np.arange(n) == 7, -1.0, fd))
    with pytest.raises(ValueError, match=r"tendon_force_reference\[7\] = -1.0"):
        TendonForceLaw(fmap, motor, TendonForceGains(), size=n, ripple_scale=0.8, path_velocity=True)(bad)


def test_tendon_sdre_gain_equals_lqr_refreshes_at_200_hz_and_settles_0_40_45(fmap):
    rig = tendon_rig()
    p = SdreTendonParams()
    ctrl = tendon_sdre_controller(rig, p, design_force=30.0, fmap=fmap)
    op = rig.operating_point(tendon_force=30.0)
    ref = lqr(tendon_rig(), np.diag(p.q_diag), [[p.r]], op)  # the framework's LQR at the same point
    np.testing.assert_allclose(ctrl.law.initial_gain, ref.K[0], rtol=1e-6)
    at_op = {"tendon_force_reference": [30.0], "motor_angle": op.state[:1], "motor_velocity": op.state[1:2]}
    np.testing.assert_allclose(ctrl.law.gains_at(at_op), ref.K[0], rtol=1e-6)
    # Fig 14.3: 0 -> 40 -> 45 N with SDRE and with the frozen gains
    limit = rig.params.motor.torque_limit
    period = int(round(3000.0 / p.update_rate))  # 15 control periods per gain refresh
    for fixed in (False, True):
        r = tendon_rig()
        loop = closed_loop(r, tendon_sdre_controller(r, p, fixed=fixed, fmap=fmap), rate_hz=3000.0)
        o = r.operating_point(tendon_force=0.0)
        ctx = loop.create_context(state=o.state, motor_torque=o.motor_torque,
                                  references={"tendon_force_reference": 0.0})
        ref = Samples([0.0, 0.05, 0.3], [0.0, 40.0, 45.0])
        log = simulate(loop, ctx, 0.6, inputs={"tendon_force_reference": ref}, log_period=DT,
                       log=("tendon_force", f"controller_{SDRE_GAIN}", "motor_torque_command", "state"))
        f, K, u = log["tendon_force"][:, 0], log[f"controller_{SDRE_GAIN}"], log["motor_torque_command"][:, 0]
        # both settle at the targets: within 0.5 N from 0.2 s after each step, to 0.01 N at the end
        t = log.t
        assert np.max(np.abs(f[(t > 0.25) & (t < 0.3)] - 40.0)) < 0.5
        assert np.max(np.abs(f[t > 0.5] - 45.0)) < 0.5 and abs(f[-1] - 45.0) < 0.01
        # Table 14.1 weights: position gain ~ sqrt(Q11 / R) = 1000 Nm/rad -> the command is far beyond the 3 Nm
        # limit right after each step (the rig saturates; REPRODUCTIONS reports it)
        assert np.max(np.abs(u)) > 100 * limit
        assert np.abs(u[int(round(0.3 / DT)) + 1]) > limit
        if fixed:
            assert np.ptp(K, axis=0).max() == 0.0
            continue
        # the gain output changes only on 5 ms boundaries and equals the LQR gain at the state sampled then
        changes = np.nonzero(np.any(np.diff(K, axis=0) != 0.0, axis=1))[0] + 1  # first sample showing a new gain
        assert len(changes) > 10 and np.all((changes - 1) % period == 0), changes
        for i in changes[:: max(1, len(changes) // 12)]:
            x = log["state"][i - 1, :2]  # state at the refresh instant (continuous across it)
            sample = {"tendon_force_reference": [ref.value(t[i - 1])], "motor_angle": x[:1], "motor_velocity": x[1:]}
            np.testing.assert_allclose(K[i], loop.controller.law.gains_at(sample), rtol=1e-9)


def test_tendon_controllers_convert_to_autodiff(fmap):
    rig = tendon_rig()
    inputs = {"tendon_force_reference": [25.0], "tendon_force": [22.0], "motor_velocity": [0.3]}
    for factory in (tendon_pd_controller, tendon_scheduled_controller):
        ctrl = factory(rig, fmap=fmap)
        J_ad, J_fd = autodiff_vs_fd(ctrl, inputs)
        np.testing.assert_allclose(J_ad, J_fd, rtol=1e-4, atol=1e-6)
    sd = tendon_sdre_controller(rig, fmap=fmap)
    J_ad, J_fd = autodiff_vs_fd(sd, {"tendon_force_reference": [25.0], "motor_angle": [0.5], "motor_velocity": [0.1]})
    np.testing.assert_allclose(J_ad, J_fd, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("field,value", [("natural_frequency", 0.0), ("damping_ratio", -0.5),
                                         ("damping_ratio", float("nan")), ("design_force", float("inf"))])
def test_tendon_gains_reject_bad_values(field, value):
    with pytest.raises(ValueError, match=field):
        TendonForceGains(**{field: value})


def test_sdre_rejects_bad_weights():
    with pytest.raises(ValueError, match="r"):
        SdreTendonParams(r=0.0)
    with pytest.raises(ValueError, match="update_rate"):
        SdreTendonParams(update_rate=float("nan"))


def test_sdre_printed_14_9_gains_do_not_depend_on_the_spring_and_friction_moves_the_jacobian_gain(fmap):
    """Table 14.1 on (14.9) as printed: K = LQR of [[0, 1], [-r_m^2 k_t(f) / B, 0]], [0, 1/B] with k_t from
    the spring law directly (scipy CARE): K_theta 999.5-1000, K_omega 10.198 at every force. The
    full-Jacobian variant gives K_omega 6.02 at rest (the closed-form LQR gain of the loop damped by the friction's
    slope at rest, checked to 1e-6) and ~10.1 in motion; with the (3.8) motor friction
    switched off it equals the printed factorisation: the gain change is the friction slope, not the spring."""
    from scipy.linalg import solve_continuous_are

    from awiwi_drake.components.spring import tendon_spring
    from awiwi_drake.analysis.linear import lqr_gain
    from awiwi_drake.control.sdre import RigJacobian, tendon_sdre_controller
    p = SdreTendonParams()
    rig = tendon_rig()
    mp = rig.params.motor
    B, r_m = mp.inertia, mp.pulley_radius
    Q, R = np.diag(p.q_diag), np.array([[p.r]])
    printed = tendon_sdre_controller(rig, p.replace(factorisation="printed"), fmap=fmap)
    jac = RigJacobian(rig)
    jac_nofric = RigJacobian(tendon_rig(params=TendonRigParams(motor=MotorParams(friction=False))))
    spring = tendon_spring(rig.params.spring)
    gains = []
    for f in (10.0, 20.0, 30.0, 40.0, 45.0):
        th = float(fmap.theta_of_force(f))
        k_t = float(spring.stiffness(spring.inverse_force(f)))
        A = np.array([[0.0, 1.0], [-r_m ** 2 * k_t / B, 0.0]])
        Bv = np.array([[0.0], [1.0 / B]])
        S = solve_continuous_are(A, Bv, Q, R)
        K_indep = (Bv.T @ S / p.r).ravel()
        K_printed = printed.law.gains_at({"motor_angle": np.array([th])})
        np.testing.assert_allclose(K_printed, K_indep, rtol=1e-3)
        gains.append(K_printed)
        K_rest = lqr_gain(*jac([th, 0.0], [r_m * f]), Q, R)[0].ravel()
        K_move = lqr_gain(*jac([th, 5.0], [r_m * f]), Q, R)[0].ravel()
        K_nofric = lqr_gain(*jac_nofric([th, 0.0], [r_m * f]), Q, R)[0].ravel()
        # at rest the (3.8) friction is the damping c = (gamma2 gamma1 + gamma3 + d) / B (its slope at w = 0); the
        # LQR of x'' = -a x - c x' + b u in closed form: k1 = (-a + sqrt(a^2 + b^2 q1 / r)) / b,
        # k2 = (-c + sqrt(c^2 + b^2 q2 / r + 2 b k1)) / b
        a, b = r_m ** 2 * k_t / B, 1.0 / B
        c = (mp.coulomb_torque * mp.friction_slope + mp.viscous_friction + mp.damping) / B
        k1 = (-a + np.sqrt(a * a + b * b * p.q_diag[0] / p.r)) / b
        np.testing.assert_allclose(K_rest, [k1, (-c + np.sqrt(c * c + b * b * p.q_diag[1] / p.r + 2 * b * k1)) / b],
                                   rtol=1e-6)
        assert K_move[1] > 10.0
        np.testing.assert_allclose(K_nofric, K_printed, rtol=5e-3)
    gains = np.array(gains)
    assert np.all((gains[:, 0] > 999.4) & (gains[:, 0] <= 1000.0))
    np.testing.assert_allclose(gains[:, 1], np.sqrt(p.q_diag[1] / p.r + 2 * B * gains[:, 0]), rtol=1e-3)
