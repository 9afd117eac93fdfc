"""Backstepping (ch. 15): scalar conversion, Lyapunov decrease, closed forms, thesis studies (short)."""

import math

import numpy as np
import pytest
from pydrake.autodiffutils import InitializeAutoDiff, ExtractGradient
from pydrake.systems.primitives import Linearize

from _fd import system_jacobians
from awiwi_drake.control.backstepping import (
    ImpedanceBackstepping, PositionBackstepping, impedance_backstepping, impedance_controller, joint_model,
    position_backstepping, position_controller)
from awiwi_drake.reproductions.ch15_backstepping import (
    antagonistic_step, antagonistic_stiffness_check, count_oscillations, delay_study, example_phase_portrait,
    impedance_steady_state, impedance_study, is_monotone_nonincreasing, load_step_command_jump, position_gain_study,
    saturation_study, table_15_1_params, table_15_1_rig)
from awiwi_drake.reproductions.ch15_scalar_example import ScalarBackstepping, ScalarExamplePlant, example_control
from awiwi_drake.control.base import closed_loop
from awiwi_drake.control.sensors import with_external_torque_sensor
from awiwi_drake.parameters.backstepping import (
    ImpedanceBacksteppingGains, ImpedanceStudy, NonlinearImpedanceStudy, PositionBacksteppingGains, PositionStudy,
    ScalarExampleGains)
from awiwi_drake.analysis import linearize
from awiwi_drake.rigs import joint_rig


@pytest.mark.parametrize("case", ["position", "impedance_linear", "impedance_nonlinear", "antagonistic"])
def test_controllers_convert_and_autodiff_matches_finite_differences(case):
    rng = np.random.default_rng(5)
    if case == "position":
        rig = table_15_1_rig()
        sys = position_controller(rig)
        x = rng.normal(0, 0.05, 4)
    elif case == "antagonistic":
        rig = joint_rig()
        sys = impedance_controller(rig, external_torque="none")
        x = rig.operating_point().state + np.concatenate([rng.normal(0, 0.02, 4), rng.normal(0, 0.1, 2)])
    else:
        rig = table_15_1_rig(spring="linear" if case.endswith("linear") else "nonlinear")
        sys = impedance_controller(rig, external_torque="none")
        x = rng.normal(0, 0.05, 4)
    assert sys.ToAutoDiffXd() is not None
    J_ad, J_fd = system_jacobians(sys, [], {"state": x, "joint_angle_reference": [0.3]}, wrt=["state"],
                                  outputs=["motor_torque"])["motor_torque"]
    np.testing.assert_allclose(J_ad, J_fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(J_ad)))


def test_scalar_example_systems_convert():
    plant, ctrl = ScalarExamplePlant(), ScalarBackstepping(ScalarExampleGains(k1=2.0, k2=3.0))
    J_ad, J_fd = system_jacobians(ctrl, [], {"state": [0.4, -0.7]}, outputs=["motor_torque"])["motor_torque"]
    np.testing.assert_allclose(J_ad, J_fd, rtol=1e-6)
    ad = plant.ToAutoDiffXd()
    ctx = ad.CreateDefaultContext()
    ctx.SetContinuousState(InitializeAutoDiff(np.array([0.5, 0.2])).ravel())
    ad.get_input_port(0).FixValue(ctx, [type(InitializeAutoDiff(np.zeros(1))[0, 0])(0.0)])
    J = ExtractGradient(ad.EvalTimeDerivatives(ctx).CopyToVector())
    x1 = 0.5
    np.testing.assert_allclose(J, [[-3 * x1 ** 2 + 2 * x1, 1.0], [0.0, 0.0]], atol=1e-12)  # (15.1)


