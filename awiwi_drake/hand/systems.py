"""Small hand-specific systems (TemplateSystems, scalar-convertible): the Coriolis cancellation of Fig 5.7,
the motor angle reference through the exact routing, the wrist's tendon offsets (6.9) and the poses of a
plant's geometry; and :func:`tendon_bending_angles`, the input of the guide friction (4.1)."""

from __future__ import annotations

import sys

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake.hand.coupling import FingerCoupling
from awiwi_drake.hand.wrist import check_motor_pulley_radius, wrist_params, wrist_tendon_offsets
from awiwi_drake.parameters.wrist import WristParams

__all__ = ["CoriolisCancellation_", "CoriolisCancellation", "MotorAngleReference_", "MotorAngleReference",
           "tendon_bending_angles",
           "WristTendonOffsets_", "WristTendonOffsets",
           "LinkGeometryPoses_", "LinkGeometryPoses"]


def _plant_as(plant, T):
    """(float plant, the plant for scalar type ``T`` (converted with ``ToScalarType``), its default context)."""
    plant_t = plant if T == float else plant.ToScalarType[T]()
    return plant, plant_t, plant_t.CreateDefaultContext()


@TemplateSystem.define("CoriolisCancellation_", scope=sys.modules[__name__])
def CoriolisCancellation_(T):
    """``generalized_force = C(q, v) v`` of ``plant`` (a finalised float MultibodyPlant without a SceneGraph
    connection) for ``state = [q; v]``: added to the plant's applied force it removes the Coriolis terms (the
    "simplified model" of Fig 5.7)."""

    class Impl(LeafSystem_[T]):
        def _construct(self, plant, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self._plant_float, self._plant, self._ctx = _plant_as(plant, T)
            nv = plant.num_velocities()
            self._u = self.DeclareVectorInputPort("state", plant.num_positions() + nv)
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


@TemplateSystem.define("MotorAngleReference_", scope=sys.modules[__name__])
def MotorAngleReference_(T):
    """Joint-space reference to motor angles through the exact routing (the ``joint-pd`` controller's).

    Input ``joint_angle_reference`` (n) [rad]; output ``motor_angle_reference`` (m) [rad] =
    ``theta_op - (h(q_ref) - h(q_op)) / r_m``: the motor angles that keep every spring at its
    operating-point elongation with the joints at ``q_ref``, exact for the nonlinear thumb base too.
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
            self._last = None
            self._q = self.DeclareVectorInputPort("joint_angle_reference", n)
            self.DeclareVectorOutputPort("motor_angle_reference", m, self._calc,
                                         prerequisites_of_calc={self._q.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.coupling, other.r_m, other.theta_op, other.q_op, converter=converter)

        def _calc(self, context, out):
            q = self._q.Eval(context)
            if T is not float:
                out.SetFromVector(self.theta_op - (self.coupling.h(q) - self._h_op) / self.r_m)
                return
            # a step or hold reference repeats its value: the last result is kept (h(q) of the hand ~15 us)
            key = np.asarray(q, dtype=float).tobytes()
            if self._last is None or self._last[0] != key:
                self._last = (key, self.theta_op - (self.coupling.h(q) - self._h_op) / self.r_m)
            out.SetFromVector(self._last[1])

    return Impl


MotorAngleReference = MotorAngleReference_[None]


@TemplateSystem.define("WristTendonOffsets_", scope=sys.modules[__name__])
def WristTendonOffsets_(T):
    """Wrist tendon offsets (6.9) as a system, or the motor feed-forward that cancels them.

    Input ``wrist_angle`` (2) = [q71, q73] [rad]; output ``wrist_tendon_offset`` (38) [m] =
    ``h_wrist(q) - h_wrist(0)``, Table 6.2 order.  With ``motor_pulley_radius`` r_m [m] (scalar or (38,))
    the output is instead ``motor_angle_offset`` (38) [rad] = ``-(h_wrist(q) - h_wrist(0)) / r_m``
    (:func:`~awiwi_drake.hand.wrist.wrist_compensation`): added to the motor angle references it keeps every
    elongation unchanged when the wrist moves.
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, params: WristParams | None = None, motor_pulley_radius=None, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self._params = wrist_params(params)
            self._last = None
            n = self._params.num_tendons
            self._r = None if motor_pulley_radius is None else check_motor_pulley_radius(motor_pulley_radius, n)
            self._u = self.DeclareVectorInputPort("wrist_angle", 2)
            self.DeclareVectorOutputPort("wrist_tendon_offset" if self._r is None else "motor_angle_offset", n,
                                         self._calc, prerequisites_of_calc={self._u.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._params, other._r, converter=converter)

        @property
        def params(self) -> WristParams:
            return self._params

        def _law(self, q):
            off = wrist_tendon_offsets(q[0], q[1], self._params)
            return off if self._r is None else -off / self._r

        def _calc(self, context, output):
            q = self._u.Eval(context)
            if T is not float:
                output.SetFromVector(self._law(q))
                return
            # Drake re-evaluates this port whenever its source's cache entry is invalidated: the last float
            # result is kept while the wrist angle is unchanged
            key = (float(q[0]), float(q[1]))
            if self._last is None or self._last[0] != key:
                self._last = (key, np.asarray(self._law(q), dtype=float))
            output.SetFromVector(self._last[1])

    return Impl


WristTendonOffsets = WristTendonOffsets_[None]


def tendon_bending_angles(coupling: FingerCoupling, p) -> np.ndarray:
    """Total bending angle per tendon [rad] at the straight pose (input of (4.1)): ``palm_bending_angle`` plus
    ``joint_wrap_angle`` for every joint pulley the tendon crosses (non-zero entry of ``P(0)``); the thumb base
    tendons run straight from the palm, so they get the palm bend only."""
    P = np.asarray(coupling.P(np.zeros(coupling.num_joints)), dtype=float)
    crossed = (np.abs(P) > 0).sum(axis=1)
    for name, c in coupling.parts.items():
        if not c.is_constant:  # thumb: base rows are straight tendons
            ts = coupling.tendon_slices[name]
            crossed[ts.start:ts.start + 4] = 0
    return p.palm_bending_angle + p.joint_wrap_angle * crossed


@TemplateSystem.define("LinkGeometryPoses_", scope=sys.modules[__name__])
def LinkGeometryPoses_(T):
    """``geometry_pose`` (a ``FramePoseVector`` for SceneGraph) of ``plant``'s bodies at ``joint_angle`` (n).

    ``plant``: a finalised float MultibodyPlant registered as a SceneGraph source but not in the
    diagram (the compiled finger/hand's); connect the output to ``scene_graph.get_source_pose_port(...)``.
    """
    from pydrake.common.value import AbstractValue
    from pydrake.geometry import FramePoseVector_
    from pydrake.multibody.tree import BodyIndex

    class Impl(LeafSystem_[T]):
        def _construct(self, plant, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self._plant_float, self._plant, self._ctx = _plant_as(plant, T)
            world = plant.world_body().index()
            self._frames = []
            for i in range(plant.num_bodies()):
                fid = plant.GetBodyFrameIdIfExists(BodyIndex(i))
                if fid is not None and BodyIndex(i) != world:
                    self._frames.append((self._plant.get_body(BodyIndex(i)), fid))
            self._q = self.DeclareVectorInputPort("joint_angle", plant.num_positions())
            self.DeclareAbstractOutputPort("geometry_pose", lambda: AbstractValue.Make(FramePoseVector_[T]()),
                                           self._calc, prerequisites_of_calc={self._q.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._plant_float, converter=converter)

        def _calc(self, context, output):
            self._plant.SetPositions(self._ctx, self._q.Eval(context))
            poses = output.get_mutable_value()
            poses.clear()
            for body, fid in self._frames:
                poses.set_value(fid, self._plant.EvalBodyPoseInWorld(self._ctx, body))

    return Impl


LinkGeometryPoses = LinkGeometryPoses_[None]
