"""Backstepping controllers for flexible joints (thesis ch. 15).

Three control laws, each a pure function generic in the scalar type (float,
AutoDiffXd; Expression where the spring law allows) and a TemplateSystem that
calls it:

* :func:`position_backstepping` / :class:`PositionBackstepping_`: position
  control of a single linear flexible joint (15.11)-(15.50), integrator chain
  on ``[q, qd, qdd, qddd]`` with gains ``k1..k4``.
* :func:`impedance_backstepping` / :class:`ImpedanceBackstepping_`: link-side
  impedance ``tau_des = -Kp,imp e - Kd,imp ed`` realised through the springs by
  two backstepping steps on the spring torques, for ``N`` motors acting on one
  joint through a constant coupling ``P`` (N x 1) and a spring law
  ``phi(x)``. ``N = 1`` with a linear spring is (15.51)-(15.70); ``N = 1``
  with a nonlinear spring is (15.71)-(15.81); ``N = 2`` with an equal torque
  share and opposite pretension offsets is the antagonistic joint
  (15.82)-(15.106).

Both laws expose the Lyapunov function of their design (output port
``lyapunov``), which is non-increasing along the nominal closed loop.

Derivation used by :func:`impedance_backstepping` (the thesis's steps written
for N tendons, with link damping ``b_q`` kept and reference derivatives
``r, r', r'', r''', r''''``)::

    tendon i:   x_i = r_m theta_i + P_i q + x0_i,   f_i = phi(x_i),   tau_i = -P_i f_i
    link:       m qdd = sum_i tau_i - b_q qd + tau_ext
    motor i:    B_i wd_i = u_i + tau_fric(w_i) - r_m f_i
    e = q - r,  alpha = -Kp e - Kd e' + m r'' + b_q r'              (15.54)
    alpha_i = o_i + w_i alpha,   z3_i = tau_i - alpha_i              (15.88), (15.90)
    beta_i = alpha_i' - K3 z3_i - e',   z4_i = tau_i' - beta_i       (15.57)
    u_i = (beta_i' - f0_i - z3_i - K4 z4_i) / g_i                    (15.63), (15.77)
    V = m e'^2/2 + Kp e^2/2 + sum z3_i^2/2 + sum z4_i^2/2            (15.64)
    V' = -(Kd + b_q) e'^2 - K3 sum z3_i^2 - K4 sum z4_i^2 <= 0

with ``tau_i'' = f0_i + g_i u_i``, ``g_i = -P_i phi'(x_i) r_m / B_i`` and
``f0_i = -P_i (phi''(x_i) x_i'^2 + phi'(x_i) (r_m (tau_fric - r_m f_i)/B_i + P_i qdd))``.
The control needs ``phi' > 0`` (strictly increasing spring: the condition
of section 15.4).
"""

from __future__ import annotations

import functools
import sys
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import is_float, smax
from awiwi_drake.components.motor import motor_friction_torque
from awiwi_drake.control.friction_observer import observer_rate
from awiwi_drake.parameters.backstepping import (
    AntagonisticBacksteppingGains,
    BacksteppingPlantParams,
    ImpedanceBacksteppingGains,
    PositionBacksteppingGains,
)
from awiwi_drake.parameters.rigs import FlexibleJointParams, JointRigParams

__all__ = [
    "REFERENCE_SIZE",
    "EXTERNAL_TORQUE_SOURCES",
    "REFERENCE_PORT",
    "JointModel",
    "position_backstepping",
    "position_feedback_coefficients",
    "impedance_backstepping",
    "PositionBackstepping_",
    "PositionBackstepping",
    "ImpedanceBackstepping_",
    "ImpedanceBackstepping",
    "plant_params",
    "joint_model",
    "position_controller",
    "impedance_controller",
]

