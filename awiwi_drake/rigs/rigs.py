"""The test rigs of the thesis as Drake diagrams.

* :func:`motor_rig` - one free motor, no tendon: the plant of ch. 3 ((3.5)).  State ``[theta, omega]``.
* :func:`tendon_rig` - one motor winding one tendon through a spring mechanism, far end fixed: the plant
  of ch. 10 (10.1) and 14.2.1.  State ``[theta, omega]``.
* :func:`flexible_joint_rig` - motor, spring, link: the 4th-order plant (12.8) (and ch. 15.2-15.4).
  State ``[q, qdot, theta, thetadot]`` as in (12.10).
* :func:`joint_rig` - one link driven antagonistically by two motors through two nonlinear springs with
  pretension (Fig 5.9, ch. 15.5).  State ``[q, qdot, theta1, theta2, omega1, omega2]``.

A rig's dynamics are *one* C++ ``SymbolicVectorSystem`` generated from the law functions
(:mod:`awiwi_drake.components.rig_system`; no MultibodyPlant, ``Rig.plant`` is None) plus the stateless
:class:`~awiwi_drake.components.rig_system.LinkRigOutputs_` for the tendon forces, stiffnesses, joint
torque and applied torque.  Every block is named; ports are named after physical quantities.
"""

from __future__ import annotations

import functools

import numpy as np
import pydrake.symbolic as sym
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import (Demultiplexer, Multiplexer, PassThrough, Saturation, SymbolicVectorSystem,
                                        ZeroOrderHold)

from awiwi_drake.components.fused_drive import DriveModel, TendonDrive
from awiwi_drake.components.rig_system import (LinkRigOutputs_, integration_state, rig_dynamics_system,
                                                rig_integration_system, sampled_dynamics, tendon_force_of_states)
from awiwi_drake.components.motor import motor_acceleration, motor_friction_torque, motor_ripple_torque
from awiwi_drake.components.routing import ConstantCoupling, antagonistic_coupling
from awiwi_drake.components.spring import AntagonisticPairSpring, LinearSpring, TendonSprings, tendon_spring
from awiwi_drake.parameters.components import HysteresisParams, MotorParams
from awiwi_drake.parameters.rigs import FlexibleJointParams, JointRigParams, TendonRigParams
from awiwi_drake.rigs.base import OperatingPoint, Rig, RigPorts, state_names

__all__ = ["motor_rig", "tendon_rig", "flexible_joint_rig", "joint_rig"]


def _limit(motor: MotorParams):
    return motor.torque_limit if motor.saturation else None


def _check_torque(rig: str, u: np.ndarray, motor: MotorParams, what: str) -> None:
    if motor.saturation and np.any(np.abs(u) > motor.torque_limit):
        raise ValueError(f"{rig}: holding {what} needs motor torque {np.round(u, 4).tolist()} Nm, beyond "
                         f"motor.torque_limit = {motor.torque_limit} Nm")


def _check_params(params, cls, rig):
    if params is None:
        return cls()
    if not isinstance(params, cls):
        raise ValueError(f"{rig}: params must be {cls.__name__}, got {type(params).__name__}")
    return params