def _closed_loop_vdot(rig, controller, x, ref, rel=1e-7):
    """dV/dt along the closed loop at state x: central difference of V along Drake's derivatives."""
    loop = closed_loop(rig, controller, rate_hz=None)
    ctx = loop.create_context(state=x, references={"joint_angle_reference": ref})
    d = loop.diagram
    ctrl = d.GetSubsystemByName("controller")
    if ctrl.num_continuous_states():       # observer: start without a disturbance estimate (w_hat = qd)
        ctrl.GetMyMutableContextFromRoot(ctx).SetContinuousState([x[1]])
    xdot = d.EvalTimeDerivatives(ctx).CopyToVector()
    full = ctx.get_continuous_state_vector().CopyToVector()
    V = []
    for s in (1, -1):
        ctx.SetContinuousState(full + s * rel * xdot)
        V.append(ctrl.GetOutputPort("lyapunov").Eval(ctrl.GetMyContextFromRoot(ctx))[0])
    ctx.SetContinuousState(full)
    return (V[0] - V[1]) / (2 * rel), ctrl.GetOutputPort("lyapunov").Eval(ctrl.GetMyContextFromRoot(ctx))[0]


@pytest.mark.parametrize("case", ["position", "impedance_linear", "impedance_nonlinear", "antagonistic"])
def test_lyapunov_decreases_along_the_nominal_closed_loop(case):
    """V' <= 0 at random states of the rig + controller diagram (undisturbed, nominal model)."""
    rng = np.random.default_rng(11)
    for _ in range(5):
        if case == "position":
            rig = table_15_1_rig()
            ctrl, x = position_controller(rig), rng.normal(0, 0.05, 4)
        elif case == "antagonistic":
            rig = joint_rig()
            ctrl = impedance_controller(rig)
            x = rig.operating_point().state + np.concatenate(
                [rng.normal(0, 0.05, 2), rng.normal(0, 0.02, 2), rng.normal(0, 0.1, 2)])
        else:
            rig = table_15_1_rig(spring="linear" if case.endswith("linear") else "nonlinear")
            ctrl = impedance_controller(rig)
            x = rng.normal(0, 0.05, 4)
        vdot, V = _closed_loop_vdot(rig, ctrl, x, rng.normal(0, 0.3))
        assert V > 0
        assert vdot < 1e-6 * abs(V), (case, vdot, V)


def test_position_closed_loop_poles_are_the_designed_ones():
    """Exact linearisation: Drake's Linearize of rig + controller has the poles of the z-dynamics (15.42)."""
    g = PositionBacksteppingGains(k1=5.0, k2=1.0, k3=100.0, k4=100.0)
    rig = table_15_1_rig()
    loop = closed_loop(rig, position_controller(rig, g), rate_hz=None)
    ctx = loop.create_context(state=np.zeros(4))
    lin = Linearize(loop.diagram, ctx, input_port_index=loop.diagram.GetInputPort("joint_angle_reference").get_index(),
                    output_port_index=loop.diagram.GetOutputPort("joint_angle").get_index())
    Az = np.array([[-g.k1, 1, 0, 0], [-1, -g.k2, 1, 0], [0, -1, -g.k3, 1], [0, 0, -1, -g.k4]])
    got = np.sort_complex(np.linalg.eigvals(lin.A()))
    want = np.sort_complex(np.linalg.eigvals(Az))
    np.testing.assert_allclose(got, want, rtol=1e-6)
    # the dominant pair is the printed e'' + (K1 + K2) e' + (1 + K1 K2) e = 0 with K2 shifted by the fast stages:
    # the Schur complement of the tridiagonal z-dynamics makes det(sI - Az) = 0 exactly
    # s^2 + (K1 + K2') s + 1 + K1 K2' = 0 with K2' = K2 + 1 / (s + K3 + 1 / (s + K4)), and for a real pole
    # |s| << K3, K4 the shift is 0 < K2' - K2 < 1 / (K3 - |s|) (~1/K3, the size of the printed pair's error)
    dominant = got[np.argsort(got.real)[-2:]]
    assert np.all(np.abs(dominant.imag) <= 1e-6 * np.abs(dominant))   # (K1 - K2)^2 > 4: an overdamped pair
    for s in dominant.real:
        k2s = g.k2 + 1.0 / (s + g.k3 + 1.0 / (s + g.k4))
        # residual of a pole known to the 1e-6 relative asserted above: 1e-6 |s| times the slope 2s + K1 + K2'
        slope = abs(2 * s + g.k1 + k2s)
        assert s * s + (g.k1 + k2s) * s + 1.0 + g.k1 * k2s == pytest.approx(0.0, abs=1e-6 * abs(s) * slope)
        assert 0.0 < k2s - g.k2 < 1.0 / (g.k3 - abs(s))


