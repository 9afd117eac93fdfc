"""Every LeafSystem of the foundation is scalar-convertible, and its AutoDiff
derivatives equal finite differences of its float dynamics/outputs."""

import numpy as np
import pytest
from pydrake.symbolic import Expression

from _fd import assert_symbolic_matches_float, check_system_autodiff_matches_fd
from awiwi_drake.components import (
    ConstantCoupling, SpringBank_, TendonRouting_, tendon_spring)
from awiwi_drake.parameters import HysteresisParams, SpringModelParams

RNG = np.random.default_rng(0)


def _fix_inputs(system, context, values):
    for name, v in values.items():
        system.GetInputPort(name).FixValue(context, v)


def _evaluate(system, x, inputs):
    """(xdot, {output: value}) of a float system at state x with inputs."""
    ctx = system.CreateDefaultContext()
    if x.size:
        ctx.SetContinuousState(x)
    _fix_inputs(system, ctx, inputs)
    xdot = system.EvalTimeDerivatives(ctx).CopyToVector() if x.size else np.zeros(0)
    outs = {system.get_output_port(i).get_name(): system.get_output_port(i).Eval(ctx).copy()
            for i in range(system.num_output_ports())}
    return xdot, outs


@pytest.mark.parametrize("hysteresis", [False, True])
def test_spring_bank_converts_and_autodiff_matches_fd(hysteresis):
    spring = tendon_spring(SpringModelParams())
    sys = SpringBank_[float](spring, 2, HysteresisParams(enabled=hysteresis))
    inputs = {"elongation": np.array([0.002, 0.004])}
    x = np.zeros(0)
    if hysteresis:
        inputs["elongation_rate"] = np.array([0.01, -0.02])
        x = np.array([1.0, -2.0])
    jac = check_system_autodiff_matches_fd(sys, x, inputs, rtol=2e-5)
    assert_symbolic_matches_float(sys, x, inputs)
    assert all(np.abs(J_ad).max() > 0 for J_ad, _ in jac.values())    # every compared Jacobian is non-trivial


def test_lever_spring_bank_autodiff_matches_fd_and_refuses_symbolic():
    from awiwi_drake.components import LeverSpringMechanism
    sys = SpringBank_[float](LeverSpringMechanism(), 2)
    # force and stiffness gradients (the stiffness slope is a difference of exact values: looser tolerance)
    check_system_autodiff_matches_fd(sys, np.zeros(0), {"elongation": np.array([0.002, 0.004])}, rtol=1e-3)
    with pytest.raises(ValueError, match="cannot be evaluated symbolically"):
        SpringBank_[Expression](LeverSpringMechanism(), 1)


def test_routing_converts_and_autodiff_matches_fd():
    coupling = ConstantCoupling([[-0.008, 0.0], [0.008, 0.0], [0.006, -0.005]])
    sys = TendonRouting_[float](coupling, 0.005, np.array([0.001, 0.002, 0.0]), True)
    inputs = {"motor_angle": np.array([0.3, -0.1, 0.2]), "joint_angle": np.array([0.2, -0.4]),
              "tendon_force": np.array([10.0, 20.0, 5.0]), "motor_velocity": np.array([1.0, 2.0, 3.0]),
              "joint_velocity": np.array([0.5, -0.5])}
    check_system_autodiff_matches_fd(sys, np.zeros(0), inputs)
    _, outs = _evaluate(sys, np.zeros(0), inputs)
    P = coupling.P()
    np.testing.assert_allclose(outs["generalized_force"], -P.T @ inputs["tendon_force"])  # tau = -P^T f
    np.testing.assert_allclose(outs["elongation"], 0.005 * inputs["motor_angle"] + P @ inputs["joint_angle"]
                               + [0.001, 0.002, 0.0])


def test_routing_virtual_work_is_consistent():
    # Power balance: tendon forces do work f . xdot = f . (r_m omega) + f . (P qdot)
    # and the joints receive tau . qdot = -f . (P qdot).
    coupling = ConstantCoupling(RNG.normal(size=(4, 2)) * 0.01)
    sys = TendonRouting_[float](coupling, 0.005, None, True)
    f = RNG.uniform(5, 50, 4)
    qd = RNG.normal(size=2)
    _, outs = _evaluate(sys, np.zeros(0), {"motor_angle": np.zeros(4), "joint_angle": np.zeros(2),
                                           "tendon_force": f, "motor_velocity": np.zeros(4),
                                           "joint_velocity": qd})
    assert outs["generalized_force"] @ qd == pytest.approx(-f @ outs["elongation_rate"], rel=1e-12)
