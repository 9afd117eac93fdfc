"""Wrist systems: TemplateSystem conversion, AutoDiff vs finite differences, Drake linearisation."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd, InitializeAutoDiff
from pydrake.symbolic import Expression, Variable
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, FirstOrderTaylorApproximation, VectorLogSink

from _fd import fd_jacobian
from awiwi_drake.hand.systems import WristTendonOffsets, WristTendonOffsets_
from awiwi_drake.hand.wrist import wrist_jacobian, wrist_tendon_offsets
from awiwi_drake.parameters.wrist import WristParams

R_M = 0.005   # motor pulley radius used by the tests [m] (any positive value)
Q = np.array([0.15, -0.25])


def _output(system, q):
    ctx = system.CreateDefaultContext()
    system.get_input_port(0).FixValue(ctx, q)
    return system.get_output_port(0).Eval(ctx)


def test_ports_and_values():
    off = WristTendonOffsets()
    comp = WristTendonOffsets(motor_pulley_radius=R_M)
    assert off.get_input_port(0).get_name() == "wrist_angle" and off.get_input_port(0).size() == 2
    assert off.GetOutputPort("wrist_tendon_offset").size() == 38
    assert comp.GetOutputPort("motor_angle_offset").size() == 38
    assert off.HasDirectFeedthrough(0, 0) and comp.HasDirectFeedthrough(0, 0)
    np.testing.assert_allclose(_output(off, Q), wrist_tendon_offsets(*Q), atol=0.0)
    # compensation cancels the elongation r_m dtheta + dh = 0 (ARCHITECTURE sign convention)
    np.testing.assert_allclose(R_M * _output(comp, Q) + _output(off, Q), 0.0, atol=1e-18)


def test_kept_float_result_follows_every_change_of_the_wrist_angle():
    """The float systems keep their last result for an unchanged angle; any change recomputes (6.9)."""
    off, comp = WristTendonOffsets(), WristTendonOffsets(motor_pulley_radius=R_M)
    for system, law in ((off, lambda q: wrist_tendon_offsets(*q)), (comp, lambda q: -wrist_tendon_offsets(*q) / R_M)):
        ctx = system.CreateDefaultContext()
        for q in (Q, Q, Q + [1e-12, 0.0], np.array([-0.3, 0.2]), Q):
            system.get_input_port(0).FixValue(ctx, q)
            np.testing.assert_array_equal(system.get_output_port(0).Eval(ctx), law(q))
    assert not np.array_equal(wrist_tendon_offsets(*Q), wrist_tendon_offsets(*(Q + [1e-12, 0.0])))


@pytest.mark.parametrize("make", [lambda: WristTendonOffsets(),
                                  lambda: WristTendonOffsets(motor_pulley_radius=np.linspace(0.004, 0.006, 38))],
                         ids=["offsets", "compensation"])
def test_autodiff_matches_finite_differences(make):
    system = make()
    ad = system.ToAutoDiffXd()
    assert isinstance(ad, WristTendonOffsets_[AutoDiffXd])
    ctx = ad.CreateDefaultContext()
    ad.get_input_port(0).FixValue(ctx, InitializeAutoDiff(Q).ravel())
    y = ad.get_output_port(0).Eval(ctx)
    J = np.array([e.derivatives() for e in y])
    fd = fd_jacobian(lambda q: _output(system, q), Q, h=1e-6)
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-7)
    # the copy keeps the parameters: float values agree
    np.testing.assert_allclose([v.value() for v in y], _output(system, Q), atol=0.0)


def test_symbolic_conversion():
    system = WristTendonOffsets()
    sym = system.ToSymbolic()
    ctx = sym.CreateDefaultContext()
    x = [Variable("q71"), Variable("q73")]
    sym.get_input_port(0).FixValue(ctx, np.array([Expression(v) for v in x]))
    y = sym.get_output_port(0).Eval(ctx)
    env = {x[0]: Q[0], x[1]: Q[1]}
    np.testing.assert_allclose([y[i].Evaluate(env) for i in (0, 20)], wrist_tendon_offsets(*Q)[[0, 20]],
                               atol=1e-15)


def test_drake_linearisation_gives_minus_jacobian_over_radius():
    comp = WristTendonOffsets(motor_pulley_radius=R_M)
    ctx = comp.CreateDefaultContext()
    comp.get_input_port(0).FixValue(ctx, Q)
    lin = FirstOrderTaylorApproximation(comp, ctx)
    np.testing.assert_allclose(lin.D(), -wrist_jacobian(*Q) / R_M, rtol=1e-12, atol=1e-12)
    # affine form y = D u + y0 reproduces the output at the operating point
    np.testing.assert_allclose(lin.D() @ Q + lin.y0(), _output(comp, Q), atol=1e-12)


def test_in_a_diagram_with_custom_params():
    params = WristParams(length=0.055)
    builder = DiagramBuilder()
    src = builder.AddSystem(ConstantVectorSource(Q))
    off = builder.AddNamedSystem("wrist", WristTendonOffsets(params))
    log = builder.AddSystem(VectorLogSink(38))
    builder.Connect(src.get_output_port(), off.get_input_port(0))
    builder.Connect(off.get_output_port(0), log.get_input_port())
    diagram = builder.Build()
    sim = Simulator(diagram)
    sim.AdvanceTo(0.01)
    data = log.FindLog(sim.get_context()).data()
    np.testing.assert_allclose(data[:, -1], wrist_tendon_offsets(*Q, params), atol=0.0)
    assert not np.allclose(data[:, -1], wrist_tendon_offsets(*Q))
    assert diagram.ToAutoDiffXd() is not None


def test_bad_construction_and_input():
    with pytest.raises(ValueError, match="motor_pulley_radius"):
        WristTendonOffsets(motor_pulley_radius=0.0)
    with pytest.raises(ValueError, match="motor_pulley_radius"):
        WristTendonOffsets(motor_pulley_radius=np.ones(3) * 0.005)
    with pytest.raises(ValueError, match="params"):
        WristTendonOffsets(params=0.05)
    with pytest.raises(ValueError, match="wrist_angle"):
        _output(WristTendonOffsets(), np.array([0.0, -1.3]))
