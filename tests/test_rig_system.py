"""The single-joint rig as C++ systems: SymbolicVectorSystem dynamics = the law functions,
scalar conversion, lean ports (no feedthrough into the state path)."""

import numpy as np
import pytest

from awiwi_drake.components import antagonistic_coupling, tendon_spring
from awiwi_drake.components.fused_drive import DriveModel, build_kernels, drive_laws
from awiwi_drake.components.rig_system import LinkRigOutputs_, rig_dynamics_system
from awiwi_drake.parameters import HysteresisParams, MotorParams, SpringModelParams
from awiwi_drake.rigs import flexible_joint_rig, joint_rig
from _fd import assert_symbolic_matches_float, check_system_autodiff_matches_fd, fd_jacobian

RNG = np.random.default_rng(11)


def _model(hysteresis: bool, saturation: bool = True):
    motor = MotorParams(friction=True, ripple=True, saturation=saturation)
    return DriveModel(motor, (tendon_spring(SpringModelParams()),) * 2, antagonistic_coupling(0.008), np.zeros(2),
                      motor.pulley_radius, HysteresisParams(enabled=hysteresis),
                      link_inertia=(7e-5,), link_damping=(1e-3,))


def _random_state(model):
    x = RNG.normal(scale=0.2, size=model.num_states)
    x[2:4] = RNG.uniform(-0.3, 1.8, size=2)          # slack, inside and beyond the calibrated range
    x[4:6] = RNG.normal(scale=3.0, size=2)
    if model.has_hysteresis:
        x[6:8] = RNG.normal(scale=5.0, size=2)
    return x


@pytest.mark.parametrize("hysteresis", [False, True])
def test_symbolic_dynamics_equal_the_laws_and_the_kernel_at_random_states(hysteresis):
    model = _model(hysteresis)
    svs = rig_dynamics_system(model)
    kernel = build_kernels(model, jit=False)["derivatives"]
    ctx = svs.CreateDefaultContext()
    for _ in range(20):
        x = _random_state(model)
        u = RNG.normal(scale=2.0, size=2)          # beyond the torque limit too (saturation inside)
        e = RNG.normal(scale=0.05, size=1)
        ctx.SetContinuousState(x)
        svs.get_input_port().FixValue(ctx, np.r_[u, e])
        got = svs.EvalTimeDerivatives(ctx).CopyToVector()
        laws = drive_laws(model, x, u, tau_ext=e)["derivatives"]
        np.testing.assert_allclose(got, laws, rtol=1e-12, atol=1e-12 * np.max(np.abs(laws)))
        np.testing.assert_allclose(kernel(x, u, e, np.empty(x.size)), laws, rtol=1e-12,
                                   atol=1e-12 * np.max(np.abs(laws)))
        np.testing.assert_array_equal(svs.get_output_port().Eval(ctx), x)   # the output is the state


@pytest.mark.parametrize("hysteresis", [False, True])
def test_integration_coordinates_are_the_laws_in_momentum_and_elongation(hysteresis):
    """The sampled rig's system (state z = [q, p, x, omega, z_h]): its output is the physical state, and its dynamics
    are z' = T xdot with T the constant map x -> z (columns from integration_state) and xdot the laws, at random
    states to 1e-12; the momentum rate equals its definition I qdd - P^T B omega' / r_m evaluated on the laws'
    derivatives (in which the spring forces appear)."""
    from awiwi_drake.components.rig_system import integration_state, rig_integration_system
    model = _model(hysteresis)
    svs = rig_integration_system(model)
    ctx = svs.CreateDefaultContext()
    n_x = model.num_states
    T = np.column_stack([integration_state(model, e) - integration_state(model, 0 * e) for e in np.eye(n_x)])
    P, I, B, r = np.array([[-0.008], [0.008]]), 7e-5, model.motor.inertia, model.motor_pulley_radius
    for _ in range(20):
        x = _random_state(model)
        u, e = RNG.normal(scale=2.0, size=2), RNG.normal(scale=0.05, size=1)
        z = integration_state(model, x)
        np.testing.assert_allclose(z, T @ x + integration_state(model, 0 * x), rtol=1e-13, atol=1e-15)   # affine map
        ctx.SetContinuousState(z)
        svs.get_input_port().FixValue(ctx, np.r_[u, e])
        xdot = drive_laws(model, x, u, tau_ext=e)["derivatives"]
        got = svs.EvalTimeDerivatives(ctx).CopyToVector()
        np.testing.assert_allclose(got, T @ xdot, rtol=1e-12, atol=1e-12 * np.max(np.abs(T @ xdot)))
        p_rate = I * xdot[1] - (P.T @ (B * xdot[4:6]) / r)[0]
        assert got[1] == pytest.approx(p_rate, rel=1e-9, abs=1e-12 * np.max(np.abs(T @ xdot)))
        np.testing.assert_allclose(svs.get_output_port().Eval(ctx), x, rtol=1e-12, atol=1e-12)   # physical state


