"""Finger and hand diagrams: links (a MultibodyPlant's dynamics) + motors, springs and routing in one system.

``finger_diagram(finger=...)`` and ``hand_diagram()`` return a :class:`HandRig` (a
:class:`awiwi_drake.rigs.Rig`), so ``analysis.linearize`` / ``analysis.simulate`` work on them.  The
plant is one system, ``hand_dynamics`` (:class:`~awiwi_drake.hand.dynamics.HandDynamics_`: its ports and
state order); ``rig.plant`` is its (standalone) MultibodyPlant.  The diagram exports its inputs
``motor_torque``, ``external_torque`` and with ``wrist=True`` ``wrist_angle`` (2) = [q71, q73] [rad]; its
outputs, and the slices ``joint_angle`` / ``joint_velocity`` (n), ``motor_angle`` / ``motor_velocity`` /
``motor_state``, ``wrist_tendon_offset`` (with the wrist) and ``joint_friction_torque`` (with the joints'
stick-slip friction, ``params.joint_friction``).

The wrist enters the routing like extra joints: the drive's coupling is the finger coupling plus ``m``
length-offset "joints" (identity columns of ``P``) fed by
:class:`~awiwi_drake.hand.systems.WristTendonOffsets_` (Table 6.2 order = our global tendon order,
``parameters.hand.TENDON_SLICES``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydrake.geometry import SceneGraph
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, MatrixGain

from ..components.fused_drive import TendonDrive
from ..components.motor import motor_ripple_torque, tendon_motor_params
from ..components.spring import TendonSprings, tendon_spring
from ..parameters.hand import (FINGERS, TENDON_SLICES, FingerRigParams,
                               HandRigParams)
from ..rigs.base import OperatingPoint, Rig
from ..rigs.base import state_names as rig_state_names
from .coupling import HandCoupling, dof_selection, finger_coupling
from .plant import coupling_force_gain, make_finger_plant, make_hand_plant
from .systems import tendon_bending_angles

__all__ = ["HandRig", "finger_diagram", "hand_diagram"]


@dataclass
class HandRig(Rig):
    """A :class:`Rig` for fingers and the hand; fixes the ``wrist_angle`` input too.

    Beyond :class:`Rig`: ``coupling`` is the finger/hand coupling without wrist
    offsets (the drive's, with them, is ``drive.model.coupling``), ``models`` the FingerModel
    handles, ``joint_names`` and ``tendon_names`` in state order, ``offsets`` the
    spring pre-elongations x0 [m], ``coupling_gain`` G, ``spring_laws`` the
    :class:`~awiwi_drake.components.spring.TendonSprings` of the tendons (one law per tendon,
    ``params.tendon_springs`` overrides; :attr:`Rig.spring` is the default law), ``joint_friction`` the joints'
    stick-slip friction the plant integrates (:attr:`~awiwi_drake.hand.dynamics.LinkModel.joint_friction`: n x 4,
    Coulomb, breakaway, Stribeck velocity, presliding angle per joint; None when off).
    """

    models: Any = None
    joint_names: list = field(default_factory=list)
    tendon_names: list = field(default_factory=list)
    offsets: Any = None
    coupling_gain: Any = None
    spring_laws: Any = None
    joint_friction: Any = None
    joint_sensors: bool = False          # the hand measures motor angles and tendon forces only (ch. 5.4)

    def set_operating_point(self, context, op, *, fix_inputs: bool = True) -> None:
        super().set_operating_point(context, op, fix_inputs=fix_inputs)
        if fix_inputs and self.diagram.HasInputPort("wrist_angle"):
            self.diagram.GetInputPort("wrist_angle").FixValue(
                context, np.zeros(2) if op.wrist_angle is None else np.asarray(op.wrist_angle, dtype=float))

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    def link_estimator(self, period: float | None = None, params=None):
        """The joint-state estimator from tendon lengths ((5.15), Algorithm 1): the hand has no joint sensors.

        A :class:`~awiwi_drake.hand.estimation.LinkStateEstimator` reading this rig's outputs (what
        :func:`awiwi_drake.control.closed_loop` uses unless ``sensors="ideal"``), sampling every ``period`` s but
        never faster than ``params.rate_hz`` (:class:`~awiwi_drake.parameters.hand_control.LinkEstimatorParams`).
        """
        from ..parameters.hand_control import LinkEstimatorParams
        from .estimation import link_state_estimator
        p = params or LinkEstimatorParams()
        period = 1.0 / p.rate_hz if period is None else max(float(period), 1.0 / p.rate_hz)
        return link_state_estimator(self.coupling, self.params.motor.pulley_radius, self.offsets,
                                    period=period, wrist=self.diagram.HasInputPort("wrist_angle"),
                                    iterations=p.iterations, step0=p.initial_step, refine=p.gauss_newton_refinement,
                                    velocity_time_constant=max(p.velocity_time_constant, period))

    def joint_angles_of(self, state) -> np.ndarray:
        """The joint angles (plant positions) in a rig state vector."""
        return np.asarray(state, dtype=float)[: self.num_joints]

    @property
    def num_tendons(self) -> int:
        return len(self.tendon_names)


def tendon_spring_laws(p, tendon_names) -> TendonSprings:
    """One spring law per tendon: ``p.spring`` for all, ``p.tendon_springs`` overriding by tendon name (names
    checked by the parameter set).  Equal parameter sets share one law object (one fit, one kernel branch)."""
    own = dict(p.tendon_springs)
    return TendonSprings([tendon_spring(own.get(t, p.spring)) for t in tendon_names])


def tendon_hysteresis(p, tendon_names):
    """The spring hysteresis of a drive: ``p.spring.hysteresis`` when every tendon has it, else one
    :class:`~awiwi_drake.parameters.components.HysteresisParams` per tendon (``p.tendon_springs`` entries
    set their own, e.g. a loop on one tendon only)."""
    own = dict(p.tendon_springs)
    per = tuple(own[t].hysteresis if t in own else p.spring.hysteresis for t in tendon_names)
    return p.spring.hysteresis if all(h == p.spring.hysteresis for h in per) else per


def _build(name, p, plant_factory, parts, wrist, visual):
    """Shared builder of finger and hand diagrams."""
    b = DiagramBuilder()
    sg = SceneGraph() if visual else None
    plant, models = plant_factory(sg)
    n = plant.num_positions()
    coupling = HandCoupling(parts) if len(parts) > 1 else next(iter(parts.values()))
    m = coupling.num_tendons
    if coupling.num_joints != n:
        raise ValueError(f"{name}: coupling has {coupling.num_joints} joints, plant {n}")
    drive_coupling = HandCoupling(parts, num_offsets=m) if wrist else coupling
    laws = tendon_spring_laws(p, coupling.tendon_names)
    spring = laws[0]
    offsets = laws.inverse_force(np.full(m, p.pretension))
    rows = np.concatenate([np.arange(38)[TENDON_SLICES[f]] for f in parts])      # Table 6.2 rows, routing order
    if rows.size != m:
        counts = ", ".join(f"{f}: {c.num_tendons}" for f, c in parts.items())
        raise ValueError(f"{name}: the fingers have {m} tendons ({counts}) but the global tendon order "
                         f"(parameters.hand.TENDON_SLICES) assigns {rows.size} Table 6.2 rows to them")
    G = coupling_force_gain(plant, models)
    model, links = _add_plant(b, name, p, plant, coupling, drive_coupling, laws, offsets, G, rows, wrist, sg)
    diagram = b.Build()
    diagram.set_name(name)
    # the drive lives inside the one plant system: its handle points at the rig
    drive = TendonDrive(diagram, model)
    joint_names = [plant.get_joint(plant.GetJointIndices()[i]).name() for i in range(n)]
    state_names = rig_state_names(joints=joint_names, motors=coupling.tendon_names, hysteresis=model.has_hysteresis,
                                  guide_friction=model.has_guide_friction, joint_friction=p.joint_friction)

    def equilibrium(pretension: float | None = None, joint_angles=None, external_torque=None,
                    wrist_angle=None) -> OperatingPoint:
        return _equilibrium(name, p, plant, coupling, laws, offsets, G, rows if wrist else None, pretension,
                            joint_angles, external_torque, wrist_angle,
                            model.num_states - 2 * m + (n if p.joint_friction else 0))

    return HandRig(name, diagram, p, state_names, equilibrium, plant, spring, drive=drive, coupling=coupling,
                   tension_only=True, torque_limit=p.motor.torque_limit if p.motor.saturation else None,
                   models=models, joint_names=joint_names,
                   tendon_names=list(coupling.tendon_names), offsets=offsets, coupling_gain=G, spring_laws=laws,
                   joint_friction=links.joint_friction)


def _add_wrist_offsets(b, rows, m):
    """``wrist_angle`` input -> the (6.9) length offsets of this rig's tendons (exported ``wrist_tendon_offset``)."""
    from .systems import WristTendonOffsets
    w = b.AddNamedSystem("wrist_tendon_offsets", WristTendonOffsets())
    select = np.zeros((m, 38))
    select[np.arange(m), rows] = 1.0
    sel = b.AddNamedSystem("wrist_offset_select", MatrixGain(select))
    b.Connect(w.get_output_port(0), sel.get_input_port())
    b.ExportInput(w.get_input_port(0), "wrist_angle")
    b.ExportOutput(sel.get_output_port(), "wrist_tendon_offset")
    return sel.get_output_port()