def test_scalar_example_converges_for_the_thesis_gain_sets():
    """Fig 15.2-15.4: (k1, k2) = (0.1, 5), (1, 1), (5, 0.1) converge from a grid of initial states."""
    starts = [(-1.0, -1.0), (1.5, 3.0), (-1.0, 3.0), (1.5, -1.0)]
    for k1, k2 in ((0.1, 5.0), (1.0, 1.0), (5.0, 0.1)):
        for variant in ("textbook", "printed"):
            runs = example_phase_portrait(ScalarExampleGains(k1=k1, k2=k2), starts, t_final=60.0, dt=0.1,
                                          variant=variant)
            for r in runs:
                assert np.linalg.norm(r.state[-1]) < 0.02 + 1.2 * math.exp(-k1 * 55.0), (k1, k2, variant, r.label)
                if variant == "textbook":
                    assert is_monotone_nonincreasing(r.lyapunov, rtol=1e-4)


def test_position_steps_settle_with_decreasing_lyapunov():
    """Fig 15.7 (K1 = 1, 5): the link settles at the 0.8 rad step with a decreasing Lyapunov function, and
    the whole response is the linear closed loop's, x(t) = x_ss + V exp(Lambda t) V^-1 (x0 - x_ss) from
    Drake's linearisation of the rig and the (linear) law; tolerance: a tenth of what a 1 % change of K1
    does to q(t), so the comparison pins the gain."""
    s = PositionStudy()

    def predicted(k1, t):
        rig = table_15_1_rig()
        A, B, K, ur = _linear_loop(rig, position_controller(rig, PositionBacksteppingGains(k1=k1, k2=s.k1_fixed_k2)),
                                   s.step)
        Acl = A + np.outer(B, K)
        x_ss = -np.linalg.solve(Acl, B * ur)
        lam, V = np.linalg.eig(Acl)
        c = np.linalg.solve(V, -x_ss)
        return np.array([(x_ss + V @ (np.exp(lam * tk) * c)).real[0] for tk in t])
    for k1, r in zip((1.0, 5.0), position_gain_study("k1", values=(1.0, 5.0), t_final=8.0)):
        assert abs(r.q[-1] - s.step) < 0.01 * s.step
        assert is_monotone_nonincreasing(r.lyapunov, rtol=1e-4)
        q = predicted(k1, r.t)
        tol = 0.1 * np.max(np.abs(predicted(1.01 * k1, r.t) - q))
        assert np.max(np.abs(r.q - q)) < tol, (np.max(np.abs(r.q - q)), tol)


def test_saturated_position_loop_stays_bounded_and_moves_towards_the_target():
    """Fig 15.10/15.11: |u| < 5e-4 Nm; the saturated loop is slower but does not diverge."""
    free, sat = saturation_study(t_final=4.0)
    s = PositionStudy()
    assert np.max(np.abs(sat.command)) <= s.saturation * (1 + 1e-9)
    assert np.max(np.abs(free.command)) > 5 * s.saturation             # the saturation is active
    assert np.all(np.diff(sat.q[sat.t > 0.5]) >= -1e-9)               # monotone approach, no oscillation
    # power balance at steady motion: u_max v >= (d_theta + d_q) v^2, so the mean speed of the approach
    # cannot exceed v_sat = u_max / (d_theta + d_q); with the command at its limit for most of the way it
    # reaches at least half of it (the loop does move towards the target at the torque-limited speed)
    p = table_15_1_params()
    v_sat = s.saturation / (p.motor_damping + p.link_damping)
    after = sat.t >= 1.0
    mean_speed = (sat.q[-1] - sat.q[after][0]) / (sat.t[-1] - sat.t[after][0])
    assert 0.5 * v_sat < mean_speed <= v_sat * (1 + 1e-6), (mean_speed, v_sat)
    assert sat.q[-1] < s.step


