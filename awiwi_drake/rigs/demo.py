"""The main demo: ``joint_rig`` under a simple 3 kHz motor-position controller.

Scenario (``demo_scenario``): the pretension ramps from ``f_start`` to
``f_end`` with the link at rest, then the link steps to ``link_step`` rad.
References are turned into motor-angle set points through the rig's own spring
law (``x_i = f^-1(f_pre)``, ``theta_i* = (x_i +- r_q q*) / r_m``); each motor runs
a PD loop with tendon-force feedforward. The controller is Drake primitives
only (``AffineSystem`` sampled by a ``ZeroOrderHold`` at 3 kHz, the Awiwi
control rate), so it is C++, linear and scalar-convertible.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import AffineSystem, Multiplexer, TrajectorySource, ZeroOrderHold
from pydrake.trajectories import PiecewisePolynomial

from awiwi_drake.parameters.rigs import DemoScenario, MotorPositionGains
from awiwi_drake.rigs.base import Rig

__all__ = ["motor_references", "joint_rig_position_loop", "start_loop_at"]


def motor_references(rig: Rig, t: np.ndarray, pretension: np.ndarray, link_angle: np.ndarray):
    """Motor-angle set points and feedforward torques realising pretension and link angle.

    Returns ``(theta_ref (2, T), torque_ff (2, T))`` for the joint rig.
    """
    p = rig.params
    r, rq = p.motor.pulley_radius, p.link_pulley_radius
    x = np.asarray(rig.spring.inverse_force(np.asarray(pretension, dtype=float)), dtype=float)
    theta = np.stack([(x + rq * link_angle) / r, (x - rq * link_angle) / r])
    ff = np.stack([r * np.asarray(pretension), r * np.asarray(pretension)])
    return theta, ff


def joint_rig_position_loop(rig: Rig, scenario: DemoScenario = DemoScenario(),
                            gains: MotorPositionGains = MotorPositionGains()):
    """Closed loop of ``rig`` (a joint rig) with the demo controller.

    Returns ``(diagram, t_knots, references)``; the diagram exports ``state``,
    ``tendon_force``, ``link_angle``, ``motor_torque`` (command) and ``link_reference``.
    """
    if rig.name != "joint_rig":
        raise ValueError(f"joint_rig_position_loop: needs a joint_rig, got {rig.name}")
    s = scenario
    grid = np.linspace(0.0, s.t_final, 601)
    grid = grid[np.abs(grid - s.step_time) > 1e-6]
    t = np.union1d(grid, [s.step_time - 1e-7, s.step_time])  # knots on both sides: a sharp step
    pre = np.interp(t, [0.0, s.ramp_time, s.t_final], [s.f_start, s.f_end, s.f_end])
    q_ref = np.where(t >= s.step_time, s.link_step, 0.0)
    theta_ref, ff = motor_references(rig, t, pre, q_ref)
    refs = np.vstack([theta_ref, ff, q_ref[None, :]])
    b = DiagramBuilder()
    plant = b.AddSystem(rig.diagram)
    source = b.AddNamedSystem("references", TrajectorySource(PiecewisePolynomial.FirstOrderHold(t, refs)))
    # u = ff + kp (theta* - theta) - kd omega ; input [state(6), theta*(2), ff(2), q*(1)]
    n = rig.num_states
    D = np.zeros((2, n + 5))
    D[0, 2], D[1, 3] = -gains.kp, -gains.kp
    D[0, 4], D[1, 5] = -gains.kd, -gains.kd
    D[0, n], D[1, n + 1] = gains.kp, gains.kp
    D[0, n + 2], D[1, n + 3] = 1.0, 1.0
    law = b.AddNamedSystem("motor_pd", AffineSystem(D=D, y0=np.zeros(2)))
    mux = b.AddNamedSystem("controller_inputs", Multiplexer([n, 5]))
    hold = b.AddNamedSystem("zoh_3kHz", ZeroOrderHold(1.0 / gains.rate_hz, 2))
    b.Connect(plant.GetOutputPort("state"), mux.get_input_port(0))
    b.Connect(source.get_output_port(), mux.get_input_port(1))
    b.Connect(mux.get_output_port(), law.get_input_port())
    b.Connect(law.get_output_port(), hold.get_input_port())
    b.Connect(hold.get_output_port(), plant.GetInputPort("motor_torque"))
    b.ExportInput(plant.GetInputPort("external_torque"), "external_torque")
    for nm in ("state", "tendon_force", "link_angle"):
        b.ExportOutput(plant.GetOutputPort(nm), nm)
    b.ExportOutput(hold.get_output_port(), "motor_torque")
    diagram = b.Build()
    diagram.set_name("joint_rig_position_loop")
    return diagram, t, dict(pretension=pre, link_reference=q_ref, theta_reference=theta_ref)


def start_loop_at(diagram, context, rig: Rig, op) -> None:
    """Start a loop from :func:`joint_rig_position_loop` at operating point ``op``.

    Sets the rig's state and the hold's initial command to ``op.motor_torque``,
    so the loop starts in equilibrium instead of with a zero command.
    """
    rig.set_operating_point(rig.diagram.GetMyMutableContextFromRoot(context), op, fix_inputs=False)
    hold = diagram.GetSubsystemByName("zoh_3kHz")
    hold.GetMyMutableContextFromRoot(context).get_mutable_discrete_state(0).SetFromVector(op.motor_torque)
    diagram.GetInputPort("external_torque").FixValue(context, [0.0])