def test_outputs_system_equals_the_laws_and_converts_with_autodiff_equal_to_finite_differences():
    model = _model(hysteresis=True)
    outs = LinkRigOutputs_[float](model)
    ctx = outs.CreateDefaultContext()
    x, u = _random_state(model), RNG.normal(scale=2.0, size=2)
    assert_symbolic_matches_float(outs, [], dict(state=x, motor_torque=u))   # Expression path = float kernel
    outs.GetInputPort("state").FixValue(ctx, x)
    outs.GetInputPort("motor_torque").FixValue(ctx, u)
    laws = drive_laws(model, x, u)
    for port, law in (("tendon_force", "tendon_force"), ("tendon_stiffness", "tendon_stiffness"),
                      ("joint_torque", "generalized_force"), ("applied_torque", "applied_torque")):
        np.testing.assert_allclose(outs.GetOutputPort(port).Eval(ctx), laws[law], rtol=1e-12, atol=1e-12, err_msg=port)
    lim = model.motor.torque_limit                   # (3.5) saturation, closed form
    np.testing.assert_array_equal(outs.GetOutputPort("applied_torque").Eval(ctx), np.clip(u, -lim, lim))
    x[2:4] = [0.9, 0.8]                               # springs stretched, away from the clamp knees
    x[4:6] *= 0.1
    check_system_autodiff_matches_fd(outs, [], dict(state=x, motor_torque=0.1 * u), rtol=2e-5)


@pytest.mark.parametrize("build", [joint_rig, flexible_joint_rig])
def test_default_single_joint_rig_is_scalar_convertible_and_autodiff_matches_fd(build):
    rig = build()
    assert rig.plant is None
    d = rig.diagram
    op = rig.operating_point()
    x = op.state + RNG.normal(scale=0.01, size=op.state.size)
    assert_symbolic_matches_float(d, x, dict(motor_torque=op.motor_torque, external_torque=np.array([0.01])))
    check_system_autodiff_matches_fd(d, x, dict(motor_torque=op.motor_torque, external_torque=np.array([0.01])),
                                     rtol=2e-5)


def test_state_path_has_no_direct_feedthrough():
    """Continuous feedthrough controllers (LQR with D != 0) close on the state outputs without
    an algebraic loop; only applied_torque depends on the command directly."""
    d = joint_rig().diagram
    u, e = d.GetInputPort("motor_torque").get_index(), d.GetInputPort("external_torque").get_index()
    for i in range(d.num_output_ports()):
        name = d.get_output_port(i).get_name()
        expect = name == "applied_torque"
        assert d.HasDirectFeedthrough(u, i) == expect, name
        assert not d.HasDirectFeedthrough(e, i), name


# --- the rig sampled at the control period (Drake's DiscreteTimeApproximation) ------------------------
H = 1.0 / 3000


def _demo_loop(rig, sampled_rig, delay=None):
    from pydrake.systems.primitives import TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    from awiwi_drake.control import closed_loop
    from awiwi_drake.control.motor_position import demo_references, motor_position_controller
    from awiwi_drake.parameters.rigs import DemoScenario
    scen = DemoScenario(t_final=0.12, ramp_time=0.04, step_time=0.06)
    t, refs = demo_references(rig, scen)
    sources = {k: TrajectorySource(PiecewisePolynomial.FirstOrderHold(t, refs[r]))
               for k, r in (("motor_angle_reference", "theta_reference"),
                            ("tendon_force_reference", "tendon_force_reference"))}
    loop = closed_loop(rig, motor_position_controller(rig), rate_hz=1 / H, delay=delay, sources=sources,
                       sampled_rig=sampled_rig)
    return loop, rig.operating_point(pretension=scen.f_start), scen