def _linear_loop(rig, controller, step):
    """(A, B) of the rig's Drake linearisation at rest and the controller's affine law read off the system:
    u = u_r + K x for the reference ``step`` (plant and law are linear)."""
    d = rig.diagram
    lin = Linearize(d, rig.context(rig.operating_point()), input_port_index=d.GetInputPort("motor_torque").get_index(),
                    output_port_index=d.GetOutputPort("state").get_index())
    cc = controller.CreateDefaultContext()
    controller.GetInputPort("joint_angle_reference").FixValue(cc, [step])

    def u(x):
        controller.GetInputPort("state").FixValue(cc, x)
        return float(controller.GetOutputPort("motor_torque").Eval(cc)[0])
    n = lin.A().shape[0]
    ur = u(np.zeros(n))
    return lin.A(), lin.B()[:, 0], np.array([u(e) - ur for e in np.eye(n)]), ur


def _sampled_delayed_prediction(loop, period, delay_periods, t_final):
    """q(t) of the linear loop sampled every ``period`` with the command delayed ``delay_periods`` periods,
    predicted without the simulator: exact ZOH discretisation (matrix exponential) of the linearisation."""
    from scipy.linalg import expm
    A, B, K, ur = loop
    n = A.shape[0]
    E = expm(np.block([[A, B[:, None]], [np.zeros((1, n + 1))]]) * period)
    Ad, Bd = E[:n, :n], E[:n, n]
    x, buf, q = np.zeros(n), [0.0] * delay_periods, []
    for _ in range(int(round(t_final / period)) + 1):
        q.append(x[0])
        buf.append(ur + K @ x)
        x = Ad @ x + Bd * buf.pop(0)
    return np.arange(len(q)) * period, np.array(q)


def test_333us_round_trip_delay_does_not_oscillate():
    """Section 15.2.4: with the 333 us round trip the K1 = 5 response stays non-oscillating; the run
    equals the sampled-data linear prediction (the plant and the law are linear), and is much slower
    than the undelayed continuous loop (closed form exp((A + B K) t) of the same linearisation)."""
    s = PositionStudy()
    t_final = 0.6
    run = delay_study(t_final=t_final, delays=(s.round_trip_delay,))[0]
    q = run.q[:, 0] if run.q.ndim > 1 else run.q
    assert np.all(np.diff(q) >= -1e-9)                          # monotone rise: no oscillation
    assert np.all(np.abs(np.diff(run.command[:, 0])) < 1e-4)      # no command chatter
    rig = table_15_1_rig()
    loop = _linear_loop(rig, position_controller(rig, PositionBacksteppingGains()), s.step)
    h, n = s.round_trip_delay / s.delay_steps, s.delay_steps
    pred = {m: np.interp(run.t, *_sampled_delayed_prediction(loop, h, m, t_final)) for m in (n - 1, n, n + 1)}
    # tolerance: a tenth of what one period more or less of delay changes in q (so the test pins the
    # delay model); the error-controlled integrator (accuracy 1e-6) lies far below that
    one_period = min(np.max(np.abs(pred[m] - pred[n])) for m in (n - 1, n + 1))
    assert np.max(np.abs(q - pred[n])) < 0.1 * one_period
    A, B, K, ur = loop
    Acl = A + np.outer(B, K)                                     # undelayed continuous loop, in modal form
    x_ss = -np.linalg.solve(Acl, B * ur)                         # (expm of Acl, |Acl| ~ 3e7 1/s, loses it)
    lam, V = np.linalg.eig(Acl)
    q_cont = (x_ss - V @ (np.exp(lam * t_final) * np.linalg.solve(V, x_ss))).real[0]
    assert q[-1] < 0.1 * q_cont                                   # much slower (REPRODUCTIONS.md: 0.013 vs 0.30)