def tendon_rig(*, params: TendonRigParams | None = None) -> Rig:
    """One motor, one spring mechanism, tendon fixed at the far end (ch. 10, 14.2.1).

    Ports: in ``motor_torque`` (1) [Nm]; out ``state`` = [theta, omega], ``motor_angle``, ``motor_velocity``,
    ``tendon_force`` [N], ``tendon_stiffness`` [N/m], ``applied_torque`` [Nm].  Operating point key:
    ``tendon_force`` [N] (default ``params.operating_force``).
    """
    p = _check_params(params, TendonRigParams, "tendon_rig")
    spring = tendon_spring(p.spring)
    diagram, drive, names, sampled = _link_rig(
        name="tendon-rig", motor=p.motor, spring=spring, coupling=ConstantCoupling(np.zeros((1, 0))), inertia=None,
        damping=None, hysteresis=p.spring.hysteresis)

    def equilibrium(tendon_force: float | None = None) -> OperatingPoint:
        tendon_force = p.operating_force if tendon_force is None else float(tendon_force)
        if not 0 <= tendon_force <= spring.max_force:
            raise ValueError(f"tendon_rig: tendon_force = {tendon_force} N must be in [0, {spring.max_force:.1f}] N "
                             "(the calibrated spring range)")
        x = float(np.ravel(spring.inverse_force(np.array([tendon_force])))[0])
        theta = x / p.motor.pulley_radius
        u = p.motor.pulley_radius * tendon_force - float(motor_ripple_torque(np.array([theta]), p.motor)[0])
        _check_torque("tendon_rig", np.array([u]), p.motor, f"tendon_force = {tendon_force} N")
        state = [theta, 0.0] + ([0.0] if drive.model.has_hysteresis else [])
        return OperatingPoint(np.array(state), np.array([u]), None, tendon_force=np.array([tendon_force]),
                              elongation=np.array([x]), tendon_stiffness=spring.stiffness(np.array([x])))

    return Rig("tendon-rig", diagram, p, names, equilibrium, None, spring, drive=drive,
               tension_only=True, torque_limit=_limit(p.motor), max_force=spring.max_force,
               tendon_force_of_state=tendon_force_of_states(drive.model), sampled_diagram=sampled[0],
               sampled_state=sampled[1], add_sampled=sampled[2])


def _link_rig(*, name, motor, spring, coupling, inertia, damping, hysteresis, motor_pulley_radius=None):
    """A one-link rig's parts (module docstring): ``(diagram, drive, state_names, (build, sampled_state, add))``.
    ``spring``: one law for every tendon, or a :class:`~awiwi_drake.components.spring.TendonSprings`; no joint
    in ``coupling`` (``inertia`` None): the tendon rig, without the link's ports."""
    names = state_names(joints=coupling.num_joints, motors=coupling.num_tendons, hysteresis=hysteresis.enabled)
    r_m = motor.pulley_radius if motor_pulley_radius is None else float(motor_pulley_radius)
    laws = spring.laws if isinstance(spring, TendonSprings) else (spring,) * coupling.num_tendons
    link = {} if inertia is None else dict(link_inertia=(float(inertia),), link_damping=(float(damping),))
    model = DriveModel(motor, laws, coupling, np.zeros(coupling.num_tendons), r_m, hysteresis, **link)

    def add(b, period=None, *, hold_applied_torque=False) -> RigPorts:
        """The rig's systems added to the DiagramBuilder ``b`` (no sub-diagram), continuous (``period`` None) or
        sampled at ``period`` [s] (:func:`~awiwi_drake.components.rig_system.sampled_dynamics` of
        :func:`~awiwi_drake.components.rig_system.rig_integration_system`); the same ports either way.  With
        ``hold_applied_torque`` a sampled rig's ``applied_torque`` is that of the input it holds over the
        current period (a zero-order hold, also output as ``held_motor_torque``)."""
        m, n = coupling.num_tendons, coupling.num_joints
        if period is None:
            dyn = b.AddNamedSystem("rig_dynamics", rig_dynamics_system(model))
        else:   # integrated in the coordinates of rig_integration_system; its output is the physical state
            dynamics = rig_integration_system(model)
            dynamics.set_name("rig_dynamics")     # Drake names the approximation DiscreteTimeApproximated_<name>
            dyn = b.AddSystem(sampled_dynamics(dynamics, period))
        ins = {"motor_torque": [dyn.get_input_port()]}
        if n:
            inputs = b.AddNamedSystem("rig_inputs", Multiplexer([m, n]))
            b.Connect(inputs.get_output_port(), dyn.get_input_port())
            ins = {"motor_torque": [inputs.get_input_port(0)], "external_torque": [inputs.get_input_port(1)]}
        outs = {"state": dyn.get_output_port()}
        parts = [("joint_angle", n), ("joint_velocity", n)] if n else []
        parts += [("motor_angle", m), ("motor_velocity", m)] + ([("hysteresis_force", m)] if model.has_hysteresis else [])
        split = b.AddNamedSystem("state_split", Demultiplexer([size for _, size in parts]))
        b.Connect(dyn.get_output_port(), split.get_input_port())
        for i, (nm, _) in enumerate(parts):
            if nm != "hysteresis_force":
                outs[nm] = split.get_output_port(i)
        laws = b.AddNamedSystem("rig_outputs", LinkRigOutputs_[float](model))
        b.Connect(dyn.get_output_port(), laws.GetInputPort("state"))
        held = None
        if not (period is not None and hold_applied_torque):
            ins["motor_torque"].append(laws.GetInputPort("motor_torque"))
        else:   # applied_torque: the torque the sampled dynamics hold over the current period
            held = b.AddNamedSystem("motor_torque_hold", ZeroOrderHold(period, m))
            ins["motor_torque"].append(held.get_input_port())
            b.Connect(held.get_output_port(), laws.GetInputPort("motor_torque"))
            outs["held_motor_torque"] = held.get_output_port()   # for the loop's motor_torque
        for nm in ("joint_torque",) * bool(n) + ("tendon_force", "tendon_stiffness", "applied_torque"):
            outs[nm] = laws.GetOutputPort(nm)
        return RigPorts(ins, outs, dyn, held)

    def build(period=None, *, hold_applied_torque=False):
        """The rig's diagram (:func:`add` into a new builder, every port exported)."""
        b = DiagramBuilder()
        add(b, period, hold_applied_torque=hold_applied_torque).export(b)
        diagram = b.Build()
        diagram.set_name(name)
        return diagram

    drive = TendonDrive(build(), model)
    return drive.diagram, drive, names, (build, functools.partial(integration_state, model), add)


