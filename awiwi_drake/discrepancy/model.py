"""The augmented rig model: nominal dynamics plus every catalog effect as a switch.

:class:`DiscrepancyModel_` is one TemplateSystem that integrates ``copies``
independent instances of a rig (``tendon``: one motor; ``joint``: two motors
and a link) side by side, each with its own catalog parameter vector (a Drake
numeric parameter).  The workflow runs every multiple-shooting window and
every finite-difference perturbation of a fit as one copy, so a whole
residual/Jacobian evaluation is one pass of one Drake ``Simulator``
("banks, not swarms": one Python call per step for all copies).

State of copy ``j`` (``n`` motors): ``[theta_1..n, omega_1..n, (q, q'), z_1..n]``
where ``z`` [N] is the Dahl hysteresis force of each spring mechanism; stored
variable-major (index ``s * copies + j``).  Input ``motor_torque``
(``n * copies``, applied torque, already delayed).  Output ``measurement``:
``[theta_1..n, f_1..n, (q)]`` per copy, ``f`` the spring-mechanism force as the
force sensor reports it.

Nominal dynamics (issue 6 data contract)::

    x_i = r theta_i + h_i(q),  h = [-r_q q, +r_q q]  (joint; tendon: h = 0)
    B theta_i'' = u_i - d theta_i' - r (f_i + F_guide,i) + tau_fric + tau_ripple
    m q'' = r_q (f_1 - f_2) - d_q q' + tau_joint_friction
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import BasicVector_, LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from . import laws
from .catalog import PARAM_INDEX, PARAM_NAMES, default_vector

__all__ = ["NominalParameters", "DiscrepancyModel_", "DiscrepancyModel"]



@dataclass(frozen=True)
class NominalParameters:
    """Nominal rig parameters as read from a dataset's JSON (SI)."""

    rig: str
    motor_inertia: float
    motor_damping: float
    motor_pulley_radius: float
    spring_poly: tuple
    link_inertia: float = 0.0
    link_damping: float = 0.0
    link_pulley_radius: float = 0.0

    @classmethod
    def from_dataset(cls, rig: str, p: dict) -> "NominalParameters":
        extra = {}
        if rig == "joint":
            extra = dict(link_inertia=p["link_inertia"], link_damping=p["link_damping"],
                         link_pulley_radius=p["link_pulley_radius"])
        return cls(rig, float(p["motor_inertia"]), float(p["motor_damping"]),
                   float(p["motor_pulley_radius"]), tuple(float(c) for c in p["spring_poly"]), **extra)

    @property
    def num_motors(self) -> int:
        return 2 if self.rig == "joint" else 1

    @property
    def has_link(self) -> bool:
        return self.rig == "joint"

    @property
    def num_states(self) -> int:
        return 3 * self.num_motors + (2 if self.has_link else 0)

    @property
    def num_measurements(self) -> int:
        return 2 * self.num_motors + (1 if self.has_link else 0)

    def state_names(self) -> list[str]:
        n = self.num_motors
        sfx = [f"_{i + 1}" for i in range(n)] if n > 1 else [""]
        names = [f"motor_angle{s}" for s in sfx] + [f"motor_velocity{s}" for s in sfx]
        if self.has_link:
            names += ["link_angle", "link_velocity"]
        return names + [f"hysteresis_force{s}" for s in sfx]

    def measurement_names(self) -> list[str]:
        n = self.num_motors
        sfx = [f"_{i + 1}" for i in range(n)] if n > 1 else [""]
        names = [f"motor_angle{s}" for s in sfx] + [f"tendon_force{s}" for s in sfx]
        return names + (["link_angle"] if self.has_link else [])


def _p(P, name):
    return P[PARAM_INDEX[name]]


def _activity(P):
    """Per catalog parameter: nonzero in any copy (None off the float path: all active)."""
    if P.dtype == object:
        return None
    return np.any(P != 0.0, axis=1)


def _active(act, *names) -> bool:
    """Whether any of ``names`` is switched on in some copy."""
    return True if act is None else bool(any(act[PARAM_INDEX[n]] for n in names))


def split_state(nom: NominalParameters, X):
    """``(theta, omega, q, q', z)`` from a stacked state ``[theta, omega, (q, q'), z]``
    (``q``, ``q'`` are None without a link)."""
    n = nom.num_motors
    q = qd = None
    if nom.has_link:
        q, qd = X[2 * n], X[2 * n + 1]
    return X[:n], X[n:2 * n], q, qd, X[-n:]


def rig_kinematics(nom: NominalParameters, theta, omega, q=None, qd=None):
    """Spring elongations and their rates ``(x, xd)`` per motor (lists of arrays)."""
    r = nom.motor_pulley_radius
    if not nom.has_link:
        return [r * theta[0]], [r * omega[0]]
    rq = nom.link_pulley_radius
    return ([r * theta[0] - rq * q, r * theta[1] + rq * q],
            [r * omega[0] - rq * qd, r * omega[1] + rq * qd])


