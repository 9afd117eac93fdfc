"""The ``Rig`` handle shared by all rigs (and by finger/hand diagrams)."""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import RevoluteJoint, SpatialInertia, UnitInertia
from pydrake.systems.framework import Context, Diagram

__all__ = ["OperatingPoint", "Rig", "RigPorts", "add_revolute_link", "state_names"]


def _labels(items) -> list[str]:
    return [str(i) for i in range(items)] if isinstance(items, int) else [str(s) for s in items]


def state_names(*, joints=0, motors=0, hysteresis: bool = False, guide_friction: bool = False,
                joint_friction: bool = False) -> tuple[str, ...]:
    """The one state-naming scheme of every rig, finger and the hand (diagram state order).

    ``joint_angle[j]``, ``joint_velocity[j]``, ``motor_angle[i]``, ``motor_velocity[i]`` (output shaft), then
    when present ``hysteresis_force[i]``, ``guide_friction_force[i]``, ``joint_friction_torque[j]``.  ``joints``
    and ``motors`` are counts (labels ``0, 1, ...``) or sequences of labels (joint names, tendon names).
    """
    j, m = _labels(joints), _labels(motors)
    return tuple([f"joint_angle[{a}]" for a in j] + [f"joint_velocity[{a}]" for a in j]
                 + [f"motor_angle[{a}]" for a in m] + [f"motor_velocity[{a}]" for a in m]
                 + ([f"hysteresis_force[{a}]" for a in m] if hysteresis else [])
                 + ([f"guide_friction_force[{a}]" for a in m] if guide_friction else [])
                 + ([f"joint_friction_torque[{a}]" for a in j] if joint_friction else []))


@dataclass(frozen=True)
class OperatingPoint:
    """An equilibrium of a rig: its full state (``Rig.state_names`` order), the motor torques [Nm] and
    external joint torques [Nm] (rigs with joints) that hold it, and what defined it or follows from it:
    the common tendon ``pretension`` [N], ``joint_angle`` and ``wrist_angle`` [rad], per tendon the
    ``tendon_force`` [N], spring ``elongation`` [m] and ``tendon_stiffness`` df/dx [N/m], the
    ``joint_stiffness`` [Nm/rad] (a number for one joint: ``r_q^2 (k1 + k2)`` of the joint rig, the torsion
    spring of the flexible joint; the matrix (5.12) for fingers and the hand) and the torsion spring's
    ``spring_torque`` [Nm] (flexible joint).  None: not defined for the rig.
    """

    state: np.ndarray
    motor_torque: np.ndarray
    external_torque: np.ndarray | None = None
    pretension: float | None = None
    joint_angle: np.ndarray | None = None
    wrist_angle: np.ndarray | None = None
    tendon_force: np.ndarray | None = None
    elongation: np.ndarray | None = None
    tendon_stiffness: np.ndarray | None = None
    joint_stiffness: float | np.ndarray | None = None
    spring_torque: float | None = None


@dataclass
class RigPorts:
    """A rig's systems added to a caller's ``DiagramBuilder`` without a sub-diagram of their own
    (``Rig.add_sampled``): its input ports by name (a list each: one rig input may feed several systems),
    its output ports by name (in the rig diagram's order), the system holding its dynamics and the
    zero-order hold of its input (or None)."""

    inputs: dict
    outputs: dict
    dynamics: Any
    hold: Any = None

    def GetInputPort(self, name: str) -> list:
        return self.inputs[name]

    def GetOutputPort(self, name: str):
        return self.outputs[name]

    def export(self, builder) -> None:
        """Export every port of the rig from ``builder`` under its name."""
        for name, targets in self.inputs.items():
            builder.ExportInput(targets[0], name)
            for port in targets[1:]:
                builder.ConnectInput(name, port)
        for name, port in self.outputs.items():
            builder.ExportOutput(port, name)


