"""Per-joint design of the chain's joint-level stage for every finger and the hand.

The thesis designs its joint laws (impedance ch. 11, pole placement ch. 12, LQR ch. 13, SDRE ch. 14) on one
joint and "applies them systematically to the 19 joints of the hand".  Here each independent DoF ``j`` gets its
own *reduced model* (:func:`joint_subsystem`, :func:`reduced_joint_models`): a one-DoF link of inertia
``M_jj = (S^T M(q_op) S)_jj`` with its bearing damping, driven by its own tendons (column ``j`` of ``P S``, each
with its own spring law, :func:`~awiwi_drake.control.chain.rig_springs`) and motors (friction linearised in
motion, :func:`design_motor`), closed by the chain's own force stage
(:class:`~awiwi_drake.control.chain.TendonForceStage`) with ``tau_ref`` as input.  Drake ``Linearize`` of that
loop, restricted to the measurable ``z = [q, qdot, tau, tau_dot]`` (``T = [C_q; C_q A; C_tau; C_tau A]``,
``F = T A T^+``, ``G = T B``), is the design model; :attr:`JointReducedModel.invariance_residual` reports
``|T A - F T| / |T A|`` (0 when every tendon's force loop has the same dynamics).

Designs on ``(F, G)`` (gains of :class:`~awiwi_drake.control.joint_stage.JointStateFeedbackLaw`, reference maps
:func:`~awiwi_drake.control.linear.reference_maps`; a sampled chain designs on :func:`sampled_model`, its one
period of delay included):

* ``cascaded`` (the impedance (11.4), the default): ``Kp`` = :func:`cascade_stiffness` (half the (11.16) bound
  behind a second-order force loop), ``Kd >= 0`` giving the slowest mode the damping ratio ``damping_ratio``;
* ``pd``: PD on the estimated angle with ``(Kp, Kd)`` placing one pair exactly at ``position_bandwidth``, damped
  to ``damping_ratio`` (it counts the torque chain and the joint's own tendon stiffness, which ``M_jj w^2`` does
  not); refused with one line when that needs ``Kd < 0`` or leaves another pole unstable;
* ``two-time-scale``: the same impedance over the tendon level of (11.3), a motor-position loop per tendon
  (:class:`~awiwi_drake.control.impedance.MotorPositionForceLaw`);
* ``pole-placement``: the double oscillator (12.13) by coefficient identification, ``omega1 = position_bandwidth``
  and ``omega2`` the modulus of the joint's own open-loop pair, damped to the largest ``xi2 <= damping_ratio``
  that keeps the motor-held damping ``Kd - K_taud K_jj`` (:func:`motor_held_damping`) non-negative, and refused
  when the torque loop gain (:func:`torque_loop_gain`) is not positive.  Both rules are derived from the whole
  finger's fast PIP/DIP mode, which the per-joint models cannot hold (:func:`sampled_loop_poles`; the
  measurements and the rejected alternatives: docs/REPRODUCTIONS.md, the guide-friction row of ch. 11-15);
* ``lqr``: Drake ``LinearQuadraticRegulator`` on ``(F, G)`` with Bryson weights
  (:class:`~awiwi_drake.parameters.joint_design.JointDesignParams`);
* ``sdre``: the LQR re-solved on the pointwise-linear models of ch. 14 tabulated in the joint torque, gains
  interpolated at the measured torque.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.controllers import DiscreteTimeLinearQuadraticRegulator, LinearQuadraticRegulator

from awiwi_drake.analysis.linear import LinearizationResult, linearize
from awiwi_drake.control.base import check_rate, closed_loop
from awiwi_drake.control.chain import (TendonChainController, TendonForceStage, chain_design_point,
                                      guide_presliding_stiffness, rig_springs)
from awiwi_drake.control.design import ChainDesign
from awiwi_drake.control.joint_stage import (JointGainScheduleLaw, JointStateFeedbackLaw, joint_damping,
                                             joint_inertia)
from awiwi_drake.control.linear import reference_maps
from awiwi_drake.control.pole_placement import double_oscillator_polynomial, place_by_identification
from awiwi_drake.hand.coupling import LinearFingerCoupling
from awiwi_drake.parameters.components import HysteresisParams, MotorParams
from awiwi_drake.parameters.hand_control import FrictionObserverParams, HandChainParams, StiffnessCorrectionParams
from awiwi_drake.parameters.joint_design import JointDesignParams
from awiwi_drake.rigs.base import OperatingPoint, Rig, add_revolute_link
from awiwi_drake.rigs.rigs import _link_rig

__all__ = ["JointReducedModel", "cascade_stiffness", "joint_subsystem", "force_loop", "design_motor", "PoleCheck",
           "check_design_poles", "reduced_joint_models", "design_joint_gains", "torque_loop_gain", "motor_held_damping",
           "sampled_model", "JointDesign", "JointObserverDesign", "design_joint_stage", "joint_stage_controller",
           "DESIGNS", "SampledLoopPoles", "PoleMatch", "sampled_loop_poles"]

DESIGNS = ("cascaded", "pd", "two-time-scale", "pole-placement", "lqr", "sdre")
_TENDON_LAW = {"two-time-scale": "motor-position"}     # the chain's tendon level per design (else params.tendon_law)


def _tendon_law(design: str, chain: HandChainParams) -> str:
    """The chain's tendon level for ``design``: its own (two-time-scale's motor-position loop (11.3)), else
    ``chain.tendon_law``; a design with its own level refuses another (one line naming the option)."""
    own = _TENDON_LAW.get(design)
    if own is not None and chain.tendon_law != "force":
        raise ValueError(f"tendon_law = {chain.tendon_law!r}: the {design} chain's tendon level is its own "
                         f"{own} loop (11.3); tendon_law applies to the force-controlled chains")
    return own or chain.tendon_law
_TORQUE_RATE = {"lqr": "motor", "sdre": "motor"}       # the stage's 4th coordinate per design (else "joint", joint_stage)
_TENDON_TOL = 1e-12


@dataclass
class JointReducedModel:
    """One DoF's reduced model ``z' = F z + G tau_ref`` on ``z = [q - q_op, qdot, tau - tau_op, tau_dot]``
    (``torque_rate="motor"``: ``sigma = tau_dot + K_jj qdot`` in place of ``tau_dot``, :mod:`.joint_stage`)."""

    name: str
    dof: int
    A: np.ndarray                     # F (4 x 4)
    B: np.ndarray                     # G (4 x 1)
    inertia: float                    # M_jj [kg m^2]
    damping: float                    # b_jj [Nm s/rad]
    stiffness: float                  # K_jj = P_j^T K_t P_j [Nm/rad] (5.12), the joint's own tendons
    tendons: tuple                    # indices of the tendons acting on the DoF
    invariance_residual: float        # |T A - F T| / |T A| (0: the restriction is exact)
    linearization: LinearizationResult
    torque_rate: str = "joint"        # the fourth coordinate: tau_dot ("joint") or sigma ("motor")
    link_torque_map: np.ndarray | None = None   # E (4 x 1): z' = F z + G tau_ref + E d, d a link-side torque [Nm]

    @property
    def poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.A)


def _dof_names(rig, S) -> list[str]:
    names = list(rig.joint_names)
    return [names[int(np.flatnonzero(S[:, j])[0])] for j in range(S.shape[1])]


def design_motor(motor: MotorParams) -> MotorParams:
    """The motor of the design model: (3.8) linearised *in motion* (slope: the viscous ``gamma3``), no ripple.
    Chosen: the slope at rest (5.6 Nm s/rad) is a joint damping that vanishes once the motors move faster than
    ``1/gamma1``; a design counting on it rings (docs/REPRODUCTIONS.md, "cascaded impedance damping").  The ripple
    is a disturbance of the motor angle, not a property of the joint."""
    viscous = motor.viscous_friction if motor.friction else 0.0
    return motor.replace(friction=False, ripple=False, damping=motor.damping + viscous)


def joint_subsystem(rig: Any, dof: int, *, point: ChainDesign | None = None, params: HandChainParams | None = None,
                    torque: float | None = None):
    """The per-DoF subsystem of the module docstring: a one-link rig with the DoF's tendons.

    Returns ``(sub, op, point)``: the :class:`~awiwi_drake.rigs.base.Rig` (``sub.plant`` its link alone), its
    operating point and its :func:`~awiwi_drake.control.chain.chain_design_point` (close it with :func:`force_loop`).
    ``torque``: the DoF torque (default ``tau_op``; forces ``f_op + W_j (torque - tau_op)``, held by an external
    torque ``-torque``).  The motors are :func:`design_motor`'s.
    """
    p = params or HandChainParams()
    point = point or chain_design_point(rig, params=p)
    S, PS = point.selection, point.coupling_matrix
    k = S.shape[1]
    if not 0 <= dof < k:
        raise ValueError(f"joint_subsystem: dof = {dof} is not an independent DoF of {rig.name!r} (0..{k - 1})")
    col = PS[:, dof]
    active = np.flatnonzero(np.abs(col) > _TENDON_TOL * np.abs(col).max())
    P_j = col[active][:, None]
    name = _dof_names(rig, S)[dof]
    coupling = LinearFingerCoupling(P_j, joint_names=[name], tendon_names=[rig.tendon_names[i] for i in active])
    M = float(joint_inertia(rig, point.joint_angle)[dof])
    b = float(joint_damping(rig)[dof, dof])
    design_params = rig.params.replace(motor=design_motor(rig.params.motor))
    springs = rig_springs(rig).subset(active)          # each of the DoF's tendons with its own law
    diagram, drive, names, _ = _link_rig(name=f"{rig.name}-{name}", motor=design_params.motor, spring=springs,
                                         coupling=coupling, inertia=M, damping=b, hysteresis=HysteresisParams())
    plant = MultibodyPlant(0.0)                        # the link alone (joint_inertia, joint_damping read it)
    add_revolute_link(plant, name="joint", inertia=M, damping=b)
    plant.Finalize()
    tau0 = -float(P_j[:, 0] @ point.tendon_force[active])
    tau = tau0 if torque is None else float(torque)
    W = -np.linalg.pinv(P_j.T)
    f = point.tendon_force[active] + W[:, 0] * (tau - tau0)
    if np.any(f <= 0):
        raise ValueError(f"joint_subsystem: joint torque {tau} Nm slackens a tendon of {name} (forces {f} N)")
    r_m = design_params.motor.pulley_radius
    x = springs.inverse_force(f)
    theta = x / r_m                                    # h(0) = 0, no offsets: x = r_m theta at q = 0
    from awiwi_drake.components.motor import motor_ripple_torque
    u = r_m * f - np.asarray(motor_ripple_torque(theta, design_params.motor), dtype=float)
    kt = springs.stiffness(x)
    op = OperatingPoint(np.concatenate([[0.0, 0.0], theta, np.zeros(active.size)]), u, np.array([-tau]),
                        joint_angle=np.zeros(1), tendon_force=f, elongation=x, tendon_stiffness=kt,
                        joint_stiffness=float(P_j[:, 0] ** 2 @ kt))
    sub = Rig(f"{rig.name}-{name}", diagram, design_params, names, lambda: op, plant, springs,
              drive=drive, coupling=coupling, tension_only=True)
    sub_point = ChainDesign(np.eye(1), P_j, f, np.array([tau]), op=op, joint_angle=np.zeros(1),
                            mechanical_stiffness=[np.eye(1)])
    return sub, op, sub_point


def force_loop(sub: Rig, point: ChainDesign, params: HandChainParams | None = None, tendon_law: str | None = None):
    """A subsystem of :func:`joint_subsystem` closed by the chain's force stage (sharing, continuous):
    the :class:`~awiwi_drake.control.base.ClosedLoop` with input ``joint_torque_reference``, and a context
    at its operating point."""
    stage = TendonForceStage(sub.coupling, sub.spring, sub.params, params or HandChainParams(), point=point,
                             distribution="sharing", tendon_law=tendon_law)
    loop = closed_loop(sub, stage, rate_hz=None, estimator=None)
    op = point.op
    return loop, loop.create_context(op, references={"joint_torque_reference": point.torque_offset})


def _coordinates(lin: LinearizationResult, stiffness: float = 0.0) -> np.ndarray:
    """``T``: the loop's state to ``z = [q, qdot, tau, tau_dot + stiffness qdot]`` (:func:`_restrict`)."""
    A, Cq, Ct = lin.A, lin.output("joint_angle").C, lin.output("joint_torque").C
    return np.vstack([Cq, Cq @ A, Ct, Ct @ A + stiffness * (Cq @ A)])


