"""The hand's control structure as blocks (thesis ch. 7-11), for a finger or the whole hand.

::

    joint_angle_reference ─> JointStage_ ─ joint_torque_reference ──> TendonForceDistribution_ (ch. 7)
    joint_angle, joint_velocity ┘ (estimated)  └ joint_stiffness_reference ┘        │ tendon_force_reference
    (tendon_force, tendon_stiffness, motor_velocity: torque feedback laws)          v
    tendon_force, motor_velocity, motor_angle ──────────────> TendonForceLaw bank (ch. 10 (10.2), ch. 3) ─> motor_torque

* :class:`~awiwi_drake.control.joint_stage.JointStage_` -- the joint-level stage, a plug-in: one law for all
  independent DoF ``q_dof = S^+ q`` (ring/fifth: the DIP follows the PIP, (5.16)) giving the desired DoF torques
  and the desired *mechanical* joint stiffness (co-contraction) for the distribution; the stages are designed per
  DoF in :mod:`awiwi_drake.control.joint_design`, which also holds the registered factories.
* :class:`TendonForceStage` -- desired DoF torques -> tendon forces -> motor torques: the ch. 7 distribution
  (:class:`~awiwi_drake.control.force_distribution.TendonForceDistributionSystem`, sampled and warm-started) or,
  for a continuous loop (linear analysis), the sharing (15.88) ``f_ref = f_op + W (tau_ref - tau_op)``,
  ``W = -((P S)^T)^+``; then per tendon (10.2) (:class:`~awiwi_drake.control.tendon_force.TendonForceLaw`, gains
  (10.11) scheduled on the reference (10.12) with each tendon's own spring curve, :func:`rig_springs`) or the
  ch. 14 tendon SDRE (:class:`~awiwi_drake.control.sdre.TendonSdreLaw`), friction (3.8) and ripple (3.5) fed forward.

:class:`TendonChainController` wires both into one controller with the port contract of
:mod:`awiwi_drake.control.base` (extra outputs ``tendon_force_reference``, ``joint_torque_reference``,
``joint_stiffness_reference``, ``distribution_status``); on a finger or the hand
:func:`~awiwi_drake.control.base.closed_loop` feeds ``joint_angle`` / ``joint_velocity`` from the tendon-length
estimator (no joint sensors).
"""

from __future__ import annotations

import sys
from dataclasses import replace
from typing import Any

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem_
from pydrake.systems.primitives import AffineSystem
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake.components.friction import guide_friction_level
from awiwi_drake.components.spring import TendonSprings
from awiwi_drake.control.design import ChainDesign, ControllerDesign
from awiwi_drake.rigs.base import Rig
from awiwi_drake.control.base import StaticLaw, StaticLawController, check_rate
from awiwi_drake.control.force_distribution import TendonForceDistributionSystem
from awiwi_drake.control.joint_stage import JointStage
from awiwi_drake.control.tendon_force import ForceMap, TendonForceLaw
from awiwi_drake.parameters.control import TendonForceGains
from awiwi_drake.hand.coupling import dof_selection
from awiwi_drake.hand.diagrams import HandRig
from awiwi_drake.parameters.hand import FINGERS
from awiwi_drake.parameters.hand_control import ForceDistributionParams, FrictionObserverParams, HandChainParams

__all__ = ["TendonPathVelocity_", "TendonPathVelocity", "TendonForceStage", "TendonChainController",
           "chain_design_point", "rig_springs", "guide_friction_levels", "joint_friction_levels"]


def rig_springs(rig: Any) -> TendonSprings:
    """The spring law of each tendon of a rig (:class:`~awiwi_drake.components.spring.TendonSprings`): a
    finger's/the hand's ``spring_laws`` (``params.tendon_springs`` overrides), else ``rig.spring`` for all."""
    if isinstance(rig, HandRig):
        return rig.spring_laws
    if isinstance(rig.spring, TendonSprings):          # e.g. a per-joint subsystem (joint_design.joint_subsystem)
        return rig.spring
    return TendonSprings([rig.spring] * rig.coupling.num_tendons)


