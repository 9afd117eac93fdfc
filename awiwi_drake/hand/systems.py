"""Small hand-specific systems (TemplateSystems, scalar-convertible).

* :class:`CoriolisCancellation_`: outputs ``C(q, v) v`` of a plant so that adding
  it to the plant's applied generalised force removes the Coriolis/centrifugal
  terms (the "simplified model" of Fig 5.7).
* :class:`MotorAngleReference_`: joint reference -> motor angle reference
  through the exact routing ``h(q)``.
(The joint-space motor PD that uses it is the ``joint-pd`` controller,
:mod:`awiwi_drake.control.joint_pd`.)
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

__all__ = ["CoriolisCancellation_", "CoriolisCancellation", "MotorAngleReference_", "MotorAngleReference"]


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