def _add_plant(b, name, p, plant, coupling, drive_coupling, laws, offsets, G, rows, wrist, sg):
    """The plant: links and drive in one :class:`~.dynamics.HandDynamics_` (compiled float path); returns its
    ``(DriveModel, LinkModel)``."""
    from ..components.fused_drive import DriveModel, GuideFrictionModel
    from .dynamics import HandDynamics_, LinkModel
    n, m = coupling.num_joints, coupling.num_tendons
    own = dict(p.tendon_guides)         # tendon names checked by the parameter set
    angles = tendon_bending_angles(coupling, p) if p.guide_friction else np.zeros(m)   # 0 rad: no friction
    gf = GuideFrictionModel(tuple(angles), p.friction, p.capstan_friction, p.friction_smoothing_velocity,
                            p.guide_presliding_length,
                            tuple((list(coupling.tendon_names).index(t), g.constant, g.capstan_exponent)
                                  for t, g in own.items())) if p.guide_friction or own else None
    model = DriveModel(tendon_motor_params(p, coupling.tendon_names), laws.laws, drive_coupling, offsets,
                       p.motor.pulley_radius, tendon_hysteresis(p, coupling.tendon_names), gf, n)
    links = LinkModel(plant, G, _joint_friction(p, plant) if p.joint_friction else None)
    dyn = b.AddNamedSystem("hand_dynamics", HandDynamics_[float](model, links))
    if wrist:
        b.Connect(_add_wrist_offsets(b, rows, m), dyn.GetInputPort("wrist_tendon_offset"))
    for nm in ("motor_torque", "external_torque"):
        b.ExportInput(dyn.GetInputPort(nm), nm)
    for nm in ("state", "joint_torque", "tendon_force", "tendon_stiffness", "elongation", "applied_torque"):
        b.ExportOutput(dyn.GetOutputPort(nm), nm)
    # state slices in C++ (a Python slicer costs ~3-4 us per read)
    rest = model.num_states - 2 * m
    nf = links.num_friction_states
    split = b.AddNamedSystem("state_split", Demultiplexer([n, n, 2 * m] + ([rest] if rest else []) + ([nf] if nf else [])))
    if nf:
        b.ExportOutput(split.get_output_port(4 if rest else 3), "joint_friction_torque")
    b.Connect(dyn.GetOutputPort("state"), split.get_input_port())
    motor = b.AddNamedSystem("motor_state_split", Demultiplexer([m, m]))
    b.Connect(split.get_output_port(2), motor.get_input_port())
    for port, nm in ((split.get_output_port(0), "joint_angle"), (split.get_output_port(1), "joint_velocity"),
                     (split.get_output_port(2), "motor_state"), (motor.get_output_port(0), "motor_angle"),
                     (motor.get_output_port(1), "motor_velocity")):
        b.ExportOutput(port, nm)
    if sg is not None:
        from .systems import LinkGeometryPoses
        b.AddNamedSystem("scene_graph", sg)
        pose = b.AddNamedSystem("geometry_pose", LinkGeometryPoses(plant))
        b.Connect(split.get_output_port(0), pose.get_input_port())
        b.Connect(pose.get_output_port(), sg.get_source_pose_port(plant.get_source_id()))
        b.ExportOutput(sg.get_query_output_port(), "query_object")
    return model, links