#: Sources of the external torque used by the impedance design (see :class:`ImpedanceBackstepping_`).
EXTERNAL_TORQUE_SOURCES = ("observer", "input", "none")
#: Entries of a full reference ``[r, r', r'', r''', r'''']``.
REFERENCE_SIZE = 5
#: Name of the reference input (ctrl1 convention: ``<rig output>_reference``).
REFERENCE_PORT = "joint_angle_reference"


def _reference_port_size(reference_derivatives: int) -> int:
    if reference_derivatives not in (0, REFERENCE_SIZE - 1):
        raise ValueError(f"reference_derivatives = {reference_derivatives!r} must be 0 (steps: derivatives "
                         f"taken as zero) or {REFERENCE_SIZE - 1} (r and its first four derivatives)")
    return 1 + reference_derivatives


def _full_reference(r):
    """Pad a 1-entry reference with zero derivatives."""
    if len(r) == REFERENCE_SIZE:
        return r
    return [r[0]] + [0.0 * r[0]] * (REFERENCE_SIZE - 1)


@dataclass(frozen=True)
class JointModel:
    """Controller model of one joint driven by N motors through springs (constant coupling).

    Attributes
    ----------
    link_inertia : float
        m [kg m^2].
    link_damping : float
        b_q [Nm s/rad], viscous link damping.
    motor_inertia : tuple of float
        B_i [kg m^2] of each motor (output side).
    coupling : tuple of float
        P_i = dh_i/dq [m/rad] (tendons) or [-] (a torsion spring: P = -1, r_m = 1).
    motor_pulley_radius : float
        r_m [m] (1 for a torsion spring written on angles).
    spring : object
        Spring law with ``force(x)``, ``stiffness(x)``, ``stiffness_derivative(x)`` generic in the scalar type.
    elongation_offset : tuple of float
        x0_i [m]: spring elongation at q = 0, theta = 0.
    motor_damping : float
        Linear motor damping b_theta [Nm s/rad].
    motor_friction : callable, optional
        ``omega -> friction torque acting on the motors`` (array in, array out), e.g. (3.8).
    torque_share : tuple of float
        w_i, sum 1: share of the desired joint torque given to tendon i (15.88).
    torque_offset : tuple of float
        o_i [Nm], sum 0: pretension expressed as joint-torque contributions (15.88).
    min_stiffness : float
        Floor on phi' used in the division by g_i [N/m]: a slack spring (phi' = 0) cannot be
        controlled; the floor keeps the law finite, the rig's monitors report the slack.
    """

    link_inertia: float
    link_damping: float
    motor_inertia: tuple
    coupling: tuple
    motor_pulley_radius: float
    spring: Any
    elongation_offset: tuple
    motor_damping: float = 0.0
    motor_friction: Callable | None = None
    torque_share: tuple = (1.0,)
    torque_offset: tuple = (0.0,)
    min_stiffness: float = 1e-9
    name: str = field(default="joint", compare=False)

    def __post_init__(self):
        n = len(self.coupling)
        for fname in ("motor_inertia", "elongation_offset", "torque_share", "torque_offset"):
            v = getattr(self, fname)
            if len(v) != n:
                raise ValueError(f"JointModel.{fname} has {len(v)} entries; coupling has {n} (one per motor)")
            object.__setattr__(self, fname, tuple(float(x) for x in v))
        object.__setattr__(self, "coupling", tuple(float(x) for x in self.coupling))
        if self.link_inertia <= 0:
            raise ValueError(f"JointModel.link_inertia = {self.link_inertia} must be > 0 [kg m^2]")
        if any(b <= 0 for b in self.motor_inertia):
            raise ValueError(f"JointModel.motor_inertia = {self.motor_inertia} must be > 0 [kg m^2]")
        if any(p == 0 for p in self.coupling):
            raise ValueError(f"JointModel.coupling = {self.coupling}: every motor must act on the joint (P_i != 0)")
        if abs(sum(self.torque_share) - 1.0) > 1e-12:
            raise ValueError(f"JointModel.torque_share = {self.torque_share} must sum to 1")
        if abs(sum(self.torque_offset)) > 1e-9 * max(1.0, max(abs(o) for o in self.torque_offset)):
            raise ValueError(f"JointModel.torque_offset = {self.torque_offset} must sum to 0 (pretension)")
        for attr in ("force", "stiffness", "stiffness_derivative"):
            if not callable(getattr(self.spring, attr, None)):
                raise ValueError(f"JointModel.spring must provide {attr}(x); got {type(self.spring).__name__}")

    @property
    def num_motors(self) -> int:
        return len(self.coupling)

    @property
    def state_size(self) -> int:
        """Rig state ``[q, qd, theta_1..N, omega_1..N]``."""
        return 2 + 2 * self.num_motors


