"""Stiffness correction (thesis ch. 8).

The stiffness felt at a joint is the series connection of the controller's
impedance and the mechanical (tendon) stiffness (8.1):

    K_eff^-1 = K_imp^-1 + K_mech^-1     (:func:`~awiwi_drake.components.tendon.series_stiffness`).

The user sets ``K_eff,des``; the pretension is chosen for ``K_mech,des =
eps K_eff,des`` (8.2, eps > 1); the controller gain is then recomputed online
from the *current* mechanical stiffness so that ``K_eff`` stays at target while
loads change ``K_mech`` (nonlinear springs). ``K_imp`` is kept positive
definite (eigenvalues >= ``min_impedance``) and bounded (``max_impedance``,
the singular case ``K_mech -> K_eff`` of section 8.3); when either limit acts,
the target is not met and the law reports it (``limited``).

:func:`impedance_for_effective_stiffness` is the matrix law (n x n);
:class:`StiffnessCorrectedImpedance_` a controller for the antagonistic joint
rig: motor-side impedance (the Awiwi hand has no link sensors: the controller
acts on the motor positions, so its compliance is in series with the springs),
motor PD with tendon-force feedforward, pretension set by (8.2), ``K_imp``
updated online from the spring stiffness at the measured elongations.
The Fig 8.3 run is :mod:`awiwi_drake.reproductions.ch08_stiffness_correction`.
"""

from __future__ import annotations

import sys

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import clip, smax
from awiwi_drake.components.tendon import series_stiffness
from awiwi_drake.parameters.hand_control import StiffnessCorrectionParams

__all__ = ["impedance_for_effective_stiffness", "pretension_elongation", "StiffnessCorrectedImpedance_",
           "StiffnessCorrectedImpedance"]


def impedance_for_effective_stiffness(K_eff_des, K_mech, params: StiffnessCorrectionParams | None = None):
    """``K_imp`` from (8.1) for a desired ``K_eff`` and the current ``K_mech``, kept positive definite.

    Returns ``(K_imp, limited)``: ``limited`` is True when an eigenvalue had to be raised to
    ``min_impedance`` (K_mech <= K_eff in that direction: the target is unreachable with a
    passive controller) or capped at ``max_impedance`` (K_mech close to K_eff).
    """
    p = params or StiffnessCorrectionParams()
    Ke, Km = np.atleast_2d(K_eff_des).astype(float), np.atleast_2d(K_mech).astype(float)
    if Ke.shape != Km.shape or Ke.shape[0] != Ke.shape[1]:
        raise ValueError(f"impedance_for_effective_stiffness: K_eff_des {Ke.shape} and K_mech {Km.shape} "
                         "must be square and of the same shape")
    for name, M in (("K_eff_des", Ke), ("K_mech", Km)):
        if not np.allclose(M, M.T, atol=1e-12) or np.min(np.linalg.eigvalsh(M)) <= 0:
            raise ValueError(f"impedance_for_effective_stiffness: {name} must be symmetric positive definite")
    C = np.linalg.inv(Ke) - np.linalg.inv(Km)          # K_imp^-1
    C = 0.5 * (C + C.T)
    w, V = np.linalg.eigh(C)
    # compliance eigenvalues -> stiffness eigenvalues, limited to [min, max]
    with np.errstate(divide="ignore"):
        k = np.where(w > 0, 1.0 / np.where(w > 0, w, 1.0), np.inf)
    limited = bool(np.any(k < p.min_impedance) or np.any(k > p.max_impedance))
    k = np.clip(k, p.min_impedance, p.max_impedance)
    return (V * k) @ V.T, limited


def pretension_elongation(spring, joint_stiffness: float, link_pulley_radius: float) -> float:
    """Common elongation x with ``2 r_q^2 k(x) = joint_stiffness`` (8.2: pretension for a K_mech target)."""
    target = joint_stiffness / (2.0 * link_pulley_radius ** 2)
    hi = float(getattr(spring, "max_elongation", 0.01))
    hi = hi if np.isfinite(hi) else 0.01
    k_lo, k_hi = float(spring.stiffness(np.array([1e-9]))[0]), float(spring.stiffness(np.array([hi]))[0])
    if not k_lo <= target <= k_hi:
        raise ValueError(f"pretension_elongation: K_mech = {joint_stiffness} Nm/rad needs a tendon stiffness of "
                         f"{target:.4g} N/m, outside the spring's range [{k_lo:.4g}, {k_hi:.4g}] N/m")
    lo = 1e-9
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if float(spring.stiffness(np.array([mid]))[0]) < target else (lo, mid)
    return 0.5 * (lo + hi)