def _restrict(lin: LinearizationResult, stiffness: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """``(F, G, residual)`` on ``[q, qdot, tau, tau_dot + stiffness qdot]`` (``stiffness`` 0: ``tau_dot``;
    ``K_jj``: the motors' rate ``sigma``)."""
    A, B = lin.A, lin.B
    T = _coordinates(lin, stiffness)
    scale = np.abs(T @ B).max() if np.abs(T @ B).max() > 0 else 1.0
    for row, nm in ((T[0], "q"), (T[1], "qdot"), (T[2], "tau")):
        if np.abs(row @ B).max() > 1e-9 * scale:          # only tau_dot' may see the input directly
            raise ValueError(f"reduced joint model: {nm} depends on tau_ref directly (|{nm}' B| > 0)")
    TA = T @ A
    F = TA @ np.linalg.pinv(T)
    res = float(np.linalg.norm(TA - F @ T) / max(np.linalg.norm(TA), 1e-300))
    return F, T @ B, res


def reduced_joint_models(rig: Any, *, point: ChainDesign | None = None, params: HandChainParams | None = None,
                         tendon_law: str | None = None, torque_rate: str = "joint") -> list[JointReducedModel]:
    """One :class:`JointReducedModel` per independent DoF of a finger or the hand (module docstring);
    ``tendon_law``: the chain's tendon level (:class:`~awiwi_drake.control.chain.TendonForceStage`);
    ``torque_rate``: the fourth coordinate, ``"joint"`` (``tau_dot``) or ``"motor"`` (``sigma``)."""
    if torque_rate not in ("joint", "motor"):
        raise ValueError(f"reduced_joint_models: torque_rate = {torque_rate!r}; use 'joint' or 'motor'")
    p = params or HandChainParams()
    point = point or chain_design_point(rig, params=p)
    S = point.selection
    names = _dof_names(rig, S)
    M = joint_inertia(rig, point.joint_angle)
    b = np.diag(joint_damping(rig))
    kt = np.asarray(point.op.tendon_stiffness, dtype=float)
    models = []
    for j in range(S.shape[1]):
        col = point.coupling_matrix[:, j]
        models.append(_reduced_model(rig, j, point, p, tendon_law, torque_rate, None, names[j], float(M[j]),
                                     float(b[j]), float(col ** 2 @ kt), tuple(int(i) for i in np.flatnonzero(col))))
    return models


def _reduced_model(rig, j, point, chain, tendon_law, torque_rate, torque, name, inertia, damping, stiffness,
                   tendons, link_torque: bool = True) -> JointReducedModel:
    """DoF ``j``'s :class:`JointReducedModel`: :func:`joint_subsystem` (at the DoF torque ``torque``) closed by
    :func:`force_loop`, linearised by Drake and restricted to ``z`` (:func:`_restrict`); ``link_torque``: also its
    :attr:`~JointReducedModel.link_torque_map` (the loop linearised from its ``external_torque`` input)."""
    sub, _, sub_point = joint_subsystem(rig, j, point=point, params=chain, torque=torque)
    loop, ctx = force_loop(sub, sub_point, chain, tendon_law)
    lin = linearize(loop.diagram, context=ctx, input="joint_torque_reference",
                    outputs=("joint_angle", "joint_torque"), equilibrium_tolerance=None)
    rate = sub_point.op.joint_stiffness if torque_rate == "motor" else 0.0
    F, G, res = _restrict(lin, rate)
    E = None
    if link_torque:     # a link-side torque (the guides' friction, a load): the loop from its external_torque input
        ext = linearize(loop.diagram, context=ctx, input="external_torque", outputs=("joint_angle", "joint_torque"),
                        equilibrium_tolerance=None)
        E = _coordinates(lin, rate) @ ext.B
    stiffness = float(sub_point.op.joint_stiffness) if stiffness is None else stiffness
    return JointReducedModel(name, j, F, G, inertia, damping, stiffness, tendons, res, lin, torque_rate, E)


def _impedance_gains(model: JointReducedModel, kp: float, zeta: float) -> np.ndarray:
    """``[Kp, Kd, 0, 0]`` with ``Kp`` given and ``Kd >= 0`` giving the slowest closed-loop mode of the reduced
    model (friction in motion) the damping ratio ``zeta`` (the smallest such ``Kd`` on ``[0, 20 sqrt(Kp M_jj)]``;
    ``Kd = 0`` when the drive alone damps it that much).  At rest the reflected motor friction adds damping."""
    from scipy.optimize import brentq
    F, G = model.A, model.B

    def excess(kd):                                    # the slowest mode's damping ratio (1: a real pole) - zeta
        lam = np.linalg.eigvals(F - G @ np.array([[kp, kd, 0.0, 0.0]]))
        s = lam[np.argmin(np.abs(lam))]
        return (float(-s.real / abs(s)) if abs(s) > 0 else 1.0) - zeta

    grid = np.linspace(0.0, 20.0 * np.sqrt(kp * model.inertia), 81)
    ex = np.array([excess(k) for k in grid])
    if ex[0] >= 0:
        return np.array([kp, 0.0, 0.0, 0.0])
    i = int(np.argmax(ex >= 0))
    if ex[i] < 0:
        raise ValueError(f"cascaded design of {model.name}: no Kd <= {grid[-1]:.3g} gives the slowest mode a damping "
                         f"ratio {zeta} (best {ex.max() + zeta:.3f})")
    return np.array([kp, brentq(excess, grid[i - 1], grid[i], xtol=1e-12 * grid[-1]), 0.0, 0.0])


def sampled_model(F: np.ndarray, G: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray]:
    """The reduced model sampled with a zero-order hold (Drake's ``DiscreteTimeApproximation``) at ``period``
    and the sampled chain's one period of delay (the distribution answers the previous sample's request): state
    ``[z_k, tau_ref,k-1]``, ``x_k+1 = Phi x_k + Gamma tau_ref,k``."""
    from pydrake.systems.analysis import DiscreteTimeApproximation
    from pydrake.systems.primitives import LinearSystem
    n = F.shape[0]
    zoh = DiscreteTimeApproximation(LinearSystem(F, G, np.zeros((0, n)), np.zeros((0, G.shape[1]))), period)
    Phi = np.zeros((n + 1, n + 1))
    Phi[:n, :n], Phi[:n, n:] = zoh.A(), zoh.B()
    Gamma = np.zeros((n + 1, 1))
    Gamma[n, 0] = 1.0
    return Phi, Gamma


def _closed_loop_matrix(model: JointReducedModel, K, period: float | None) -> tuple[np.ndarray, np.ndarray]:
    """``(A_cl, Gamma)``: a DoF's designed loop ``F - G K`` (``period`` None) or the sampled chain's
    ``Phi - Gamma K`` (:func:`sampled_model`), with its input matrix."""
    if period is None:
        return model.A - model.B @ np.asarray(K)[None, :4], model.B
    Phi, Gamma = sampled_model(model.A, model.B, period)
    return Phi - Gamma @ np.asarray(K)[None, :], Gamma


def _placed_pd_gains(model: JointReducedModel, p: JointDesignParams, period: float | None) -> np.ndarray:
    """``[Kp, Kd, 0, 0, 0]`` placing one closed-loop pair at ``s*`` (``pd`` in the module docstring)."""
    s = p.position_bandwidth * (-p.damping_ratio + 1j * np.sqrt(max(0.0, 1.0 - p.damping_ratio ** 2)))
    if period is None:
        A, B, pole = model.A, model.B, s
    else:
        (A, B), pole = sampled_model(model.A, model.B, period), np.exp(period * s)
    R = np.linalg.solve(pole * np.eye(A.shape[0]) - A, B).ravel()    # det(pole I - A + B K) = 0: 1 + K R = 0
    M = np.array([[R[0].real, R[1].real], [R[0].imag, R[1].imag]])
    kp, kd = np.linalg.solve(M, [-1.0, 0.0])
    K = np.zeros(A.shape[0] if period is not None else 5)
    K[:2] = kp, kd
    cl = np.linalg.eigvals(A - B @ K[None, :A.shape[0]])
    stable = np.all(np.abs(cl) < 1.0) if period is not None else np.all(cl.real < 0)
    if not (kp > 0 and kd >= 0 and stable):
        raise ValueError(f"pd design of {model.name}: placing a pair at {p.position_bandwidth} rad/s, damping "
                         f"{p.damping_ratio} needs Kp = {kp:.4g}, Kd = {kd:.4g} and leaves poles "
                         f"[{', '.join(f'{z:.4g}' for z in cl)}] "
                         "(needs Kp > 0, Kd >= 0, the rest stable): change JointDesignParams.position_bandwidth")
    return K


def _lqr_weights(p: JointDesignParams, model: JointReducedModel):
    """Bryson's weights on ``z``; on the motors' rate ``sigma = tau_dot + K_jj qdot`` its bound is the sum of the
    torque-rate and the velocity bounds' (a motion at ``lqr_velocity`` under a steady torque needs
    ``sigma = K_jj qdot``): a stiff joint (thumb base, K_jj = 47 Nm/rad) is not held to a crawl by it."""
    rate = p.lqr_torque_rate + (model.stiffness * p.lqr_velocity if model.torque_rate == "motor" else 0.0)
    Q = np.diag(1.0 / np.array([p.lqr_angle_error, p.lqr_velocity, p.lqr_torque_error, rate]) ** 2)
    return Q, np.array([[1.0 / p.lqr_input ** 2]])


def _pole_placement_gains(model: JointReducedModel, p: JointDesignParams, period: float | None) -> np.ndarray:
    """(12.13) on one DoF (``pole-placement`` in the module docstring); the largest admissible ``xi2`` in
    ``[pair_damping_min, damping_ratio]`` by bisection (the motor-held damping falls as ``xi2`` rises)."""
    F, G = model.A, model.B
    lam = np.linalg.eigvals(F)
    pair = abs(lam[np.argmax(np.abs(lam.imag))])        # the link on its tendons through the force loop

    def gains(xi2):
        target = double_oscillator_polynomial(p.position_bandwidth, p.damping_ratio, pair, xi2)
        if period is None:
            return np.append(place_by_identification(F, G, target).ravel(), 0.0)
        Phi, Gamma = sampled_model(F, G, period)      # poles mapped z = exp(h s), the delay's at 0
        zs = np.concatenate([np.exp(period * np.roots(target)), [0.0]])
        return place_by_identification(Phi, Gamma, np.real(np.poly(zs))).ravel()

    def excess(xi2):
        return motor_held_damping(gains(xi2), model)

    low = p.pair_damping_min
    if excess(p.damping_ratio) >= 0.0:
        K = gains(p.damping_ratio)
    elif excess(low) < 0.0:
        raise ValueError(f"pole-placement design of {model.name}: no damping xi2 in [{low}, {p.damping_ratio}] of the "
                         f"joint's pair ({pair:.4g} rad/s) keeps the motor-held damping Kd - K_taud K_jj >= 0; change "
                         f"JointDesignParams.pair_damping_min or position_bandwidth")
    else:
        from scipy.optimize import brentq
        K = gains(brentq(excess, low, p.damping_ratio, xtol=1e-12))
    if torque_loop_gain(K) <= 0.0:
        raise ValueError(f"pole-placement design of {model.name}: torque loop gain 1 + K_tau + K_prev = "
                         f"{torque_loop_gain(K):.4g} <= 0 (a positive torque feedback: no positive static stiffness); "
                         f"change JointDesignParams.position_bandwidth")
    return K


def motor_held_damping(K, model: JointReducedModel) -> float:
    """The link damping [Nm s/rad] a gain row ``K`` (5,) of one DoF feeds back while the motors are held:
    ``Kd - K_taud K_jj`` on ``tau_dot`` (``omega = 0``: ``tau_dot = -K_jj qdot``, ``K_jj`` (5.12)), ``Kd`` on
    ``sigma``.  Negative, it is an active negative damping of any mode where the link moves against its tendons
    faster than the motors follow."""
    K = np.asarray(K, dtype=float)
    return float(K[1] - (K[3] * model.stiffness if model.torque_rate == "joint" else 0.0))


def torque_loop_gain(K) -> float:
    """``1 + K_tau + K_prev`` of a gain row ``K`` (5,): the static gain of the torque loop the stage closes around
    the force loop with the link held (:attr:`JointDesign.static_stiffness` is ``Kp`` over it).  Negative, the
    measured torque is fed back positively and any link-side stiffness meets a negative joint stiffness."""
    K = np.asarray(K, dtype=float)
    return float(1.0 + K[2] + (K[4] if K.size > 4 else 0.0))


def cascade_stiffness(inertia: float, chain: HandChainParams) -> float:
    """The cascaded stage's impedance ``Kp`` of a DoF of inertia ``M_jj``: ``min(joint_stiffness, cascade_margin
    M_jj force_bandwidth^2 / 4)``, ``M w^2 / 4`` the stability bound of (11.16) behind a second-order force loop
    (:class:`~awiwi_drake.parameters.hand_control.HandChainParams` ``cascade_margin``)."""
    return min(chain.joint_stiffness, chain.cascade_margin * inertia * chain.force_bandwidth ** 2 / 4.0)


def design_joint_gains(model: JointReducedModel, design: str, *, params: JointDesignParams | None = None,
                       chain: HandChainParams | None = None, period: float | None = None) -> np.ndarray:
    """The gain row ``K_j`` (5,) of one DoF for ``design`` in :data:`DESIGNS` (module docstring): on ``z``
    and, for a sampled chain (``period``), on the previous request (:func:`sampled_model`)."""
    p = params or JointDesignParams()
    c = chain or HandChainParams()
    F, G = model.A, model.B
    if design in ("cascaded", "two-time-scale"):
        K = _impedance_gains(model, cascade_stiffness(model.inertia, c), p.damping_ratio)
        return np.append(K, 0.0)
    if design == "pd":
        return _placed_pd_gains(model, p, period)
    if design == "pole-placement":
        return _pole_placement_gains(model, p, period)
    if design in ("lqr", "sdre"):
        Q, R = _lqr_weights(p, model)
        if period is None:
            K, _ = LinearQuadraticRegulator(F, G, Q, R)
            return np.append(np.asarray(K).ravel(), 0.0)
        # chosen: the continuous weights by the rectangle rule (not Van Loan's exact sampled cost), so the tuning
        # parameters stay the continuous design's and the delay state is not penalised
        Phi, Gamma = sampled_model(F, G, period)
        Qd = np.zeros((5, 5))
        Qd[:4, :4] = Q
        K, _ = DiscreteTimeLinearQuadraticRegulator(Phi, Gamma, Qd, R)
        return np.asarray(K).ravel()
    raise ValueError(f"unknown joint design {design!r}; use one of {', '.join(DESIGNS)}")


@dataclass
class JointObserverDesign:
    """The chain's (9.2) observer as a design sees it, per DoF (k each): its ``gain`` ``L`` [1/s], ``scale``
    ``kappa`` [-] (:class:`~awiwi_drake.control.joint_stage.JointFrictionObserver_`) and the guides'
    ``presliding_stiffness`` ``K_g`` [Nm/rad] (:func:`~awiwi_drake.control.chain.guide_presliding_stiffness`)."""

    gain: np.ndarray
    scale: np.ndarray
    presliding_stiffness: np.ndarray


@dataclass
class JointDesign:
    """A designed joint stage: the law for all DoF, its reduced models and the designed closed-loop poles
    (``period`` None: continuous, ``eig(F - G K)``; else the sampled chain's z-plane ``eig(Phi - Gamma K)``)."""

    design: str
    law: JointStateFeedbackLaw
    models: list
    gains: np.ndarray                 # (k, 5)
    design_poles: list                # per DoF
    period: float | None = None
    observer: JointObserverDesign | None = None       # the chain's (9.2) observer, None without

    @property
    def static_stiffness(self) -> np.ndarray:
        """The joint stiffness the designed loop shows to a constant load, per DoF [Nm/rad]:
        ``Kp / (1 + K_tau + K_prev)`` (at rest ``tau = tau_ref = tau_ref(t - h)``; the springs do not appear: the
        series law (8.1) of a motor-side impedance is not the chain's)."""
        K = self.gains
        return K[:, 0] / (1.0 + K[:, 2] + K[:, 4])

    def loop(self, dof: int) -> tuple[np.ndarray, np.ndarray]:
        """``(A, b)``: DoF ``dof``'s designed closed loop from its reference step ``dr``, ``x' = A x + b dr``
        (continuous) or ``x_k+1 = A x_k + b dr`` (sampled), ``q - q_op = x[0]``.

        State ``z`` (the stage's loop ``F - G K``), the sampled chain's previous request (:func:`sampled_model`)
        and, with :attr:`observer`, the (9.2) observer's ``w_hat`` (its compensation ``-kappa d_hat``,
        ``d_hat = L M (qdot - w_hat)``, joins the request) with the guides' presliding stiffness ``K_g``
        (:func:`~awiwi_drake.control.chain.guide_presliding_stiffness`) on the link: ``F - K_g E e_q^T`` (``E``:
        :attr:`JointReducedModel.link_torque_map`).  The observer cancels that spring's torque through the chain's
        lag ``T``: a rest mode near ``-Kp / ((Kp + K_g) (1 / L + T))``, the slowest where ``K_g >> Kp``."""
        m, K, nx, nu = self.models[dof], self.gains[dof], self.law.Nx[dof], self.law.Nu[dof]
        obs = self.observer
        if obs is not None:
            m = dataclasses.replace(m, A=m.A - obs.presliding_stiffness[dof] * m.link_torque_map @ np.eye(1, 4))
        A, B = _closed_loop_matrix(m, K, self.period)
        b = B[:, 0] * (nu + K[:4] @ nx + (0.0 if self.period is None else K[4] * nu))
        if obs is None:
            return A, b
        L, M, damping = obs.gain[dof], m.inertia, m.damping
        c = obs.scale[dof] * L * M                   # the compensation -kappa d_hat = c (w_hat - qdot)
        n = A.shape[0]
        Ao = np.zeros((n + 1, n + 1))
        Ao[:n, :n] = A
        Ao[:n, 1] -= B[:, 0] * c
        Ao[:n, n] = B[:, 0] * c
        # w_hat' = (tau - b qdot + d_hat) / M on the deviations (tau - tau_op = z[2]); sampled: its Euler step
        rate = np.zeros(n + 1)
        rate[1], rate[2], rate[n] = L - damping / M, 1.0 / M, -L
        Ao[n] = rate if self.period is None else np.eye(n + 1)[n] + self.period * rate
        return Ao, np.append(b, 0.0)

    @property
    def loop_poles(self) -> list:
        """Per DoF the poles of :meth:`loop` (the stage, and with :attr:`observer` the observer on the guides'
        presliding stiffness); s-plane (continuous) or z-plane (sampled)."""
        return [np.linalg.eigvals(self.loop(j)[0]) for j in range(len(self.models))]

    def tracking_time_constant(self, min_share: float = 0.01) -> float:
        """The slowest of :meth:`tracking_time_constants` [s], over all DoF.  The compare's short mode sizes its step
        window with it."""
        return max(self.tracking_time_constants(min_share))

    def tracking_time_constants(self, min_share: float = 0.01) -> list[float]:
        """``1 / sigma`` [s] per DoF of the slowest pole of :meth:`loop` (sampled: ``s = ln(z) / h``) that the
        joint angle's step response shows: a pole's share of the DC gain is ``|c v_i w_i b / lambda_i|``
        (sampled ``|... / (1 - z_i)|``); poles under ``min_share`` of the total are ignored."""
        taus = []
        for j in range(len(self.models)):
            A, b = self.loop(j)
            lam, V = np.linalg.eig(A)
            cv = V[0]
            wb = np.linalg.solve(V, b)
            if self.period is None:
                share, s = np.abs(cv * wb / lam), lam
            else:
                share = np.abs(cv * wb / (1.0 - lam))
                with np.errstate(divide="ignore", invalid="ignore"):      # log(0): the delay state's z = 0
                    s = np.log(lam.astype(complex)) / self.period
            keep = (share / share.sum() > min_share) & np.isfinite(s)
            taus.append(float(1.0 / np.min(-s.real[keep])))
        return taus

    def table(self) -> str:
        """Per DoF: ``M_jj``, ``K_jj``, the gains and the slowest designed pole [1/s] (sampled: ``ln(z) / h``) of the
        stage's own loop and, with :attr:`observer`, of :meth:`loop` (the observer on the guides' presliding)."""
        def slowest(lam):
            if self.period is not None:
                with np.errstate(divide="ignore"):           # the delay state's z = 0
                    lam = np.log(np.asarray(lam, dtype=complex)) / self.period
            return lam[np.argmax(lam.real)]

        head = "  slowest pole [1/s]" + ("  with the observer" if self.observer is not None else "")
        rows = [f"{'DoF':>10} {'M_jj':>10} {'K_jj':>9} {'Kp':>10} {'Kd':>10} {'K_tau':>9} {'K_taud':>9} "
                f"{'K_prev':>8}{head}"]
        observed = self.loop_poles if self.observer is not None else [None] * len(self.models)
        for m, K, lam, lo in zip(self.models, self.gains, self.design_poles, observed):
            s = slowest(lam)
            row = (f"{m.name:>10} {m.inertia:10.3g} {m.stiffness:9.3g} {K[0]:10.4g} {K[1]:10.4g} {K[2]:9.4g} "
                   f"{K[3]:9.4g} {K[4]:8.3g}  {s.real:.4g}{s.imag:+.4g}j")
            if lo is not None:
                o = slowest(lo)
                row += f"  {o.real:.4g}{o.imag:+.4g}j"
            rows.append(row)
        return "\n".join(rows)


def design_joint_stage(rig: Any, design: str = "cascaded", *, point: ChainDesign | None = None,
                       params: JointDesignParams | None = None, chain: HandChainParams | None = None,
                       models: list | None = None, period: float | None = None) -> JointDesign:
    """Design the joint stage ``design`` for every DoF of a finger/the hand (module docstring); ``period``:
    for the sampled chain (its distribution's one period of delay, :func:`sampled_model`)."""
    if design not in DESIGNS:
        raise ValueError(f"unknown joint design {design!r}; use one of {', '.join(DESIGNS)}")
    c = chain or HandChainParams()
    p = params or JointDesignParams()
    point = point or chain_design_point(rig, params=c)
    rate = _TORQUE_RATE.get(design, "joint")
    models = models or reduced_joint_models(rig, point=point, params=c, tendon_law=_tendon_law(design, c),
                                            torque_rate=rate)
    if any(m.torque_rate != rate for m in models):
        raise ValueError(f"design_joint_stage: the {design} stage measures torque_rate={rate!r}; the models given "
                         f"are on {sorted({m.torque_rate for m in models})}")
    gains = np.array([design_joint_gains(m, design, params=p, chain=c, period=period) for m in models])
    Nx, Nu = [], []
    for m in models:
        nx, nu = reference_maps(m.A, m.B, np.array([1.0, 0.0, 0.0, 0.0]))
        Nx.append(nx)
        Nu.append(float(nu[0]))
    S = point.selection
    kw = dict(state_map=np.array(Nx), input_map=np.array(Nu), joint_angle_op=np.linalg.pinv(S) @ point.joint_angle,
              torque_op=point.torque_offset, name=design.replace("-", "_"), torque_rate=rate)
    if design == "sdre":
        law = _sdre_law(rig, point, c, p, kw, period)
    else:
        law = JointStateFeedbackLaw(rig.coupling, S, rig.params.motor.pulley_radius, gains, **kw)
    poles = [np.linalg.eigvals(_closed_loop_matrix(m, K, period)[0]) for m, K in zip(models, gains)]
    return JointDesign(design, law, models, gains, poles, period)


def _sdre_law(rig, point, c, p, kw, period):
    """The SDRE (ch. 14) per DoF: LQR on the pointwise-linear model at each tabulated joint torque."""
    S = point.selection
    k = S.shape[1]
    grid = np.linspace(-p.sdre_torque_range, p.sdre_torque_range, p.sdre_points)
    table = np.empty((k, grid.size, 5))
    for j in range(k):
        for i, dt in enumerate(grid):
            model = _reduced_model(rig, j, point, c, c.tendon_law, kw["torque_rate"],
                                   point.torque_offset[j] + dt, "", 0.0, 0.0, None, (), link_torque=False)
            table[j, i] = design_joint_gains(model, "sdre", params=p, chain=c, period=period)
    return JointGainScheduleLaw(rig.coupling, S, rig.params.motor.pulley_radius, grid, table, **kw)


def joint_stage_controller(rig: Any, design: str = "cascaded", *, op: Any = None,
                           params: JointDesignParams | None = None, chain: HandChainParams | None = None,
                           distribution: str | None = None, rate_hz: float = 3000.0,
                           friction_observer: FrictionObserverParams | None = FrictionObserverParams(),
                           **kw) -> TendonChainController:
    """Registered factories ``cascaded``, ``lqr`` (...) for fingers and the hand: the chain with the joint
    stage ``design`` (:func:`design_joint_stage`) designed at ``op`` (default: the rig's operating point).

    ``stiffness_correction`` (ch. 8, ``StiffnessCorrectionParams``): the distribution is asked for ``K_mech = eps
    K_eff`` (8.2) per DoF, ``K_eff`` the design's :attr:`JointDesign.static_stiffness` ((8.1) is the identity here: no
    spring is in series with the chain's force control).  ``friction_observer``: the (9.2) observer per DoF, on by
    default (the guides' friction otherwise leaves the impedance a dead band); None removes it.  ``kw``:
    ``mechanical_stiffness``, ``gains``, ``distribution_params`` (:class:`~.chain.TendonChainController`)."""
    c = chain or HandChainParams()
    correction = kw.pop("stiffness_correction", None)
    if correction is not None and not isinstance(correction, StiffnessCorrectionParams):
        raise TypeError(f"joint_stage_controller: stiffness_correction = {correction!r} must be None or a "
                        f"StiffnessCorrectionParams")
    rate_hz = check_rate("joint_stage_controller", rate_hz)
    point = chain_design_point(rig, op, params=c, mechanical_stiffness=kw.pop("mechanical_stiffness", None))
    sampled = (distribution or c.distribution_method) != "sharing"
    d = design_joint_stage(rig, design, point=point, params=params, chain=c,
                           period=1.0 / rate_hz if sampled else None)
    if correction is not None:                          # (8.2): K_mech,des = eps K_eff,des per DoF
        sizes = [cp.dof_selection.shape[1] for cp in rig.coupling.parts.values()]
        starts = np.cumsum([0] + sizes)
        K_mech = correction.epsilon * d.static_stiffness
        point = chain_design_point(rig, op, params=c, mechanical_stiffness=[
            np.diag(K_mech[a:b]) for a, b in zip(starts[:-1], starts[1:])])
    ctrl = TendonChainController(rig, d.law, c, point=point, distribution=distribution, rate_hz=rate_hz,
                                 tendon_law=_tendon_law(design, c), name=f"{design.replace('-', '_')}_chain",
                                 friction_observer=friction_observer, **kw)
    obs = ctrl._observer                               # the design's loop with the chain's (9.2) observer
    if obs is not None:
        d.observer = JointObserverDesign(obs.gain.copy(), obs.scale.copy(), guide_presliding_stiffness(rig, point))
    ctrl.design.joint_design = d
    ctrl.design.time_constant = d.tracking_time_constant()
    return ctrl


@dataclass
class PoleMatch:
    """One designed pole of a DoF and the whole loop's pole it becomes (:meth:`PoleCheck.matches`), in 1/s.

    ``loop``: followed continuously along ``D + s E``, ``s`` 0 -> 1 (one to one); ``radius``: the certified
    ``|loop - centre| <= radius`` of the isolated Gershgorin disc around ``centre = design + (V^-1 E V)_ii``, ``inf``
    where no disc is isolated (the pole is *not found*); ``inertia`` / ``tendons``: the pole with only that
    coupling turned on (the cause of the move)."""

    dof: str
    design: complex
    loop: complex
    centre: complex
    radius: float
    inertia: complex
    tendons: complex

    @property
    def found(self) -> bool:
        return bool(np.isfinite(self.radius))

    @property
    def move(self) -> float:
        """``|loop - design| / |design|``."""
        return float(abs(self.loop - self.design) / abs(self.design))

    @property
    def cause(self) -> str:
        """The neglected coupling that alone moves the pole more: ``"inertia"`` or ``"tendons"``."""
        return "inertia" if abs(self.inertia - self.design) >= abs(self.tendons - self.design) else "tendons"


def _follow_poles(D: np.ndarray, E: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """The eigenvalues of ``D + E`` that ``lam`` (those of ``D``) become along ``D + s E``, ``s`` 0 -> 1: each step
    pairs the eigenvalues one to one (least total distance) and is halved until no pole moves more than a quarter of
    its distance to the nearest other pole (so no two can swap; poles equal to 1e-6 of the largest, e.g. the ``pd``
    designs' one placed pair on every DoF, are interchangeable, and which of them a DoF keeps is arbitrary)."""
    from scipy.optimize import linear_sum_assignment
    cur, s, ds, steps = np.asarray(lam, dtype=complex), 0.0, 1.0 / 16, 0
    while s < 1.0:
        steps += 1
        if steps > 20000:
            raise RuntimeError(f"pole continuation: stuck at s = {s:.6g} after 20000 steps (poles closer than the "
                               f"steps resolve); the poles there: {np.sort_complex(cur)}")
        step = min(ds, 1.0 - s)
        new = np.linalg.eigvals(D + (s + step) * E)
        row, col = linear_sum_assignment(np.abs(cur[:, None] - new[None, :]))
        moved = new[col[np.argsort(row)]]
        dist = np.abs(cur[:, None] - cur[None, :])
        gap = np.where(dist > 1e-6 * np.abs(cur).max(), dist, np.inf).min(axis=1)   # equal poles: interchangeable
        if np.any(np.abs(moved - cur) > 0.25 * gap) and step > 1e-9:
            ds = step / 2
            continue
        cur, s, ds = moved, s + step, min(2 * step, 1.0 / 16)
    return cur


def _isolated_radius(F: np.ndarray, i: int) -> float:
    """Radius of the smallest Gershgorin disc of ``F`` (``Lambda + V^-1 E V``) around ``F_ii`` isolated from the other
    discs by a diagonal similarity (row ``i``'s off-diagonal scaled by ``t``, column ``i`` by ``1/t``): isolated,
    it holds exactly one eigenvalue (Gershgorin); ``inf`` when no ``t`` isolates it."""
    c = np.diag(F)                                          # the centres: F is Lambda + V^-1 E V
    off = np.abs(F) - np.diag(np.abs(c))
    R = off[i].sum()
    if R == 0.0:
        return 0.0 if np.all(off[:, i] == 0.0) else np.inf
    lo, hi = 0.0, np.inf
    for l in range(F.shape[0]):
        if l == i:
            continue
        g = abs(c[i] - c[l]) - (off[l].sum() - off[l, i])  # room left between the centres
        a = off[l, i]
        if g <= 0.0 or g * g < 4.0 * R * a:                # t R + a / t <= g has no t > 0
            return np.inf
        root = np.sqrt(g * g - 4.0 * R * a)
        lo, hi = max(lo, (g - root) / (2.0 * R)), min(hi, (g + root) / (2.0 * R))
    return float(lo * R) if lo <= hi else np.inf


@dataclass
class PoleCheck:
    """The per-DoF designs against the whole loop's linearisation (:func:`check_design_poles`).

    ``poles``: the whole continuous loop's (Drake ``Linearize``); ``z_poles``: those of its restriction ``A_z``
    to ``z = [q_j, qdot_j, tau_j, tau_dot_j]`` of every DoF (a subset of ``poles`` when ``invariance_residual``
    ~ 0); ``design``: the per-DoF loops ``F_j - G_j K_j`` (block diagonal ``D``).  ``A_z = D + E``, ``E`` the
    coupling the per-joint models neglect, in closed form (:attr:`coupling_residual`: Drake's ``E`` against it):
    the inertia matrix ``qdd = M^-1 (tau - B qdot)`` in place of each model's ``M_jj`` (``E_M``; ``inertia_ratio``
    ``(M^-1)_jj M_jj``) and the tendons shared by joints, ``- sum_l K_jl qdd_l`` (``E_K``, with the thumb base's
    lever arms ``J = d tau / d q``).  :meth:`matches` pairs each designed pole with the loop pole it becomes."""

    poles: np.ndarray
    z_poles: np.ndarray
    design: np.ndarray                # D (4k x 4k)
    coupling: np.ndarray              # E = A_z - D (4k x 4k)
    invariance_residual: float
    dof_names: list
    inertia_coupling: np.ndarray      # E_M
    tendon_coupling: np.ndarray       # E_K (with the thumb base's lever arms)
    inertia_ratio: np.ndarray         # (M^-1)_jj M_jj per DoF: 1 for a DoF the others' inertia does not reach

    @property
    def design_poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.design)

    @property
    def coupling_residual(self) -> float:
        """``|E - E_M - E_K| / |A_z|`` (0: the neglected coupling is exactly the inertia matrix and the shared
        tendons' stiffness)."""
        Az = self.design + self.coupling
        return float(np.abs(self.coupling - self.inertia_coupling - self.tendon_coupling).max() / np.abs(Az).max())

    def matches(self) -> list[PoleMatch]:
        """Every designed pole with the loop pole it becomes (:class:`PoleMatch`), ordered by DoF and modulus."""
        lam, V = np.linalg.eig(self.design)
        F = np.linalg.solve(V, self.coupling @ V)
        G = np.diag(lam) + F
        loop = _follow_poles(self.design, self.coupling, lam)
        alone = [_follow_poles(self.design, E, lam) for E in (self.inertia_coupling, self.tendon_coupling)]
        dof = np.argmax(np.abs(V).reshape(len(self.dof_names), 4, -1).sum(axis=1), axis=0)
        # a DoF the coupling does not reach (its rows and columns of E vanish to round-off): A_z is block diagonal
        # there, so its designed poles are poles of A_z to that round-off
        E, tol = np.abs(self.coupling), 1e-12 * np.abs(self.design + self.coupling).max()
        free = [max(E[4 * j:4 * j + 4].max(), E[:, 4 * j:4 * j + 4].max()) <= tol for j in range(len(self.dof_names))]
        # only where z is invariant are the z poles poles of the loop (ring/fifth: the stiff PIP/DIP coupling element
        # of (5.16) is a plant DoF of its own, outside z): nothing is certified otherwise
        exact = self.invariance_residual <= 1e-9
        out = [PoleMatch(self.dof_names[dof[i]], complex(lam[i]), complex(loop[i]), complex(G[i, i]),
                         np.inf if not exact else 1e-9 * abs(lam[i]) if free[dof[i]] else _isolated_radius(G, i),
                         complex(alone[0][i]), complex(alone[1][i])) for i in range(lam.size)]
        return sorted(out, key=lambda m: (self.dof_names.index(m.dof), abs(m.design), m.design.imag))

    def table(self) -> str:
        """One row per designed pole: the DoF, the design's pole, the loop's, the certified radius or why it is not
        found."""
        rows = [f"{'DoF':>6} {'designed [1/s]':>22} {'loop [1/s]':>22} {'move':>7}  verdict"]
        if self.invariance_residual > 1e-9:
            rows.insert(0, f"z is not invariant (residual {self.invariance_residual:.2g}): the z poles are not poles of "
                           f"the loop, nothing is certified")
        for m in self.matches():
            ratio = self.inertia_ratio[self.dof_names.index(m.dof)]
            verdict = (f"found (within {m.radius:.3g} of the first-order {m.centre.real:.4g}{m.centre.imag:+.4g}j)"
                       if m.found else f"not found: moved by the {m.cause} coupling ((M^-1)_jj M_jj = {ratio:.3g})")
            rows.append(f"{m.dof:>6} {m.design.real:10.4g}{m.design.imag:+11.4g}j {m.loop.real:10.4g}"
                        f"{m.loop.imag:+11.4g}j {m.move:7.2%}  {verdict}")
        return "\n".join(rows)

    @property
    def stable(self) -> bool:
        return bool(np.all(self.poles.real < 0))


def _lever_arm_stiffness(rig: Any, S: np.ndarray, op: Any) -> np.ndarray:
    """``J = d tau / d q`` (k x k) [Nm/rad] at constant tendon forces, ``tau = -(P(q) S)^T f_op``: the lever arms'
    change with the pose (AutoDiff; zero where the routing's ``P`` is constant, e.g. every finger but the thumb
    base)."""
    from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, InitializeAutoDiff
    q = S @ InitializeAutoDiff(np.linalg.pinv(S) @ np.asarray(op.joint_angle, dtype=float)).ravel()
    tau = -(np.asarray(rig.coupling.P(q)) @ S).T @ np.asarray(op.tendon_force, dtype=float)
    J = ExtractGradient(np.array([t if isinstance(t, AutoDiffXd) else AutoDiffXd(float(t)) for t in tau]))
    return J if J.shape == (S.shape[1], S.shape[1]) else np.zeros((S.shape[1], S.shape[1]))   # constant P: none


def check_design_poles(rig: Any, design: str = "cascaded", *, chain: HandChainParams | None = None,
                       params: JointDesignParams | None = None) -> PoleCheck:
    """Linearise a finger/the hand closed by the chain with the per-DoF ``design`` (continuous: sharing
    (15.88), the true joint state) and compare its poles with the designs (:class:`PoleCheck`).

    Use a rig built with the design's motor model (``params.replace(motor=design_motor(params.motor))``)
    without hysteresis and guide friction for the comparison the per-joint models make."""
    c = chain or HandChainParams()
    ctrl = joint_stage_controller(rig, design, chain=c, params=params, distribution="sharing",
                                  friction_observer=None)      # the designs: the stage itself, no ch. 9 observer
    d = ctrl.design.joint_design
    loop = closed_loop(rig, ctrl, rate_hz=None, sensors="ideal")
    op = ctrl.operating_point
    ctx = loop.create_context(op, references={"joint_angle_reference": op.joint_angle})
    lin = linearize(loop.diagram, context=ctx, input="joint_angle_reference", outputs=("joint_angle", "joint_torque"))
    A = lin.A
    S = ctrl.design.selection
    Cq = np.linalg.pinv(S) @ lin.output("joint_angle").C
    Ct = S.T @ lin.output("joint_torque").C
    k = S.shape[1]
    T = np.vstack([np.stack([Cq[j], Cq[j] @ A, Ct[j], Ct[j] @ A]) for j in range(k)])
    TA = T @ A
    Az = TA @ np.linalg.pinv(T)
    res = float(np.linalg.norm(TA - Az @ T) / np.linalg.norm(TA))
    # the neglected coupling in closed form (class docstring): M, B, K of the DoF at the operating point
    Mi = np.linalg.inv(joint_inertia(rig, op.joint_angle, full=True))
    b = np.diag(joint_damping(rig))
    K_dof = S.T @ np.asarray(op.joint_stiffness, dtype=float) @ S
    J = _lever_arm_stiffness(rig, S, op)
    w, xi = ctrl._force.gains.natural_frequency, ctrl._force.gains.damping_ratio
    link = np.zeros((k, 4 * k))                        # qdd = M^-1 (tau - B qdot) on z
    link[:, 1::4], link[:, 2::4] = -Mi * b[None, :], Mi
    D, E_M, E_K = np.zeros_like(Az), np.zeros_like(Az), np.zeros_like(Az)
    motor = d.law.torque_rate == "motor"
    for j, (m, K) in enumerate(zip(d.models, d.gains)):
        Tj = np.eye(4)
        if motor:                                      # sigma_j = tau_dot_j + K_jj qdot_j in the DoF's design
            Tj[3, 1] = m.stiffness
        blk = slice(4 * j, 4 * j + 4)
        D[blk, blk] = np.linalg.solve(Tj, (m.A - m.B @ K[None, :4]) @ Tj)
        own = np.zeros(4 * k)                          # the design's qdd_j
        own[4 * j + 1], own[4 * j + 2] = -b[j] / m.inertia, 1.0 / m.inertia
        E_M[4 * j + 1] = link[j] - own
        E_M[4 * j + 3] = -m.stiffness * (link[j] - own)
        others = np.delete(np.arange(k), j)
        # the lever arms' torque J q of the force loop's (10.11) stiffness and damping (the sharing's forces are
        # those of the operating point's P) and J qdd
        E_K[4 * j + 3] = -K_dof[j, others] @ link[others] + J[j] @ link
        E_K[4 * j + 3, 0::4] += w ** 2 * J[j]
        E_K[4 * j + 3, 1::4] += 2.0 * xi * w * J[j]
        # the stage measures tau_dot without the lever arms' change (J qdot) and sigma with every shared tendon
        E_K[4 * j + 3, 1::4] += m.B[3, 0] * K[3] * J[j]
        if motor:
            E_K[4 * j + 3, 4 * others + 1] -= m.B[3, 0] * K[3] * K_dof[j, others]
    return PoleCheck(np.linalg.eigvals(A), np.linalg.eigvals(Az), D, Az - D, res, [m.name for m in d.models], E_M, E_K,
                     np.diag(Mi) * np.array([m.inertia for m in d.models]))


@dataclass
class SampledLoopPoles:
    """The poles of a sampled closed loop (:func:`sampled_loop_poles`): the eigenvalues ``z`` of the Jacobian of
    its one-period map ``x_{k+1} = Phi(x_k)`` at the operating point (all discrete states: the plant sampled
    exactly with a zero-order hold, the controller's and the estimator's states), ``s = ln(z) / h``.

    ``neutral``: the modes at ``z = 1`` to ``1e-9`` (a continuum of equilibria, e.g. the spring hysteresis's
    memory: any Dahl force at rest is an equilibrium); :attr:`spectral_radius` is over the others.
    ``residual``: ``max |Phi(x_0) - x_0|`` (0 at a fixed point of the sampled loop)."""

    z: np.ndarray
    period: float
    jacobian: np.ndarray              # d x_k+1 / d x_k
    residual: float
    reference_map: np.ndarray         # d x_k+1 / d q_ref (the joint_angle_reference input)
    joint_angle_map: np.ndarray       # d q_k / d x_k (the rig's joint_angle output)

    def step_response(self, dq_ref, duration: float) -> tuple[np.ndarray, np.ndarray]:
        """``(t, dq)``: the linear sampled loop's joint angles (deviations, one row per sample) after a
        reference step ``dq_ref`` at ``t = 0``, for ``duration`` s."""
        n = int(round(duration / self.period))
        x = np.zeros(self.jacobian.shape[0])
        u = self.reference_map @ np.asarray(dq_ref, dtype=float)
        out = [self.joint_angle_map @ x]
        for _ in range(n):
            x = self.jacobian @ x + u
            out.append(self.joint_angle_map @ x)
        return self.period * np.arange(n + 1), np.array(out)

    @property
    def neutral(self) -> np.ndarray:
        return np.abs(self.z - 1.0) <= 1e-9

    @property
    def spectral_radius(self) -> float:
        return float(np.abs(self.z[~self.neutral]).max())

    @property
    def s(self) -> np.ndarray:
        """The equivalent continuous poles ``ln(z) / h`` [1/s] (``-inf`` for ``z = 0``)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log(self.z.astype(complex)) / self.period

    def slowest(self) -> complex:
        """The non-neutral mode of largest ``|z|`` as ``s`` [1/s] (the slowest decay)."""
        z = np.where(self.neutral, 0.0, np.abs(self.z))
        return complex(self.s[int(np.argmax(z))])


def sampled_loop_poles(rig: Any, controller: Any, *, rate_hz: float = 3000.0, estimator: Any = "auto",
                       op: Any = None, fused: bool = True) -> SampledLoopPoles:
    """Poles of ``rig`` closed by ``controller`` (a fresh system) sampled at ``rate_hz``, the linear analysis of
    what :func:`~awiwi_drake.control.base.closed_loop` ``(rig, controller, rate_hz=rate_hz)`` simulates.

    The rig is linearised at ``op`` by Drake (motor friction (3.8) at rest, hysteresis as the presliding spring),
    sampled exactly with Drake's ``DiscreteTimeApproximation`` (zero-order hold) and closed in the same
    ``closed_loop`` wiring with the controller's discrete states and the tendon-length estimator (``estimator``:
    ``"auto"``, the rig's at the same rate; ``None``/``"ideal"``: the true joint state).  Drake's ``Linearize``
    takes one discrete state group only, so the Jacobian of the one-period map (``EvalUniquePeriodicDiscreteUpdate``)
    is taken in ``AutoDiffXd``; every periodic update must have the period ``1 / rate_hz``.  ``fused``: as
    :func:`~awiwi_drake.control.base.closed_loop` (the same poles).
    """

    from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff
    from pydrake.systems.analysis import DiscreteTimeApproximation
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import AffineSystem, Demultiplexer, LinearSystem

    from awiwi_drake.control.base import measurement_ports
    h = 1.0 / check_rate("sampled_loop_poles", rate_hz)
    op = op or rig.operating_point()
    ideal = estimator in (None, "ideal")
    est = None if ideal else (rig.link_estimator(h) if estimator == "auto" else estimator)
    if est is not None and abs(est.period - h) > 1e-12 * h:
        raise ValueError(f"sampled_loop_poles: the estimator samples every {est.period:.6g} s, the loop every "
                         f"{h:.6g} s: one rate only (the one-period map)")
    need = set(measurement_ports(controller)) | {"joint_angle"}
    if est is not None:
        need |= {est.system.get_input_port(i).get_name() for i in range(est.system.num_input_ports())}
    outputs = tuple(sorted(need))
    lin = linearize(rig, op, outputs=outputs, equilibrium_tolerance=None)
    C = np.vstack([lin.outputs[o].C for o in outputs])
    D = np.vstack([lin.outputs[o].D for o in outputs])
    y0 = np.concatenate([lin.outputs[o].y0 for o in outputs])
    zoh = DiscreteTimeApproximation(LinearSystem(lin.A, lin.B, C, D), h)
    b = DiagramBuilder()
    aff = b.AddNamedSystem("sampled_rig", AffineSystem(zoh.A(), zoh.B(), -zoh.B() @ lin.u0, C, D,
                                                       y0 - D @ lin.u0, h))
    b.ExportInput(aff.get_input_port(), "motor_torque")
    split = b.AddNamedSystem("outputs", Demultiplexer([lin.outputs[o].y0.size for o in outputs]))
    b.Connect(aff.get_output_port(), split.get_input_port())
    for i, o in enumerate(outputs):
        b.ExportOutput(split.get_output_port(i), o)
    sampled = b.Build()
    sampled.set_name(rig.name)
    loop = closed_loop(dataclasses.replace(rig, diagram=sampled), controller, rate_hz=None, estimator=est,
                       sensors="ideal" if ideal else None, fused=fused)
    diagram = loop.diagram
    ctx = diagram.CreateDefaultContext()
    loop.initialize_controller(ctx, None if est is None else op.joint_angle)
    diagram.GetInputPort("joint_angle_reference").FixValue(ctx, op.joint_angle)
    for nm in loop.disturbances:
        port = diagram.GetInputPort(nm)
        port.FixValue(ctx, op.external_torque if nm == "external_torque" and op.external_torque is not None
                      else np.zeros(port.size()))
    if ctx.num_continuous_states():        # the one-period map would hold them fixed: poles silently missing
        raise ValueError(f"sampled_loop_poles: the loop has {ctx.num_continuous_states()} continuous state(s) "
                         f"besides the sampled rig (a continuous controller or estimator); give a sampled one")
    groups = ctx.get_discrete_state()
    sizes = [groups.get_vector(i).size() for i in range(groups.num_groups())]
    x0 = np.concatenate([groups.get_vector(i).CopyToVector() for i in range(groups.num_groups())])
    ad = diagram.ToAutoDiffXd()
    actx = ad.CreateDefaultContext()
    actx.SetTimeStateAndParametersFrom(ctx)
    ref = diagram.GetInputPort("joint_angle_reference")
    r0 = np.asarray(ref.Eval(ctx), dtype=float)
    xa = InitializeAutoDiff(np.concatenate([x0, r0])).ravel()
    ad.FixInputPortsFrom(diagram, ctx, actx)          # the fixed inputs, then the reference with its derivatives
    ad.get_input_port(ref.get_index()).FixValue(actx, xa[x0.size:])
    start = 0
    for i, n in enumerate(sizes):
        actx.SetDiscreteState(i, xa[start:start + n])
        start += n
    try:
        new = ad.EvalUniquePeriodicDiscreteUpdate(actx)
    except RuntimeError as exc:
        raise ValueError(f"sampled_loop_poles: the loop is not one-rate at {rate_hz:g} Hz ({exc})") from None
    x1 = np.concatenate([new.get_vector(i).CopyToVector() for i in range(new.num_groups())])
    G = ExtractGradient(x1)
    Cq = ExtractGradient(ad.GetOutputPort("joint_angle").Eval(actx))[:, :x0.size]
    J = G[:, :x0.size]
    return SampledLoopPoles(np.linalg.eigvals(J), h, J, float(np.abs(ExtractValue(x1).ravel() - x0).max()),
                            G[:, x0.size:], Cq)