# ---------------------------------------------------------------------------
# Position control of the linear flexible joint (15.11)-(15.50)
# ---------------------------------------------------------------------------
def _shift(c: np.ndarray) -> np.ndarray:
    """Coefficients of d/dt (c . X) for the integrator chain X' = [X2, X3, X4, .]."""
    if c[-1] != 0.0:
        raise AssertionError("virtual control depends on the last chain state")
    return np.concatenate([[0.0], c[:-1]])


def position_feedback_coefficients(gains: PositionBacksteppingGains) -> dict:
    """Virtual-control coefficient vectors of the integrator chain (15.27)-(15.43).

    Returns ``{"c1", "c2", "c3", "dc3"}``: ``alpha_k = c_k . X`` with ``X = [e, e', e'', e''']``
    and ``dc3 . X = d alpha_3 / dt``. They depend on the gains only.
    """
    k1, k2, k3 = gains.k1, gains.k2, gains.k3
    e = np.eye(4)
    c1 = -k1 * e[0]                                        # (15.27)
    c2 = -e[0] + _shift(c1) - k2 * (e[1] - c1)             # (15.31)
    c3 = -(e[1] - c1) + _shift(c2) - k3 * (e[2] - c2)      # (15.37)
    return {"c1": c1, "c2": c2, "c3": c3, "dc3": _shift(c3)}


def position_backstepping(state, reference, plant: BacksteppingPlantParams, gains: PositionBacksteppingGains,
                          coefficients: dict | None = None):
    """Motor torque of the position backstepping controller (15.43)/(15.50) and its Lyapunov value.

    Parameters
    ----------
    state : array (4,)
        ``[q, qd, theta, thetad]`` (12.10).
    reference : array (5,)
        The link-angle reference and its first four derivatives (steps: zeros beyond r).
    plant : BacksteppingPlantParams
        Controller model (m, b, K, b_q, b_theta). The thesis neglects the damping in the design;
        here it is kept, so that the design model is the plant (set it to 0 to follow the thesis).
    gains : PositionBacksteppingGains
        k1..k4 > 0.

    Returns
    -------
    u, V : scalar
        Motor torque [Nm] and ``V4 = (x1^2 + z2^2 + z3^2 + z4^2)/2`` (15.44).
    """
    q, qd, th, thd = state[0], state[1], state[2], state[3]
    m, b, k = plant.link_inertia, plant.motor_inertia, plant.stiffness
    bq, bth = plant.link_damping, plant.motor_damping
    qdd = (k * (th - q) - bq * qd) / m
    qddd = (k * (thd - qd) - bq * qdd) / m
    thdd0 = (-bth * thd - k * (th - q)) / b
    q4_0 = (k * (thdd0 - qdd) - bq * qddd) / m               # q'''' without the input
    g4 = k / (m * b)                                          # (15.21)
    X = [q - reference[0], qd - reference[1], qdd - reference[2], qddd - reference[3]]
    f4 = q4_0 - reference[4]
    c = coefficients or position_feedback_coefficients(gains)
    dot = lambda v: sum(float(v[i]) * X[i] for i in range(4) if v[i] != 0.0)  # noqa: E731
    a1, a2, a3 = dot(c["c1"]), dot(c["c2"]), dot(c["c3"])
    z2, z3, z4 = X[1] - a1, X[2] - a2, X[3] - a3
    u = (-f4 - z3 + dot(c["dc3"]) - gains.k4 * z4) / g4     # (15.43)
    V = 0.5 * (X[0] * X[0] + z2 * z2 + z3 * z3 + z4 * z4)
    return u, V