def test_impedance_steady_state_is_disturbance_over_stiffness():
    """Fig 15.16: steady deflection = tau_ext / Kp,imp (closed loop linearised by Drake, observer on)."""
    g = ImpedanceBacksteppingGains()
    for kp in ImpedanceStudy().stiffness_values:
        dq = impedance_steady_state(table_15_1_rig(), g.replace(stiffness=kp), 0.2)
        assert dq == pytest.approx(0.2 / kp, rel=1e-6)


def _nonlinear_impedance_loop():
    """Sec 15.4.3 rig (lever-spring pair) and nonlinear controller with an ideal load sensor."""
    ns = NonlinearImpedanceStudy()
    rig = with_external_torque_sensor(table_15_1_rig(spring="nonlinear"))
    g = ImpedanceBacksteppingGains(stiffness=ns.stiffness, damping=ns.damping, k3=ns.k3, k4=ns.k4)
    return ns, rig, g, closed_loop(rig, impedance_controller(rig, g, external_torque="input"), rate_hz=None)


def test_nonlinear_impedance_holds_load_at_load_over_kp():
    """Fig 15.19/15.20: under the 0.5 Nm load the nonlinear-spring loop rests at q = r + load / Kp,imp
    (the impedance law (15.54)), with spring deflection phi^-1(-load); that equilibrium is exponentially
    stable and its local compliance dq/dtau_ext is 1 / Kp,imp although the spring stiffens (Drake Linearize)."""
    ns, rig, g, loop = _nonlinear_impedance_loop()
    q_ss = ns.step + ns.disturbance / ns.stiffness
    op = rig.operating_point(joint_angle=q_ss, external_torque=ns.disturbance)
    assert op.joint_stiffness > 1.1 * float(np.ravel(rig.spring.stiffness(np.array([0.0])))[0])  # load stiffens
    ctx = loop.create_context(op, references={"joint_angle_reference": ns.step})
    xdot = loop.diagram.EvalTimeDerivatives(ctx).CopyToVector()
    assert np.max(np.abs(xdot)) < 1e-6
    lin = Linearize(loop.diagram, ctx, input_port_index=loop.diagram.GetInputPort("external_torque").get_index(),
                    output_port_index=loop.diagram.GetOutputPort("joint_angle").get_index(),
                    equilibrium_check_tolerance=1e-6)
    assert np.max(np.linalg.eigvals(lin.A()).real) < 0
    compliance = float((lin.C() @ -np.linalg.solve(lin.A(), lin.B()))[0, 0])
    assert compliance == pytest.approx(1.0 / ns.stiffness, rel=1e-6)


def test_load_step_jumps_impedance_command_by_closed_form():
    """Why the Fig 15.19 run leaves its yield for tens of rad after the load: a step dtau in the measured load
    enters qdd and qddd of (15.62), so the command jumps by
    du = B dtau / (phi' m) (phi' - 1 - Kp - (K3 + K4) Kd + Kd b_q / m) (derived from (15.54)-(15.63));
    with Table 15.1 (m = 7.2e-7 kg m^2) that is ~1e4 times the holding torque."""
    ns, rig, g, loop = _nonlinear_impedance_loop()
    model = joint_model(rig)
    x = np.array([ns.step, 0.0, ns.step, 0.0])
    r = np.array([ns.step, 0.0, 0.0, 0.0, 0.0])
    du = (impedance_backstepping(x, r, model, g, ns.disturbance)[0] - impedance_backstepping(x, r, model, g, 0.0)[0])[0]
    k = float(np.ravel(rig.spring.stiffness(np.array([0.0])))[0])
    m, b, bq = model.link_inertia, model.motor_inertia[0], model.link_damping
    closed = b * ns.disturbance / (k * m) * (k - 1 - g.stiffness - (g.k3 + g.k4) * g.damping + g.damping * bq / m)
    assert du == pytest.approx(closed, rel=1e-9)
    assert load_step_command_jump(ns) == pytest.approx(closed, rel=1e-9)   # what the study reports
    assert du > 5e3 * ns.disturbance


