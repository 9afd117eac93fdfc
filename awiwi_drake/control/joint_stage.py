"""The joint-level stage of the hand's control chain (ch. 11-14 laws per joint): one vectorised system.

The first stage of the chain (:mod:`awiwi_drake.control.chain`) is a plug-in: :class:`JointStage_` evaluates a
*joint law* for all independent DoF ``q_d = S^+ q`` at once, giving ``joint_torque_reference`` (n_dof) [Nm] and the
constant desired mechanical stiffness ``joint_stiffness_reference`` [Nm/rad] for the distribution.

Each DoF ``j`` is controlled on its own *measurable* coordinates (what the real hand has: the
tendon-length estimate of ``q``, ``qdot`` and the spring sensors' tendon forces)::

    z_j = [q_j - q_op_j,  qdot_j,  tau_j - tau_op_j,  tau_dot_j]        (torque_rate="joint"), or
    z_j = [q_j - q_op_j,  qdot_j,  tau_j - tau_op_j,  sigma_j]          (torque_rate="motor"),
    tau = -(P(q) S)^T f                     the joint torque of the measured tendon forces,
    tau_dot = -(P(q) S)^T k_t(f) (r_m omega + P(q) qdot)     its rate (f = phi(x), x = r_m theta + h(q) + x0),
    sigma = -(P(q) S)^T k_t(f) r_m omega    the rate the motors drive (tau_dot = sigma - K qdot, K (5.12)).

``sigma`` needs no joint velocity (motor encoders and spring sensors only).  ``tau_dot`` multiplies the
late, differentiated tendon-length estimate by the tendon stiffness, which drives the DIP's link mode on its
tendons unstable under the LQR's torque-rate gain at 3 kHz, so the LQR/SDRE stages measure ``sigma``; pole
placement keeps ``tau_dot`` (on ``sigma`` its poles need a negative velocity gain).  The measurements:
docs/REPRODUCTIONS.md ("every joint-level law per joint").

The per-DoF linear law of :class:`JointStateFeedbackLaw` is::

    tau_ref_j = tau_op_j + Nu_j dr_j - K_j . (z_j - Nx_j dr_j),     dr_j = (S^+ q_ref)_j - q_op_j,

(``(Nx, Nu)``: :func:`awiwi_drake.control.linear.reference_maps`).  PD / impedance (11.4) is ``K_j = [K, D, 0, 0]``
(no force input read); pole placement (ch. 12) and LQR (ch. 13) use the full ``K_j``
(:mod:`awiwi_drake.control.joint_design`); the SDRE (ch. 14) interpolates them in the joint torque
(:class:`JointGainScheduleLaw`).
"""

from __future__ import annotations

import sys
import warnings
from typing import Any

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import clip
from awiwi_drake.components.friction import joint_breakaway_bound, joint_friction_bound
from awiwi_drake.control.base import StaticLaw, check_gains
from awiwi_drake.control.compiled import float_inputs, joint_feedback
from awiwi_drake.control.friction_observer import observer_rate, observer_step
from awiwi_drake.control.tendon_force import interp
from awiwi_drake.hand.coupling import dof_selection

__all__ = ["joint_inertia", "joint_damping", "JointStateFeedbackLaw", "JointGainScheduleLaw", "JointStage_",
           "JointStage", "JointFrictionObserver_", "JointFrictionObserver"]


def joint_inertia(rig: Any, q, *, full: bool = False) -> np.ndarray:
    """Inertia of each independent DoF, ``diag(S^T M(q) S)`` [kg m^2] (``full``: the matrix), from the rig's plant."""
    plant = rig.plant
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, np.asarray(q, dtype=float))
    S = dof_selection(rig.coupling)
    M = S.T @ plant.CalcMassMatrix(ctx) @ S
    return M if full else np.diag(M).copy()