# ---------------------------------------------------------------------------
# Impedance backstepping, N motors on one joint (15.51)-(15.106)
# ---------------------------------------------------------------------------
def impedance_backstepping(state, reference, model: JointModel, gains: ImpedanceBacksteppingGains,
                           external_torque=0.0, compensation=0.0):
    """Motor torques of the impedance backstepping controller and its Lyapunov value.

    Parameters
    ----------
    state : array (2 + 2N,)
        ``[q, qd, theta_1..N, omega_1..N]`` (the flexible-joint and joint-rig state orders).
    reference : array (5,)
        ``[r, r', r'', r''', r'''']`` of the link angle.
    model : JointModel
        Design model (spring law, coupling, inertias, damping, torque sharing).
    gains : ImpedanceBacksteppingGains
        Kp,imp, Kd,imp, K3, K4 > 0.
    external_torque : scalar
        Measured/estimated external joint torque (0 when unknown, as in the thesis's practice).
    compensation : scalar
        Torque added to the impedance torque (ch. 9: ``-d_hat`` cancels an estimated friction);
        treated as constant in the derivatives, like the external torque.

    Returns
    -------
    u : array (N,)
        Motor torques [Nm].
    V : scalar
        Lyapunov function (15.64)/(15.97).
    tau_des : scalar
        The impedance torque ``alpha`` (15.54) [Nm].
    """
    n = model.num_motors
    state = np.asarray(state, dtype=float if is_float(state) else object)
    q, qd = state[0], state[1]
    th, om = state[2:2 + n], state[2 + n:2 + 2 * n]
    P = np.array(model.coupling)
    B = np.array(model.motor_inertia)
    rm = model.motor_pulley_radius
    m, bq = model.link_inertia, model.link_damping
    x = rm * th + P * q + np.array(model.elongation_offset)
    xd = rm * om + P * qd
    f = model.spring.force(x)
    k = model.spring.stiffness(x)
    dk = model.spring.stiffness_derivative(x)
    tau_i = -P * f
    taud_i = -P * k * xd
    fric = -model.motor_damping * om
    if model.motor_friction is not None:
        fric = fric + model.motor_friction(om)
    qdd = (np.sum(tau_i) - bq * qd + external_torque) / m
    qddd = (np.sum(taud_i) - bq * qdd) / m
    xdd0 = rm * (fric - rm * f) / B + P * qdd
    f0 = -P * (dk * xd * xd + k * xdd0)
    g = -P * smax(k, model.min_stiffness) * rm / B
    r0, r1, r2, r3, r4 = (reference[i] for i in range(REFERENCE_SIZE))
    Kp, Kd, K3, K4 = gains.stiffness, gains.damping, gains.k3, gains.k4
    e, ed, edd, eddd = q - r0, qd - r1, qdd - r2, qddd - r3
    alpha = -Kp * e - Kd * ed + m * r2 + bq * r1 + compensation   # (15.54) + reference feedforward
    alpha_d = -Kp * ed - Kd * edd + m * r3 + bq * r2
    alpha_dd = -Kp * edd - Kd * eddd + m * r4 + bq * r3
    w = np.array(model.torque_share)
    z3 = tau_i - (np.array(model.torque_offset) + w * alpha)
    z3d = taud_i - w * alpha_d
    beta = w * alpha_d - K3 * z3 - ed                          # (15.57)
    beta_d = w * alpha_dd - K3 * z3d - edd
    z4 = taud_i - beta
    u = (beta_d - f0 - z3 - K4 * z4) / g                       # (15.63), (15.77)
    V = 0.5 * m * ed * ed + 0.5 * Kp * e * e + 0.5 * np.sum(z3 * z3) + 0.5 * np.sum(z4 * z4)
    return u, V, alpha