@dataclass
class Rig:
    """A plant diagram with named ports, its parameters and its operating points.

    ``diagram`` exports the input ``motor_torque`` (and ``external_torque`` for link rigs) and the outputs
    ``state`` and named physical quantities; ``state_names`` names its continuous state in diagram order;
    ``equilibrium(**kwargs) -> OperatingPoint`` (see :meth:`operating_point`); ``spring`` is the spring law
    used, ``drive`` the tendon-drive handle and ``coupling`` its routing (``h(q)``, ``P(q)``).  For the
    monitors: ``tension_only`` (slack is monitored on ``tendon_force``), ``torque_limit`` [Nm] (None: no
    saturation), ``max_force`` [N] (upper end of the calibrated spring range), ``pair_slack`` ``(x0, r)`` of an
    antagonistic torsion-spring pair whose hidden tendons can slacken, ``spring_kind`` (``"linear"`` or
    ``"nonlinear"``, flexible joint) and ``tendon_force_of_state`` (``states (T, n_states) -> forces (T, m)``,
    the ``tendon_force`` law over logged samples).  ``joint_sensors``: the joint angles are measured (False for
    fingers and the hand, :class:`~awiwi_drake.hand.diagrams.HandRig`, whose ``link_estimator()`` estimates them).

    The single-joint rigs also have a sampled form (None elsewhere): ``sampled_diagram(period,
    hold_applied_torque=False)`` is a new diagram with the same ports whose dynamics are Drake's
    ``DiscreteTimeApproximation`` at ``period`` [s] (fixed-step RK3, one step per period, input held), in the
    integration coordinates of :func:`~awiwi_drake.components.rig_system.rig_integration_system` (its
    ``state`` output is physical); ``sampled_state(state)`` maps a physical state into them;
    ``add_sampled(builder, period, hold_applied_torque=False) -> RigPorts`` adds the same systems to a
    caller's builder without a sub-diagram (what :func:`~awiwi_drake.control.closed_loop` does).
    """

    name: str
    diagram: Diagram
    params: Any
    state_names: tuple
    equilibrium: Callable[..., OperatingPoint]
    plant: MultibodyPlant | None = None
    spring: Any = None
    drive: Any = None
    coupling: Any = None
    tension_only: bool = True
    torque_limit: float | None = None
    max_force: float | None = None
    pair_slack: tuple | None = None
    spring_kind: str | None = None
    tendon_force_of_state: Callable | None = None
    joint_sensors: bool = True
    sampled_diagram: Callable[[float], Diagram] | None = None
    sampled_state: Callable | None = None
    add_sampled: Callable | None = None

    @property
    def num_states(self) -> int:
        return len(self.state_names)

    @property
    def input_names(self) -> list[str]:
        return [self.diagram.get_input_port(i).get_name() for i in range(self.diagram.num_input_ports())]

    @property
    def output_names(self) -> list[str]:
        return [self.diagram.get_output_port(i).get_name() for i in range(self.diagram.num_output_ports())]

    def operating_point(self, **kwargs) -> OperatingPoint:
        """The equilibrium named by ``kwargs`` (see the rig's builder for the keys).

        Every given value must be finite (NaN/inf raise a ``ValueError`` naming the
        key), and so must the resulting state and torques.
        """
        params = inspect.signature(self.equilibrium).parameters
        if not any(q.kind is inspect.Parameter.VAR_KEYWORD for q in params.values()):
            known = [n for n, q in params.items()
                     if q.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)]
            for key in kwargs:
                if key not in known:
                    raise ValueError(f"{self.name}.operating_point: unknown key {key!r}; known: "
                                     f"{', '.join(known) if known else '(none)'}")
        for key, value in kwargs.items():
            if value is None or isinstance(value, str):
                continue
            try:
                arr = np.asarray(value, dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f"{self.name}.operating_point: {key} = {value!r} is not a number "
                                 f"or a sequence of numbers") from None
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{self.name}.operating_point: {key} = {value!r} must be finite")
        op = self.equilibrium(**kwargs)
        if not (np.all(np.isfinite(op.state)) and np.all(np.isfinite(op.motor_torque))):
            raise ValueError(f"{self.name}.operating_point({', '.join(f'{k}={v!r}' for k, v in kwargs.items())}) "
                             f"has no finite equilibrium")
        return op

    def context(self, op: OperatingPoint | None = None) -> Context:
        """A context at ``op`` (default operating point if None) with all inputs fixed."""
        op = self.operating_point() if op is None else op
        ctx = self.diagram.CreateDefaultContext()
        self.set_operating_point(ctx, op)
        return ctx

    def set_operating_point(self, context: Context, op: OperatingPoint, *, fix_inputs: bool = True) -> None:
        """Write ``op`` into the rig's (sub)context; fix its inputs unless told not to."""
        state = np.asarray(op.state, dtype=float)
        if state.shape != (self.num_states,):
            raise ValueError(f"{self.name}: operating point state has {state.size} entries, "
                             f"expected {self.num_states} ({', '.join(self.state_names)})")
        context.SetContinuousState(state)
        if fix_inputs:
            self.diagram.GetInputPort("motor_torque").FixValue(context, np.asarray(op.motor_torque, dtype=float))
            if self.diagram.HasInputPort("external_torque"):
                ext = op.external_torque if op.external_torque is not None else \
                    np.zeros(self.diagram.GetInputPort("external_torque").size())
                self.diagram.GetInputPort("external_torque").FixValue(context, np.asarray(ext, dtype=float))


def add_revolute_link(plant: MultibodyPlant, *, name: str, inertia: float, damping: float,
                      mass: float = 0.02) -> RevoluteJoint:
    """Add one link on a revolute joint about z to ``plant``.

    The centre of mass is on the joint axis (gravity, along -z, gives no torque;
    the thesis finds gravity negligible, ch. 5) and the rotational inertia about
    the axis is ``inertia`` [kg m^2]. ``mass`` only matters for reaction forces.
    """
    if not inertia > 0 or not mass > 0 or damping < 0:
        raise ValueError(f"add_revolute_link: need inertia > 0, mass > 0, damping >= 0 (got {inertia}, {mass}, {damping})")
    I_unit = inertia / mass
    body = plant.AddRigidBody(f"{name}_body", SpatialInertia(mass, np.zeros(3), UnitInertia(I_unit, I_unit, I_unit)))
    joint = plant.AddJoint(RevoluteJoint(name, plant.world_frame(), body.body_frame(), [0.0, 0.0, 1.0], damping))
    plant.AddJointActuator(f"{name}_tendons", joint)
    return joint