def model_derivatives(nom: NominalParameters, X, U, P):
    """Time derivatives of all copies.

    Parameters
    ----------
    X : array (num_states, copies)
    U : array (num_motors, copies) applied motor torques [Nm]
    P : array (num_params, copies) catalog parameters

    Returns
    -------
    array (num_states, copies), generic in the scalar type.
    """
    n = nom.num_motors
    theta, omega, q, qd, z = split_state(nom, X)
    x, xd = rig_kinematics(nom, theta, omega, q, qd)
    B = nom.motor_inertia * (1.0 + _p(P, "motor_inertia_rel"))
    d = nom.motor_damping + _p(P, "motor_damping_add")
    r = nom.motor_pulley_radius
    forces, elastic = [], []
    for i in range(n):
        f, f0 = laws.spring_with_hysteresis(x[i], z[i], nom.spring_poly, _p(P, "spring_scale_rel"))
        forces.append(f)
        elastic.append(f0)
    # switches: a catalog effect whose parameters are zero in every copy is skipped
    # (float path only; AutoDiffXd/Expression always evaluate every term)
    act = _activity(P)
    fric_on = _active(act, "motor_coulomb", "motor_viscous")
    guide_on = _active(act, "guide_c0", "guide_mu")
    hyst_on = _active(act, "hysteresis_width")
    acc, zdot = [], []
    for i in range(n):
        m = i + 1
        tau = U[i] - d * omega[i]
        if fric_on:
            tau = tau + laws.motor_friction(omega[i], _p(P, "motor_coulomb"), _p(P, "motor_slope"),
                                            _p(P, "motor_viscous"))
        harmonics = [(_p(P, f"ripple_order_{k}"), _p(P, f"ripple_sin{k}_m{m}"), _p(P, f"ripple_cos{k}_m{m}"))
                     for k in (1, 2) if _active(act, f"ripple_sin{k}_m{m}", f"ripple_cos{k}_m{m}")]
        if harmonics:
            tau = tau + laws.ripple(theta[i], harmonics)
        tension = forces[i]
        if guide_on:
            tension = tension + laws.guide_friction(r * omega[i], forces[i], _p(P, "guide_c0"),
                                                    _p(P, "guide_mu"), laws.GUIDE_VELOCITY)
        acc.append((tau - r * tension) / B)
        if hyst_on:
            zdot.append(laws.hysteresis_force_rate(z[i], x[i], xd[i], elastic[i], _p(P, "hysteresis_width"),
                                                   _p(P, "hysteresis_length")))
        else:
            zdot.append(0.0 * z[i])
    out = [omega[i] for i in range(n)] + acc
    if nom.has_link:
        mq = nom.link_inertia * (1.0 + _p(P, "link_inertia_rel"))
        dq = nom.link_damping + _p(P, "link_damping_add")
        rq = nom.link_pulley_radius
        tq = rq * (forces[0] - forces[1]) - dq * qd
        if _active(act, "joint_coulomb"):
            tq = tq + laws.joint_friction(qd, _p(P, "joint_coulomb"), _p(P, "joint_velocity"))
        qdd = tq / mq
        out += [qd, qdd]
    out += zdot
    return np.array(out)


def model_measurements(nom: NominalParameters, X, P):
    """Measured signals ``[theta..., f_meas..., (q)]`` of all copies (num_measurements, copies)."""
    n = nom.num_motors
    theta, omega, q, qd, z = split_state(nom, X)
    x, _ = rig_kinematics(nom, theta, omega, q, qd)
    out = [theta[i] + _p(P, f"motor_bias_{i + 1}") for i in range(n)]  # encoder bias
    for i in range(n):
        f, _ = laws.spring_with_hysteresis(x[i], z[i], nom.spring_poly, _p(P, "spring_scale_rel"))
        out.append((1.0 + _p(P, "force_gain")) * f + _p(P, f"force_offset_{i + 1}"))
    if nom.has_link:
        out.append((1.0 + _p(P, "link_scale_rel")) * q + _p(P, "link_bias"))  # link encoder calibration
    return np.array(out)


@TemplateSystem.define("DiscrepancyModel_")
def DiscrepancyModel_(T):

    class Impl(LeafSystem_[T]):
        """``copies`` instances of the augmented rig (see module docstring)."""

        def _construct(self, nominal: NominalParameters, copies: int = 1, converter=None):
            LeafSystem_[T].__init__(self, converter)
            if copies < 1:
                raise ValueError(f"DiscrepancyModel: copies must be >= 1, got {copies}")
            self._nom = nominal
            self._copies = int(copies)
            n = nominal.num_motors
            M = self._copies
            self._ns = nominal.num_states
            self._np = len(PARAM_NAMES)
            self.DeclareContinuousState(self._ns * M)
            self.DeclareNumericParameter(BasicVector_[T](np.tile(default_vector()[:, None], (1, M)).ravel()))
            self.DeclareVectorInputPort("motor_torque", n * M)
            self.DeclareVectorOutputPort(
                "measurement", nominal.num_measurements * M, self._calc_measurement,
                prerequisites_of_calc={self.all_state_ticket(), self.all_parameters_ticket()})
            self.DeclareVectorOutputPort(
                "state", self._ns * M, self._calc_state,
                prerequisites_of_calc={self.all_state_ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._nom, other._copies, converter=converter)

        @property
        def nominal(self) -> NominalParameters:
            return self._nom

        @property
        def copies(self) -> int:
            return self._copies

        def _arrays(self, context):
            M = self._copies
            X = context.get_continuous_state_vector().CopyToVector().reshape(self._ns, M)
            P = context.get_numeric_parameter(0).CopyToVector().reshape(self._np, M)
            return X, P

        def DoCalcTimeDerivatives(self, context, derivatives):
            X, P = self._arrays(context)
            U = self.get_input_port(0).Eval(context).reshape(self._nom.num_motors, self._copies)
            xdot = model_derivatives(self._nom, X, U, P)
            derivatives.get_mutable_vector().SetFromVector(np.asarray(xdot).ravel())

        def _calc_measurement(self, context, output):
            X, P = self._arrays(context)
            output.SetFromVector(np.asarray(model_measurements(self._nom, X, P)).ravel())

        def _calc_state(self, context, output):
            output.SetFromVector(context.get_continuous_state_vector().CopyToVector())

    return Impl


DiscrepancyModel = DiscrepancyModel_[None]