@pytest.mark.parametrize("delay_periods", [0, 1, 2])
def test_sampled_rig_loop_is_the_continuous_loop_under_fixed_step_rk3_to_round_off(delay_periods):
    """The sampled loop (rig as DiscreteTimeApproximation, RK3, one step per period) against the continuous rig
    behind the hold under simulate's fixed-step RK3 at the period: the same arithmetic, so equal to round-off, with
    the pretension ramp, the step transient, saturation and a round-trip delay; every logged signal at the same
    times, the held command and the applied torque included."""
    from awiwi_drake.analysis import rig_monitors, simulate
    from awiwi_drake.analysis.simulate import sampled_plants
    runs = {}
    for sampled in (False, True):
        rig = joint_rig()
        loop, op, scen = _demo_loop(rig, sampled, delay=delay_periods * H or None)
        assert loop.sampled_rig is sampled and bool(sampled_plants(loop.diagram)) is sampled
        ctx = loop.create_context(op)
        runs[sampled] = simulate(loop.diagram, ctx, scen.t_final, monitors=rig_monitors(rig),
                                 log=("state", "motor_torque", "applied_torque", "tendon_force"))
    cont, samp = runs[False], runs[True]
    assert samp.info["mode"] == cont.info["mode"] == "fixed_step" and samp.info["step"] == pytest.approx(H)
    np.testing.assert_allclose(samp.t, cont.t, rtol=0, atol=1e-12)
    x = cont["state"]
    assert np.ptp(x[:, 0]) > 0.05                    # the link moved (the step), so the comparison means something
    err = np.max(np.abs(samp["state"] - x), axis=0) / np.max(np.abs(x), axis=0)
    assert np.all(err < 1e-11), err
    for name in ("motor_torque", "applied_torque", "tendon_force"):
        ref = cont[name]
        np.testing.assert_allclose(samp[name], ref, rtol=0, atol=1e-9 * np.max(np.abs(ref)), err_msg=name)
    assert [(e.kind, e.channel) for e in samp.events] == [(e.kind, e.channel) for e in cont.events]
    # the rig's state at the end (the sampled rig integrates in other coordinates: round-off on each state's scale)
    np.testing.assert_allclose(samp.final_state, cont.final_state, rtol=0, atol=1e-11 * np.max(np.abs(x)))
    assert any(e.kind == "actuator_saturation" for e in cont.events)    # the step saturates the motors


def _linearizations(rig, op):
    """``(A, B)`` of Drake's Linearize of the continuous rig, ``(Ad, Bd)`` of the sampled rig (with its period) and
    ``(Ad_rk3, Bd_rk3)``: the RK3 step of (A, B) in closed form, I + hA + (hA)^2/2 + (hA)^3/6 and
    h (I + hA/2 + (hA)^2/6) B."""
    from pydrake.systems.primitives import Linearize

    def lin(d, ctx, tol):
        return Linearize(d, ctx, input_port_index=d.GetInputPort("motor_torque").get_index(),
                         output_port_index=d.GetOutputPort("state").get_index(), equilibrium_check_tolerance=tol)
    cont = lin(rig.diagram, rig.context(op), 1e-6)
    sampled = rig.sampled_diagram(H)
    ctx = sampled.CreateDefaultContext()
    ctx.SetDiscreteState(0, rig.sampled_state(op.state))
    sampled.GetInputPort("motor_torque").FixValue(ctx, op.motor_torque)
    sampled.GetInputPort("external_torque").FixValue(ctx, op.external_torque)
    disc = lin(sampled, ctx, 1e-9)
    assert disc.time_period() == pytest.approx(H)
    # the sampled rig integrates in other coordinates z and outputs the physical state x = C z (C from Drake's
    # Linearize of that output, D = 0): in x, A_d = C A_z C^-1 and B_d = C B_z
    C = np.array(disc.C())
    np.testing.assert_array_equal(np.array(disc.D()), 0.0)
    Ad, Bd = C @ np.array(disc.A()) @ np.linalg.inv(C), C @ np.array(disc.B())
    A, B = np.array(cont.A()), np.array(cont.B())
    hA = H * A
    rk3 = (np.eye(6) + hA + hA @ hA / 2 + hA @ hA @ hA / 6, H * (np.eye(6) + hA / 2 + hA @ hA / 6) @ B)
    return (A, B), (Ad, Bd), rk3


