"""Small hand-specific systems (TemplateSystems, scalar-convertible) and controller builders.

* :class:`CoriolisCancellation_`: outputs ``C(q, v) v`` of a plant so that adding
  it to the plant's applied generalised force removes the Coriolis/centrifugal
  terms (the "simplified model" of Fig 5.7).
* :class:`MotorAngleReference_`: joint reference -> motor angle reference
  through the exact routing ``h(q)``.
* :func:`add_joint_space_controller`: a motor-side PD around an operating
  point with a joint-space reference (the law is Drake C++ primitives),
  sampled at 3 kHz by a ``ZeroOrderHold``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.primitives import AffineSystem, Multiplexer, ZeroOrderHold
from pydrake.systems.scalar_conversion import TemplateSystem

__all__ = ["CoriolisCancellation_", "CoriolisCancellation", "MotorAngleReference_", "MotorAngleReference",
           "JointSpaceControllerPorts",
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


@TemplateSystem.define("MotorAngleReference_")
def MotorAngleReference_(T):
    """Joint-space reference to motor angles through the exact routing.

    Input ``joint_angle_reference`` (n) [rad]; output ``motor_angle_reference``
    (m) [rad] = ``theta_op - (h(q_ref) - h(q_op)) / r_m``: the motor angles that
    keep every spring at its operating-point elongation with the joints at
    ``q_ref`` (x = r_m theta + h(q) - h(0) + x0).  Exact for the nonlinear
    thumb base too (a linearised ``P(q_op)`` is off by ~3 mm of tendon at
    0.5 rad there).
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, coupling, motor_pulley_radius: float, theta_op, q_op, converter=None):
            LeafSystem_[T].__init__(self, converter)
            m, n = coupling.num_tendons, coupling.num_joints
            theta_op, q_op = np.asarray(theta_op, float), np.asarray(q_op, float)
            if theta_op.shape != (m,) or q_op.shape != (n,):
                raise ValueError(f"MotorAngleReference: theta_op must have {m} and q_op {n} entries, got "
                                 f"{theta_op.shape} and {q_op.shape}")
            if not motor_pulley_radius > 0:
                raise ValueError(f"MotorAngleReference: motor_pulley_radius = {motor_pulley_radius} must be > 0 [m]")
            self.coupling, self.r_m, self.theta_op, self.q_op = coupling, float(motor_pulley_radius), theta_op, q_op
            self._h_op = np.asarray(coupling.h(q_op), dtype=float)
            self._q = self.DeclareVectorInputPort("joint_angle_reference", n)
            self.DeclareVectorOutputPort("motor_angle_reference", m, self._calc,
                                         prerequisites_of_calc={self._q.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.coupling, other.r_m, other.theta_op, other.q_op, converter=converter)

        def _calc(self, context, out):
            q = self._q.Eval(context)
            out.SetFromVector(self.theta_op - (self.coupling.h(q) - self._h_op) / self.r_m)

    return Impl


MotorAngleReference = MotorAngleReference_[None]


@dataclass
class JointSpaceControllerPorts:
    """Handles of the controller: input ports to connect, output port of motor torques."""

    reference: object
    mux: object
    gain: object
    hold: object
    joint_angle_reference: object   # input port (n)
    motor_state: object             # input port (2m): [theta; omega]
    motor_torque: object            # output port (m), sampled at 1/period
    motor_angle_offset: object = None  # input port (m) [rad] added to the motor references


def add_joint_space_controller(builder, *, coupling, motor_pulley_radius: float,
                               theta_op: np.ndarray, u_op: np.ndarray, q_op: np.ndarray,
                               kp: float, kd: float, period: float = CONTROL_PERIOD,
                               motor_angle_offset: bool = False,
                               name: str = "joint_controller") -> JointSpaceControllerPorts:
    """Motor PD with a joint-space reference around an operating point.

    ``theta_ref`` from :class:`MotorAngleReference_` (exact routing), then
    ``u = u_op + kp (theta_ref - theta) - kd omega``, held by a
    ``ZeroOrderHold`` of ``period`` (3 kHz).  With ``motor_angle_offset``
    an extra input (m) [rad] is added to ``theta_ref`` (e.g. the wrist
    feedforward ``-h_wrist / r_m``).  The law is a stateless C++
    ``AffineSystem`` after a ``Multiplexer``; the reference map is evaluated
    only when the hold samples (3 kHz) or the reference changes.
    """
    m, n = coupling.num_tendons, coupling.num_joints
    for label, v, size in (("theta_op", theta_op, m), ("u_op", u_op, m), ("q_op", q_op, n)):
        if np.shape(v) != (size,):
            raise ValueError(f"{name}: {label} must have shape ({size},), got {np.shape(v)}")
    if kp < 0 or kd < 0:
        raise ValueError(f"{name}: kp and kd must be >= 0 (got kp={kp}, kd={kd})")
    if period <= 0:
        raise ValueError(f"{name}: period must be > 0, got {period}")
    ref = builder.AddNamedSystem(name + "_reference", MotorAngleReference(coupling, motor_pulley_radius,
                                                                            theta_op, q_op))
    sizes = [m, 2 * m] + ([m] if motor_angle_offset else [])
    mux = builder.AddNamedSystem(name + "_mux", Multiplexer(sizes))
    D = np.hstack([kp * np.eye(m), -kp * np.eye(m), -kd * np.eye(m)]
                  + ([kp * np.eye(m)] if motor_angle_offset else []))
    gain = builder.AddNamedSystem(name + "_law", AffineSystem(
        A=np.zeros((0, 0)), B=np.zeros((0, sum(sizes))), f0=np.zeros(0),
        C=np.zeros((m, 0)), D=D, y0=np.asarray(u_op, float)))
    hold = builder.AddNamedSystem(name + "_zoh", ZeroOrderHold(period, m))
    builder.Connect(ref.get_output_port(0), mux.get_input_port(0))
    builder.Connect(mux.get_output_port(0), gain.get_input_port(0))
    builder.Connect(gain.get_output_port(0), hold.get_input_port())
    return JointSpaceControllerPorts(ref, mux, gain, hold, ref.get_input_port(0), mux.get_input_port(1),
                                     hold.get_output_port(),
                                     mux.get_input_port(2) if motor_angle_offset else None)
