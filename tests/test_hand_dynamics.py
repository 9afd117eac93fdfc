"""The finger / hand plant in one system (``hand.dynamics.HandDynamics_``): its compiled float path
equals MultibodyPlant's forward dynamics (articulated-body algorithm) driven by the drive's law
functions, its AutoDiffXd conversion equals finite differences, its Expression conversion the
float values, and its ports are lean."""

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd

from awiwi_drake.components.fused_drive import drive_laws
from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram
from awiwi_drake.hand.dynamics import HandDynamics_, ldl_solve
from awiwi_drake.parameters.hand import FingerRigParams, HandRigParams
from _fd import assert_symbolic_matches_float, check_system_autodiff_matches_fd

RNG = np.random.default_rng(5)
ON = dict(ripple=True, hysteresis=True, guide_friction=True)


def _dynamics(rig):
    return rig.diagram.GetSubsystemByName("hand_dynamics")


def _random_state(rig):
    """Around the operating point: springs engaged or slack, links moving, friction states loaded."""
    op = rig.operating_point()
    n, m = rig.num_joints, rig.num_tendons
    x = op.state.copy()
    x[:n] += RNG.uniform(-0.3, 0.3, n)
    x[n:2 * n] = RNG.normal(scale=2.0, size=n)
    x[2 * n:2 * n + m] += RNG.normal(scale=0.05, size=m)
    x[2 * n + m:2 * n + 2 * m] = RNG.normal(scale=3.0, size=m)
    x[2 * n + 2 * m:] = RNG.normal(scale=2.0, size=x.size - 2 * n - 2 * m)
    return x


def _multibody_reference(rig, x, u, tau_ext, off):
    """``[v, MultibodyPlant.CalcTimeDerivatives (ABA), drive rates]`` with the tendon forces of the
    drive's law functions (float, not compiled) as the plant's applied generalised force."""
    model, plant = rig.drive.model, rig.plant
    n = rig.num_joints
    q, v = x[:n], x[n:2 * n]
    q_all = q if model.num_joints == n else np.concatenate([q, off])
    d = drive_laws(model, x[2 * n:], u, q_all, v)
    tau = d["generalized_force"][:n] + tau_ext
    if rig.coupling_gain is not None:
        tau = tau - rig.coupling_gain @ x[:2 * n]
    ctx = plant.CreateDefaultContext()
    plant.SetPositionsAndVelocities(ctx, x[:2 * n])
    plant.get_applied_generalized_force_input_port().FixValue(ctx, tau)
    vdot = plant.EvalTimeDerivatives(ctx).CopyToVector()[n:]
    return np.concatenate([v, vdot, d["derivatives"]]), d


