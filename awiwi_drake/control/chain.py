"""The hand's control structure as blocks (thesis ch. 7-11), for a finger or the whole hand.

::

    joint_angle_reference ─> JointImpedanceBank_ ─ joint_torque_reference ──> TendonForceDistribution_ (ch. 7)
    joint_angle, joint_velocity ┘ (estimated)     └ joint_stiffness_reference ┘        │ tendon_force_reference
                                                                                       v
    tendon_force, motor_velocity, motor_angle ──────────────> TendonForceLaw bank (ch. 10 (10.2), ch. 3) ─> motor_torque

* :class:`JointImpedanceBank_` -- the joint-level law on the independent DoF ``q_dof = S^+ q``
  (ring/fifth: the DIP follows the PIP, (5.16)): ``tau = tau_op + K (q_ref - q) - D qdot``
  (the joint impedance of (11.4)), and the desired *mechanical* joint stiffness (co-contraction,
  the thesis's central claim) for the distribution.  Each DoF is designed from its own model:
  ``D = 2 zeta sqrt(K M_jj)`` with ``M_jj`` the joint's inertia at the operating point.
* :class:`~awiwi_drake.control.force_distribution.TendonForceDistribution_` -- exact torque,
  closest stiffness, forces in bounds (the optimal (7.6) program or Algorithm 2), sampled at the
  control rate and warm-started.
* :class:`~awiwi_drake.control.tendon_force.TendonForceLaw` with ``size = m`` -- (10.2) per tendon,
  gains (10.11) scheduled on the reference (10.12), slope ``alpha = r_m k_t(f)`` of the tendon's
  own spring curve (:meth:`ForceMap.from_spring`), friction (3.8) and ripple (3.5) fed forward.

:class:`TendonChainController` wires the three into one controller with the port contract of
:mod:`awiwi_drake.control.base` (inputs ``joint_angle_reference``, ``joint_angle``,
``joint_velocity``, ``tendon_force``, ``motor_velocity``, ``motor_angle``; output
``motor_torque``; extra outputs ``tendon_force_reference``, ``joint_torque_reference``,
``joint_stiffness_reference``, ``distribution_status``).  On a finger or the hand
:func:`~awiwi_drake.control.base.closed_loop` feeds ``joint_angle`` / ``joint_velocity`` from the
tendon-length estimator (no joint sensors).  Registered as ``cascaded`` for fingers and the hand.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake.rigs.base import Rig
from awiwi_drake.control.base import StaticLawController, check_gains
from awiwi_drake.control.force_distribution import TendonForceDistributionSystem
from awiwi_drake.control.tendon_force import ForceMap, TendonForceLaw
from awiwi_drake.parameters.control import RippleCompensationParams, TendonForceGains
from awiwi_drake.hand.coupling import dof_selection
from awiwi_drake.parameters.hand import FINGERS
from awiwi_drake.parameters.hand_control import ForceDistributionParams, HandChainParams

__all__ = ["JointImpedanceBank_", "JointImpedanceBank", "TendonPathVelocity_", "TendonPathVelocity",
           "TendonChainController",
           "joint_inertia", "check_one_spring_law", "chain_controller"]


def check_one_spring_law(rig: Any, owner: str) -> None:
    """Refuse a rig whose tendons have their own spring laws (``params.tendon_springs``).

    The force map, the distribution's ``k_t(f)`` and the backstepping's ``phi(x)`` model every
    tendon with the rig's one spring law; with per-tendon laws they would control a different
    plant without saying so (nothing silently dropped).
    """
    overrides = getattr(getattr(rig, "params", None), "tendon_springs", ())
    if overrides:
        names = ", ".join(t for t, _ in overrides)
        raise ValueError(f"{owner}: rig {getattr(rig, 'name', '?')!r} has per-tendon spring laws "
                         f"(params.tendon_springs: {names}); this controller models every tendon with "
                         f"params.spring: design it on a rig without tendon_springs (a deliberate model mismatch: "
                         f"closed_loop(rig, make_controller(name, nominal_rig)))")


def joint_inertia(rig: Any, q, *, full: bool = False) -> np.ndarray:
    """Inertia of each independent DoF, ``diag(S^T M(q) S)`` [kg m^2] (``full``: the matrix), from the rig's plant."""
    plant = rig.plant
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, np.asarray(q, dtype=float))
    S = dof_selection(rig.coupling)
    M = S.T @ plant.CalcMassMatrix(ctx) @ S
    return M if full else np.diag(M).copy()