def test_sampled_rig_linearization_is_the_rk3_step_of_the_continuous_linearization():
    """At an equilibrium every RK3 stage sits at the operating point, so Drake's Linearize of the sampled rig (with
    its period) is exactly the RK3 step of the continuous linearisation (A, B): A_d = I + hA + (hA)^2/2 + (hA)^3/6,
    B_d = h (I + hA/2 + (hA)^2/6) B."""
    rig = joint_rig()
    _, (Ad, Bd), (Ad_rk3, Bd_rk3) = _linearizations(rig, rig.operating_point(pretension=25.0, joint_angle=0.1))
    np.testing.assert_allclose(Ad, Ad_rk3, rtol=0, atol=1e-10 * np.max(np.abs(Ad_rk3)))
    np.testing.assert_allclose(Bd, Bd_rk3, rtol=0, atol=1e-10 * np.max(np.abs(Bd_rk3)))
    # the sampled step is stable where the continuous rig is (RK3 inside its stability region at 3 kHz)
    assert np.max(np.abs(np.linalg.eigvals(Ad_rk3))) <= 1 + 1e-12


def test_discrete_lqr_on_the_sampled_rig_is_the_discrete_riccati_solution_and_stabilises_it():
    """Drake's DiscreteTimeLinearQuadraticRegulator on the sampled rig's linearisation equals scipy's discrete
    Riccati gain on the closed-form RK3 matrices of the continuous linearisation, and the sampled loop's spectral
    radius is below 1."""
    from pydrake.systems.controllers import DiscreteTimeLinearQuadraticRegulator
    from scipy.linalg import solve_discrete_are
    rig = joint_rig()
    _, (Ad, Bd), (Ad_rk3, Bd_rk3) = _linearizations(rig, rig.operating_point(pretension=20.0))
    Q, R = np.diag([100.0, 1.0, 1.0, 1.0, 0.01, 0.01]), np.eye(2)
    K, S = DiscreteTimeLinearQuadraticRegulator(Ad, Bd, Q, R)
    P = solve_discrete_are(Ad_rk3, Bd_rk3, Q, R)
    K_ref = np.linalg.solve(R + Bd_rk3.T @ P @ Bd_rk3, Bd_rk3.T @ P @ Ad_rk3)
    np.testing.assert_allclose(K, K_ref, rtol=1e-6, atol=1e-9 * np.max(np.abs(K_ref)))
    assert np.max(np.abs(np.linalg.eigvals(Ad - Bd @ K))) < 1.0


def test_sampled_rig_converts_to_autodiff_and_its_update_matches_finite_differences():
    """The sampled rig's discrete update (the RK3 step) in AutoDiffXd equals central differences of the float
    update at a non-equilibrium state."""
    rig = joint_rig()
    sampled = rig.sampled_diagram(H)
    ad = sampled.ToAutoDiffXd()
    op = rig.operating_point(pretension=25.0)
    x0 = op.state + np.array([0.02, 0.5, 0.01, -0.01, 1.0, -2.0])
    u0 = op.motor_torque + 0.1

    x0 = rig.sampled_state(x0)                       # the sampled rig's own (integration) coordinates

    def step(x):
        ctx = sampled.CreateDefaultContext()
        ctx.SetDiscreteState(0, x)
        sampled.GetInputPort("motor_torque").FixValue(ctx, u0)
        sampled.GetInputPort("external_torque").FixValue(ctx, [0.01])
        return sampled.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).CopyToVector()

    from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff
    actx = ad.CreateDefaultContext()
    actx.SetDiscreteState(0, InitializeAutoDiff(x0).ravel())
    ad.GetInputPort("motor_torque").FixValue(actx, u0)
    ad.GetInputPort("external_torque").FixValue(actx, np.array([0.01]))
    out = ad.EvalUniquePeriodicDiscreteUpdate(actx).get_vector(0).CopyToVector()
    np.testing.assert_allclose(ExtractValue(out).ravel(), step(x0), rtol=1e-14, atol=1e-15)
    J = ExtractGradient(out)
    J_fd = fd_jacobian(step, x0, h=1e-6)
    np.testing.assert_allclose(J, J_fd, rtol=1e-5, atol=1e-7 * np.max(np.abs(J_fd)))