# ---------------------------------------------------------------------------
# Systems
# ---------------------------------------------------------------------------
@TemplateSystem.define("PositionBackstepping_", scope=sys.modules[__name__])
def PositionBackstepping_(T):
    class Impl(LeafSystem_[T]):
        """Position backstepping controller of a linear flexible joint (15.11)-(15.50).

        Input ports: ``state`` (4: ``[q, qd, theta, thetad]``), ``joint_angle_reference``
        (1, or 5 = reference and four derivatives with ``reference_derivatives=4``).
        Output ports: ``motor_torque`` (1) [Nm], ``lyapunov`` (1).
        """

        def _construct(self, plant=None, gains=None, reference_derivatives=0, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.plant = plant or BacksteppingPlantParams()
            self.gains = gains or PositionBacksteppingGains()
            self.reference_derivatives = reference_derivatives
            self._coeffs = position_feedback_coefficients(self.gains)
            self.DeclareVectorInputPort("state", 4)
            self.DeclareVectorInputPort(REFERENCE_PORT, _reference_port_size(reference_derivatives))
            _declare_outputs(self, (("motor_torque", 1), ("lyapunov", 1)), {self.all_input_ports_ticket()})
            self.set_name("backstepping_position")

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.plant, other.gains, other.reference_derivatives, converter=converter)

        def _eval(self, context):
            x = self.get_input_port(0).Eval(context)
            r = _full_reference(self.get_input_port(1).Eval(context))
            return position_backstepping(x, r, self.plant, self.gains, self._coeffs)

    return Impl


PositionBackstepping = PositionBackstepping_[None]