def flexible_joint_rig(*, params: FlexibleJointParams | None = None, spring: str | None = None) -> Rig:
    """Fourth-order flexible joint (12.8): motor, spring, link.

    ``m qdd = -d_q qd + tau_s + tau_ext``, ``b thdd = -d_th thd - tau_s + u``, with ``tau_s = k (theta - q)``
    (``spring="linear"``, Table 12.1) or the antagonistic lever-spring pair ``phi(theta - q)``
    (``spring="nonlinear"``, ch. 15.4); no (3.8) motor friction ((12.8) uses the damping d_theta).  Ports as
    :func:`joint_rig`'s with one motor; ``tendon_force`` is the spring torque tau_s [Nm] and
    ``tendon_stiffness`` [Nm/rad].  Operating point keys: ``joint_angle`` [rad], ``external_torque`` [Nm].
    """
    p = _check_params(params, FlexibleJointParams, "flexible_joint_rig")
    if spring is not None:  # keyword shortcut for params.spring_model
        p = p.replace(spring_model=spring)
    spring = p.spring_model
    if spring == "linear":
        default = FlexibleJointParams()
        unused = [n for n in ("pretension", "pulley_radius", "spring") if getattr(p, n) != getattr(default, n)]
        if unused:
            raise ValueError(f"flexible_joint_rig: {', '.join(unused)} only apply to spring_model='nonlinear' "
                             "(the linear spring uses stiffness)")
        law = LinearSpring(p.stiffness, tension_only=False)
    elif spring == "nonlinear":
        law = AntagonisticPairSpring(tendon_spring(p.spring), p.pretension, p.pulley_radius)
    else:
        raise ValueError(f"flexible_joint_rig: spring = {spring!r} must be 'linear' or 'nonlinear'")
    finite_limit = bool(np.isfinite(p.torque_limit))
    motor = MotorParams(inertia=p.motor_inertia, friction=False, damping=p.motor_damping, ripple=False,
                        saturation=finite_limit, torque_limit=p.torque_limit if finite_limit else 1.0)
    diagram, drive, names, sampled = _link_rig(
        name="flexible-joint", motor=motor, spring=law, coupling=ConstantCoupling([[-1.0]]),
        inertia=p.link_inertia, damping=p.link_damping,
        hysteresis=HysteresisParams(),  # (12.8) and ch. 15.4 have no hysteresis
        motor_pulley_radius=1.0)

    def equilibrium(joint_angle: float = 0.0, external_torque: float = 0.0) -> OperatingPoint:
        tau_s = -float(external_torque)
        delta = float(np.ravel(law.inverse_force(np.array([tau_s])))[0]) if spring == "nonlinear" else tau_s / p.stiffness
        state = np.array([joint_angle, 0.0, joint_angle + delta, 0.0] + ([0.0] if drive.model.has_hysteresis else []))
        if finite_limit and abs(tau_s) > p.torque_limit:
            raise ValueError(f"flexible_joint_rig: external_torque = {external_torque} Nm needs a motor torque "
                             f"beyond torque_limit = {p.torque_limit} Nm")
        return OperatingPoint(state, np.array([tau_s]), np.array([float(external_torque)]),
                              joint_angle=np.array([joint_angle]), spring_torque=tau_s,
                              joint_stiffness=float(np.ravel(law.stiffness(np.array([delta])))[0]))

    return Rig("flexible-joint", diagram, p, names, equilibrium, None, law, drive=drive,
               spring_kind=spring, tension_only=False, torque_limit=p.torque_limit if finite_limit else None,
               pair_slack=(law.x0, law.r) if spring == "nonlinear" else None, sampled_diagram=sampled[0],
               sampled_state=sampled[1], add_sampled=sampled[2])


