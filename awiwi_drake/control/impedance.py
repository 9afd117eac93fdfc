"""Joint impedance control on top of tendon force control (ch. 11).

Link side (11.4), regulation form without the negligible ``M qdd_des`` and
Coriolis/gravity terms of a finger (ch. 5)::

    tau_des = Kp_imp (q_des - q) - Kd_imp qdot

Desired tendon forces from the coupling pseudo-inverse plus the pretension
null-space term (section 11.3, ch. 7)::

    f_des = f_pre + c^+ tau_des      (tau = sum_i c_i f_i)

Three tendon-level laws turn ``f_des`` into motor torques (motor ``i`` winds
tendon ``i`` on a pulley of radius ``r_m``):

``pd`` (baseline, no impedance layer)
    PD on the motor angles towards the motor angles that hold the link at
    ``q_des`` (equilibrium family of the rig linearisation, exact for these
    rigs): ``u = u_ref(q_des) + Kp_m (theta_ref(q_des) - theta) - Kd_m thetadot``.
    The joint stiffness at rest is the mechanical stiffness in series with
    the motor position loop.
``two-time-scale`` (11.3)
    motor-position inner loop towards the motor angle that generates
    ``f_des``: ``theta_des = theta + (f_des - f) / alpha`` (``alpha = r_m k_t``,
    exact for a linear spring, first order otherwise)::

        u = r_m f + Kp_m (theta_des - theta) - Kd_m thetadot + b_hat(thetadot)

    with ``Kp_m = B w_m^2``, ``Kd_m = 2 xi_m w_m B``.
``cascaded`` (11.16)
    linearising force controller (the cascaded form needs a law in ``f``, not
    ``theta``, section 11.7).  With the link model ``M qdd = c.f - d_q qdot``
    (+ the unknown external torque) and the drive ``B thdd = u - r_m f + b(thetadot)``
    the force obeys ``fdd = (k r_m / B)(u - r_m f + b) - k c qdd`` (the
    ``k'(x) xdot^2`` term of a nonlinear spring is neglected: it vanishes at rest
    and in the linearisation).  The law::

        u = r_m f - b_hat + (B / alpha) (fdd_des + k c qdd_hat
                                         + 2 xi_f w_f (fdot_des - fdot) + w_f^2 (f_des - f)),

    with ``alpha = r_m k``, ``fdot = k (r_m thetadot - c qdot)``, the model
    estimates ``qdd_hat = (c.f - d_q qdot + tau_hat) / M``,
    ``qddd_hat = (c.fdot - d_q qdd_hat) / M`` and the derivatives of
    ``f_des = f_pre + c^+ (Kp_imp (q_des - q) + Kd_imp (qdot_des - qdot))``::

        fdot_des = c^+ (Kp_imp (qdot_des - qdot) + Kd_imp (qdd_des - qdd_hat)),
        fdd_des  = c^+ (Kp_imp (qdd_des - qdd_hat) - Kd_imp qddd_hat),

    makes the force error ``e_f = f_des - f`` of every tendon obey
    ``e_f'' + 2 xi_f w_f e_f' + w_f^2 e_f = 0`` exactly (for the model) and the
    link ``M qdd + (d_q + Kd_imp) qdot + Kp_imp (q - q_des) = -c.e_f``: a cascade
    whose linearisation has the designed force pole pair (once per tendon) and
    the link pair (tested with Drake's ``Linearize`` of the continuous loop).
    ``qdd_hat`` includes an external-torque estimate ``tau_hat`` from a
    momentum observer (De Luca's generalised-momentum residual, one continuous
    state ``z``): ``zdot = c.f - d_q qdot + tau_hat``, ``tau_hat = K_O (M qdot - z)``,
    so ``tau_hat' = K_O (tau_ext - tau_hat)``.  Without it a constant external
    torque enters ``qdd_hat`` as ``tau_ext / M`` (M = 4e-7 kg m^2 on the flexible
    joint) and biases the force loop so much that the static joint stiffness
    becomes *negative*.  With it
    the loop is a triangular cascade (observer error -> force errors -> link):
    eigenvalues = force pair(s) + link pair + ``-K_O``, and at rest under a
    load ``f = f_des`` (stiffness = Kp_imp).
    The reference is a set point (``joint_angle_reference`` only):
    ``qdot_des = qdd_des = 0`` between its changes (:meth:`ImpedanceLaw.desired_force_rates`
    takes them for trajectory use).

Rigs: the flexible joint (``c = [1]``, ``r_m = 1``: the "tendon force" is the
spring torque) and the antagonistic joint rig (``c = [r_q, -r_q]``).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import smax
from awiwi_drake.control.base import COMMAND_PORT, StaticLaw, StaticLawController, check_gain, check_gains
from awiwi_drake.control.registry import rig_kind
from awiwi_drake.control.tendon_force import identified_gains
from awiwi_drake.parameters.components import MotorParams
from awiwi_drake.parameters.control import ImpedanceParams

__all__ = ["Transmission", "transmission", "ImpedanceLaw", "motor_position_command", "MotorPositionForceLaw", "CascadedImpedanceController_",
           "CascadedImpedanceController", "LinkReferenceMotorPdLaw", "impedance_controller", "MODES"]

MODES = ("pd", "two-time-scale", "cascaded")


@dataclass(frozen=True)
class Transmission:
    """Static transmission of a joint rig: ``tau = c . f``, motor pulley ``r_m``, pretension, motors."""

    coupling: np.ndarray      # c_i [m] (or 1 for the flexible joint)
    pulley_radius: float      # r_m
    pretension: np.ndarray    # f_pre per tendon [N] (or [Nm])
    motor: MotorParams
    compensate_friction: bool
    min_alpha: float = 0.0    # floor of r_m k_t in the laws: a slack tendon has k_t = 0
    link_inertia: float = 0.0  # M [kg m^2] of the link model (cascaded law)
    link_damping: float = 0.0  # d_q [Nm s/rad] of the link model (cascaded law)

    @property
    def pseudo_inverse(self) -> np.ndarray:
        c = self.coupling
        return c / float(c @ c)


def transmission(rig: Any) -> Transmission:
    """The :class:`Transmission` of a flexible-joint or joint rig (from its parameters)."""
    kind = rig_kind(rig)
    p = rig.params
    if kind == "flexible-joint":
        # the rig's motor: no (3.8) friction, linear damping d_theta (12.8); nothing to compensate
        motor = MotorParams(inertia=p.motor_inertia, friction=False, damping=p.motor_damping, ripple=False,
                            saturation=False)
        return Transmission(np.array([1.0]), 1.0, np.array([0.0]), motor, False, 0.05 * p.stiffness,
                            p.link_inertia, p.link_damping)
    if kind == "joint-rig":
        rq = p.link_pulley_radius
        k_pre = float(np.ravel(rig.operating_point().tendon_stiffness)[0])
        # floor: 5 % of the stiffness at pretension (chosen: keeps the laws finite when a tendon goes slack)
        return Transmission(np.array([rq, -rq]), p.motor.pulley_radius, np.full(2, p.pretension), p.motor, True,
                            0.05 * p.motor.pulley_radius * k_pre, p.link_inertia, p.link_damping)
    raise ValueError(f"impedance control needs a joint rig (flexible-joint or joint-rig), got {kind!r}")


class ImpedanceLaw(StaticLaw):
    """Joint impedance (11.4) over a tendon law ``pd`` / ``two-time-scale`` (11.3) / ``cascaded`` (11.16)."""

    def __init__(self, tr: Transmission, params: ImpedanceParams | None = None, *, mode: str = "two-time-scale"):
        if mode not in MODES[1:]:
            raise ValueError(f"impedance mode {mode!r} unknown; use one of {', '.join(MODES[1:])}")
        if mode == "cascaded":
            check_gain("link_inertia", tr.link_inertia, owner="cascaded transmission")
            check_gain("link_damping", tr.link_damping, owner="cascaded transmission", allow_zero=True)
        p = params or ImpedanceParams()
        self.name = mode.replace("-", "_")
        self.mode, self.tr, self.params = mode, tr, p
        self.kp_imp = check_gain("joint_stiffness", p.joint_stiffness, owner=self.name)
        self.kd_imp = check_gain("joint_damping", p.joint_damping, owner=self.name, allow_zero=True)
        self.kp_m, self.kd_m = motor_position_gains(p, tr.motor.inertia, self.name)
        wf = check_gain("force_bandwidth", p.force_bandwidth, owner=self.name)
        xf = check_gain("force_damping_ratio", p.force_damping_ratio, owner=self.name)
        self.kf, self.kfd = wf ** 2, 2 * xf * wf
        n = len(tr.coupling)
        self.inputs = {"joint_angle_reference": 1, "joint_angle": 1, "joint_velocity": 1, "motor_velocity": n,
                       "tendon_force": n, "tendon_stiffness": n}
        self.output_size = n

    def desired_forces(self, q_des, q, qdot, qdot_des=0.0):
        """``f_des = f_pre + c^+ (Kp_imp (q_des - q) + Kd_imp (qdot_des - qdot))`` (11.4)."""
        tau = self.kp_imp * (q_des - q) + self.kd_imp * (qdot_des - qdot)
        return self.tr.pretension + self.tr.pseudo_inverse * tau

    def link_model(self, f, fdot, qdot, tau_hat=0.0):
        """Model estimates ``(qdd_hat, qddd_hat)`` from ``M qdd = c.f - d_q qdot + tau_hat`` (``tau_hat`` const)."""
        tr = self.tr
        qdd = (tr.coupling @ f - tr.link_damping * qdot + tau_hat) / tr.link_inertia
        qddd = (tr.coupling @ fdot - tr.link_damping * qdd) / tr.link_inertia
        return qdd, qddd

    def desired_force_rates(self, qdot, qdd, qddd, qdot_des=0.0, qdd_des=0.0):
        """``(fdot_des, fdd_des)``: time derivatives of :meth:`desired_forces` (``qddd_des = 0``)."""
        c_plus = self.tr.pseudo_inverse
        fdot_des = c_plus * (self.kp_imp * (qdot_des - qdot) + self.kd_imp * (qdd_des - qdd))
        fdd_des = c_plus * (self.kp_imp * (qdd_des - qdd) - self.kd_imp * qddd)
        return fdot_des, fdd_des

    def __call__(self, u):
        return self.command(u)

    def command(self, u, tau_hat=0.0):
        """Motor torques; ``tau_hat``: external link torque estimate (cascaded law only)."""
        from awiwi_drake.components import motor_friction_torque
        tr = self.tr
        q, qd = u["joint_angle"][0], u["joint_velocity"][0]
        w, f, k = u["motor_velocity"], u["tendon_force"], u["tendon_stiffness"]
        f_des = self.desired_forces(u["joint_angle_reference"][0], q, qd)
        B, r = tr.motor.inertia, tr.pulley_radius
        alpha = smax(r * k, tr.min_alpha)
        if self.mode == "two-time-scale":
            comp = -motor_friction_torque(w, tr.motor) if (tr.compensate_friction and
                                                           self.params.friction_compensation) else 0.0 * w
            return motor_position_command(f_des, f, w, alpha, r, self.kp_m, self.kd_m) + comp
        # linearising force law: model-based, so the modelled motor damping/friction is always cancelled
        comp = -motor_friction_torque(w, tr.motor) if self.params.friction_compensation else 0.0 * w
        fdot = k * (r * w - tr.coupling * qd)
        qdd, qddd = self.link_model(f, fdot, qd, tau_hat)
        fdot_des, fdd_des = self.desired_force_rates(qd, qdd, qddd)
        return r * f + comp + (B / alpha) * (fdd_des + k * tr.coupling * qdd + self.kfd * (fdot_des - fdot)
                                             + self.kf * (f_des - f))


def motor_position_gains(p: ImpedanceParams, inertia: float, owner: str) -> tuple[float, float]:
    """``(Kp_m, Kd_m) = (B w_m^2, 2 xi_m w_m B)`` of a motor-position loop at ``p``'s motor bandwidth and damping:
    (10.11) with a unit slope (:func:`~awiwi_drake.control.tendon_force.identified_gains`)."""
    return identified_gains(1.0, check_gain("inertia", inertia, owner=owner),
                            check_gain("motor_bandwidth", p.motor_bandwidth, owner=owner),
                            check_gain("motor_damping_ratio", p.motor_damping_ratio, owner=owner))


def motor_position_command(f_des, f, omega, alpha, pulley_radius, kp_m, kd_m):
    """The tendon level of (11.3): a motor-position loop towards the motor angle that generates ``f_des``,
    ``u = r_m f + Kp_m (theta_des - theta) - Kd_m thetadot`` with ``theta_des - theta = (f_des - f) / alpha``
    (``alpha = r_m k_t``: exact for a linear spring, first order otherwise).  Element-wise (a bank)."""
    return pulley_radius * f + kp_m * (f_des - f) / alpha - kd_m * omega


class MotorPositionForceLaw(StaticLaw):
    """(11.3)'s tendon level as a bank of ``size`` tendons (the two-time-scale chain of a finger/the hand).

    Inputs ``tendon_force_reference``, ``tendon_force``, ``tendon_stiffness``, ``motor_velocity`` (size);
    ``Kp_m = B w_m^2``, ``Kd_m = 2 xi_m w_m B`` (:class:`ImpedanceParams` motor bandwidth), ``alpha`` floored
    at ``min_alpha`` (a slack tendon has ``k_t = 0``; one number, or one per tendon), motor friction (3.8) fed forward times ``friction_scale``.

    ``path_velocity=True`` (the finger/hand chain) adds the input ``tendon_path_velocity`` ``v = P(q) qdot``
    [m/s] and damps the motor velocity *relative to the tendon path*, ``Kd_m (thetadot + v / r_m)`` (the
    spring's elongation rate over ``r_m``, as (10.2)'s force rate estimate): the motor velocity that keeps the
    force constant while the joints move is ``-v / r_m``, not 0.  Damping the absolute motor velocity instead
    acts on the joints as a viscous damping ``sum_i P_ij^2 Kd_m / r_m^2`` (about 4 Nm s/rad on an index joint,
    against stiffnesses of 0.002-0.2 Nm/rad: slow real poles).  On the joint rig (ch. 11) the link is far heavier
    and this term is the thesis's.
    """

    def __init__(self, motor: MotorParams, params: ImpedanceParams | None = None, *, size: int,
                 min_alpha: float, friction_scale: float = 1.0, name: str = "motor_position_control",
                 path_velocity: bool = False):
        p = params or ImpedanceParams()
        self.name, self.motor = name, motor
        self.kp_m, self.kd_m = motor_position_gains(p, motor.inertia, name)
        size = int(size)
        self.min_alpha = (check_gains("min_alpha", min_alpha, shape=(size,), owner=name, positive=True)
                          if np.ndim(min_alpha) else check_gain("min_alpha", min_alpha, owner=name))
        self.friction_scale = check_gain("friction_scale", friction_scale, allow_zero=True, owner=name)
        self.r_m = check_gain("pulley_radius", motor.pulley_radius, owner=name)
        self.inputs = {"tendon_force_reference": size, "tendon_force": size, "tendon_stiffness": size,
                       "motor_velocity": size}
        self.path_velocity = bool(path_velocity)
        if self.path_velocity:
            self.inputs["tendon_path_velocity"] = size
        self.output_size = size

    def __call__(self, u):
        from awiwi_drake.components import motor_friction_torque
        w = u["motor_velocity"]
        w_rel = w + u["tendon_path_velocity"] / self.r_m if self.path_velocity else w
        alpha = smax(self.r_m * u["tendon_stiffness"], self.min_alpha)
        return (motor_position_command(u["tendon_force_reference"], u["tendon_force"], w_rel, alpha, self.r_m,
                                       self.kp_m, self.kd_m)
                - self.friction_scale * motor_friction_torque(w, self.motor))


@TemplateSystem.define("CascadedImpedanceController_", scope=sys.modules[__name__])
def CascadedImpedanceController_(T):
    """The cascaded law (11.16) with a momentum observer of the external link torque (one continuous state).

    Inputs: the law's ports; outputs ``motor_torque`` (feedthrough) and
    ``external_torque_estimate`` [Nm].  State ``z`` [kg m^2 rad/s] starts at 0
    (exact for a link at rest: ``tau_hat = K_O (M qdot - z)``).
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, law: "ImpedanceLaw", observer_gain: float, converter=None):
            LeafSystem_[T].__init__(self, converter)
            if not isinstance(law, ImpedanceLaw) or law.mode != "cascaded":
                raise ValueError("CascadedImpedanceController: law must be a cascaded ImpedanceLaw")
            self.law = law
            self.observer_gain = check_gain("observer_bandwidth", observer_gain, owner=law.name)
            self._ports = {nm: self.DeclareVectorInputPort(nm, int(sz)) for nm, sz in law.inputs.items()}
            self.DeclareContinuousState(1)
            tickets = {p.ticket() for p in self._ports.values()} | {self.all_state_ticket()}
            self.DeclareVectorOutputPort(COMMAND_PORT, int(law.output_size), self._calc,
                                         prerequisites_of_calc=tickets)
            self.DeclareVectorOutputPort("external_torque_estimate", 1, self._calc_estimate,
                                         prerequisites_of_calc={self._ports["joint_velocity"].ticket(),
                                                                self.all_state_ticket()})
            self.set_name(law.name)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.law, other.observer_gain, converter=converter)

        def _estimate(self, context):
            z = context.get_continuous_state_vector().CopyToVector()[0]
            qd = self._ports["joint_velocity"].Eval(context)[0]
            return self.observer_gain * (self.law.tr.link_inertia * qd - z)

        def _calc(self, context, output):
            values = {nm: p.Eval(context) for nm, p in self._ports.items()}
            output.SetFromVector(np.asarray(self.law.command(values, self._estimate(context))).reshape(-1))

        def _calc_estimate(self, context, output):
            output.SetFromVector(np.array([self._estimate(context)]))

        def DoCalcTimeDerivatives(self, context, derivatives):
            tr = self.law.tr
            f = self._ports["tendon_force"].Eval(context)
            qd = self._ports["joint_velocity"].Eval(context)[0]
            zdot = tr.coupling @ f - tr.link_damping * qd + self._estimate(context)
            derivatives.get_mutable_vector().SetFromVector(np.array([zdot]))

    return Impl