def test_sampled_rig_is_used_only_where_it_is_the_same_loop():
    """Continuous loops, loops whose controller has continuous state (it would read a staircase) and
    sampled_rig=False keep the continuous rig; simulate refuses error control on a sampled rig with one line."""
    from awiwi_drake.analysis import simulate
    from awiwi_drake.control import closed_loop
    from awiwi_drake.control.motor_position import motor_position_controller
    rig = joint_rig()
    assert not closed_loop(rig, motor_position_controller(rig), rate_hz=None).sampled_rig
    rig = joint_rig()
    assert not closed_loop(rig, motor_position_controller(rig), sampled_rig=False).sampled_rig
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import Integrator, PassThrough
    b = DiagramBuilder()        # a controller with a continuous state (an integrator on a spare signal)
    inner = b.AddSystem(motor_position_controller(rig))
    integ = b.AddSystem(Integrator(1))
    for i in range(inner.num_input_ports()):
        b.ExportInput(inner.get_input_port(i), inner.get_input_port(i).get_name())
    b.ExportOutput(inner.GetOutputPort("motor_torque"), "motor_torque")
    spare = b.AddSystem(PassThrough(1))
    b.Connect(spare.get_output_port(), integ.get_input_port())
    b.ExportInput(spare.get_input_port(), "spare_reference")
    b.ExportOutput(integ.get_output_port(), "spare")
    ctrl = b.Build()
    loop = closed_loop(joint_rig(), ctrl)
    assert not loop.sampled_rig
    rig = joint_rig()
    loop, op, scen = _demo_loop(rig, True)
    with pytest.raises(ValueError, match="mode = 'error_controlled'.*sampled plant.*sampled_rig=False"):
        simulate(loop.diagram, loop.create_context(op), 0.01, mode="error_controlled")
    with pytest.raises(ValueError, match="step = .*sampled plant"):
        simulate(loop.diagram, loop.create_context(op), 0.01, mode="fixed_step", step=H / 2)
    with pytest.raises(ValueError, match="integrator = 'runge_kutta2'.*sampled plant"):
        simulate(loop.diagram, loop.create_context(op), 0.01, integrator="runge_kutta2")
    res = simulate(loop.diagram, loop.create_context(op), 0.05)      # 0.05 s: 150 periods up to round-off
    assert res.t[-1] == 150 * H and res.info["t_final"] == 150 * H


def test_sampled_batch_equals_the_continuous_batch_behind_a_hold_to_round_off():
    """Three batched joint rigs under a C++ motor PD (a matrix gain on the batch state plus a constant): the batch as
    one DiscreteTimeApproximation at 3 kHz reading the PD at the sample instant, against the continuous batch
    behind a zero-order hold under fixed-step RK3 at the period (analysis.simulate's default) -- the same
    trajectories to round-off, each copy moving (different set points)."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import Adder, ConstantVectorSource, MatrixGain, ZeroOrderHold

    from awiwi_drake.analysis import simulate
    from awiwi_drake.rigs.batch import batched_joint_rig
    N = 3
    ends = {}
    for sampled in (False, True):
        br = batched_joint_rig(N)
        ops = [br.single.operating_point(pretension=f) for f in (15.0, 25.0, 35.0)]
        K = np.zeros((2 * N, 6 * N))
        theta_ref = np.concatenate([op.state[2:4] + d for op, d in zip(ops, (0.05, -0.05, 0.1))])
        for i in range(2 * N):
            K[i, 6 * (i // 2) + 2 + i % 2], K[i, 6 * (i // 2) + 4 + i % 2] = -40.0, -0.4
        u0 = np.concatenate([op.motor_torque for op in ops]) + 40.0 * theta_ref
        b = DiagramBuilder()
        plant = b.AddSystem(br.sampled_diagram(H) if sampled else br.diagram)
        gain, const = b.AddSystem(MatrixGain(K)), b.AddSystem(ConstantVectorSource(u0))
        add = b.AddSystem(Adder(2, 2 * N))
        b.Connect(plant.GetOutputPort("state"), gain.get_input_port())
        b.Connect(gain.get_output_port(), add.get_input_port(0))
        b.Connect(const.get_output_port(), add.get_input_port(1))
        cmd = add.get_output_port()
        if not sampled:
            hold = b.AddSystem(ZeroOrderHold(H, 2 * N))
            b.Connect(cmd, hold.get_input_port())
            cmd = hold.get_output_port()
        b.Connect(cmd, plant.GetInputPort("motor_torque"))
        b.ExportInput(plant.GetInputPort("external_torque"), "external_torque")
        b.ExportOutput(plant.GetOutputPort("state"), "state")
        d = b.Build()
        ctx = d.CreateDefaultContext()
        x, u, e = br.stack(ops)
        pctx = plant.GetMyMutableContextFromRoot(ctx)
        pctx.SetDiscreteState(0, x) if sampled else pctx.SetContinuousState(x)
        d.GetInputPort("external_torque").FixValue(ctx, e)
        res = simulate(d, ctx, 0.03, log=("state",))
        assert res.info["step"] == pytest.approx(H)
        ends[sampled] = res["state"]
    moved = np.ptp(ends[False][:, [6 * i + 2 for i in range(N)]], axis=0)
    assert np.all(moved > 0.01), moved                                  # every copy's motor moved to its set point
    np.testing.assert_allclose(ends[True], ends[False], rtol=0, atol=1e-11 * np.max(np.abs(ends[False])))


@pytest.mark.parametrize("name", ["pd", "pole-placement"])
def test_registered_controllers_on_the_sampled_flexible_joint_equal_the_continuous_rig(name):
    """The flexible joint (12.8) under registered joint controllers at 3 kHz: the sampled rig (the default) and the
    continuous rig behind the hold give the same trajectory through a reference step, to 1e-8 of each signal's
    range: the same RK3 step in coordinates related by a constant linear map, so round-off apart, amplified by that
    map's conditioning (the link velocity is recovered from the momentum I qdot + B thetadot, B/I = 5000: ~3.7 digits)
    and accumulated by the loop, which amplifies round-off (measured: a 1e-15 rad/s change of the initial motor
    velocity alone moves the continuous loop by 3e-11 of the range over these 150 periods); 1e-8 is over 100x below
    the step's RK3 error against a tight reference (README "How the plants are built, and speed")."""
    from awiwi_drake.analysis import simulate
    from awiwi_drake.analysis.schedules import Step
    from awiwi_drake.control import closed_loop
    from awiwi_drake.control.registry import get_entry
    out = {}
    for sampled in (False, True):
        rig = flexible_joint_rig()
        entry = get_entry(name, rig)
        loop = closed_loop(rig, entry.factory(rig), **{**entry.loop_options, "rate_hz": 1 / H}, sampled_rig=sampled)
        assert loop.sampled_rig is sampled
        ctx = loop.create_context(rig.operating_point())
        # 150 periods: H * 150 is the sample instant itself (0.05 is 1 ulp past it: the continuous run would log
        # the next period's held command after a 1e-17 s step there)
        out[sampled] = simulate(loop.diagram, ctx, 150 * H, inputs={"joint_angle_reference": Step(0.01, 0.1)},
                                log=("state", "motor_torque"))
    x = out[False]["state"]
    assert np.ptp(x[:, 0]) > 0.01                                      # the link followed the step
    for sig in ("state", "motor_torque"):
        ref = out[False][sig]
        np.testing.assert_allclose(out[True][sig], ref, rtol=0, atol=1e-8 * np.max(np.abs(ref)), err_msg=sig)


