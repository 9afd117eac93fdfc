"""The hand's motor-side joint PD as a registered controller (``joint-pd``, fingers and the hand).

The simplest way to hold a finger or the hand at a joint-space reference
without joint sensors: every motor is position controlled towards the motor
angle that keeps its spring at the operating-point elongation with the joints
at the reference,

    theta_ref = theta_op - (h(q_ref) - h(q_op)) / r_m         (exact routing, thumb base included)
    u = u_op + kp (theta_ref - theta) - kd omega

(:class:`~awiwi_drake.hand.systems.MotorAngleReference_` then one C++
``AffineSystem``).  The pretension stays at the operating point's, so the
joint stiffness is the mechanism's own (ch. 7: it changes by co-contraction,
which this controller does not command; the force-distribution chain does).

Port contract: inputs ``joint_angle_reference`` (n) [rad], ``motor_state`` (2m)
= [theta; omega], and with ``wrist_compensation`` ``wrist_tendon_offset`` (m)
[m] (the tendon path change the wrist causes, (6.9), computed from the
measured wrist angles): the references shift by ``-offset / r_m``; output
``motor_torque`` (m) [N m].  :func:`awiwi_drake.control.closed_loop` samples it
at 3 kHz.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import AffineSystem, Multiplexer

from awiwi_drake.rigs.base import Rig
from awiwi_drake.hand.systems import MotorAngleReference
from awiwi_drake.parameters.hand import JointControllerParams

__all__ = ["joint_pd_controller"]


def joint_pd_controller(rig: Any, params: JointControllerParams | None = None, *, op: Any = None,
                        wrist_compensation: bool | None = None):
    """The joint-space motor PD of a finger/hand rig around ``op`` (default: the rig's operating point).

    ``wrist_compensation`` (default: when the rig has the ``wrist_angle``
    input) adds the ``wrist_tendon_offset`` input.  Returns a Diagram (see the
    module docstring for the ports).
    """
    c = params or JointControllerParams()
    if not isinstance(c, JointControllerParams):
        raise ValueError(f"joint_pd_controller: params must be JointControllerParams, got {type(c).__name__}")
    coupling = rig.coupling if isinstance(rig, Rig) else None
    if coupling is None:
        raise ValueError(f"joint_pd_controller: rig {getattr(rig, 'name', '?')!r} is not a finger or hand rig "
                         "(it has no tendon coupling)")
    has_wrist = rig.diagram.HasInputPort("wrist_angle")
    if wrist_compensation is None:
        wrist_compensation = has_wrist
    if wrist_compensation and not has_wrist:
        raise ValueError("joint_pd_controller: wrist_compensation needs a rig built with wrist=True")
    op = op or rig.operating_point()
    m, n = coupling.num_tendons, coupling.num_joints
    theta_op = np.asarray(op.state, float)[2 * n: 2 * n + m]
    u_op = np.asarray(op.motor_torque, float)
    r_m = rig.params.motor.pulley_radius
    kp, kd = c.kp, c.kd
    b = DiagramBuilder()
    ref = b.AddNamedSystem("motor_angle_reference", MotorAngleReference(coupling, r_m, theta_op,
                                                                        op.joint_angle))
    sizes = [m, 2 * m] + ([m] if wrist_compensation else [])
    mux = b.AddNamedSystem("joint_pd_inputs", Multiplexer(sizes))
    # u = u_op + kp (theta_ref - theta) - kd omega [- kp offset / r_m]
    D = np.hstack([kp * np.eye(m), -kp * np.eye(m), -kd * np.eye(m)]
                  + ([-kp / r_m * np.eye(m)] if wrist_compensation else []))
    law = b.AddNamedSystem("joint_pd_law", AffineSystem(
        A=np.zeros((0, 0)), B=np.zeros((0, sum(sizes))), f0=np.zeros(0), C=np.zeros((m, 0)), D=D, y0=u_op))
    b.Connect(ref.get_output_port(0), mux.get_input_port(0))
    b.Connect(mux.get_output_port(0), law.get_input_port(0))
    b.ExportInput(ref.get_input_port(0), "joint_angle_reference")
    b.ExportInput(mux.get_input_port(1), "motor_state")
    if wrist_compensation:
        b.ExportInput(mux.get_input_port(2), "wrist_tendon_offset")
    b.ExportOutput(law.get_output_port(0), "motor_torque")
    d = b.Build()
    d.set_name("joint_pd")
    return d