@pytest.mark.parametrize("build", [
    lambda: hand_diagram(),                                                    # default physics, wrist, all fingers
    lambda: finger_diagram(finger="ring", params=FingerRigParams.for_finger("ring").with_physics(**ON)),
], ids=["hand", "ring-physics-on"])
def test_compiled_plant_equals_multibody_plant_and_the_laws_at_random_states(build):
    """The compiled kernels (forced: a float system takes the generic path for its first
    ``COMPILE_AFTER_CALLS`` evaluations, then the kernels) = the MultibodyPlant + drive laws; then the generic
    float path of a fresh system = the kernels at the same states."""
    rig = build()
    n, m = rig.num_joints, rig.num_tendons
    _dynamics(rig).kernels()
    ctx = rig.diagram.CreateDefaultContext()
    wrist = rig.diagram.HasInputPort("wrist_angle")
    for _ in range(4):
        x = _random_state(rig)
        u = RNG.normal(scale=2.0, size=m)
        tau_ext = RNG.normal(scale=0.05, size=n)
        ctx.SetContinuousState(x)
        rig.diagram.GetInputPort("motor_torque").FixValue(ctx, u)
        rig.diagram.GetInputPort("external_torque").FixValue(ctx, tau_ext)
        off = np.zeros(0)
        if wrist:
            rig.diagram.GetInputPort("wrist_angle").FixValue(ctx, RNG.uniform(-0.4, 0.4, 2))
            off = rig.diagram.GetOutputPort("wrist_tendon_offset").Eval(ctx)
        got = rig.diagram.EvalTimeDerivatives(ctx).CopyToVector()
        ref, laws = _multibody_reference(rig, x, u, tau_ext, off)
        assert np.abs(ref[n:2 * n]).max() > 1.0           # the links accelerate: a real comparison
        scale = np.maximum(1.0, np.abs(ref))
        np.testing.assert_array_less(np.abs(got - ref) / scale, 1e-12)
        for port in ("tendon_force", "tendon_stiffness", "elongation"):
            np.testing.assert_allclose(rig.diagram.GetOutputPort(port).Eval(ctx), laws[port], rtol=1e-12,
                                       atol=1e-12 * np.abs(laws[port]).max(), err_msg=port)
        np.testing.assert_allclose(rig.diagram.GetOutputPort("joint_torque").Eval(ctx),
                                   laws["generalized_force"][:n], rtol=1e-12, atol=1e-14)
        np.testing.assert_array_equal(rig.diagram.GetOutputPort("state").Eval(ctx), x)
        fresh = build()                                   # a fresh system: its first calls take the generic path
        fctx = fresh.diagram.CreateDefaultContext()
        fctx.SetTimeStateAndParametersFrom(ctx)
        for i in range(rig.diagram.num_input_ports()):
            if rig.diagram.get_input_port(i).HasValue(ctx):
                fresh.diagram.get_input_port(i).FixValue(fctx, rig.diagram.get_input_port(i).Eval(ctx))
        np.testing.assert_array_less(np.abs(fresh.diagram.EvalTimeDerivatives(fctx).CopyToVector() - got) / scale,
                                     1e-12)
        np.testing.assert_allclose(fresh.diagram.GetOutputPort("tendon_force").Eval(fctx),
                                   rig.diagram.GetOutputPort("tendon_force").Eval(ctx), rtol=1e-12, atol=1e-12)
        assert _dynamics(fresh)._kernels is None
    assert _dynamics(rig)._kernels is not None


def test_ldl_solve_solves_spd_systems_for_floats_and_autodiff():
    A = RNG.normal(size=(5, 5))
    M = A @ A.T + 5 * np.eye(5)
    b = RNG.normal(size=5)
    np.testing.assert_allclose(ldl_solve(M, b), np.linalg.solve(M, b), rtol=1e-13)
    # AutoDiffXd: d y / d b = M^-1
    bad = np.array([AutoDiffXd(b[i], np.eye(5)[i]) for i in range(5)], dtype=object)
    y = ldl_solve(M.astype(object), bad)
    np.testing.assert_allclose(np.array([yi.derivatives() for yi in y]), np.linalg.inv(M), rtol=1e-12, atol=1e-14)


@pytest.fixture(scope="module")
def ring_on():
    return finger_diagram(finger="ring", params=FingerRigParams.for_finger("ring").with_physics(**ON))


def test_plant_system_autodiff_equals_finite_differences(ring_on):
    """Coupled PIP/DIP (G), hysteresis and guide friction: every Jacobian of the one system."""
    sys_ = _dynamics(ring_on)
    x = _random_state(ring_on)
    x[ring_on.num_joints:2 * ring_on.num_joints] *= 0.05     # slow links: the Dahl states stay smooth for FD
    inputs = dict(motor_torque=RNG.normal(scale=1.0, size=ring_on.num_tendons),
                  external_torque=RNG.normal(scale=0.02, size=ring_on.num_joints))
    jac = check_system_autodiff_matches_fd(sys_, x, inputs, rtol=1e-5)
    # closed forms from MultibodyPlant, independent of the compiled kernel: dq/dt = v, and the external torque
    # enters the links only through M(q) vdot = ... + tau_ext, so d vdot / d tau_ext = M(q)^-1
    J = jac["xdot"][0]
    n, m = ring_on.num_joints, ring_on.num_tendons
    np.testing.assert_allclose(J[:n, :x.size], np.eye(n, x.size, n), atol=1e-12)
    ctx = ring_on.plant.CreateDefaultContext()
    ring_on.plant.SetPositions(ctx, x[:n])
    M = ring_on.plant.CalcMassMatrix(ctx)
    np.testing.assert_allclose(J[n:2 * n, x.size + m:], np.linalg.inv(M), rtol=1e-9,
                               atol=1e-9 * np.abs(np.linalg.inv(M)).max())