def test_motor_pd_with_its_reference_is_the_loop_with_reference_sources():
    """The demo loop's PD given its reference (one TrajectoryAffineSystem, u = y0(t) + D x) against the same PD
    with reference ports fed by TrajectorySources: the law at random times and states is the closed form
    r_m f_ref(t) + kp (theta_ref(t) - theta) - kd omega (references linear between knots); the two loops
    simulate the same trajectory (the feed-forward kp theta_ref + r_m f_ref is combined at the knots instead
    of after interpolation: round-off, bounded here by the sampled-vs-continuous test's 1e-11 of each channel's
    scale); the loop and the law convert to AutoDiffXd, the law's gradient being the PD gains."""
    from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

    from awiwi_drake.analysis import simulate
    from awiwi_drake.control.motor_position import demo_references, joint_rig_position_loop, motor_position_controller
    from awiwi_drake.parameters.rigs import MotorPositionGains
    rig = joint_rig()
    loop_src, op, scen = _demo_loop(rig, True)
    t, refs = demo_references(rig, scen)
    g, r_m = MotorPositionGains(), rig.params.motor.pulley_radius
    law = motor_position_controller(joint_rig(), reference=(t, refs["theta_reference"], refs["tendon_force_reference"]))
    assert [law.get_input_port(i).get_name() for i in range(law.num_input_ports())] == ["state"]
    ctx = law.CreateDefaultContext()
    rng = np.random.default_rng(3)
    for _ in range(5):
        tk, xk = rng.uniform(0, scen.t_final), op.state + rng.normal(0, 0.1, 6)
        ctx.SetTime(tk)
        law.GetInputPort("state").FixValue(ctx, xk)
        th = np.array([np.interp(tk, t, row) for row in refs["theta_reference"]])
        f = np.array([np.interp(tk, t, row) for row in refs["tendon_force_reference"]])
        np.testing.assert_allclose(law.GetOutputPort("motor_torque").Eval(ctx),
                                   r_m * f + g.kp * (th - xk[2:4]) - g.kd * xk[4:6], rtol=1e-12, atol=1e-12)
    rig = joint_rig()
    loop = joint_rig_position_loop(rig, scen)
    assert loop.references == () and loop.sampled_rig
    # a plain diagram controller of a sampled rig enters the loop as its leaves (no sub-diagram): one leaf is
    # "controller", several "controller.<leaf>"
    assert type(loop.diagram.GetSubsystemByName("controller")).__name__ == "TrajectoryAffineSystem"
    assert {"controller.motor_position_inputs", "controller.motor_position_law"} <= {
        s.get_name() for s in loop_src.diagram.GetSystems()}
    runs = [simulate(lp.diagram, lp.create_context(op), scen.t_final, log=("state", "motor_torque", "applied_torque"))
            for lp in (loop_src, loop)]
    x = runs[0]["state"]
    assert np.ptp(x[:, 0]) > 0.05
    for name in ("state", "motor_torque", "applied_torque"):
        ref = runs[0][name]
        err = np.max(np.abs(runs[1][name] - ref), axis=0) / np.max(np.abs(ref), axis=0)   # per channel's scale
        assert runs[1][name].shape == ref.shape and np.all(err < 1e-11), (name, err)
    assert loop.diagram.ToAutoDiffXd() is not None
    ad = law.ToAutoDiffXd()             # the law in AutoDiffXd: same value, gradient -D on the state
    ad_ctx = ad.CreateDefaultContext()
    ad_ctx.SetTime(tk)
    ad.GetInputPort("state").FixValue(ad_ctx, InitializeAutoDiff(xk))
    u_ad = ad.GetOutputPort("motor_torque").Eval(ad_ctx)
    np.testing.assert_allclose(ExtractValue(u_ad).ravel(), law.GetOutputPort("motor_torque").Eval(ctx), rtol=1e-14)
    D = np.zeros((2, 6))
    D[:, 2:4], D[:, 4:6] = -g.kp * np.eye(2), -g.kd * np.eye(2)
    np.testing.assert_array_equal(ExtractGradient(u_ad), D)
    with pytest.raises(ValueError, match="reference motor_angle has shape"):
        motor_position_controller(joint_rig(), reference=(t, refs["theta_reference"][:1], refs["tendon_force_reference"]))


