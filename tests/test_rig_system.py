"""The single-joint rig as C++ systems: SymbolicVectorSystem dynamics = the law functions,
scalar conversion, lean ports (no feedthrough into the state path)."""

import numpy as np
import pytest

from awiwi_drake.components import antagonistic_coupling, tendon_spring
from awiwi_drake.components.fused_drive import DriveModel, build_kernels, drive_laws
from awiwi_drake.components.rig_system import LinkRigOutputs_, rig_dynamics_system
from awiwi_drake.parameters import HysteresisParams, MotorParams, SpringModelParams
from awiwi_drake.rigs import flexible_joint_rig, joint_rig
from _fd import assert_symbolic_matches_float, check_system_autodiff_matches_fd

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
    assert rig.backend == "compiled" and rig.plant is None
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