def guide_friction_levels(rig: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(C, mu alpha)`` per tendon (m each) of the rig's own guide friction, the parameters its plant uses
    (:meth:`~awiwi_drake.components.fused_drive.GuideFrictionModel.levels`); zeros when its guides have no friction."""
    drive = getattr(rig, "drive", None)
    gm = None if drive is None else drive.model.guide_friction
    m = rig.coupling.num_tendons
    return gm.levels() if gm is not None else (np.zeros(m), np.zeros(m))


def joint_friction_levels(rig: Any) -> np.ndarray:
    """The breakaway level ``Fs`` [Nm] per plant joint (n) of the rig's own stick-slip joint friction (the most it can
    hold, :func:`~awiwi_drake.components.friction.stick_slip_rate`; ``HandRig.joint_friction``); zeros when off."""
    jf = rig.joint_friction if isinstance(rig, HandRig) else None
    return np.zeros(rig.coupling.num_joints) if jf is None else np.array(jf[:, 1], dtype=float)


def guide_presliding_stiffness(rig: Any, point: ControllerDesign, *, full: bool = False) -> np.ndarray:
    """``K_g`` per independent DoF [Nm/rad]: the rig's guide friction linearised at rest, ``sum_i (P S)_ij^2 W_i /
    delta`` at the design ``point``'s tendon forces (:func:`chain_design_point`).  Each guide's Dahl rate (4.1)
    (:func:`~awiwi_drake.components.friction.guide_friction_rate`) at zero friction force and zero sliding speed
    has the slope ``W / delta`` in the speed (``W`` the sliding level
    :func:`~awiwi_drake.components.friction.guide_friction_level` at direction 0, ``delta`` the presliding length):
    a spring on each tendon path, and through ``h = P q`` the spring ``(P S)^T diag(W / delta) (P S)`` on the joints
    (its diagonal; ``full``: the k x k matrix).  Zeros when the rig's guides have no friction."""
    PS = np.asarray(point.coupling_matrix, dtype=float)
    drive = getattr(rig, "drive", None)
    gm = None if drive is None else drive.model.guide_friction
    if gm is None:
        return np.zeros((PS.shape[1],) * (2 if full else 1))
    C, exponent = gm.levels()
    W = guide_friction_level(np.asarray(point.tendon_force, dtype=float), C, exponent, 0.0)
    return PS.T @ (PS * (W / gm.presliding_length)[:, None]) if full else (PS ** 2).T @ (W / gm.presliding_length)