def _joint_friction(p, plant) -> np.ndarray:
    """Per plant joint (position order) ``[coulomb, static, stribeck_velocity, presliding_angle]`` of the joints'
    stick-slip friction: ``p.joint_friction_params``, ``p.joint_frictions`` overriding joints by name."""
    names = [plant.get_joint(j).name() for j in plant.GetJointIndices() if plant.get_joint(j).num_positions()]
    starts = [plant.get_joint(j).position_start() for j in plant.GetJointIndices() if plant.get_joint(j).num_positions()]
    own = dict(p.joint_frictions)
    for joint in own:
        if joint not in names:
            raise ValueError(f"joint_frictions: unknown joint {joint!r}; joints are {', '.join(names)}")
    out = np.empty((plant.num_positions(), 4))
    for name, k in zip(names, starts):
        jp = own.get(name, p.joint_friction_params)
        out[k] = (jp.coulomb, jp.static, jp.stribeck_velocity, jp.presliding_angle)
    return out


def _equilibrium(name, p, plant, coupling, laws, offsets, G, wrist_rows, pretension, joint_angles,
                 external_torque, wrist_angle, num_friction_states=0):
    """Static equilibrium ``-P(q)^T f + tau_c(q) + tau_g(q) + tau_ext = 0``, ``f`` closest to the pretension."""
    n, m = coupling.num_joints, coupling.num_tendons
    f0 = p.pretension if pretension is None else float(pretension)
    if not f0 > 0:
        raise ValueError(f"{name}: pretension = {f0} must be > 0 [N]")
    S = dof_selection(coupling)
    if joint_angles is None:
        q = np.zeros(n)
    else:
        qa = np.asarray(joint_angles, dtype=float).ravel()
        if qa.shape == (S.shape[1],) and S.shape[1] != n:
            q = S @ qa                       # independent DoF given: DIP follows (5.16)-(5.17)
        elif qa.shape == (n,):
            q = qa
        else:
            raise ValueError(f"{name}: joint_angles must have {n} (plant joints) or {S.shape[1]} (DoF) "
                             f"entries, got {qa.size}")
    tau_ext = np.zeros(n) if external_torque is None else np.asarray(external_torque, dtype=float).ravel()
    if tau_ext.shape != (n,):
        raise ValueError(f"{name}: external_torque must have {n} entries, got {tau_ext.size}")
    tau_c = np.zeros(n) if G is None else -G[:, :n] @ q
    tau_g = np.zeros(n)
    if p.gravity:
        pctx = plant.CreateDefaultContext()
        plant.SetPositions(pctx, q)
        tau_g = plant.CalcGravityGeneralizedForces(pctx)
    P = np.asarray(coupling.P(q), dtype=float)
    # P^T f = tau_ext + tau_c + tau_g ; f = particular + f0 * projection of 1 onto ker(P^T)
    rhs = tau_ext + tau_c + tau_g
    f_part, *_ = np.linalg.lstsq(P.T, rhs, rcond=None)
    if np.linalg.norm(P.T @ f_part - rhs) > 1e-9 * max(1.0, np.linalg.norm(rhs)):
        raise ValueError(f"{name}: the tendons cannot balance external_torque/joint_angles here (the "
                         "coupled DIP must satisfy q_DIP = (r_x3/r_x2) q_PIP and carry no separate torque)")
    ones = np.ones(m)
    f_null = ones - P @ np.linalg.lstsq(P, ones, rcond=None)[0]
    f = f_part + f0 * f_null / np.mean(f_null)
    if np.any(f <= 0):
        bad = [coupling.tendon_names[i] for i in np.flatnonzero(f <= 0)]
        raise ValueError(f"{name}: pretension {f0} N leaves tendon(s) {', '.join(bad)} slack at this "
                         f"operating point (forces {np.round(f, 3)} N)")
    x = laws.inverse_force(f)
    h0 = np.asarray(coupling.h(np.zeros(n)), dtype=float)
    w_off = np.zeros(m)
    wa = np.zeros(2) if wrist_angle is None else np.asarray(wrist_angle, dtype=float).ravel()
    if wa.shape != (2,):
        raise ValueError(f"{name}: wrist_angle must be [q71, q73], got {wa}")
    if wrist_rows is not None:
        from .wrist import wrist_tendon_offsets
        w_off = np.asarray(wrist_tendon_offsets(wa[0], wa[1]), dtype=float)[wrist_rows]
    elif wrist_angle is not None:
        raise ValueError(f"{name}: wrist_angle given but the diagram has no wrist (wrist=False)")
    r_m = p.motor.pulley_radius
    theta = (x - offsets - (np.asarray(coupling.h(q), dtype=float) - h0) - w_off) / r_m
    u = r_m * f - np.asarray(motor_ripple_torque(theta, tendon_motor_params(p, coupling.tendon_names)), dtype=float)
    if p.motor.saturation and np.any(np.abs(u) > p.motor.torque_limit):
        raise ValueError(f"{name}: holding torques up to {np.abs(u).max():.3g} N m exceed "
                         f"motor.torque_limit = {p.motor.torque_limit} N m")
    # the hysteresis and guide friction states (Dahl) rest at 0: the pretension is the elastic force
    state = np.concatenate([q, np.zeros(n), theta, np.zeros(m), np.zeros(num_friction_states)])
    K_t = laws.stiffness(x)
    from .coupling import joint_stiffness
    Kq = joint_stiffness(coupling, q, f, K_t) + (0 if G is None else G[:, :n])
    return OperatingPoint(state, u, tau_ext, pretension=f0, joint_angle=q, tendon_force=f, elongation=x,
                          tendon_stiffness=K_t, joint_stiffness=Kq, wrist_angle=wa)


