"""Small hand-specific systems (TemplateSystems, scalar-convertible) and controller builders.

* :class:`CoriolisCancellation_`: outputs ``C(q, v) v`` of a plant so that adding
  it to the plant's applied generalised force removes the Coriolis/centrifugal
  terms (the "simplified model" of Fig 5.7).
* :func:`add_joint_space_controller`: a linear motor-side PD around an
  operating point with a joint-space reference, built from Drake primitives
  (C++) and sampled at 3 kHz by a ``ZeroOrderHold``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.primitives import AffineSystem, Multiplexer, ZeroOrderHold
from pydrake.systems.scalar_conversion import TemplateSystem

__all__ = ["CoriolisCancellation_", "CoriolisCancellation", "JointSpaceControllerPorts",
           "add_joint_space_controller", "CONTROL_PERIOD"]

# Thesis: control at 3 kHz (ch. 1/3; MODEL_NOTES "The system in one paragraph").
CONTROL_PERIOD = 1.0 / 3000.0


@TemplateSystem.define("CoriolisCancellation_")
def CoriolisCancellation_(T):
    """``generalized_force = C(q, v) v`` of ``plant`` for ``state = [q; v]``.

    The plant passed in is a finalised float MultibodyPlant *without* a
    SceneGraph connection (e.g. from ``make_finger_plant()``); for other
    scalar types it is converted with ``ToScalarType``.
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, plant, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self._plant_float = plant
            self._plant = plant if T == float else plant.ToScalarType[T]()
            self._ctx = self._plant.CreateDefaultContext()
            n, nv = plant.num_positions(), plant.num_velocities()
            self._n, self._nv = n, nv
            self._u = self.DeclareVectorInputPort("state", n + nv)
            self.DeclareVectorOutputPort("generalized_force", nv, self._calc,
                                         prerequisites_of_calc={self._u.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._plant_float, converter=converter)

        def _calc(self, context, output):
            x = self._u.Eval(context)
            self._plant.SetPositionsAndVelocities(self._ctx, x)
            output.SetFromVector(self._plant.CalcBiasTerm(self._ctx))

    return Impl


CoriolisCancellation = CoriolisCancellation_[None]


@dataclass
class JointSpaceControllerPorts:
    """Handles of the controller: input ports to connect, output port of motor torques."""

    mux: object
    gain: object
    hold: object
    joint_angle_reference: object   # input port (n)
    motor_state: object             # input port (2m): [theta; omega]
    motor_torque: object            # output port (m), sampled at 1/period
    motor_angle_offset: object = None  # input port (m) [rad] added to the motor references


def add_joint_space_controller(builder, *, P_op: np.ndarray, motor_pulley_radius: float,
                               theta_op: np.ndarray, u_op: np.ndarray, q_op: np.ndarray,
                               kp: float, kd: float, period: float = CONTROL_PERIOD,
                               motor_angle_offset: bool = False,
                               name: str = "joint_controller") -> JointSpaceControllerPorts:
    """Motor PD with a joint-space reference, linear around an operating point.

    ``theta_ref = theta_op - P_op (q_ref - q_op) / r_m`` keeps every spring
    at its operating elongation when the joints sit at ``q_ref`` (exact for
    constant ``P``; first order for the thumb base).  Then
    ``u = u_op + kp (theta_ref - theta) - kd omega``, held by a
    ``ZeroOrderHold`` of ``period`` (3 kHz).  With ``motor_angle_offset``
    an extra input (m) [rad] is added to ``theta_ref`` (e.g. the wrist
    feedforward ``-h_wrist / r_m``).  All blocks are Drake C++
    primitives (``Multiplexer``, stateless ``AffineSystem``, ``ZeroOrderHold``).
    """
    P_op = np.asarray(P_op, float)
    m, n = P_op.shape
    for label, v, size in (("theta_op", theta_op, m), ("u_op", u_op, m), ("q_op", q_op, n)):
        if np.shape(v) != (size,):
            raise ValueError(f"{name}: {label} must have shape ({size},), got {np.shape(v)}")
    if kp < 0 or kd < 0:
        raise ValueError(f"{name}: kp and kd must be >= 0 (got kp={kp}, kd={kd})")
    if period <= 0:
        raise ValueError(f"{name}: period must be > 0, got {period}")
    rm = float(motor_pulley_radius)
    sizes = [n, 2 * m] + ([m] if motor_angle_offset else [])
    mux = builder.AddNamedSystem(name + "_mux", Multiplexer(sizes))
    D = np.hstack([-kp * P_op / rm, -kp * np.eye(m), -kd * np.eye(m)]
                  + ([kp * np.eye(m)] if motor_angle_offset else []))
    y0 = np.asarray(u_op, float) + kp * (np.asarray(theta_op, float) + P_op @ np.asarray(q_op, float) / rm)
    gain = builder.AddNamedSystem(name + "_law", AffineSystem(
        A=np.zeros((0, 0)), B=np.zeros((0, sum(sizes))), f0=np.zeros(0),
        C=np.zeros((m, 0)), D=D, y0=y0))
    hold = builder.AddNamedSystem(name + "_zoh", ZeroOrderHold(period, m))
    builder.Connect(mux.get_output_port(0), gain.get_input_port(0))
    builder.Connect(gain.get_output_port(0), hold.get_input_port())
    return JointSpaceControllerPorts(mux, gain, hold, mux.get_input_port(0), mux.get_input_port(1),
                                     hold.get_output_port(),
                                     mux.get_input_port(2) if motor_angle_offset else None)