@TemplateSystem.define("TendonPathVelocity_", scope=sys.modules[__name__])
def TendonPathVelocity_(T):
    """``tendon_path_velocity = P(q) qdot`` (m) [m/s]: the rate of the tendon path lengths ``h(q)``.

    Inputs ``joint_angle``, ``joint_velocity`` (n) (on the hand: the estimates).  Feeds the force
    rate estimate of the tendon force law (the spring elongation moves with the joints too).
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, coupling, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.coupling = coupling
            n, m = coupling.num_joints, coupling.num_tendons
            self._q = self.DeclareVectorInputPort("joint_angle", n)
            self._v = self.DeclareVectorInputPort("joint_velocity", n)
            self.DeclareVectorOutputPort("tendon_path_velocity", m, self._calc,
                                         prerequisites_of_calc={self._q.ticket(), self._v.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.coupling, converter=converter)

        def _calc(self, context, out):
            out.SetFromVector(np.asarray(self.coupling.P(self._q.Eval(context))) @ self._v.Eval(context))

    return Impl


TendonPathVelocity = TendonPathVelocity_[None]



def chain_design_point(rig: Any, op: Any = None, params: HandChainParams | None = None,
                       mechanical_stiffness=None) -> ChainDesign:
    """The chain's design point: ``S``, ``q_op``, ``f_op``, ``tau_op = -(P S)^T f_op`` and the desired
    mechanical stiffness blocks (default ``params.stiffness_scale`` times the op's own (5.12) blocks)."""
    p = params or HandChainParams()
    coupling = rig.coupling if isinstance(rig, Rig) else None
    if coupling is None:
        raise ValueError(f"TendonChainController: rig {getattr(rig, 'name', '?')!r} is not a finger or hand rig")
    fingers = tuple(coupling.parts)
    if any(f not in FINGERS for f in fingers):
        raise ValueError(f"TendonChainController: unknown fingers {fingers}")
    op = op or rig.operating_point()
    S = dof_selection(coupling)
    q_op = np.asarray(op.joint_angle, dtype=float)
    f_op = np.asarray(op.tendon_force, dtype=float)
    PS = np.asarray(coupling.P(q_op), dtype=float) @ S
    K_dof = S.T @ np.asarray(op.joint_stiffness, dtype=float) @ S
    sizes = [c.dof_selection.shape[1] for c in coupling.parts.values()]
    starts = np.cumsum([0] + sizes)
    if mechanical_stiffness is None:
        blocks = [p.stiffness_scale * K_dof[a:b, a:b] for a, b in zip(starts[:-1], starts[1:])]
    else:
        blocks = [np.asarray(B_, dtype=float) for B_ in mechanical_stiffness]
        if len(blocks) != len(sizes) or any(B_.shape != (s_, s_) for B_, s_ in zip(blocks, sizes)):
            raise ValueError(f"TendonChainController: mechanical_stiffness must be {len(sizes)} blocks of "
                             f"shapes {[(s_, s_) for s_ in sizes]}")
    return ChainDesign(S, PS, f_op, -PS.T @ f_op, op=op, fingers=fingers, joint_angle=q_op,
                       mechanical_stiffness=blocks)


class TendonForceStage(Diagram):
    """Desired DoF torques -> tendon force references -> motor torques (module docstring).

    Inputs ``joint_torque_reference`` (k), ``joint_stiffness_reference`` (the distribution only),
    ``joint_angle``, ``joint_velocity`` (n), ``tendon_force``, ``motor_velocity`` (m) and with the
    ripple feed-forward ``motor_angle`` (m); outputs ``motor_torque``, ``tendon_force_reference`` and
    (distribution) ``distribution_status``.

    ``distribution``: ``"optimal"`` / ``"algorithm2"`` (ch. 7, sampled every ``1/rate_hz``) or ``"sharing"``
    (15.88, continuous, ``W`` at ``point``).  ``tendon_law`` (default ``params.tendon_law``): ``"force"`` (10.2),
    ``"sdre"`` (ch. 14, gains re-solved at ``params.sdre_update_rate`` and held, output ``tendon_sdre_gain``; held at
    ``point``'s forces in a continuous stage) or ``"motor-position"`` (the tendon level of (11.3),
    :class:`~awiwi_drake.control.impedance.MotorPositionForceLaw`, input ``tendon_stiffness``).  ``spring``: one law
    for every tendon or a ``TendonSprings`` (each tendon's force map, gains and stiffness table its own law's).
    """

    def __init__(self, coupling, spring, drive_params, params: HandChainParams | None = None, *,
                 point: ChainDesign, distribution: str | None = None, gains: TendonForceGains | None = None,
                 distribution_params: ForceDistributionParams | None = None, rate_hz: float = 3000.0,
                 tendon_law: str | None = None):
        super().__init__()
        p = params or HandChainParams()
        tendon_law = tendon_law or p.tendon_law
        method = distribution or p.distribution_method
        m = coupling.num_tendons
        springs = spring if isinstance(spring, TendonSprings) else TendonSprings([spring] * m)
        if len(springs) != m:
            raise ValueError(f"TendonForceStage: {len(springs)} spring laws for {m} tendons")
        r_m = drive_params.motor.pulley_radius
        b = DiagramBuilder()
        sharing = None
        if method == "sharing":     # f_ref = f_op + W (tau_ref - tau_op): -(P S)^T f_ref = tau_ref, no bounds
            W = -np.linalg.pinv(point.coupling_matrix.T)
            sharing = (W, point.tendon_force, point.torque_offset)
            dist = b.AddNamedSystem("force_sharing", AffineSystem(D=W, y0=sharing[1] - W @ sharing[2]))
            dist_in, dist_out = dist.get_input_port(), dist.get_output_port()
        elif method in ("optimal", "algorithm2"):
            dist_kw = dict(fingers=point.fingers, method=method, period=1.0 / rate_hz, stiffness="full",
                           iterations_per_period=p.distribution_iterations, params=distribution_params,
                           drive=drive_params, springs=springs)
            dist = b.AddNamedSystem("force_distribution", TendonForceDistributionSystem(**dist_kw))
            dist_in = dist.GetInputPort("joint_torque_reference")
            dist_out = dist.GetOutputPort("tendon_force_reference")
        else:
            raise ValueError(f"TendonForceStage: distribution = {method!r}; use 'optimal', 'algorithm2' or 'sharing'")
        gains = gains or TendonForceGains(natural_frequency=p.force_bandwidth,
                                          friction_scale=p.force_friction_scale)
        self.gains = gains
        if tendon_law == "force":
            maps = {id(law_): ForceMap.from_spring(law_, r_m) for law_, _ in springs.groups}
            fmap = maps[id(springs[0])] if springs.uniform else [maps[id(law_)] for law_ in springs]
            law = TendonForceLaw(fmap, drive_params.motor, gains, scheduled=p.scheduled, size=m,
                                 ripple_scale=p.force_ripple_scale if drive_params.motor.ripple else 0.0,
                                 name="tendon_force_control", path_velocity=True)
        elif tendon_law == "sdre":                   # ch. 14, one bank; gains held over 1 / sdre_update_rate
            from awiwi_drake.control.sdre import TendonSdreLaw
            maps = {id(law_): ForceMap.from_spring(law_, r_m) for law_, _ in springs.groups}
            law = TendonSdreLaw([maps[id(law_)] for law_ in springs], drive_params.motor, q_diag=p.tendon_sdre_weights(drive_params.motor.inertia),
                                r=p.sdre_input_weight, design_forces=point.tendon_force,
                                update_period=None if method == "sharing" else 1.0 / p.sdre_update_rate,
                                friction_scale=p.force_friction_scale,
                                ripple_scale=p.force_ripple_scale if drive_params.motor.ripple else 0.0,
                                path_velocity=True, name="tendon_force_control")
        elif tendon_law == "motor-position":
            from awiwi_drake.control.impedance import MotorPositionForceLaw
            from awiwi_drake.parameters.control import ImpedanceParams
            k_min = springs.stiffness(springs.inverse_force(np.full(m, gains.min_schedule_force)))
            # chosen: the motor loop as fast as the force loop of (10.2) (a fair comparison); at ImpedanceParams'
            # 150 rad/s its friction dead band is 4x wider (0.16 rad of PIP error on a 0.2 rad step, measured)
            motor_loop = ImpedanceParams(motor_bandwidth=gains.natural_frequency,
                                         motor_damping_ratio=gains.damping_ratio)
            law = MotorPositionForceLaw(drive_params.motor, motor_loop, size=m, friction_scale=p.friction_scale,
                                        min_alpha=r_m * (k_min[0] if springs.uniform else k_min), path_velocity=True)
        else:
            raise ValueError(f"TendonForceStage: tendon_law = {tendon_law!r}; use 'force', 'sdre' or 'motor-position'")
        if tendon_law == "sdre":
            from awiwi_drake.control.sdre import TendonSdreController
            force = b.AddNamedSystem("tendon_force_control", TendonSdreController(law))
        else:
            force = b.AddNamedSystem("tendon_force_control", StaticLawController(law))
        if force.HasInputPort("tendon_path_velocity"):
            path = b.AddNamedSystem("tendon_path_velocity", TendonPathVelocity(coupling))
            b.Connect(path.get_output_port(0), force.GetInputPort("tendon_path_velocity"))
        b.Connect(dist_out, force.GetInputPort("tendon_force_reference"))
        b.ExportInput(dist_in, "joint_torque_reference")
        if dist.HasInputPort("joint_stiffness_reference"):
            b.ExportInput(dist.GetInputPort("joint_stiffness_reference"), "joint_stiffness_reference")
        if force.HasInputPort("tendon_path_velocity"):
            q_in = b.ExportInput(path.GetInputPort("joint_angle"), "joint_angle")
            b.ExportInput(path.GetInputPort("joint_velocity"), "joint_velocity")
            if dist.HasInputPort("joint_angle"):       # the thumb's P(q)
                b.ConnectInput(q_in, dist.GetInputPort("joint_angle"))
        elif dist.HasInputPort("joint_angle"):
            b.ExportInput(dist.GetInputPort("joint_angle"), "joint_angle")
        for nm in law.inputs:
            if nm not in ("tendon_force_reference", "tendon_path_velocity"):
                b.ExportInput(force.GetInputPort(nm), nm)
        b.ExportOutput(force.GetOutputPort("motor_torque"), "motor_torque")
        if force.HasOutputPort("tendon_sdre_gain"):
            b.ExportOutput(force.GetOutputPort("tendon_sdre_gain"), "tendon_sdre_gain")
        b.ExportOutput(dist_out, "tendon_force_reference")
        if dist.HasOutputPort("distribution_status"):
            b.ExportOutput(dist.GetOutputPort("distribution_status"), "distribution_status")
        b.BuildInto(self)
        self.set_name("tendon_force_stage")
        self._dist = dist if method != "sharing" else None
        self._f_op = np.asarray(point.tendon_force, dtype=float)
        # what the fused chain (control/fused.py) evaluates: the same law and distribution objects
        self.fused_parts = dict(
            law=law, path_coupling=coupling if force.HasInputPort("tendon_path_velocity") else None,
            sharing=sharing,
            distribution=None if method == "sharing" else dist_kw,
            distribution_system=self._dist, initial_forces=None if method == "sharing" else self._f_op)

    def initialize_state(self, context, rig_state=None) -> None:
        """Start the distribution at the design point's tendon forces (``context``: this stage's)."""
        if self._dist is not None:
            self.GetMutableSubsystemContext(self._dist, context).SetDiscreteState(0, self._f_op)


class TendonChainController(Diagram):
    """A joint stage -> force distribution -> tendon force law, as one controller (module docstring).

    ``rig``: a finger or the hand; ``joint_law``: a ``StaticLaw`` with ``n_dof`` outputs (e.g. a
    :class:`~awiwi_drake.control.joint_stage.JointStateFeedbackLaw` of :mod:`awiwi_drake.control.joint_design`);
    ``point``: :func:`chain_design_point` (default at the rig's operating point); ``distribution``: ``"optimal"``,
    ``"algorithm2"`` or ``"sharing"`` (continuous, for linear analysis), default ``params.distribution_method``;
    ``rate_hz``: the distribution's rate (the thesis's 3 kHz).  ``friction_observer`` (FrictionObserverParams) adds
    the (9.2) observer per DoF (:class:`~awiwi_drake.control.joint_stage.JointFrictionObserver_`, bounded by the rig's
    own guide and joint friction levels) to the stage's torques, with outputs ``friction_compensation`` and
    ``friction_compensation_bound``; sampled (and fused) in a sampled chain, continuous with ``"sharing"``.
    """

    def __init__(self, rig: Any, joint_law: StaticLaw, params: HandChainParams | None = None, *,
                 point: ChainDesign | None = None, gains: TendonForceGains | None = None,
                 distribution: str | None = None, distribution_params: ForceDistributionParams | None = None,
                 rate_hz: float = 3000.0, tendon_law: str | None = None, friction_observer=None,
                 name: str = "cascaded_chain"):
        super().__init__()
        p = params or HandChainParams()
        tendon_law = tendon_law or p.tendon_law
        rate_hz = check_rate("TendonChainController", rate_hz)
        point = point or chain_design_point(rig, params=p)
        self.operating_point = point.op
        k = point.selection.shape[1]
        if not isinstance(joint_law, StaticLaw) or joint_law.output_size != k:
            raise ValueError(f"TendonChainController: joint_law must be a StaticLaw with {k} outputs (one per DoF), "
                             f"got {joint_law!r}")
        K_mech = np.concatenate([B_.ravel() for B_ in point.mechanical_stiffness])
        b = DiagramBuilder()
        joint = b.AddNamedSystem("joint_stage", JointStage(joint_law, K_mech))
        force = b.AddNamedSystem("force_stage", TendonForceStage(
            rig.coupling, rig_springs(rig), rig.params, p, point=point, distribution=distribution, gains=gains,
            distribution_params=distribution_params, rate_hz=rate_hz, tendon_law=tendon_law))
        self.design = replace(point, joint_law=joint_law, force_gains=force.gains,
                              distribution_method=distribution or p.distribution_method)
        tau_ref = joint.GetOutputPort("joint_torque_reference")
        observer = None
        if friction_observer is not None and not isinstance(friction_observer, FrictionObserverParams):
            raise TypeError(f"TendonChainController: friction_observer = {friction_observer!r} must be None or a "
                            f"FrictionObserverParams")
        if friction_observer is not None:            # ch. 9: -d_hat added to the desired torques
            from pydrake.systems.primitives import Adder
            from awiwi_drake.control.joint_stage import JointFrictionObserver, joint_damping, joint_inertia
            S = point.selection
            sampled = (distribution or p.distribution_method) != "sharing"
            # kappa times the stage's torque loop gain: at rest its torque feedback divides what is added to the
            # request by that gain (FrictionObserverParams.compensation_scale)
            g = getattr(joint_law, "torque_loop_gains", np.ones(S.shape[1]))
            observer = b.AddNamedSystem("friction_observer", JointFrictionObserver(
                rig.coupling, S, joint_inertia(rig, point.joint_angle), np.diag(joint_damping(rig)),
                friction_observer.gain / np.asarray(g, dtype=float), 1.0 / rate_hz if sampled else None,
                (friction_observer.compensation_scale_motor_position if tendon_law == "motor-position"
                 else friction_observer.compensation_scale) * np.asarray(g, dtype=float),
                (*guide_friction_levels(rig), joint_friction_levels(rig))))
            add = b.AddNamedSystem("friction_compensated_torque", Adder(2, S.shape[1]))
            b.Connect(tau_ref, add.get_input_port(0))
            b.Connect(observer.GetOutputPort("friction_compensation"), add.get_input_port(1))
            tau_ref = add.get_output_port()
        b.Connect(tau_ref, force.GetInputPort("joint_torque_reference"))
        if force.HasInputPort("joint_stiffness_reference"):
            b.Connect(joint.GetOutputPort("joint_stiffness_reference"), force.GetInputPort("joint_stiffness_reference"))
        if joint.HasInputPort("tendon_force_reference"):    # the previous request, read back (sampled chain)
            b.Connect(force.GetOutputPort("tendon_force_reference"), joint.GetInputPort("tendon_force_reference"))
        exported = {}
        for sys_ in (joint, force) + ((observer,) if observer is not None else ()):
            for i in range(sys_.num_input_ports()):
                port = sys_.get_input_port(i)
                nm = port.get_name()
                if nm in ("joint_torque_reference", "joint_stiffness_reference", "tendon_force_reference"):
                    continue
                if nm in exported:
                    b.ConnectInput(exported[nm], port)
                else:
                    exported[nm] = b.ExportInput(port, nm)
        b.ExportOutput(force.GetOutputPort("motor_torque"), "motor_torque")
        b.ExportOutput(force.GetOutputPort("tendon_force_reference"), "tendon_force_reference")
        for nm in ("distribution_status", "tendon_sdre_gain"):
            if force.HasOutputPort(nm):
                b.ExportOutput(force.GetOutputPort(nm), nm)
        b.ExportOutput(tau_ref, "joint_torque_reference")
        if observer is not None:
            for nm in ("friction_compensation", "friction_compensation_bound"):
                b.ExportOutput(observer.GetOutputPort(nm), nm)
        b.ExportOutput(joint.GetOutputPort("joint_stiffness_reference"), "joint_stiffness_reference")
        b.BuildInto(self)
        self.set_name(name)
        self._force, self._observer = force, observer
        self._joint_law, self._stiffness = joint_law, K_mech

    def fused_spec(self, estimator) -> dict | None:
        """The :class:`~awiwi_drake.control.fused.FusedChain_` spec of this chain behind the rig's link estimator
        ``estimator`` (a :class:`~awiwi_drake.hand.estimation.LinkStateEstimator`), or None when the chain is
        continuous (its friction observer has continuous state) and is closed as its blocks."""
        if self._observer is not None and self._observer.period is None:
            return None
        spec = dict(self._force.fused_parts, **estimator.fused_spec(), joint_law=self._joint_law,
                    stiffness=self._stiffness, name=self.get_name())
        if self._observer is not None:
            spec["observer_system"] = self._observer
        return spec

    def initialize_state(self, context, rig_state=None) -> None:
        """Start the distribution at the design point's tendon forces and the friction observer at the
        joints' velocity in ``rig_state`` (``context``: this controller's)."""
        self._force.initialize_state(self.GetMutableSubsystemContext(self._force, context))
        if self._observer is not None:
            n = self._observer.S.shape[0]
            self._observer.initialize(self.GetMutableSubsystemContext(self._observer, context),
                                      None if rig_state is None else np.asarray(rig_state, float)[n:2 * n])