@TemplateSystem.define("JointImpedanceBank_")
def JointImpedanceBank_(T):
    """Joint impedance on the independent DoF of a finger/hand (one system for all joints).

    Inputs ``joint_angle_reference``, ``joint_angle``, ``joint_velocity`` (n plant joints) [rad,
    rad/s].  Outputs ``joint_torque_reference`` (n_dof) [Nm] ``= tau_op + K S^+ (q_ref - q) -
    D S^+ qdot`` (feedthrough) and ``joint_stiffness_reference`` [Nm/rad] (constant: the desired
    mechanical stiffness, in the layout of the force distribution: per DoF, or the row-major block
    of each finger).  ``S`` maps DoF to plant joints (``q = S q_dof``).
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, selection, stiffness, damping, torque_offset, mechanical_stiffness,
                       converter=None):
            LeafSystem_[T].__init__(self, converter)
            S = np.asarray(selection, dtype=float)
            if S.ndim != 2 or S.shape[0] < S.shape[1]:
                raise ValueError(f"JointImpedanceBank: selection must be n x n_dof (n >= n_dof), got {S.shape}")
            n, k = S.shape
            self.S = S
            self.K = check_gains("joint_stiffness", stiffness, shape=(k,), owner="JointImpedanceBank", positive=True)
            self.D = check_gains("damping", damping, shape=(k,), owner="JointImpedanceBank")
            self.tau0 = check_gains("torque_offset", torque_offset, shape=(k,), owner="JointImpedanceBank")
            self.Kmech = check_gains("mechanical_stiffness", np.ravel(mechanical_stiffness),
                                     owner="JointImpedanceBank")
            if np.any(self.D < 0):
                raise ValueError(f"JointImpedanceBank: damping must be >= 0, got {self.D}")
            self._Sp = np.linalg.pinv(S)
            self._r = self.DeclareVectorInputPort("joint_angle_reference", n)
            self._q = self.DeclareVectorInputPort("joint_angle", n)
            self._v = self.DeclareVectorInputPort("joint_velocity", n)
            self.DeclareVectorOutputPort("joint_torque_reference", k, self._calc_tau,
                                         prerequisites_of_calc={self._r.ticket(), self._q.ticket(), self._v.ticket()})
            self.DeclareVectorOutputPort("joint_stiffness_reference", self.Kmech.size, self._calc_K,
                                         prerequisites_of_calc={self.nothing_ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.S, other.K, other.D, other.tau0, other.Kmech, converter=converter)

        def _calc_tau(self, context, out):
            e = self._Sp @ (self._r.Eval(context) - self._q.Eval(context))
            v = self._Sp @ self._v.Eval(context)
            out.SetFromVector(self.tau0 + self.K * e - self.D * v)

        def _calc_K(self, context, out):
            out.SetFromVector(self.Kmech.copy())

    return Impl


JointImpedanceBank = JointImpedanceBank_[None]


@TemplateSystem.define("TendonPathVelocity_")
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


class TendonChainController(Diagram):
    """Joint impedance -> force distribution -> tendon force PD, as one controller (module docstring).

    Parameters
    ----------
    rig : HandRig
        A finger or the hand (``finger_diagram`` / ``hand_diagram``).
    params : HandChainParams, optional
    op : OperatingPoint, optional
        Design point (default: the rig's); ``tau_op``, the inertias and the default mechanical
        stiffness are taken there, and the distribution starts at its tendon forces.
    mechanical_stiffness : list of arrays, optional
        Desired mechanical joint stiffness [Nm/rad] (co-contraction), one symmetric n_f x n_f block
        per finger on its DoF; default ``params.stiffness_scale`` times the operating point's own
        (5.12) blocks (then the distribution's optimum at the operating point is its forces).
    joint_stiffness : array (n_dof,) or float, optional
        Impedance ``K`` per DoF (default ``params.joint_stiffness`` for all).
    rate_hz : float
        Rate of the distribution (the thesis's 3 kHz).
    """

    def __init__(self, rig: Any, params: HandChainParams | None = None, *, op: Any = None,
                 mechanical_stiffness=None, joint_stiffness=None, gains: TendonForceGains | None = None,
                 distribution: ForceDistributionParams | None = None, rate_hz: float = 3000.0):
        super().__init__()
        p = params or HandChainParams()
        coupling = rig.coupling if isinstance(rig, Rig) else None
        if coupling is None:
            raise ValueError(f"TendonChainController: rig {getattr(rig, 'name', '?')!r} is not a finger or hand rig")
        check_one_spring_law(rig, "TendonChainController")
        fingers = tuple(coupling.parts)
        if any(f not in FINGERS for f in fingers):
            raise ValueError(f"TendonChainController: unknown fingers {fingers}")
        op = op or rig.operating_point()
        self.operating_point = op
        S = dof_selection(coupling)
        n, k = S.shape
        m = coupling.num_tendons
        q_op = np.asarray(op.joint_angle, dtype=float)
        f_op = np.asarray(op.tendon_force, dtype=float)
        P = np.asarray(coupling.P(q_op), dtype=float)
        tau_op = -(P @ S).T @ f_op
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
        K_mech = np.concatenate([B_.ravel() for B_ in blocks])
        M = joint_inertia(rig, q_op)
        K = np.minimum(p.joint_stiffness, M * p.joint_bandwidth ** 2) if joint_stiffness is None else \
            np.broadcast_to(np.asarray(joint_stiffness, dtype=float), (k,)).copy()
        D = 2.0 * p.damping_ratio * np.sqrt(K * M)
        self.design = dict(selection=S, joint_stiffness=K, damping=D, inertia=M, torque_offset=tau_op,
                           mechanical_stiffness=blocks, tendon_force=f_op)
        b = DiagramBuilder()
        joint = b.AddNamedSystem("joint_impedance", JointImpedanceBank(S, K, D, tau_op, K_mech))
        dist = b.AddNamedSystem("force_distribution", TendonForceDistributionSystem(
            fingers, method=p.distribution_method, period=1.0 / rate_hz,
            iterations_per_period=p.distribution_iterations, stiffness="full", params=distribution,
            drive=rig.params))
        fmap = ForceMap.from_spring(rig.spring, rig.params.motor.pulley_radius)
        gains = gains or TendonForceGains(natural_frequency=p.force_bandwidth, friction_scale=p.friction_scale)
        self.design["force_gains"] = gains
        law = TendonForceLaw(fmap, rig.params.motor, gains, scheduled=p.scheduled, size=m,
                             ripple_scale=RippleCompensationParams().amplitude_scale if rig.params.motor.ripple else 0.0,
                             name="tendon_force_control", path_velocity=True)
        force = b.AddNamedSystem("tendon_force_control", StaticLawController(law))
        path = b.AddNamedSystem("tendon_path_velocity", TendonPathVelocity(coupling))
        b.Connect(path.get_output_port(0), force.GetInputPort("tendon_path_velocity"))
        b.Connect(joint.GetOutputPort("joint_torque_reference"), dist.GetInputPort("joint_torque_reference"))
        b.Connect(joint.GetOutputPort("joint_stiffness_reference"), dist.GetInputPort("joint_stiffness_reference"))
        b.Connect(dist.GetOutputPort("tendon_force_reference"), force.GetInputPort("tendon_force_reference"))
        b.ExportInput(joint.GetInputPort("joint_angle_reference"), "joint_angle_reference")
        q_in = b.ExportInput(joint.GetInputPort("joint_angle"), "joint_angle")
        if dist.HasInputPort("joint_angle"):       # the thumb's P(q)
            b.ConnectInput(q_in, dist.GetInputPort("joint_angle"))
        b.ConnectInput(q_in, path.GetInputPort("joint_angle"))
        v_in = b.ExportInput(joint.GetInputPort("joint_velocity"), "joint_velocity")
        b.ConnectInput(v_in, path.GetInputPort("joint_velocity"))
        for nm in law.inputs:
            if nm not in ("tendon_force_reference", "tendon_path_velocity"):
                b.ExportInput(force.GetInputPort(nm), nm)
        b.ExportOutput(force.GetOutputPort("motor_torque"), "motor_torque")
        b.ExportOutput(dist.GetOutputPort("tendon_force_reference"), "tendon_force_reference")
        b.ExportOutput(dist.GetOutputPort("distribution_status"), "distribution_status")
        b.ExportOutput(joint.GetOutputPort("joint_torque_reference"), "joint_torque_reference")
        b.ExportOutput(joint.GetOutputPort("joint_stiffness_reference"), "joint_stiffness_reference")
        b.BuildInto(self)
        self.set_name("cascaded_chain")
        self._dist = dist
        self._f_op = f_op

    def initialize_state(self, context, rig_state=None) -> None:
        """Start the distribution at the design point's tendon forces (``context``: this controller's)."""
        self.GetMutableSubsystemContext(self._dist, context).SetDiscreteState(0, self._f_op)


def chain_controller(rig: Any, params: HandChainParams | None = None, **kw) -> TendonChainController:
    """Registered factory ``cascaded`` for fingers and the hand (see :class:`TendonChainController`)."""
    return TendonChainController(rig, params, **kw)