@pytest.mark.parametrize("hysteresis", [False, True])
def test_tendon_force_of_states_is_the_law_at_every_logged_sample(hysteresis):
    """The monitors' batch evaluation (the generated kernel in numpy's elementwise forms, all samples at once)
    equals drive_laws' tendon force sample by sample (slack, inside and beyond the calibrated range), to 1e-12 of
    the largest force; the tendon rig (no joints) too."""
    from awiwi_drake.components.rig_system import tendon_force_of_states
    from awiwi_drake.rigs import tendon_rig
    model = _model(hysteresis)
    X = np.array([_random_state(model) for _ in range(200)])
    ref = np.array([drive_laws(model, x, want=("tendon_force",))["tendon_force"] for x in X])
    assert np.any(ref == 0.0) and np.any(ref > 0.0)             # slack samples among them
    got = tendon_force_of_states(model)(X)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.max(np.abs(ref)))
    rig = tendon_rig()
    Xt = rig.operating_point().state + RNG.normal(0, 0.05, (50, rig.num_states))
    ref = np.array([drive_laws(rig.drive.model, x, np.zeros(1), np.zeros(0), want=("tendon_force",))["tendon_force"]
                    for x in Xt])
    np.testing.assert_allclose(rig.tendon_force_of_state(Xt), ref, rtol=0, atol=1e-12 * np.max(np.abs(ref)))


def test_vectorized_kernels_equal_the_scalar_source_on_every_construct():
    """codegen's numpy forms (np.where for if-then-else, np.logical_* for and/or/not, np.arctan2, the unary
    functions, min/max) evaluate arrays of samples to the plain scalar source's values at each sample (to a
    few ulp: numpy's and libm's transcendental functions may differ in the last bit)."""
    import pydrake.symbolic as sym

    from awiwi_drake.components.codegen import compile_kernels
    a, b = sym.Variable("a"), sym.Variable("b")
    outs = [sym.if_then_else(sym.logical_and(a > 0, sym.logical_not(b > 1)), sym.atan2(a, b), sym.tanh(b) * a),
            sym.if_then_else(sym.logical_or(a > 1, b < -1), sym.sqrt(a * a + 1), sym.cos(a) - sym.exp(-b * b)),
            sym.min(a, b) + sym.max(a, 0) + abs(b) ** 3 + sym.atan(a)]
    fns = {"f": ([[a, b]], outs)}
    vec = compile_kernels(fns, tag="test_vectorized", vectorized=True)["f"]
    scalar = compile_kernels(fns, tag="test_vectorized", jit=False)["f"]
    S = RNG.uniform(-3, 3, size=(2, 300))
    got = vec(S, np.empty((3, 300)))
    ref = np.array([scalar(S[:, k], np.empty(3)) for k in range(300)]).T
    # numpy's vectorised cos/exp/tanh and libm's may differ in the last bit; cos(a) - exp(-b^2) cancels
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-14 * np.max(np.abs(ref)))