@TemplateSystem.define("ImpedanceBackstepping_", scope=sys.modules[__name__])
def ImpedanceBackstepping_(T):
    class Impl(LeafSystem_[T]):
        """Impedance backstepping controller of a joint driven by N motors (15.51)-(15.106).

        Input ports: ``state`` (2 + 2N: ``[q, qd, theta_1..N, omega_1..N]``), ``joint_angle_reference``
        (1, or 5 with ``reference_derivatives=4``) and, with ``external_torque="input"``,
        ``external_torque_measured`` (1) [Nm].
        Output ports: ``motor_torque`` (N) [Nm], ``lyapunov`` (1), ``joint_torque_desired`` (1) [Nm],
        ``external_torque_estimate`` (1) [Nm].

        The design (15.62) needs the external torque ``tau_ext``. ``external_torque`` chooses its source:
        ``"observer"`` (default): the observer (9.2) on the link momentum, gain
        ``gains.observer_gain`` (one continuous state ``w_hat``; its estimate stays 0 in undisturbed
        nominal motion, so the Lyapunov function still decreases); ``compensate=True`` also cancels the
        estimate in the impedance torque (the friction compensation of ch. 9); ``"input"``: a measured value on the
        port ``external_torque_measured``; ``"none"``: taken as 0 (the thesis's practice and the law
        (15.70)/(16.3); a constant load then drives the loop far from the impedance behaviour).
        """

        def _construct(self, model: JointModel, gains=None, reference_derivatives=0, external_torque="observer",
                       compensate=False, converter=None):
            LeafSystem_[T].__init__(self, converter)
            if not isinstance(model, JointModel):
                raise ValueError(f"ImpedanceBackstepping: model must be a JointModel, got {type(model).__name__}")
            if external_torque not in EXTERNAL_TORQUE_SOURCES:
                raise ValueError(f"ImpedanceBackstepping: external_torque = {external_torque!r} must be one of "
                                 f"{EXTERNAL_TORQUE_SOURCES}")
            self.model = model
            self.gains = gains or ImpedanceBacksteppingGains()
            self.reference_derivatives = reference_derivatives
            self.external_torque = external_torque
            self.compensate = bool(compensate)
            if self.compensate and external_torque == "none":
                raise ValueError("ImpedanceBackstepping: compensate=True needs an external torque source "
                                 "('observer' or 'input')")
            n = model.num_motors
            self.DeclareVectorInputPort("state", model.state_size)
            self.DeclareVectorInputPort(REFERENCE_PORT, _reference_port_size(reference_derivatives))
            if external_torque == "input":
                self.DeclareVectorInputPort("external_torque_measured", 1)
            tickets = {self.all_input_ports_ticket()}
            if external_torque == "observer":
                self.DeclareContinuousState(1)
                tickets.add(self.all_state_ticket())
            _declare_outputs(self, (("motor_torque", n), ("lyapunov", 1), ("joint_torque_desired", 1)), tickets)
            self.DeclareVectorOutputPort("external_torque_estimate", 1, self._calc_text,
                                         prerequisites_of_calc=tickets)
            self.set_name("backstepping_impedance" if n == 1 else "backstepping_antagonistic")

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.model, other.gains, other.reference_derivatives,
                            other.external_torque, other.compensate, converter=converter)

        def _observer(self, context, x):
            """(w_hat', tau_ext_hat) of the observer (9.2) on the link."""
            m = self.model
            w_hat = context.get_continuous_state_vector().GetAtIndex(0)
            n = m.num_motors
            P = np.array(m.coupling)
            xe = m.motor_pulley_radius * np.asarray(x[2:2 + n]) + P * x[0] + np.array(m.elongation_offset)
            known = np.sum(-P * m.spring.force(xe)) - m.link_damping * x[1]
            return observer_rate(w_hat, x[1], known, m.link_inertia, self.gains.observer_gain)

        def _text(self, context, x):
            if self.external_torque == "observer":
                return self._observer(context, x)[1]
            if self.external_torque == "input":
                return self.get_input_port(2).Eval(context)[0]
            return 0.0 * x[0]

        def _eval(self, context):
            x = self.get_input_port(0).Eval(context)
            r = _full_reference(self.get_input_port(1).Eval(context))
            d = self._text(context, x)
            return impedance_backstepping(x, r, self.model, self.gains, d, -d if self.compensate else 0.0 * d)

        def _calc_text(self, context, output):
            output.SetAtIndex(0, self._text(context, self.get_input_port(0).Eval(context)))

        def DoCalcTimeDerivatives(self, context, derivatives):
            if self.external_torque == "observer":
                x = self.get_input_port(0).Eval(context)
                derivatives.get_mutable_vector().SetAtIndex(0, self._observer(context, x)[0])

    return Impl


ImpedanceBackstepping = ImpedanceBackstepping_[None]


def _declare_outputs(system, outputs, tickets) -> None:
    """Output ports ``(name, size)`` of ``system``, the i-th the i-th value of ``system._eval(context)``."""
    for i, (name, size) in enumerate(outputs):
        system.DeclareVectorOutputPort(name, size, lambda context, output, i=i: output.SetFromVector(
            np.reshape(system._eval(context)[i], -1)), prerequisites_of_calc=tickets)


# ---------------------------------------------------------------------------
# controllers for the rigs (design model from the rig's parameters)
def plant_params(rig) -> BacksteppingPlantParams:
    """The design model of the position controller from a linear ``flexible_joint_rig``."""
    p = rig.params
    if not isinstance(p, FlexibleJointParams) or rig.spring_kind != "linear":
        raise ValueError(f"plant_params: the position controller (15.11)-(15.50) needs a linear flexible_joint_rig, "
                         f"got {rig.name} ({rig.spring_kind})")
    return BacksteppingPlantParams(link_inertia=p.link_inertia, motor_inertia=p.motor_inertia,
                                   motor_damping=p.motor_damping, link_damping=p.link_damping, stiffness=p.stiffness)


