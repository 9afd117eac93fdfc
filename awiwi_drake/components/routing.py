"""Tendon routing: the map between motors, springs and joints (thesis (5.5)-(5.9)).

Sign convention (docs/ARCHITECTURE.md): ``P(q) = dh/dq``, elongation ``x = r_m theta + h(q) - h(0) + x0``,
joint torque ``tau = -P(q)^T f``.  A *coupling* is any object with ``num_tendons``, ``num_joints``, ``h(q)``,
``P(q)`` and ``tension_hessian(q, f)`` generic in the scalar type (the finger couplings of
:mod:`awiwi_drake.hand` too).
"""

from __future__ import annotations

import sys

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import asarray_like

__all__ = ["ConstantCoupling", "TendonRouting_", "TendonRouting", "antagonistic_coupling", "joint_backlash_angle"]


class ConstantCoupling:
    """Coupling with a constant matrix: ``h(q) = P q`` (index/middle type fingers, (5.6))."""

    def __init__(self, P, name: str = "constant"):
        P = np.atleast_2d(np.asarray(P, dtype=float))
        if P.ndim != 2 or not np.all(np.isfinite(P)):
            raise ValueError(f"ConstantCoupling: P must be a finite 2-D matrix, got shape {np.shape(P)}")
        self._P = P
        self.name = name
        self.num_tendons, self.num_joints = P.shape

    def h(self, q):
        return self._P @ q

    def P(self, q=None):
        return self._P

    def tension_hessian(self, q, f):
        """``d(P(q)^T f)/dq = sum_i f_i d^2 h_i/dq^2`` (n x n): zero for a constant coupling."""
        return np.zeros((self.num_joints, self.num_joints))


def antagonistic_coupling(link_pulley_radius: float) -> ConstantCoupling:
    """The one-joint, two-tendon coupling of Fig 5.9: ``h = [-r_q q, +r_q q]``."""
    if not link_pulley_radius > 0:
        raise ValueError(f"antagonistic_coupling: link_pulley_radius = {link_pulley_radius} must be > 0 [m]")
    return ConstantCoupling([[-link_pulley_radius], [link_pulley_radius]], name="antagonistic")


def joint_backlash_angle(q, torque_and_stiffness, half_width, smoothing: float = 0.05, newton_steps: int = 2,
                         stiffness_floor: float = 1e-6):
    """Angle of a tendon pulley that turns with play ``+-b`` on its link at ``q`` (backlash at the joint).

    The pulley is massless: inside the play it rests where the tendons' torque on it vanishes,
    ``tau(q_p0) = 0`` (``newton_steps`` Newton steps from the link angle; ``torque_and_stiffness(a)``
    returns the tendons' torque ``tau = -P^T f`` on the pulley at angle ``a`` and the joint stiffness
    ``K = -dtau/da = P^T diag(k) P``); at an end of the play the link holds it, ``q_p = q -+ b``.
    So ``q_p = q + sat_b(q_p0 - q)``, the saturation rounded over ``smoothing * b``
    (``0.5 (sqrt((y + b)^2 + e^2) - sqrt((y - b)^2 + e^2))``) for the integrator. The link then
    feels the tendons' torque at ``q_p``: none inside the play (a dead zone), the spring torque at
    ``q -+ b`` outside. ``stiffness_floor`` [Nm/rad] keeps the step finite with both tendons slack.
    Generic in the scalar type; ``b > 0``.
    """
    a = q
    for _ in range(newton_steps):
        tau, K = torque_and_stiffness(a)
        a = a + tau / (K + stiffness_floor)
    y, e = a - q, smoothing * half_width
    return q + 0.5 * (np.sqrt((y + half_width) ** 2 + e * e) - np.sqrt((y - half_width) ** 2 + e * e))


def _check_coupling(coupling):
    for attr in ("num_tendons", "num_joints", "h", "P"):
        if not hasattr(coupling, attr):
            raise ValueError(f"TendonRouting: coupling lacks {attr!r} (needs num_tendons, num_joints, h(q), P(q))")


@TemplateSystem.define("TendonRouting_", scope=sys.modules[__name__])
def TendonRouting_(T):
    """Maps motor and joint angles to spring elongations and tendon forces to joint torques.

    Inputs ``motor_angle`` (m) [rad], ``joint_angle`` (n) [rad], ``tendon_force`` (m) [N]; outputs
    ``elongation`` (m) [m] = ``r_m theta + h(q) - h(0) + x0`` and ``generalized_force`` (n) [Nm] =
    ``-P(q)^T f``; with ``rates=True`` also the inputs ``motor_velocity`` (m), ``joint_velocity`` (n) and the
    output ``elongation_rate`` (m) [m/s] = ``r_m omega + P(q) qdot``.
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, coupling=None, motor_pulley_radius: float = 0.005, offsets=None,
                       rates: bool = False, converter=None):
            LeafSystem_[T].__init__(self, converter)
            _check_coupling(coupling)
            if not motor_pulley_radius > 0:
                raise ValueError(f"TendonRouting: motor_pulley_radius = {motor_pulley_radius} must be > 0 [m]")
            m, n = coupling.num_tendons, coupling.num_joints
            offsets = np.zeros(m) if offsets is None else np.asarray(offsets, dtype=float)
            if offsets.shape != (m,) or not np.all(np.isfinite(offsets)):
                raise ValueError(f"TendonRouting: offsets must be {m} finite numbers [m], got {offsets!r}")
            self.coupling, self.r_m, self.offsets, self.rates = coupling, float(motor_pulley_radius), offsets, rates
            self._h0 = np.asarray(coupling.h(np.zeros(n)), dtype=float)
            self._theta = self.DeclareVectorInputPort("motor_angle", m)
            self._q = self.DeclareVectorInputPort("joint_angle", n)
            self._f = self.DeclareVectorInputPort("tendon_force", m)
            self.DeclareVectorOutputPort("elongation", m, self._calc_elongation,
                                         prerequisites_of_calc={self._theta.ticket(), self._q.ticket()})
            self.DeclareVectorOutputPort("generalized_force", n, self._calc_tau,
                                         prerequisites_of_calc={self._q.ticket(), self._f.ticket()})
            if rates:
                self._omega = self.DeclareVectorInputPort("motor_velocity", m)
                self._qd = self.DeclareVectorInputPort("joint_velocity", n)
                self.DeclareVectorOutputPort(
                    "elongation_rate", m, self._calc_rate,
                    prerequisites_of_calc={self._q.ticket(), self._omega.ticket(), self._qd.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.coupling, other.r_m, other.offsets, other.rates, converter=converter)

        def _calc_elongation(self, context, out):
            theta = self._theta.Eval(context)
            q = self._q.Eval(context)
            x = self.r_m * theta + self.coupling.h(q) - self._h0 + self.offsets
            out.SetFromVector(asarray_like(x, theta))

        def _calc_tau(self, context, out):
            q = self._q.Eval(context)
            f = self._f.Eval(context)
            out.SetFromVector(asarray_like(-(np.asarray(self.coupling.P(q)).T @ f), f))

        def _calc_rate(self, context, out):
            q = self._q.Eval(context)
            omega = self._omega.Eval(context)
            qd = self._qd.Eval(context)
            out.SetFromVector(asarray_like(self.r_m * omega + np.asarray(self.coupling.P(q)) @ qd, omega))

    return Impl


TendonRouting = TendonRouting_[None]