def joint_damping(rig: Any) -> np.ndarray:
    """Bearing damping of each independent DoF, ``S^T diag(b) S`` (matrix) [Nm s/rad], from the rig's plant."""
    plant = rig.plant
    b = np.array([plant.get_joint(j).default_damping_vector()[0] for j in plant.GetJointIndices()])
    S = dof_selection(rig.coupling)
    return S.T @ np.diag(b) @ S


class JointStateFeedbackLaw(StaticLaw):
    """Per-DoF linear state feedback on ``z_j`` (module docstring); one call for all DoF.

    ``coupling`` (``P(q)``), ``selection`` ``S`` (n x k), ``pulley_radius`` r_m [m]; ``gains`` (k, 4) ``K_j`` or
    (k, 5) with the gain on a sampled chain's previous request ``tau_ref(t - h) = -(P S)^T f_ref`` (read back from the
    distribution); ``state_map`` (k, 4) ``Nx``, ``input_map`` (k,) ``Nu``; ``joint_angle_op``, ``torque_op`` (k,);
    ``torque_rate``: the fourth coordinate, ``"joint"`` (``tau_dot``) or ``"motor"`` (``sigma``).
    """

    def __init__(self, coupling, selection, pulley_radius: float, gains, *, state_map, input_map,
                 joint_angle_op, torque_op, name: str = "joint_state_feedback", torque_rate: str = "joint"):
        if torque_rate not in ("joint", "motor"):
            raise ValueError(f"{name}: torque_rate = {torque_rate!r}; use 'joint' or 'motor'")
        self.torque_rate = torque_rate
        S = np.asarray(selection, dtype=float)
        if S.ndim != 2 or S.shape[0] < S.shape[1]:
            raise ValueError(f"{name}: selection must be n x n_dof (n >= n_dof), got {S.shape}")
        n, k = S.shape
        self.name = name
        self.coupling, self.S, self.Sp = coupling, S, np.linalg.pinv(S)
        self.r_m = float(pulley_radius)
        K = np.asarray(gains, dtype=float)
        if K.ndim == 2 and K.shape == (k, 4):
            K = np.hstack([K, np.zeros((k, 1))])
        self.K = check_gains("K", K, shape=(k, 5), owner=name)
        self.Nx = check_gains("state_map", state_map, shape=(k, 4), owner=name)
        self.Nu = check_gains("input_map", input_map, shape=(k,), owner=name)
        self.q0 = check_gains("joint_angle_op", joint_angle_op, shape=(k,), owner=name)
        self.tau0 = check_gains("torque_op", torque_op, shape=(k,), owner=name)
        self.uses_forces = bool(np.any(self.K[:, 2:4] != 0.0))
        self.uses_previous = bool(np.any(self.K[:, 4] != 0.0))
        m = coupling.num_tendons
        self.inputs = {"joint_angle_reference": n, "joint_angle": n, "joint_velocity": n}
        if self.uses_forces:
            self.inputs.update(tendon_force=m, tendon_stiffness=m, motor_velocity=m)
        if self.uses_previous:
            self.inputs.update(tendon_force_reference=m)
        self.output_size = k

    @property
    def torque_loop_gains(self) -> np.ndarray:
        """``1 + K_tau + K_prev`` per DoF: the factor by which the stage's torque feedback divides a torque added to
        its request, at rest (the force loop holding ``tau = tau_ref``); 1 for PD / impedance."""
        return 1.0 + self.K[:, 2] + self.K[:, 4]

    def coordinates(self, u):
        """``z`` (k x 5: ``[q - q_op, qdot, tau - tau_op, tau_dot, tau_ref(t - h) - tau_op]``) and ``dr`` (k,)."""
        q, v = u["joint_angle"], u["joint_velocity"]
        qd, vd = self.Sp @ q, self.Sp @ v
        if self.uses_forces:         # tau = -(P S)^T f and its rate tau_dot, or the motors' sigma (module docstring)
            P = np.asarray(self.coupling.P(q))
            PS = P @ self.S
            w = self.r_m * u["motor_velocity"]
            rate = w if self.torque_rate == "motor" else w + P @ v
            cols = [qd - self.q0, vd, -(PS.T @ u["tendon_force"]) - self.tau0, -(PS.T @ (u["tendon_stiffness"] * rate))]
        else:
            cols = [qd - self.q0, vd, 0.0 * vd, 0.0 * vd]
        if self.uses_previous:
            PS = np.asarray(self.coupling.P(u["joint_angle"])) @ self.S
            cols.append(-(PS.T @ u["tendon_force_reference"]) - self.tau0)
        else:
            cols.append(0.0 * vd)
        dr = self.Sp @ u["joint_angle_reference"] - self.q0
        return np.stack(cols, axis=1), dr

    def gains(self, z):
        return self.K

    def __call__(self, u):
        if not self.uses_forces and not self.uses_previous and type(self) is JointStateFeedbackLaw \
                and float_inputs(u, ("joint_angle", "joint_velocity", "joint_angle_reference")):
            # float hot path of the PD / impedance form K = [K, D, 0, 0, 0]: one compiled call, the same sums
            return joint_feedback(self.Sp, u["joint_angle"], u["joint_velocity"], u["joint_angle_reference"],
                                  self.q0, self.K, self.Nx, self.Nu, self.tau0)
        z, dr = self.coordinates(u)
        K = self.gains(z)
        ref = np.hstack([self.Nx, self.Nu[:, None]])       # equilibrium: z = Nx dr, tau_ref(t - h) = Nu dr
        err = z - ref * dr[:, None]
        return self.tau0 + self.Nu * dr - np.sum(K * err, axis=1)