def test_plant_system_expression_equals_float_and_ports_are_lean(ring_on):
    sys_ = _dynamics(ring_on)
    x = _random_state(ring_on)
    inputs = dict(motor_torque=RNG.normal(size=ring_on.num_tendons),
                  external_torque=RNG.normal(scale=0.02, size=ring_on.num_joints))
    assert_symbolic_matches_float(sys_, x, inputs, rtol=1e-11)
    u = sys_.GetInputPort("motor_torque").get_index()
    for i in range(sys_.num_output_ports()):
        name = sys_.get_output_port(i).get_name()
        assert sys_.HasDirectFeedthrough(u, i) == (name == "applied_torque"), name
        assert not sys_.HasDirectFeedthrough(sys_.GetInputPort("external_torque").get_index(), i), name
    assert HandDynamics_[AutoDiffXd] is not None


def test_hand_linearises_at_rest_with_the_multibody_mass_matrix():
    """Linearize on the one-system hand (default physics: hysteresis states): the velocity block of A is
    ``-M^-1 (D + G_v)`` with M and the joint damping D from MultibodyPlant."""
    from awiwi_drake.analysis import linearize
    rig = hand_diagram()
    op = rig.operating_point()
    lin = linearize(rig, op)
    n = rig.num_joints
    ctx = rig.plant.CreateDefaultContext()
    rig.plant.SetPositions(ctx, op.joint_angle)
    M = rig.plant.CalcMassMatrix(ctx)
    # d qdd / d v = -M^-1 (D + G_v) with the joint damping D and the coupling damping (the Dahl
    # states at rest are springs, not dampers, and carry the velocity only through their own state)
    D = np.diag([rig.plant.get_joint(j).default_damping_vector()[0] for j in rig.plant.GetJointIndices()])
    Gv = rig.coupling_gain[:, n:]
    Avv = lin.A[n:2 * n, n:2 * n]
    np.testing.assert_allclose(M @ Avv, -(D + Gv), atol=1e-9 * np.abs(D + Gv).max())


def test_link_geometry_poses_are_the_plant_body_poses_and_convert():
    """The compiled finger is drawn from its joint angles: every geometry frame gets its body's pose."""
    from pydrake.geometry import SceneGraph
    from awiwi_drake.hand.plant import make_finger_plant
    from awiwi_drake.hand.systems import LinkGeometryPoses_
    sg = SceneGraph()
    plant, model = make_finger_plant("index", visual=True, scene_graph=sg)
    sys_ = LinkGeometryPoses_[float](plant)
    q = RNG.uniform(-0.5, 0.5, plant.num_positions())
    ctx = sys_.CreateDefaultContext()
    sys_.get_input_port().FixValue(ctx, q)
    poses = sys_.get_output_port().Eval(ctx)
    pctx = plant.CreateDefaultContext()
    plant.SetPositions(pctx, q)
    assert len(poses.ids()) == len(model.bodies)
    for body in model.bodies:
        X = poses.value(plant.GetBodyFrameIdOrThrow(body.index()))
        np.testing.assert_allclose(X.GetAsMatrix4(), plant.EvalBodyPoseInWorld(pctx, body).GetAsMatrix4(), atol=1e-15)
    ad = sys_.ToAutoDiffXd()
    actx = ad.CreateDefaultContext()
    ad.get_input_port().FixValue(actx, np.array([AutoDiffXd(v) for v in q], dtype=object))
    assert len(ad.get_output_port().Eval(actx).ids()) == len(model.bodies)


def test_thumb_coupling_and_hessians_fast_path_equals_the_law_functions():
    """The distribution's per-period thumb kinematics (one compiled call) = P(q) and d2h/dq2 of the laws."""
    from awiwi_drake.control.force_distribution import _nullspace_jit, coupling_nullspace
    from awiwi_drake.hand.coupling import finger_coupling
    c = finger_coupling("thumb")
    for _ in range(5):
        q = RNG.uniform(-0.6, 0.6, 4)
        P, H = c.coupling_and_hessians(q)
        qo = q.astype(object)
        np.testing.assert_allclose(P, np.asarray(c.P(qo), dtype=float), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(H, np.asarray(c.tension_hessians(qo), dtype=float),
                                   rtol=1e-12, atol=1e-15)
        for a, b in zip(_nullspace_jit(P, 1e-10), coupling_nullspace(P)):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