def joint_model(rig, *, spring=None, pretension: float | None = None, damping: bool = True) -> JointModel:
    """The controller design model of a rig (single flexible joint or antagonistic joint rig).

    Parameters
    ----------
    rig : Rig
        ``flexible_joint_rig`` (N = 1, torsion spring ``tau = phi(theta - q)``) or ``joint_rig``
        (N = 2, tendons ``x_i = r_m theta_i + P_i q``, P = [-r_q, r_q], equal torque share, pretension).
    spring : spring law, optional
        Design spring law (default: the rig's own law: the nominal design). Pass
        ``LinearSpring(k, tension_only=False)`` for the "linear controller" of section 15.4.
    pretension : float, optional
        Tendon pretension [N] of the joint rig (default: the rig's).
    damping : bool
        Keep link/motor damping and motor friction in the design model (the nominal design;
        the thesis neglects them: ``False``).
    """
    p = rig.params
    law = rig.spring if spring is None else spring
    if isinstance(p, FlexibleJointParams):
        return JointModel(link_inertia=p.link_inertia, link_damping=p.link_damping if damping else 0.0,
                          motor_inertia=(p.motor_inertia,), coupling=(-1.0,), motor_pulley_radius=1.0, spring=law,
                          elongation_offset=(0.0,), motor_damping=p.motor_damping if damping else 0.0,
                          name=rig.name)
    if isinstance(p, JointRigParams):
        rq = p.link_pulley_radius
        f0 = p.pretension if pretension is None else float(pretension)
        if not f0 > 0:
            raise ValueError(f"joint_model: pretension = {f0} N must be > 0 (tendons must stay taut)")
        friction = functools.partial(motor_friction_torque, p=p.motor) if damping else None
        return JointModel(link_inertia=p.link_inertia, link_damping=p.link_damping if damping else 0.0,
                          motor_inertia=(p.motor.inertia,) * 2, coupling=(-rq, rq),
                          motor_pulley_radius=p.motor.pulley_radius, spring=law, elongation_offset=(0.0, 0.0),
                          motor_friction=friction, torque_share=(0.5, 0.5), torque_offset=(rq * f0, -rq * f0),
                          name=rig.name)
    raise ValueError(f"joint_model: no backstepping design model for rig {rig.name!r}")


def position_controller(rig, gains: PositionBacksteppingGains | None = None, **kw):
    """:class:`PositionBackstepping` for a linear flexible-joint rig."""
    return PositionBackstepping(plant_params(rig), gains or PositionBacksteppingGains(), **kw)


def impedance_controller(rig, gains=None, *, spring=None, pretension=None, damping=True, **kw):
    """:class:`ImpedanceBackstepping` for a flexible-joint rig (N = 1) or the joint rig (N = 2).

    ``gains`` may be :class:`AntagonisticBacksteppingGains` (its pretension is used) or
    :class:`ImpedanceBacksteppingGains`; ``kw`` go to the controller (``external_torque``,
    ``reference_derivatives``, ``compensate``).
    """
    if gains is None:
        gains = AntagonisticBacksteppingGains() if isinstance(rig.params, JointRigParams) else \
            ImpedanceBacksteppingGains()
    if isinstance(gains, AntagonisticBacksteppingGains):
        pretension = gains.pretension if pretension is None else pretension
        gains = ImpedanceBacksteppingGains(stiffness=gains.stiffness, damping=gains.damping, k3=gains.k3,
                                           k4=gains.k4)
    if pretension is None and isinstance(rig.params, JointRigParams):
        pretension = rig.params.pretension
    model = joint_model(rig, spring=spring, pretension=pretension, damping=damping)
    return ImpedanceBackstepping(model, gains, **kw)