class JointGainScheduleLaw(JointStateFeedbackLaw):
    """:class:`JointStateFeedbackLaw` with gains interpolated in the measured joint torque deviation.

    ``schedule`` (p,) increasing deviations ``tau - tau_op`` [Nm], ``table`` (k, p, 5) the gains designed there
    (ch. 14).  Outside the table the end gains are held, not silently: the first float evaluation outside warns
    (``RuntimeWarning``) and :attr:`outside_count` counts such evaluations per DoF.
    """

    def __init__(self, coupling, selection, pulley_radius, schedule, table, **kw):
        table = np.asarray(table, dtype=float)
        super().__init__(coupling, selection, pulley_radius, table[:, table.shape[1] // 2, :], **kw)
        self.schedule = check_gains("schedule", schedule, owner=self.name)
        if self.schedule.ndim != 1 or np.any(np.diff(self.schedule) <= 0):
            raise ValueError(f"{self.name}: schedule must be strictly increasing, got {self.schedule}")
        if table.shape != (self.S.shape[1], self.schedule.size, 5):
            raise ValueError(f"{self.name}: table has shape {table.shape}, expected "
                             f"{(self.S.shape[1], self.schedule.size, 5)}")
        self.table = table
        self.outside_count = np.zeros(self.S.shape[1], dtype=int)
        if not self.uses_forces:
            raise ValueError(f"{self.name}: a torque-scheduled law needs the torque feedback (K[:, 2:] != 0)")

    def gains(self, z):
        lo, hi = float(self.schedule[0]), float(self.schedule[-1])
        if np.asarray(z).dtype != object:
            self._note_outside(np.asarray(z, dtype=float)[:, 2], lo, hi)
        rows = []
        for j in range(self.S.shape[1]):
            t = clip(z[j, 2], lo, hi)
            rows.append([interp(t, self.schedule, self.table[j, :, c]) for c in range(5)])
        return np.array(rows, dtype=object if np.asarray(z).dtype == object else float)

    def _note_outside(self, dev, lo, hi):
        out = (dev < lo) | (dev > hi)
        if not out.any():
            return
        if not self.outside_count.any():
            j = int(np.argmax(out))
            warnings.warn(f"{self.name}: measured joint torque deviation {dev[j]:.4g} Nm of DoF {j} is outside the "
                          f"gain schedule [{lo:.4g}, {hi:.4g}] Nm: the end gains are held (warned once; "
                          f"outside_count counts such evaluations)", RuntimeWarning, stacklevel=2)
        self.outside_count += out


@TemplateSystem.define("JointStage_", scope=sys.modules[__name__])
def JointStage_(T):
    """The chain's joint-level stage: a joint law for all DoF (module docstring).

    Inputs: the law's ports (``joint_angle_reference``, ``joint_angle``, ``joint_velocity`` (n plant
    joints) and, for laws with torque feedback, ``tendon_force``, ``tendon_stiffness``,
    ``motor_velocity`` (m)).  Outputs ``joint_torque_reference`` (n_dof, feedthrough) and
    ``joint_stiffness_reference`` (constant).
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, law, mechanical_stiffness, converter=None):
            LeafSystem_[T].__init__(self, converter)
            if not isinstance(law, StaticLaw):
                raise ValueError(f"JointStage: law must be a StaticLaw, got {type(law).__name__}")
            self.law = law
            self.Kmech = check_gains("mechanical_stiffness", np.ravel(mechanical_stiffness), owner="JointStage")
            self._ports = [(nm, self.DeclareVectorInputPort(nm, int(sz))) for nm, sz in law.inputs.items()]
            self.DeclareVectorOutputPort("joint_torque_reference", int(law.output_size), self._calc_tau,
                                         prerequisites_of_calc={p.ticket() for _, p in self._ports})
            self.DeclareVectorOutputPort("joint_stiffness_reference", self.Kmech.size, self._calc_K,
                                         prerequisites_of_calc={self.nothing_ticket()})
            self.set_name(law.name)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.law, other.Kmech, converter=converter)

        def _calc_tau(self, context, out):
            out.SetFromVector(np.asarray(self.law({nm: p.Eval(context) for nm, p in self._ports})).reshape(-1))

        def _calc_K(self, context, out):
            out.SetFromVector(self.Kmech.copy())

    return Impl


JointStage = JointStage_[None]


@TemplateSystem.define("JointFrictionObserver_", scope=sys.modules[__name__])
def JointFrictionObserver_(T):
    """The joint friction observer (9.2) on every DoF of a finger/the hand, as a compensating torque (ch. 9).

    Per DoF ``j``: ``M_jj w_hat' = tau_j - b_jj qdot_j + d_hat_j``, ``d_hat_j = L M_jj (qdot_j - w_hat_j)``
    (:func:`~awiwi_drake.control.friction_observer.observer_rate`, the one place of the law), ``tau = -(P(q) S)^T f``
    of the measured tendon forces; an ``inertia`` matrix (k, k) ``M`` couples the DoF (the 15.5 backstepping's link
    model, whose off-diagonal inertial torques are then not counted as friction).
    Inputs ``joint_angle``, ``joint_velocity`` (n, the estimates on the hand), ``tendon_force`` (m); output
    ``friction_compensation`` (k) ``= -scale d_hat`` [Nm] (``scale`` per DoF, default 1), added to the joint stage's
    desired torques; state ``w_hat`` (k), to be started at the measured velocity (0 at rest).

    ``friction_levels`` ``(C, mu alpha, Fs)`` (the plant's own guide friction parameters, m each,
    :meth:`~awiwi_drake.components.fused_drive.GuideFrictionModel.levels`, zeros when the guides have no friction; and
    its joints' breakaway levels, n, :func:`~awiwi_drake.control.chain.joint_friction_levels`, zeros when off)
    bound the estimate by what the guides' and the joints' friction can be (:meth:`friction_bound`): the output
    becomes ``scale clip(-d_hat, -B, B)``.  Chosen: the observer is link-side, so its ``d_hat`` holds the friction AND
    any external load; the thesis's (9.1)-(9.2) sits on the actuator side, where a load is not cancelled and the joint
    stays an impedance.  The bound keeps that: a load beyond ``B`` is compensated only up to ``B`` (output
    ``friction_compensation_bound`` ``= scale B``).  ``friction_levels`` None: unbounded (the load observer of
    :class:`~.finger_backstepping.ObservedBacksteppingController`, which estimates the load on purpose).

    ``period`` None: continuous state (linear analysis); ``h``: a discrete state stepped by
    :func:`~awiwi_drake.control.friction_observer.observer_step` (pole ``1 - L h``).
    :class:`~awiwi_drake.control.fused.FusedChain_` calls the same :meth:`compensation` and :meth:`next_state`.
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, coupling, selection, inertia, damping, gain: float, period: float | None = None,
                       scale=None, friction_levels=None, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.coupling, self.S = coupling, np.asarray(selection, dtype=float)
            n, k = self.S.shape
            self.Sp = np.linalg.pinv(self.S)
            inertia = np.asarray(inertia, dtype=float)
            if inertia.ndim == 2:              # the DoF inertia matrix (coupled links): symmetric positive definite
                self.M = check_gains("inertia", inertia, shape=(k, k), owner="JointFrictionObserver")
                if not (np.allclose(self.M, self.M.T) and np.linalg.eigvalsh(self.M).min() > 0):
                    raise ValueError(f"JointFrictionObserver: inertia matrix must be symmetric positive definite, "
                                     f"got {self.M!r}")
                self.Minv = np.linalg.inv(self.M)      # constant: inverted once, not at every sample
            else:
                self.M = check_gains("inertia", inertia, shape=(k,), owner="JointFrictionObserver", positive=True)
                self.Minv = None
            self.b = check_gains("damping", damping, shape=(k,), owner="JointFrictionObserver")
            self.gain = check_gains("gain", np.broadcast_to(np.asarray(gain, dtype=float), (k,)).copy(),
                                    shape=(k,), owner="JointFrictionObserver", positive=True)
            self.scale = (np.ones(k) if scale is None else
                          check_gains("scale", scale, shape=(k,), owner="JointFrictionObserver", positive=True))
            self.period = None if period is None else float(check_gains("period", [period],
                                                                        owner="JointFrictionObserver",
                                                                        positive=True)[0])
            m = coupling.num_tendons
            if friction_levels is not None and len(friction_levels) != 3:
                raise ValueError(f"JointFrictionObserver: friction_levels must be (C, mu alpha, Fs), got "
                                 f"{len(friction_levels)} arrays")
            self.levels = None if friction_levels is None else tuple(
                check_gains(nm, lv, shape=(size,), owner="JointFrictionObserver")
                for nm, lv, size in zip(("friction_levels[0] (constant C)", "friction_levels[1] (capstan exponent)",
                                         "friction_levels[2] (joint breakaway Fs)"), friction_levels, (m, m, n)))
            if self.levels is not None and any(np.any(lv < 0) for lv in self.levels):
                raise ValueError(f"JointFrictionObserver: friction_levels must be >= 0, got {friction_levels}")
            self.joint_hold = None if self.levels is None else joint_breakaway_bound(self.levels[2], self.S)
            if self.period is None:
                self.DeclareContinuousState(k)
            else:
                self._w = self.DeclareDiscreteState(k)
                self.DeclarePeriodicDiscreteUpdateEvent(self.period, 0.0, self._update)
            self._q = self.DeclareVectorInputPort("joint_angle", n)
            self._v = self.DeclareVectorInputPort("joint_velocity", n)
            self._f = self.DeclareVectorInputPort("tendon_force", coupling.num_tendons)
            bounded = () if self.levels is None else (self._q.ticket(), self._f.ticket())
            self.DeclareVectorOutputPort("friction_compensation", k, self._calc,
                                         prerequisites_of_calc={self.all_state_ticket(), self._v.ticket(), *bounded})
            if self.levels is not None:
                self.DeclareVectorOutputPort(
                    "friction_compensation_bound", k,
                    lambda c, o: o.SetFromVector(self.scale * self.friction_bound(self._q.Eval(c), self._f.Eval(c))),
                    prerequisites_of_calc=set(bounded))

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.coupling, other.S, other.M, other.b, other.gain, other.period,
                            other.scale, other.levels, converter=converter)

        def _state(self, context):
            if self.period is None:
                return context.get_continuous_state_vector().CopyToVector()
            return context.get_discrete_state(self._w).CopyToVector()

        def friction_bound(self, q, f, P=None):
            """``B_j = sum_i |(P(q) S)_ij| W_i(f_i) + sum_l |S_lj| Fs_l`` (k) [Nm]: the largest torque the guides' and
            the joints' friction can put on each DoF at the measured tendon forces ``f`` (m) (``P``: ``P(q)`` when the
            caller has it); None when unbounded."""
            if self.levels is None:
                return None
            P = np.asarray(self.coupling.P(q) if P is None else P)
            # the measured f is the lever's tension (the rig's tendon_force, hysteresis inside): guides and joints
            C, mu_alpha, _ = self.levels
            return joint_friction_bound(P, f, C, mu_alpha, joint_hold=self.joint_hold, selection=self.S)

        def compensation(self, w_hat, v, bound=None):
            """``scale clip(-d_hat, -bound, bound)`` (k) [Nm] at the observer state ``w_hat`` (k), joint velocities
            ``v`` (n) and the :meth:`friction_bound` ``bound`` (None: unclipped)."""
            minus_d = -observer_rate(w_hat, self.Sp @ v, 0.0 * w_hat, self.M, self.gain, self.Minv)[1]
            return self.scale * (minus_d if bound is None else clip(minus_d, -bound, bound))

        def _known_torque(self, q, w, f, P=None):
            """``tau_a = -S^T P(q)^T f - b w`` per DoF at the DoF velocities ``w`` (``P``: ``P(q)`` when the caller
            has it)."""
            P = np.asarray(self.coupling.P(q) if P is None else P)
            return -(self.S.T @ (P.T @ f)) - self.b * w

        def next_state(self, w_hat, q, v, f, P=None):
            """``w_hat`` one period later (sampled form) from the sample ``(q, v, f)`` (``P``: ``P(q)``, computed once
            per period by the caller, or here)."""
            w = self.Sp @ v
            return observer_step(w_hat, w, self._known_torque(q, w, f, P), self.M, self.gain, self.period,
                                self.Minv)[0]

        def _calc(self, context, out):
            bound = None if self.levels is None else self.friction_bound(self._q.Eval(context), self._f.Eval(context))
            out.SetFromVector(self.compensation(self._state(context), self._v.Eval(context), bound))

        def _update(self, context, discrete_state):
            discrete_state.set_value(self._w, self.next_state(self._state(context), self._q.Eval(context),
                                                              self._v.Eval(context), self._f.Eval(context)))

        def DoCalcTimeDerivatives(self, context, derivatives):
            if self.period is not None:                 # the sampled form has no continuous state
                return
            w = self.Sp @ self._v.Eval(context)
            tau = self._known_torque(self._q.Eval(context), w, self._f.Eval(context))
            rate, _ = observer_rate(self._state(context), w, tau, self.M, self.gain, self.Minv)
            derivatives.get_mutable_vector().SetFromVector(rate)

        def initialize(self, context, joint_velocity=None) -> None:
            """Start ``w_hat`` at ``S^+ joint_velocity`` (0 at rest) in this system's ``context``."""
            w = np.zeros(self.S.shape[1]) if joint_velocity is None else self.Sp @ np.asarray(joint_velocity, float)
            if self.period is None:
                context.SetContinuousState(w)
            else:
                context.SetDiscreteState(self._w, w)

    return Impl


JointFrictionObserver = JointFrictionObserver_[None]