CascadedImpedanceController = CascadedImpedanceController_[None]


class LinkReferenceMotorPdLaw(StaticLaw):
    """``u = u_ref(r) + Kp_m (theta_ref(r) - theta) - Kd_m thetadot`` on the motor coordinates of ``state``
    (``x_ref``, ``u_ref``: the linearisation's equilibrium family, :class:`~awiwi_drake.control.linear.LinearReferenceModel`)."""

    def __init__(self, lin, motor_index, inertia: float, params: ImpedanceParams | None = None):
        from awiwi_drake.control.linear import LinearReferenceModel
        self.name = "pd"
        self.kp_m, self.kd_m = motor_position_gains(params or ImpedanceParams(), inertia, self.name)
        self.model = LinearReferenceModel(lin)
        self.ith, self.iw = list(motor_index[0]), list(motor_index[1])
        self.inputs, self.output_size = dict(self.model.inputs), lin.B.shape[1]

    def __call__(self, u):
        x = u["state"]
        x_ref, u_ref = self.model.equilibrium(u["joint_angle_reference"][0])
        return u_ref + self.kp_m * (x_ref[self.ith] - x[self.ith]) - self.kd_m * (x[self.iw] - x_ref[self.iw])


def impedance_controller(rig: Any, params: ImpedanceParams | None = None, *, mode: str = "two-time-scale"):
    """Registered factories ``pd``, ``two-time-scale``, ``cascaded``."""
    if mode == "pd":
        from awiwi_drake.analysis.linear import linearize
        tr = transmission(rig)
        lin = linearize(rig, outputs=("state", "joint_angle"))
        names = list(rig.state_names)
        n = len(tr.coupling)
        ith = [names.index(f"motor_angle[{i}]") for i in range(n)]
        iw = [names.index(f"motor_velocity[{i}]") for i in range(n)]
        return StaticLawController(LinkReferenceMotorPdLaw(lin, (ith, iw), tr.motor.inertia, params))
    law = ImpedanceLaw(transmission(rig), params, mode=mode)
    if mode == "cascaded":
        return CascadedImpedanceController(law, law.params.observer_bandwidth)
    return StaticLawController(law)