def test_tendon_rig_sampled_loop_equals_its_continuous_loop():
    """The tendon rig (no link) has the sampled path too: in integration coordinates ``[x, omega]``
    (``x = r_m theta``; the motor's ripple on) its 3 kHz loop under the (10.2) force PD follows the continuous
    rig integrated by fixed-step RK3 at the period to round-off through a 20 -> 40 N step; the mapping
    ``sampled_state`` is the elongation law."""
    from awiwi_drake.analysis import Step, simulate
    from awiwi_drake.control import closed_loop, make_controller
    from awiwi_drake.parameters import MotorParams, TendonRigParams
    from awiwi_drake.rigs import tendon_rig
    p = TendonRigParams(motor=MotorParams(ripple=True))
    out = {}
    for sampled in (True, False):
        rig = tendon_rig(params=p)
        loop = closed_loop(rig, make_controller("tendon-pd", rig), sampled_rig=sampled)
        assert loop.sampled_rig == sampled
        op = rig.operating_point(tendon_force=20.0)
        ctx = loop.create_context(op, references={"tendon_force_reference": 20.0})
        out[sampled] = simulate(loop, ctx, 0.1, inputs={"tendon_force_reference": Step(0.02, 40.0, 20.0)},
                                log=("state", "tendon_force", "motor_torque"), log_period=H)
    a, b = out[True], out[False]
    assert a["state"].shape == b["state"].shape == (301, 2)
    assert abs(a["tendon_force"][-1, 0] - 40.0) < 0.5 and np.ptp(a["state"][:, 1]) > 1.0   # stepped, motor moved
    rel = np.abs(a["state"] - b["state"]) / np.abs(b["state"]).max(axis=0)     # per state, of its range
    assert rel.max() < 1e-12, rel.max(axis=0)
    np.testing.assert_allclose(a["motor_torque"], b["motor_torque"], rtol=0, atol=1e-9 * np.abs(b["motor_torque"]).max())
    x = rig.sampled_state(op.state)
    assert x[0] == pytest.approx(float(op.elongation[0]), rel=1e-14) and x[1:].tolist() == op.state[1:].tolist()


def test_a_controller_at_another_rate_keeps_the_continuous_rig():
    """The SDRE refreshes its gain at 200 Hz in a 3 kHz loop: that update can fall an ulp after the sampled rig's
    (Drake times each rate by its own period) and would read the next period's state, so such a loop keeps the
    continuous rig (tests/test_control_tendon.py's refresh test compares the gain with the state at its
    instant); the force PD at the loop's own rate gets the sampled rig."""
    from awiwi_drake.control import closed_loop, make_controller
    from awiwi_drake.rigs import flexible_joint_rig, tendon_rig
    for name, rig_of in (("tendon-sdre", tendon_rig), ("sdre", flexible_joint_rig)):
        rig = rig_of()
        assert not closed_loop(rig, make_controller(name, rig), rate_hz=3000.0).sampled_rig
    rig = tendon_rig()
    assert closed_loop(rig, make_controller("tendon-pd", rig), rate_hz=3000.0).sampled_rig


def test_kernel_cache_key_ignores_docstrings_and_comments_but_not_code():
    """The compiled kernels are keyed by :func:`code_text` of the package's laws: a docstring or comment edit keeps
    the key (no recompile), a changed constant, default or statement changes it."""
    from awiwi_drake.components.codegen import code_text

    base = 'def f(x, k=2.0):\n    """Spring (5.1)."""\n    return k * x\n'
    assert code_text(base) == code_text('def f(x, k=2.0):\n    """Another text."""\n    # note\n    return k * x\n')
    assert code_text(base) == code_text('def f(x, k=2.0):\n\n    return k * x  # no docstring\n')
    for changed in ('def f(x, k=2.5):\n    return k * x\n', 'def f(x, k=2.0):\n    return k * x * x\n',
                    'def f(x, k=2.0):\n    "Spring."\n    return k + x\n'):
        assert code_text(base) != code_text(changed), changed
    assert code_text('class A:\n    """Only a docstring."""\n') == code_text('class A:\n    pass\n')