def finger_diagram(*, finger: str = "index", params: FingerRigParams | None = None,
                   wrist: bool = False, visual: bool = False) -> HandRig:
    """One finger (one of FINGERS) with its motors, springs and routing (see module docstring).

    ``params`` default ``FingerRigParams.for_finger(finger)``; ``wrist`` adds the ``wrist_angle`` input
    (the wrist's offsets of this finger's tendons enter the routing); ``visual`` registers cylinder
    geometry with a SceneGraph (for Meshcat).  Operating point keys: ``pretension`` [N], ``joint_angles``
    (plant joints or independent DoF) [rad], ``external_torque`` [N m], ``wrist_angle`` [rad].
    """
    if finger not in FINGERS:
        raise ValueError(f"finger must be one of {FINGERS}, got {finger!r}")
    p = params if params is not None else FingerRigParams.for_finger(finger)
    if not isinstance(p, FingerRigParams):
        raise ValueError(f"finger_diagram: params must be FingerRigParams, got {type(p).__name__}")
    if p.finger_name != finger:
        raise ValueError(f"finger_diagram: params.finger_name is {p.finger_name!r}, not {finger!r} "
                         f"(use FingerRigParams.for_finger({finger!r}))")
    fp = p.finger

    def plant_factory(scene_graph):
        return make_finger_plant(finger, fp, visual=visual, gravity=p.gravity, scene_graph=scene_graph)

    return _build(f"finger-{finger}", p, plant_factory, {finger: finger_coupling(finger, fp)}, wrist, visual)


def hand_diagram(*, params: HandRigParams | None = None, wrist: bool = True, visual: bool = False) -> HandRig:
    """The hand: 5 fingers (21 plant joints, 19 DoF), 38 motors and springs, wrist input, with the thesis's
    physics (:class:`~awiwi_drake.parameters.hand.FingerDriveParams`); tendons in the global order of
    ``parameters.hand``.  Same ports and operating-point keys as :func:`finger_diagram`."""
    p = params if params is not None else HandRigParams()
    if not isinstance(p, HandRigParams):
        raise ValueError(f"hand_diagram: params must be HandRigParams, got {type(p).__name__}")

    def plant_factory(scene_graph):
        return make_hand_plant(p.hand, visual=visual, gravity=p.gravity, scene_graph=scene_graph)

    parts = {f: finger_coupling(f, p.hand.finger(f)) for f in FINGERS}
    return _build("hand", p, plant_factory, parts, wrist, visual)


