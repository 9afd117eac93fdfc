"""Small plants from Drake primitives for the controller tests (not a test module).

``linear_flexible_joint_rig`` is (12.8) with Table 12.1 values written as a
``LinearSystem`` and exported with the rig port names; it lets the controller
tests check closed forms independently of the foundation rigs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LinearSystem, Multiplexer, MatrixGain

B_M, M_L, K_S, D_Q, D_TH = 2e-3, 4e-7, 0.605, 0.0012, 0.0012  # Table 12.1


def flexible_joint_matrices(k=K_S, m=M_L, b=B_M, dq=D_Q, dth=D_TH):
    A = np.array([[0, 1, 0, 0], [-k / m, -dq / m, k / m, 0], [0, 0, 0, 1], [k / b, 0, -k / b, -dth / b]])
    B = np.array([[0.0], [0.0], [0.0], [1.0 / b]])
    E = np.array([[0.0], [1.0 / m], [0.0], [0.0]])  # external link torque
    return A, B, E


@dataclass
class Op:
    state: np.ndarray
    motor_torque: np.ndarray


@dataclass
class SimpleRig:
    name: str
    diagram: object
    state_names: list = field(default_factory=list)

    def operating_point(self, **kw):
        return Op(np.zeros(4), np.zeros(1))

    def context(self, op=None):
        op = op or self.operating_point()
        ctx = self.diagram.CreateDefaultContext()
        ctx.SetContinuousState(op.state)
        self.diagram.GetInputPort("motor_torque").FixValue(ctx, op.motor_torque)
        self.diagram.GetInputPort("external_torque").FixValue(ctx, [0.0])
        return ctx


def linear_flexible_joint_rig(k=K_S, m=M_L, name="flexible-joint", feedthrough=0.0):
    """``feedthrough``: a direct term from ``motor_torque`` to every output (a rig with one)."""
    A, B, E = flexible_joint_matrices(k=k, m=m)
    builder = DiagramBuilder()
    D = np.zeros((4, 2))
    D[:, 0] = feedthrough
    sys = builder.AddNamedSystem("plant", LinearSystem(A, np.hstack([B, E]), np.eye(4), D))
    mux = builder.AddNamedSystem("mux", Multiplexer([1, 1]))
    builder.Connect(mux.get_output_port(0), sys.get_input_port())
    builder.ExportInput(mux.get_input_port(0), "motor_torque")
    builder.ExportInput(mux.get_input_port(1), "external_torque")
    builder.ExportOutput(sys.get_output_port(), "state")
    for i, nm in enumerate(["joint_angle", "joint_velocity", "motor_angle", "motor_velocity"]):
        g = builder.AddNamedSystem(nm, MatrixGain(np.eye(4)[i:i + 1]))
        builder.Connect(sys.get_output_port(), g.get_input_port())
        builder.ExportOutput(g.get_output_port(), nm)
    return SimpleRig(name, builder.Build(), ["q", "qdot", "theta", "thetadot"])

