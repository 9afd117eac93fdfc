"""The rigs as physics: (12.10), LQR against an independent Riccati solution,
closed-loop convergence, energy conservation and passivity, Linearize against
finite differences, and stiffness versus pretension."""

import numpy as np
import pytest
import scipy.linalg

from _fd import fd_jacobian
from awiwi_drake.analysis import linearize, lqr, simulate
from awiwi_drake.control import closed_loop
from awiwi_drake.control.lqr import lqr_controller
from awiwi_drake.parameters import FlexibleJointParams, JointRigParams, MotorParams, TendonRigParams
from awiwi_drake.diagrams import build_target
from awiwi_drake.rigs import flexible_joint_rig, joint_rig, motor_rig, tendon_rig

def expected_12_10(p: FlexibleJointParams):
    m, b, k, dq, dth = p.link_inertia, p.motor_inertia, p.stiffness, p.link_damping, p.motor_damping
    A = np.array([[0, 1, 0, 0],
                  [-k / m, -dq / m, k / m, 0],
                  [0, 0, 0, 1],
                  [k / b, 0, -k / b, -dth / b]])
    B = np.array([[0], [0], [0], [1 / b]])
    return A, B


def test_flexible_joint_linearisation_equals_12_10():
    p = FlexibleJointParams()  # Table 12.1
    rig = flexible_joint_rig(params=p)
    assert rig.state_names == ("joint_angle[0]", "joint_velocity[0]", "motor_angle[0]", "motor_velocity[0]")
    res = linearize(rig)
    A, B = expected_12_10(p)
    np.testing.assert_allclose(res.A, A, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(res.B, B, rtol=1e-12)
    # Also away from the nominal values and at a loaded operating point (linear spring: same A).
    p2 = p.replace(link_inertia=7.2e-7, stiffness=1.15, link_damping=1e-3)
    res2 = linearize(flexible_joint_rig(params=p2),
                     flexible_joint_rig(params=p2).operating_point(joint_angle=0.4, external_torque=0.05))
    np.testing.assert_allclose(res2.A, expected_12_10(p2)[0], rtol=1e-12, atol=1e-9)


def test_lqr_equals_independent_riccati_solution():
    rig = flexible_joint_rig()
    Q = np.diag([10, 0.01, 1, 0.01])  # Table 13.1
    for r in (1e-4, 1e-2, 1.0):
        R = np.array([[r]])
        res = lqr(rig, Q, R)
        A, B = expected_12_10(rig.params)
        S = scipy.linalg.solve_continuous_are(A, B, Q, R)
        K = np.linalg.solve(R, B.T @ S)
        np.testing.assert_allclose(res.K, K, rtol=1e-6)
        np.testing.assert_allclose(res.S, S, rtol=1e-6)
        assert np.all(res.closed_loop_poles.real < 0)


def test_lqr_closed_loop_converges_and_cost_matches_riccati():
    rig = flexible_joint_rig()
    Q, R = np.diag([10, 0.01, 1, 0.01]), np.array([[1e-2]])
    op = rig.operating_point(joint_angle=0.0)
    loop = closed_loop(rig, lqr_controller(rig, op=op, Q=Q, R=R), rate_hz=None)
    x0 = np.array([0.2, 0.0, 0.1, 0.0])
    ctx = loop.create_context(state=x0, references={"joint_angle_reference": 0.0})
    res = simulate(loop.diagram, ctx, 1.0, log=("state", "motor_torque"), max_step=1e-4, accuracy=1e-8)
    assert np.max(np.abs(res["state"][-1])) < 1e-3 * np.max(np.abs(x0))
    # The realised quadratic cost equals x0^T S x0 (Riccati value function).
    x, u, t = res["state"], res["motor_torque"], res.t
    stage = np.einsum("ij,jk,ik->i", x, Q, x) + R[0, 0] * u[:, 0] ** 2
    cost = np.trapezoid(stage, t)
    assert cost == pytest.approx(x0 @ lqr(rig, Q, R, op).S @ x0, rel=2e-2)


def test_joint_rig_lqr_closed_loop_stiffness_against_an_external_push():
    rig = joint_rig()
    op = rig.operating_point(pretension=20.0)
    Q, R = np.diag([1e3, 1e-4, 1e3, 1e3, 1e-4, 1e-4]), np.diag([1.0, 1.0])  # slowest pole -5.6 1/s
    design = lqr(rig, Q, R, op)
    loop = closed_loop(rig, lqr_controller(rig, op=op, Q=Q, R=R), rate_hz=None)
    push = 0.01  # Nm on the link
    ctx = loop.create_context(op, references={"joint_angle_reference": op.state[0]},
                              disturbances={"external_torque": [push]})
    res = simulate(loop.diagram, ctx, 2.5, log=("state",), max_step=1e-3, accuracy=1e-8)
    # Linear prediction of the steady state: 0 = (A - B K) dx + E push, E = d xdot / d tau_ext = e_qdot / m.
    lin = design.linearization
    E = np.zeros(rig.num_states)
    E[1] = 1.0 / rig.params.link_inertia
    dx = np.linalg.solve(lin.A - lin.B @ design.K, -E * push)
    np.testing.assert_allclose(res["state"][-1] - op.state, dx, rtol=0.02, atol=1e-6)
    assert dx[0] > 0  # the link yields in the direction of the push


def _flexible_energy(p, x, u=0.0):
    q, qd, th, thd = x
    return 0.5 * p.link_inertia * qd ** 2 + 0.5 * p.motor_inertia * thd ** 2 + 0.5 * p.stiffness * (th - q) ** 2 - u * th


def test_undamped_flexible_joint_conserves_energy():
    p = FlexibleJointParams(link_damping=0.0, motor_damping=0.0)
    rig = flexible_joint_rig(params=p)
    ctx = rig.context()
    x0 = np.array([0.1, 0.0, -0.05, 2.0])
    ctx.SetContinuousState(x0)
    u = 0.01
    rig.diagram.GetInputPort("motor_torque").FixValue(ctx, [u])
    res = simulate(rig.diagram, ctx, 0.01, log=("state",), max_step=1e-4, accuracy=1e-7)
    E = np.array([_flexible_energy(p, x, u) for x in res["state"]])
    assert np.max(np.abs(E - E[0])) < 1e-5 * abs(E[0])


def _joint_energy(rig, ctx_like_state, u):
    p = rig.params
    q, qd, th1, th2, w1, w2 = ctx_like_state
    x1 = p.motor.pulley_radius * th1 - p.link_pulley_radius * q
    x2 = p.motor.pulley_radius * th2 + p.link_pulley_radius * q
    V = float(rig.spring.energy(np.array([x1]))[0] + rig.spring.energy(np.array([x2]))[0])
    return (0.5 * p.link_inertia * qd ** 2 + 0.5 * p.motor.inertia * (w1 ** 2 + w2 ** 2) + V
            - u[0] * th1 - u[1] * th2)


def test_frictionless_joint_rig_conserves_energy_and_friction_dissipates():
    motor = MotorParams(friction=False, damping=0.0, saturation=False)
    p = JointRigParams(motor=motor, link_damping=0.0)
    rig = joint_rig(params=p)
    op = rig.operating_point(pretension=20.0)
    x0 = op.state + np.array([0.05, 0.0, 0.0, 0.0, 3.0, -1.0])
    ctx = rig.context(op)
    ctx.SetContinuousState(x0)
    res = simulate(rig.diagram, ctx, 0.01, log=("state",), max_step=1e-4, accuracy=1e-7)
    E = np.array([_joint_energy(rig, x, op.motor_torque) for x in res["state"]])
    assert np.max(np.abs(E - E[0])) < 1e-5 * np.max(np.abs(E))
    # With (3.8) friction and link damping the same start loses energy monotonically (passivity).
    rig_f = joint_rig(params=JointRigParams())
    op_f = rig_f.operating_point(pretension=20.0)
    ctx = rig_f.context(op_f)
    ctx.SetContinuousState(op_f.state + np.array([0.05, 0.0, 0.0, 0.0, 3.0, -1.0]))
    res = simulate(rig_f.diagram, ctx, 0.01, log=("state",), max_step=1e-4, accuracy=1e-7)
    E = np.array([_joint_energy(rig_f, x, op_f.motor_torque) for x in res["state"]])
    assert np.all(np.diff(E) <= 1e-9 * np.max(np.abs(E)))
    assert E[-1] < E[0]


def _fd_jacobian(rig, op):
    """d xdot / d x of the rig diagram at ``op`` by the shared central differences."""
    ctx = rig.context(op)

    def xdot(x):
        ctx.SetContinuousState(x)
        return rig.diagram.EvalTimeDerivatives(ctx).CopyToVector()
    return fd_jacobian(xdot, op.state)


def test_joint_rig_linearisation_agrees_with_finite_differences():
    rig = joint_rig(params=JointRigParams(motor=MotorParams(ripple=True)))
    op = rig.operating_point(pretension=25.0, joint_angle=0.3, external_torque=0.02)
    res = linearize(rig, op)
    A_fd = _fd_jacobian(rig, op)
    np.testing.assert_allclose(res.A, A_fd, rtol=1e-5, atol=1e-5 * np.max(np.abs(A_fd)))


def test_tendon_rig_linearisation_closed_form():
    rig = tendon_rig()
    op = rig.operating_point(tendon_force=30.0)
    res = linearize(rig, op)
    p = rig.params.motor
    k = float(op.tendon_stiffness[0])
    friction_slope = p.coulomb_torque * p.friction_slope + p.viscous_friction  # d(3.8)/dw at w = 0
    A = np.array([[0, 1], [-p.pulley_radius ** 2 * k / p.inertia, -friction_slope / p.inertia]])
    np.testing.assert_allclose(res.A, A, rtol=1e-9)
    assert rig.diagram.GetOutputPort("tendon_force").Eval(rig.context(op))[0] == pytest.approx(30.0, rel=1e-12)


def test_joint_stiffness_from_linearisation_rises_with_pretension_as_the_spring_predicts():
    rig = joint_rig()
    m, rq = rig.params.link_inertia, rig.params.link_pulley_radius
    stiffness = []
    for f0 in (5.0, 10.0, 20.0, 40.0, 80.0):
        op = rig.operating_point(pretension=f0)
        A = linearize(rig, op).A
        K_q = -m * A[1, 0]  # link row: m qdd = -K_q q + ...  (motors held)
        k_spring = rig.spring.stiffness(rig.spring.inverse_force(np.array([f0, f0])))
        assert K_q == pytest.approx(rq ** 2 * np.sum(k_spring), rel=1e-9)
        stiffness.append(K_q)
    assert np.all(np.diff(stiffness) > 0)


def test_operating_point_errors_are_clear():
    with pytest.raises(ValueError, match="slack"):
        joint_rig().operating_point(pretension=1.0, external_torque=1.0)
    with pytest.raises(ValueError, match="params must be JointRigParams"):
        joint_rig(params=TendonRigParams())
    with pytest.raises(ValueError, match="unknown rig"):
        build_target("hand-of-god")
    with pytest.raises(ValueError, match="unknown parameter 'link_mass'"):
        build_target("joint-rig", {"link_mass": "1"})
    with pytest.raises(ValueError, match=r"JointRigParams.link_inertia = -1.0 is out of range"):
        build_target("joint-rig", {"link_inertia": "-1"})


@pytest.mark.parametrize("motor", [MotorParams(ripple=True), MotorParams(saturation=False, ripple=True, damping=1e-3)])
def test_motor_rig_is_3_5_and_its_autodiff_linearisation_equals_finite_differences(motor):
    """The motor rig's dynamics are (3.5) written out here, B thdd = sat(u) - gamma2 atan(gamma1 w) - gamma3 w - d w
    + a_m sin(N th + phi_m) + a_o sin(th + phi_o) (Table 3.3 friction, ripple of both bearings), at random states and
    torques beyond the limit; ``applied_torque`` is sat(u); Drake's Linearize (AutoDiffXd of the generated system)
    equals central differences of its float dynamics."""
    rig = motor_rig(motor)
    d = rig.diagram
    ctx = d.CreateDefaultContext()
    rng = np.random.default_rng(3)
    p = motor
    for _ in range(6):
        th, w, u = rng.uniform(-3, 3), rng.uniform(-4, 4), rng.uniform(-2, 2) * p.torque_limit
        ctx.SetContinuousState([th, w])
        d.GetInputPort("motor_torque").FixValue(ctx, [u])
        sat = float(np.clip(u, -p.torque_limit, p.torque_limit)) if p.saturation else u
        tau = (sat - p.coulomb_torque * np.arctan(p.friction_slope * w) - p.viscous_friction * w - p.damping * w
               + p.ripple_motor_amplitude * np.sin(p.gear_ratio * th + p.ripple_motor_phase)
               + p.ripple_output_amplitude * np.sin(th + p.ripple_output_phase))
        np.testing.assert_allclose(d.EvalTimeDerivatives(ctx).CopyToVector(), [w, tau / p.inertia], rtol=1e-12)
        assert d.GetOutputPort("applied_torque").Eval(ctx)[0] == pytest.approx(sat, rel=1e-15)
        lin = linearize(rig, state=[th, w], motor_torque=[u])

        def f(z):
            ctx.SetContinuousState(z[:2])
            d.GetInputPort("motor_torque").FixValue(ctx, z[2:])
            return d.EvalTimeDerivatives(ctx).CopyToVector()
        J = fd_jacobian(f, np.array([th, w, u]), h=1e-6)
        np.testing.assert_allclose(np.hstack([lin.A, lin.B]), J, rtol=1e-6, atol=1e-6 * np.abs(J).max())