def test_impedance_simulation_is_the_exact_linear_response_and_deflects_by_disturbance_over_stiffness():
    """Step then load on the Table 15.1 joint (linear, ideal torque sensor): the simulated link angle is the
    exact response of Drake's ``Linearize`` of the loop (matrix exponentials over the piecewise-constant
    inputs), whose steady deflection is disturbance / Kp,imp.  Tolerance: the variable-step integrator keeps
    each step's local error under ``accuracy`` (1e-6, ``run_loop``) relative; on this stable loop the global
    error is at most their sum over the t_final / max_step steps."""
    from scipy.linalg import expm
    s = ImpedanceStudy().replace(step_time=0.05, disturbance_time=0.2, duration=0.35)
    run = impedance_study("stiffness", s, values=(0.5,))[0]
    rig = with_external_torque_sensor(table_15_1_rig())
    g = ImpedanceBacksteppingGains(stiffness=0.5, damping=s.stiffness_fixed_damping)
    loop = closed_loop(rig, impedance_controller(rig, g, external_torque="input"), rate_hz=None)
    ctx = loop.create_context(state=rig.operating_point().state)
    lin = {p: linearize(loop.diagram, context=ctx, input=p, outputs=("joint_angle",))
           for p in ("joint_angle_reference", "external_torque")}
    A, C = lin["external_torque"].A, lin["external_torque"].C
    x_eq = lambda r, d: -np.linalg.solve(A, (lin["joint_angle_reference"].B * r + lin["external_torque"].B * d).ravel())  # noqa: E731
    x_step = x_eq(s.step, 0.0) + expm(A * (s.disturbance_time - s.step_time)) @ (0.0 - x_eq(s.step, 0.0))
    q_lin = []
    for t in run.t:
        if t <= s.step_time:
            q_lin.append(0.0)
        elif t <= s.disturbance_time:
            q_lin.append((C @ (x_eq(s.step, 0.0) + expm(A * (t - s.step_time)) @ -x_eq(s.step, 0.0)))[0])
        else:
            xe = x_eq(s.step, s.disturbance)
            q_lin.append((C @ (xe + expm(A * (t - s.disturbance_time)) @ (x_step - xe)))[0])
    q_lin = np.array(q_lin)
    tol = s.duration / 1e-3 * 1e-6 * np.max(np.abs(q_lin))      # max_step 1e-3, accuracy 1e-6 (run_loop)
    assert np.max(np.abs(run.q - run.q[0] - q_lin)) <= tol
    assert (C @ (x_eq(s.step, s.disturbance) - x_eq(s.step, 0.0)))[0] == pytest.approx(s.disturbance / 0.5,
                                                                                         rel=1e-8)
    assert np.max(q_lin) > 10.0 * s.disturbance / 0.5                # the 7.2e-7 kg m^2 link is thrown far first
    assert is_monotone_nonincreasing(run.lyapunov[(run.t > 0.06) & (run.t < s.disturbance_time)], rtol=1e-4)


def test_antagonistic_step_and_impedance_check():
    run = antagonistic_step(t_final=0.8)
    assert run.q[-1] == pytest.approx(math.radians(30.0), abs=1e-4)
    assert np.all(run.tendon_force > 0)                      # no slack with the pretension
    assert is_monotone_nonincreasing(run.lyapunov[run.t > 0.051], rtol=1e-4)
    # Fig 15.27: the tendon torque under an imposed deflection is proportional to Kp,imp
    kp = np.array([0.01, 0.02, 0.05, 0.1])
    d = antagonistic_stiffness_check(kp, deflection=0.3)
    np.testing.assert_allclose(d.torque, kp * 0.3, rtol=1e-6)