@TemplateSystem.define("StiffnessCorrectedImpedance_", scope=sys.modules[__name__])
def StiffnessCorrectedImpedance_(T):
    class Impl(LeafSystem_[T]):
        """Motor-side joint impedance with online stiffness correction on the antagonistic joint rig.

        Inputs: ``state`` (6, joint rig order), ``joint_angle_reference`` (1) [rad],
        ``effective_stiffness_reference`` (1) [Nm/rad]. ``online=False`` computes K_imp once from the
        nominal K_mech = eps K_eff (no correction), for comparison.
        Outputs: ``motor_torque`` (2) [Nm]; ``stiffness`` (3) = ``[K_imp, K_mech, K_eff (8.1)]`` [Nm/rad];
        ``effective_stiffness`` (1) = ``K_eff`` [Nm/rad], the quantity ``effective_stiffness_reference``
        sets (the rig cannot measure it).

        ``q_m = r_m (theta1 - theta2) / (2 r_q)`` is the motor-side joint angle, ``tau = r_q (f1 - f2)``
        the joint torque of the tendons. The motors track ``q_m,des = q_ref - tau / K_imp`` (the
        controller compliance) at the common elongation ``x_c`` of (8.2) with a PD and the
        tendon-force feedforward ``r_m f_i``. At rest ``q - q_ref = tau_ext (1/K_imp + 1/K_mech)``.
        """

        def _construct(self, rig_params, spring, params=None, motor_gains=(50.0, 1.0), online=True,
                       converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.rig_params, self.spring, self.online = rig_params, spring, bool(online)
            self.params = params or StiffnessCorrectionParams()
            self.motor_gains = tuple(float(g) for g in motor_gains)
            if min(self.motor_gains) <= 0:
                raise ValueError(f"StiffnessCorrectedImpedance: motor_gains = {motor_gains} must be > 0")
            self.DeclareVectorInputPort("state", 6)
            self.DeclareVectorInputPort("joint_angle_reference", 1)
            self.DeclareVectorInputPort("effective_stiffness_reference", 1)
            t = {self.all_input_ports_ticket()}
            self.DeclareVectorOutputPort("motor_torque", 2, self._calc_u, prerequisites_of_calc=t)
            self.DeclareVectorOutputPort("stiffness", 3, self._calc_k, prerequisites_of_calc=t)
            self.DeclareVectorOutputPort("effective_stiffness", 1, self._calc_k_eff, prerequisites_of_calc=t)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.rig_params, other.spring, other.params, other.motor_gains,
                            other.online, converter=converter)

        def _law(self, context):
            x = self.get_input_port(0).Eval(context)
            q_ref = self.get_input_port(1).Eval(context)[0]
            k_eff = self.get_input_port(2).Eval(context)[0]
            p, sp = self.rig_params, self.spring
            rm, rq = p.motor.pulley_radius, p.link_pulley_radius
            q, th, om = x[0], x[2:4], x[4:6]
            xe = np.array([rm * th[0] - rq * q, rm * th[1] + rq * q])
            f = sp.force(xe)
            k_mech = rq * rq * (sp.stiffness(xe[0:1])[0] + sp.stiffness(xe[1:2])[0])
            # (8.1) solved for K_imp, kept in [min, max] (scalar joint); without online correction
            # the nominal K_mech = eps K_eff of (8.2) is used
            k_model = k_mech if self.online else self.params.epsilon * k_eff
            compliance = 1.0 / k_eff - 1.0 / k_model
            k_imp = clip(1.0 / smax(compliance, 1.0 / self.params.max_impedance),
                         self.params.min_impedance, self.params.max_impedance)
            tau = rq * (f[0] - f[1])
            x_c = self._elongation(k_eff)
            q_m_des = q_ref - tau / k_imp
            th_ref = np.array([(x_c + rq * q_m_des) / rm, (x_c - rq * q_m_des) / rm])
            kp, kd = self.motor_gains
            u = rm * f + kp * (th_ref - th) - kd * om
            return u, k_imp, k_mech

        def _elongation(self, k_eff):
            """(8.2) pretension for K_mech,des = eps K_eff: the common elongation ``x_c`` with
            ``2 r_q^2 k(x_c) = eps K_eff`` (root cached per target value). Its derivative follows from
            the implicit function theorem, ``dx_c/dK_eff = eps / (2 r_q^2 k'(x_c))``, so AutoDiffXd
            sees how the pretension moves with the stiffness target."""
            key = float(k_eff.value() if hasattr(k_eff, "value") else k_eff)
            cache = self.__dict__.setdefault("_xc", {})
            if key not in cache:
                rq, eps = self.rig_params.link_pulley_radius, self.params.epsilon
                x_c = pretension_elongation(self.spring, eps * key, rq)
                slope = eps / (2.0 * rq * rq * float(self.spring.stiffness_derivative(np.array([x_c]))[0]))
                cache[key] = (x_c, slope)
            x_c, slope = cache[key]
            return x_c + slope * (k_eff - key)

        def _calc_u(self, context, output):
            output.SetFromVector(self._law(context)[0])

        def _calc_k(self, context, output):
            _, k_imp, k_mech = self._law(context)
            output.SetFromVector(np.array([k_imp, k_mech, series_stiffness(k_imp, k_mech)]))

        def _calc_k_eff(self, context, output):
            _, k_imp, k_mech = self._law(context)
            output.SetAtIndex(0, series_stiffness(k_imp, k_mech))

    return Impl


StiffnessCorrectedImpedance = StiffnessCorrectedImpedance_[None]