def joint_rig(*, params: JointRigParams | None = None) -> Rig:
    """One link, two antagonistic motors and nonlinear springs with pretension (Fig 5.9, ch. 15.5).

    ``x1 = r_m th1 - r_q q``, ``x2 = r_m th2 + r_q q``, ``f_i = f(x_i)``,
    ``m qdd = r_q (f1 - f2) - d_q qd + tau_ext``, motors per (3.5).

    Ports: in ``motor_torque`` (2), ``external_torque`` (1) [Nm]; out ``state``, ``joint_angle``,
    ``joint_velocity``, ``motor_angle`` (2), ``motor_velocity`` (2), ``tendon_force`` (2) [N],
    ``tendon_stiffness`` (2) [N/m], ``joint_torque`` [Nm], ``applied_torque`` (2).  Operating point keys:
    ``pretension`` [N] (default ``params.pretension``), ``joint_angle`` [rad], ``external_torque`` [Nm]; the
    joint stiffness there is ``r_q^2 (k1 + k2)``.
    """
    p = _check_params(params, JointRigParams, "joint_rig")
    spring = tendon_spring(p.spring)
    coupling = antagonistic_coupling(p.link_pulley_radius)
    diagram, drive, names, sampled = _link_rig(
        name="joint-rig", motor=p.motor, spring=spring, coupling=coupling, inertia=p.link_inertia,
        damping=p.link_damping, hysteresis=p.spring.hysteresis)
    r, rq = p.motor.pulley_radius, p.link_pulley_radius

    def equilibrium(pretension: float | None = None, joint_angle: float = 0.0,
                    external_torque: float = 0.0) -> OperatingPoint:
        f0 = p.pretension if pretension is None else float(pretension)
        f = np.array([f0 - external_torque / (2 * rq), f0 + external_torque / (2 * rq)])
        if np.any(f > spring.max_force):
            raise ValueError(f"joint_rig: pretension {f0} N with external_torque {external_torque} Nm needs tendon "
                             f"forces {f} N beyond the calibrated range ({spring.max_force:.1f} N)")
        if np.any(f <= 0):
            raise ValueError(f"joint_rig: pretension {f0} N cannot hold external_torque {external_torque} Nm "
                             f"without slack (tendon forces would be {f} N)")
        x = np.asarray(spring.inverse_force(f), dtype=float)
        theta = np.array([(x[0] + rq * joint_angle) / r, (x[1] - rq * joint_angle) / r])
        u = r * f - motor_ripple_torque(theta, p.motor)
        _check_torque("joint_rig", u, p.motor, f"pretension = {f0} N")
        hysteresis = np.zeros(2) if drive.model.has_hysteresis else []
        state = np.concatenate([[joint_angle, 0.0], theta, [0.0, 0.0], hysteresis])
        k = np.asarray(spring.stiffness(x), dtype=float)
        return OperatingPoint(state, u, np.array([float(external_torque)]), pretension=f0,
                              joint_angle=np.array([joint_angle]), tendon_force=f, elongation=x, tendon_stiffness=k,
                              joint_stiffness=float(rq ** 2 * k.sum()))

    return Rig("joint-rig", diagram, p, names, equilibrium, None, spring, drive=drive,
               coupling=coupling, tension_only=True, torque_limit=_limit(p.motor), max_force=spring.max_force,
               tendon_force_of_state=tendon_force_of_states(drive.model),
               sampled_diagram=sampled[0], sampled_state=sampled[1], add_sampled=sampled[2])