def _sampled_period_map_radius(controller_factory, rate_hz=3000.0):
    """Spectral radius of the one-period map of ``closed_loop(joint_rig(), controller, rate_hz)`` at rest: the
    Jacobian of x(t_k) -> x(t_k+1) (zero-order-held command, the rig and the controller's continuous observer
    integrated by Drake's Simulator in AutoDiffXd, fixed RK3 steps of h/16; h/8 and h/32 give the same
    |z| to 1e-4).  ``sampled_loop_poles`` needs a fully sampled controller; this one's observer (9.2) is continuous."""
    from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue, InitializeAutoDiff
    from pydrake.systems.analysis import Simulator_
    rig = joint_rig()
    loop = closed_loop(rig, controller_factory(rig), rate_hz=rate_hz)
    op = rig.operating_point()
    ctx = loop.create_context(op, references={"joint_angle_reference": op.joint_angle})
    groups = range(ctx.num_discrete_state_groups())

    def flat(c):
        return np.concatenate([c.get_continuous_state_vector().CopyToVector()]
                              + [c.get_discrete_state(i).CopyToVector() for i in groups])
    x0 = flat(ctx)
    diagram = loop.diagram.ToAutoDiffXd()
    c_ad = diagram.CreateDefaultContext()
    c_ad.SetTimeStateAndParametersFrom(ctx)
    for i in range(loop.diagram.num_input_ports()):
        diagram.get_input_port(i).FixValue(c_ad, loop.diagram.get_input_port(i).Eval(ctx))
    xa = InitializeAutoDiff(x0)[:, 0]
    nc = ctx.num_continuous_states()
    c_ad.SetContinuousState(xa[:nc])
    k = nc
    for i in groups:
        m = ctx.get_discrete_state(i).size()
        c_ad.SetDiscreteState(i, xa[k:k + m])
        k += m
    h = 1.0 / rate_hz
    sim = Simulator_[AutoDiffXd](diagram, c_ad)
    integrator = sim.get_mutable_integrator()
    integrator.set_maximum_step_size(h / 16)
    integrator.request_initial_step_size_target(h / 16)
    integrator.set_fixed_step_mode(True)
    sim.Initialize()
    sim.AdvanceTo(h)
    x1 = flat(sim.get_context())
    assert np.max(np.abs(ExtractValue(x1).ravel() - x0)) < 1e-12      # the operating point is a fixed point
    return float(np.max(np.abs(np.linalg.eigvals(ExtractGradient(x1)))))


def test_registered_joint_rig_backstepping_is_stable_at_3khz_and_unstable_without_the_damping_limit():
    """Issue 10 item 6 ("saturates and does not move" at 3 kHz): the cause was the impedance damping's link pole
    -Kd,imp/m outside what a 3 kHz zero-order hold can follow (control/catalog.py, Kd,imp <= m f_s/4).
    The registered controller's sampled loop at the thesis's 3 kHz has all poles inside the unit circle (measured
    0.993); with the limit removed (the parameter default Kd,imp = 0.01 Nm s/rad, h Kd/m = 4.6) the same loop
    has a pole outside (measured 1.81): the test fails if the cause comes back."""
    from awiwi_drake.control.backstepping import impedance_controller
    from awiwi_drake.control.registry import get_entry, make_controller
    from awiwi_drake.parameters.backstepping import AntagonisticBacksteppingGains
    assert get_entry("backstepping", joint_rig()).loop_options["rate_hz"] == 3000.0
    assert _sampled_period_map_radius(lambda rig: make_controller("backstepping", rig)) < 1.0
    g = AntagonisticBacksteppingGains()
    assert g.damping > joint_rig().params.link_inertia * 3000.0 / 4.0        # the limit is active
    assert _sampled_period_map_radius(lambda rig: impedance_controller(rig, g)) > 1.0