def motor_rig(motor: MotorParams | None = None) -> Rig:
    """One free motor (no tendon): ``B thdd = sat(u) + tau_fric + tau_ripple`` ((3.5)); state [theta, omega].

    The dynamics are one C++ ``SymbolicVectorSystem`` generated from the law
    (:func:`~awiwi_drake.components.motor.motor_acceleration`), as the link rigs' are; ``applied_torque`` is
    the command after Drake's ``Saturation`` (``sat(u)``, the law's :func:`~awiwi_drake.components.motor.saturate_torque`).
    """
    p = motor or MotorParams()
    if not isinstance(p, MotorParams):
        raise ValueError(f"motor_rig: motor must be MotorParams, got {type(p).__name__}")
    theta, omega, u = sym.Variable("theta"), sym.Variable("omega"), sym.Variable("u")
    with np.errstate(invalid="ignore"):     # symbolic object arrays leave meaningless FPU flags
        acc = motor_acceleration(*(np.array([sym.Expression(v)]) for v in (theta, omega, u)), 0.0, p)[0]
    b = DiagramBuilder()
    dyn = b.AddNamedSystem("motor", SymbolicVectorSystem(state=[theta, omega], input=[u], dynamics=[omega, acc],
                                                         output=[theta, omega]))
    split = b.AddNamedSystem("motor_state_split", Demultiplexer([1, 1]))
    sat = b.AddNamedSystem("torque_saturation", Saturation([-p.torque_limit], [p.torque_limit]) if p.saturation
                           else PassThrough(1))
    b.Connect(dyn.get_output_port(), split.get_input_port())
    b.ExportInput(dyn.get_input_port(), "motor_torque")
    b.ConnectInput("motor_torque", sat.get_input_port(0))
    for port, nm in ((dyn.get_output_port(), "state"), (split.get_output_port(0), "motor_angle"),
                     (split.get_output_port(1), "motor_velocity"), (sat.get_output_port(0), "applied_torque")):
        b.ExportOutput(port, nm)
    d = b.Build()
    d.set_name("motor-rig")

    def equilibrium(motor_velocity: float = 0.0) -> OperatingPoint:
        w = float(motor_velocity)
        return OperatingPoint(np.array([0.0, w]), -np.atleast_1d(motor_friction_torque(np.array([w]), p)))

    return Rig("motor-rig", d, p, state_names(motors=1), equilibrium)
