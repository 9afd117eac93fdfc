"""Antagonistic backstepping (thesis 15.5, (15.82)-(15.106)) for a finger or the whole hand, and its position
(15.2) and nonlinear-spring (15.4) variants.

Section 15.5 lets "the motors not be aware of one another": the desired link torque is *shared* among the
tendons, a pretension is added, and the backstepping steps on the tendon force are done per tendon; the motor
torques come out of the law directly (no force distribution, no force loop).  Here for ``n`` plant joints, ``k``
independent DoF (``q = S q_d``; ring/fifth: the DIP follows the PIP) and ``m`` tendons with the coupling ``P(q)``::

    e = S^+ (q - q_ref),  e' = S^+ qdot                            DoF errors (references held)
    alpha = tau_op - Kp e - Kd e'                                   (15.54), Kp and Kd k x k
    f_d = f_op + W (alpha + (P S)^T f_op),  W = -((P S)^T)^+        sharing (15.88): -(PS)^T f_d = alpha
    z3 = f - f_d,  beta = f_d' - K3 z3 + (P S) e',  z4 = f' - beta  (15.90), (15.57)
    u = (beta' - f0 - z3 - K4 z4) / g                               (15.63)

``f = phi_i(x_i)`` is each tendon's own spring law (``rig.spring_laws``) at its measured elongation (the lever's
angle calibrated to force, ch. 4: its friction ``z`` and the guides' ``g`` are not measured); ``f' = phi'(x) x'``,
``x' = r_m omega + P qdot``, ``f'' = f0 + g u``, ``g = phi'(x) r_m / B``, ``f0 = phi'' x'^2 + phi' r_m (tau_fric(omega)
+ tau_ripple(theta) - r_m f) / B`` with the motor friction (3.8) scaled by
``HandChainParams.backstepping_friction_scale`` (ch. 3: under-compensate) and the ripple (3.5) in full.  The joint
accelerations come from the link model ``M_d e'' = -(P S)^T f - B_q e'`` (``M_d = S^T M(q_op) S``; Coriolis terms,
second order at rest, left out).  With ``HandChainParams.link_acceleration_feedforward=True`` ``f0`` also holds
``phi' P qddot`` (the exact design), for which::

    V = e'^T M_d e' / 2 + e^T Kp e / 2 + |z3|^2 / 2 + |z4|^2 / 2,   (Kp symmetric positive definite)
    V' = -e'^T (Kd + B_q) e' - z3^T K3 z3 - z4^T K4 z4 <= 0      (K3, K4 diagonal, one gain per tendon)

(the ``(P S) e'`` in ``beta`` cancels the link equation's cross term) and the linearised loop on the ideal plant has
exactly the designed error-system poles (tested); ``terms(u)["V"]`` gives ``V``.  One DoF with ``P = [-r_q, r_q]^T``
is the antagonistic joint of 15.5.  The feed-forward is off by default: on the light finger links it turns every
link-side force the model lacks (the guides' friction (4.1)) into motor torque and an unstable pole (README, "The
thesis's control on fingers and the hand").  The frictions then leave a dead band:
:meth:`FingerBacksteppingLaw.rest_error` is the law's rest in closed form, :meth:`~FingerBacksteppingLaw.dead_band`
its half-width per DoF, and ``compare`` flags a step row that stops in it
(:meth:`~FingerBacksteppingLaw.friction_hold`).

**External load** (``load_observer`` of :func:`finger_backstepping_controller`): the link model has no external
torque, so a load ``tau_ext`` rests at ``Kp e = (I + G) S^T tau_ext`` (``G`` of the dead band); 15.3 "formally
requires the measure of the external torque".  The option estimates it with the joint observer (9.2) per DoF
(:class:`ObservedBacksteppingController`) on the law's own sensed torque ``-(P S)^T phi(x)``, adds ``d_hat`` to the
link model, and the loop rests at ``Kp e = S^T tau_ext - (P S)^T (z + g)``.  **Friction compensation**
(``friction_observer``, registered ``backstepping-friction-observer``): (9.1) on the joint level, ``alpha +=
clip(-d_hat, +-B)`` with ``B`` the frictions' bound (:meth:`~FingerBacksteppingLaw.friction_bound`, the one law
:func:`~awiwi_drake.components.friction.joint_friction_bound`, with the lever's hysteresis added because the law's
sensor misses it).

Gains (chosen, 15.5: "the gains have been initially selected to lead to feedback gains for the tendon force error
that is close to the cascaded case"): per tendon ``K3 = K4 = w_f`` (then ``(1 + K3 K4) / g ~ w_f^2 B / alpha``
equals the cascaded (10.11) gain at the same bandwidth, ``alpha = r_m phi'``).  The joint gains are designed on the
modes of ``M_d = V diag(mu) V^T``: mode i gets ``k_i = min(joint_stiffness, mu_i w_max^2)`` and the damping ``2 zeta
sqrt(k_i mu_i)``, so every mode has ``|lambda| <= w_max = sampled_pole_limit * rate_hz`` (the law acts through the
whole ``M_d^-1``: per-DoF gains on its diagonal put a pole far beyond the 3 kHz rate, docs/REPRODUCTIONS.md);
``rate_hz=None`` designs for continuous time.  ``w_f``, ``zeta``, ``joint_stiffness`` from :class:`HandChainParams`.

Variants (``variant``, registered ``backstepping-position`` and ``backstepping-nonlinear-spring``):

* ``"position"``: the link steps of the position law (15.27), (15.31) on every DoF in the metric of ``M_d``, rates
  ``K1 = K2 = V diag(k) V^T``: ``z2 = e' + K1 e``, ``alpha = tau_op - M_d (I + K2 K1) e - (M_d (K1 + K2) - B_q) e'``,
  ``beta = f_d' - K3 z3 + (P S) z2``::

      V = e^T M_d e / 2 + z2^T M_d z2 / 2 + |z3|^2 / 2 + |z4|^2 / 2
      V' = -e^T M_d K1 e - z2^T M_d K2 z2 - z3^T K3 z3 - z4^T K4 z4

  Mode i has poles ``-k_i +- i`` and stiffness ``mu_i (1 + k_i^2)``; ``k_i`` the largest with ``mu_i (1 + k_i^2) <=
  joint_stiffness`` and ``sqrt(1 + k_i^2) <= w_max``.  (One rate for every mode leaves the distal modes below what
  the hysteresis lets move; the unweighted (15.44) form needs ``M_d^-1`` in the force step, unstable when sampled.)
* ``"nonlinear-spring"``: the steps of (15.71)-(15.81) on the joint torques ``tau = -(P S)^T phi(x)``, ``z3 = tau -
  alpha``, ``beta = alpha' - K3 z3 - e'``, ``z4 = tau' - beta``; the motor torques realise ``tau'' = beta' - z3 - K4
  z4`` through ``W`` and hold the forces' null space (``Pi = I + W (P S)^T``) at the pretension by the same steps::

      V = e'^T M_d e'/2 + e^T Kp e/2 + |z3|^2/2 + |z4|^2/2 + |Pi (f - f_op)|^2/2 + |Pi (f' + K3 (f - f_op))|^2/2

  Weighting ``z3``, ``z4`` by ``((P S)^T P S)^-1`` turns it into the 15.5 law for a constant coupling (15.5 is the
  15.4 construction in the metric of the tendon forces).

Measurements: ``joint_angle``, ``joint_velocity`` (the tendon-length estimator on the hand), ``elongation`` (the
spring sensors), ``motor_angle``, ``motor_velocity``; reference ``joint_angle_reference`` (n plant joints,
derivatives taken as zero: a set-point law).  Scalar types float and AutoDiffXd (``W`` is evaluated at the value of
``q``: exact for the constant-coupling fingers; the thumb base's ``dW/dq`` is not differentiated).  On the thumb
base the pretension's own torque ``-(P(q) S)^T f_op`` moves with the pose ((5.12)), so the sharing adds ``(P S)^T
f_op + tau_op`` to keep (15.88) exact at every pose.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake.rigs.base import Rig
from awiwi_drake.components import motor_friction_torque, motor_ripple_torque
from awiwi_drake.control.base import StaticLaw, StaticLawController
from awiwi_drake.components.spring import PolynomialSpring, SpringBank
from awiwi_drake._math import clip, positive_part, scalar_value
from awiwi_drake.components.friction import joint_breakaway_bound, joint_friction_bound
from awiwi_drake.control.chain import (guide_friction_levels, guide_presliding_stiffness, joint_friction_levels,
                                       rig_springs)
from awiwi_drake.control.compiled import float_inputs, motor_law_kernels
from awiwi_drake.control.design import BacksteppingDesign
from awiwi_drake.control.joint_stage import JointFrictionObserver, joint_inertia
from awiwi_drake.hand.coupling import dof_selection
from awiwi_drake.parameters.hand_control import FrictionObserverParams, HandChainParams

__all__ = ["FingerBacksteppingLaw", "finger_backstepping_controller", "ObservedBacksteppingController", "FrictionBound_",
           "check_backstepping_springs", "VARIANTS"]

#: The law's variants (module docstring): 15.5 per tendon (registered ``backstepping``), 15.2 link steps
#: (``backstepping-position``), 15.4 steps on the joint torques (``backstepping-nonlinear-spring``).
VARIANTS = ("antagonistic", "position", "nonlinear-spring")


def _values(a) -> np.ndarray:
    a = np.asarray(a)
    return a.astype(float) if a.dtype != object else np.vectorize(scalar_value, otypes=[float])(a)


class FingerBacksteppingLaw(StaticLaw):
    """The law of the module docstring (one call: all DoF and tendons of a finger or the hand)."""

    def __init__(self, rig: Any, params: HandChainParams | None = None, *, op: Any = None,
                 rate_hz: float | None = 3000.0, joint_gains: tuple | None = None, force_gains: tuple | None = None,
                 variant: str = "antagonistic", link_torque_estimate: bool = False,
                 friction_compensation: bool = False):
        """``variant`` in :data:`VARIANTS` (module docstring); ``link_torque_estimate``: the link model takes the
        estimated link-side torque from the input ``friction_compensation`` (``-d_hat`` of the (9.2) observer, module
        docstring); ``joint_gains = (Kp, Kd)`` (k x k) replaces the mode
        design (``antagonistic``, ``nonlinear-spring``);
        ``force_gains = (K3, K4)`` (per tendon, (m,) or scalars; scalars for ``nonlinear-spring``, whose steps are
        on the joint torques) the ``force_bandwidth`` (e.g. the ch. 16 selection,
        :func:`awiwi_drake.control.optimal_gains.select_finger_force_gains`); each must be positive.
        ``friction_compensation`` (needs ``link_torque_estimate``): add the estimate, bounded by what the frictions
        can hold (:meth:`friction_bound`), to the desired joint torque ``alpha`` ((9.1), module docstring)."""
        if variant not in VARIANTS:
            raise ValueError(f"finger backstepping: variant = {variant!r}; use one of {', '.join(VARIANTS)}")
        if variant == "position" and joint_gains is not None:
            raise ValueError("finger backstepping: the position variant's gains follow from its rates on the modes "
                             "of M (module docstring), not from joint_gains")
        self.variant = variant
        p = params or HandChainParams()
        if p.tendon_law != "force":
            raise ValueError(f"tendon_law = {p.tendon_law!r}: the 15.5 finger backstepping computes the motor torques "
                             f"itself (no tendon force law); tendon_law applies to the force-controlled chains")
        coupling = rig.coupling if isinstance(rig, Rig) else None
        if coupling is None:
            raise ValueError(f"finger backstepping: rig {getattr(rig, 'name', '?')!r} is not a finger or hand rig")
        op = op or rig.operating_point()
        self.name = "finger_backstepping"
        self.coupling, self.motor = coupling, rig.params.motor
        self.springs = rig_springs(rig)
        self.S = dof_selection(coupling)
        self.Sp = np.linalg.pinv(self.S)
        n, k = self.S.shape
        m = coupling.num_tendons
        self.r_m, self.B = float(self.motor.pulley_radius), float(self.motor.inertia)
        self.q_op = np.asarray(op.joint_angle, dtype=float)
        self.f_op = np.asarray(op.tendon_force, dtype=float)
        self.P_op = np.asarray(coupling.P(self.q_op), dtype=float)
        self.PS_op = self.P_op @ self.S
        self.tau_op = -self.PS_op.T @ self.f_op
        self.M = joint_inertia(rig, self.q_op, full=True)          # S^T M(q_op) S (DoF inertia matrix)
        self._Minv = np.linalg.inv(self.M)
        plant = rig.plant
        b_q = np.array([plant.get_joint(j).default_damping_vector()[0] for j in plant.GetJointIndices()])
        self.Bq = self.S.T @ np.diag(b_q) @ self.S                # joint damping on the DoF
        wf, zeta = p.force_bandwidth, p.damping_ratio
        if rate_hz is not None and not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"finger backstepping: rate_hz = {rate_hz} must be > 0 [Hz] (None: continuous design)")
        self.rate_hz = rate_hz
        mu, V = np.linalg.eigh(self.M)
        w_max = np.inf if rate_hz is None else p.sampled_pole_limit * float(rate_hz)
        k_modes = np.minimum(p.joint_stiffness, mu * w_max ** 2)
        self.Kp = (V * k_modes) @ V.T
        self.Kd = (V * (2.0 * zeta * np.sqrt(k_modes * mu))) @ V.T
        self.mode_stiffness = k_modes
        if variant == "position":                 # the same rules per mode: k_i from the stiffness cap and the rate
            k_pos = np.sqrt(np.minimum(np.maximum(p.joint_stiffness / mu - 1.0, 0.0), w_max ** 2 - 1.0))
            if not np.all(k_pos > 0):
                raise ValueError(f"finger backstepping (position): mode inertias {mu} leave no positive k_i "
                                 f"(joint_stiffness {p.joint_stiffness} Nm/rad, rate limit {w_max:.4g} 1/s)")
            self.K1 = (V * k_pos) @ V.T                             # k1 = k2 per mode
            self.Kp = (V * (mu * (1.0 + k_pos ** 2))) @ V.T         # M (I + K2 K1)
            self.Kd = (V * (2.0 * mu * k_pos)) @ V.T - self.Bq      # M (K1 + K2) - B_q
            self.mode_stiffness = mu * (1.0 + k_pos ** 2)
            self.mode_rates = k_pos
        if joint_gains is not None:
            Kp, Kd = (np.asarray(g, dtype=float) for g in joint_gains)
            if Kp.shape != (k, k) or Kd.shape != (k, k):
                raise ValueError(f"finger backstepping: joint_gains must be two {k} x {k} matrices (Kp, Kd), got "
                                 f"{Kp.shape}, {Kd.shape}")
            if np.linalg.eigvalsh(0.5 * (Kp + Kp.T)).min() <= 0 or np.linalg.eigvalsh(0.5 * (Kd + Kd.T)).min() < 0:
                raise ValueError("finger backstepping: joint_gains Kp must be positive definite and Kd positive "
                                 "semi-definite (the Lyapunov function of the module docstring)")
            self.Kp, self.Kd = Kp, Kd
        self.K3 = np.full(m, float(wf))
        self.K4 = np.full(m, float(wf))
        if force_gains is not None:
            for name, g in zip(("K3", "K4"), force_gains):
                g = np.broadcast_to(np.asarray(g, dtype=float), (m,)).copy()
                if not np.all(np.isfinite(g) & (g > 0)):
                    raise ValueError(f"finger backstepping: force_gains {name} = {g} must be finite and > 0 [1/s] "
                                     f"(one per tendon, {m})")
                if variant == "nonlinear-spring" and np.ptp(g) > 0:
                    raise ValueError(f"finger backstepping (nonlinear-spring): force_gains {name} must be one value "
                                     "(its steps act on the joint torques, not per tendon)")
                setattr(self, name, g)
        # the 15.5 law's own fraction; the 15.2 / 15.4 variants keep friction_scale (HandChainParams: at 0.8 the
        # nonlinear-spring variant's sampled loop through the estimator is unstable on the index)
        self.friction_scale = float(p.backstepping_friction_scale if variant == "antagonistic" else p.friction_scale)
        self.link_feedforward = bool(p.link_acceleration_feedforward)
        # the sharing W = -((P S)^T)^+ is block-diagonal by finger: constant fingers once, the thumb per call
        parts = coupling.parts
        self._blocks = []                 # (tendon slice, plant-joint slice, DoF slice, constant W or None)
        t0 = j0 = d0 = 0
        for c in parts.values():
            m_f, n_f, k_f = c.num_tendons, c.num_joints, c.dof_selection.shape[1]
            sl = (slice(t0, t0 + m_f), slice(j0, j0 + n_f), slice(d0, d0 + k_f))
            W_f = -np.linalg.pinv((np.asarray(c.P(np.zeros(n_f)), float) @ c.dof_selection).T) if c.is_constant else None
            self._blocks.append(sl + (W_f,))
            t0, j0, d0 = t0 + m_f, j0 + n_f, d0 + k_f
        self.inputs = {"joint_angle_reference": n, "joint_angle": n, "joint_velocity": n, "elongation": m,
                       "motor_angle": m, "motor_velocity": m}
        self.link_torque_estimate = bool(link_torque_estimate)
        if self.link_torque_estimate:
            self.inputs["friction_compensation"] = k
        self.friction_compensation = bool(friction_compensation)
        if self.friction_compensation and not (self.link_torque_estimate and variant == "antagonistic"):
            raise ValueError("finger backstepping: friction_compensation needs the link torque estimate "
                             "(load observer) and the antagonistic variant")
        self.friction_levels = link_friction_levels(rig, self.S)
        # the motor-side part of the lever's hysteresis at rest: the law's motor model lacks r_m z (rest_error)
        self._motor_gain = np.asarray(op.tendon_stiffness, dtype=float) * self.r_m ** 2 / self.B
        self.output_size = m
        # the designed joint error dynamics M e'' + Kd e' + Kp e = 0: its slowest mode (compare's short window)
        A_e = np.block([[np.zeros((k, k)), np.eye(k)], [-self._Minv @ self.Kp, -self._Minv @ self.Kd]])
        self.design = BacksteppingDesign(
            self.S, self.PS_op, self.f_op, self.tau_op, float(1.0 / np.min(-np.linalg.eigvals(A_e).real)),
            friction_hold=self.friction_hold, inertia=self.M, Kp=self.Kp, Kd=self.Kd, K3=self.K3, K4=self.K4)
        self.design.dead_band = self.dead_band()

    def friction_bound(self, f, P=None):
        """``B_j = sum_i |(P S)_ij| (W_i(f_i + w_i) + w_i) + sum_l |S_lj| Fs_l`` (k) [Nm]: the largest link-side torque
        the guides' friction (4.1) (sliding level ``W_i``, pulled, at the tension ``phi + z <= f + w``), the lever's
        hysteresis (Fig 4.8b, half-width ``w_i = beta f_i + z0``) and the joints' stick-slip (breakaway ``Fs_l``) can
        put on each DoF at the sensed forces ``f = phi(x)``, none of which the spring sensors measure
        (:func:`~awiwi_drake.components.friction.joint_friction_bound`)."""
        P = np.asarray(self.P_op if P is None else P)
        (C, mu_alpha), (beta, z0), hold = self.friction_levels
        return joint_friction_bound(P, f, C, mu_alpha, beta * positive_part(f) + z0, hold, self.S)

    def rest_error(self, guide_force, hysteresis_force, external_torque=None, bound=None):
        """The DoF error ``e`` (k) at which the loop rests with the guides' friction forces ``g`` and the lever's
        hysteresis forces ``z`` (m each, the plant's states) and the joint load ``tau_ext`` (n): the law's rest
        equations (omega = 0, e' = 0, the motors at rest: ``u = r_m (phi + z) - ripple``) with the link's balance
        ``-(P S)^T (phi + z + g) + S^T tau_ext = 0`` (module docstring), linear about the operating point::

            tau_f = (P S)^T (z + g) - S^T tau_ext                      the torque the sensors see at rest
            z3 = D^-1 ((W A2 + (K3 + K4) W A1 + P S M_d^-1) tau_f - c z)   D = 1 + K3 K4, c = phi' r_m^2 / B
            Kp e = tau_op - tau_f + comp - (P S)^T z3

        with ``A1 = -Kd M_d^-1``, ``A2 = -(Kp - Kd M_d^-1 B_q) M_d^-1`` (the model's phantom acceleration ``M_d^-1
        tau_f``; zero with the link torque estimate, whose ``d_hat`` explains ``tau_f``) and ``comp = clip(tau_f, +-B)``
        with ``friction_compensation`` (else 0; ``bound`` (k): ``B`` at the rest's forces, default at the operating
        point's).  Without the load: the friction dead band."""
        g, z = (np.asarray(a, dtype=float) for a in (guide_force, hysteresis_force))
        PS = self.PS_op
        tau_f = PS.T @ (z + g)
        if external_torque is not None:
            tau_f = tau_f - self.S.T @ np.asarray(external_torque, dtype=float)
        phantom = 0.0 if self.link_torque_estimate else self._phantom_map() @ tau_f
        z3 = phantom - self._motor_gain * z / (1.0 + self.K3 * self.K4)
        comp = 0.0
        if self.friction_compensation:
            B = self.friction_bound(self.f_op) if bound is None else np.asarray(bound, dtype=float)
            comp = np.clip(tau_f, -B, B)
        return np.linalg.solve(self.Kp, self.tau_op - tau_f + comp - PS.T @ z3)

    def _phantom_map(self) -> np.ndarray:
        """``Z`` (m x k): the force error ``z3 = Z tau`` at rest of a link-side torque ``tau`` the law's link model
        lacks, through its phantom acceleration ``M_d^-1 tau`` (:meth:`rest_error`); ``G = (P S)^T Z``."""
        PS, W = self.PS_op, self._sharing(self.P_op)
        a1, a2 = -self.Kd, -(self.Kp - self.Kd @ self._Minv @ self.Bq)
        return (W @ a2 + (self.K3 + self.K4)[:, None] * (W @ a1) + PS) @ self._Minv / (1.0 + self.K3 * self.K4)[:, None]

    def observer_rest_modes(self, gain: float, guide_stiffness: np.ndarray) -> np.ndarray:
        """The rest modes [1/s] (k) of the (9.2) observer (gain ``L``) on a link held by the guides' presliding
        stiffness ``K_g`` (k x k, :func:`~awiwi_drake.control.chain.guide_presliding_stiffness` ``full=True``),
        quasi-static (the joint and force steps at rest).  The frictions' torque ``tau_f = K_g e`` is what the
        sensors see; the observer's estimate ``delta`` of it obeys ``delta' = L (tau_f - delta)`` and, with the
        friction compensation, joins the request; the law's model sees the phantom ``tau_f - delta`` (``G``,
        :meth:`_phantom_map`), so at rest (:meth:`rest_error`) ``Kp e = -tau_f + c delta - G (tau_f - delta)`` (``c`` 1
        with the compensation, else 0) and ``delta' = L (K_g (Kp + (I + G) K_g)^-1 (c I + G) - I) delta``.  One DoF:
        ``-L Kp / (Kp + (1 + G) K_g)``; where the phantom amplifies the guides' hold (``1 + G`` up to 13.5 on the
        index) this is the loop's slowest mode (index -1.0 1/s at L = 100; tests/test_hand_control.py)."""
        PS = self.PS_op
        G = PS.T @ self._phantom_map()
        k = G.shape[0]
        Kg = np.asarray(guide_stiffness, dtype=float)
        c = np.eye(k) if self.friction_compensation else np.zeros((k, k))
        return np.linalg.eigvals(gain * (Kg @ np.linalg.solve(self.Kp + (np.eye(k) + G) @ Kg, c + G) - np.eye(k)))

    def _rest_maps(self):
        """``(T, Ez, w)``: the rest error's map ``e = e0 - Kp^-1 T tau_f + Ez z`` (:meth:`rest_error`, no load) from
        the torque ``tau_f = (P S)^T (z + g)`` the frictions hold (``T = I + G``, the law's phantom acceleration ``G``;
        ``T = 0`` with the friction compensation inside its bound) and from the lever's motor-side hysteresis ``z``
        alone (0.2 % of ``z`` over the force-step gain on the index: ``phi' r_m^2 / (B (1 + K3 K4))``), and the
        hysteresis half-widths ``w`` (m) at the operating point."""
        m, k = self.f_op.size, self.S.shape[1]
        zero = np.zeros(m)
        base = self.rest_error(zero, zero)
        Sl = self.S @ np.linalg.inv(self.S.T @ self.S)              # a DoF torque as a plant-joint load: S^T Sl = I
        # small unit loads and forces (1e-4 Nm, 1e-3 N): inside the friction bound, where the map is linear
        T = np.column_stack([self.Kp @ (self.rest_error(zero, zero, 1e-4 * Sl[:, j]) - base) / 1e-4
                             for j in range(k)])
        eye = 1e-3 * np.eye(m)
        PS = self.PS_op
        # z alone less its link-side part (through tau_f): what the motors' r_m z adds
        Ez = np.column_stack([(self.rest_error(zero, eye[i]) - base) / 1e-3 + np.linalg.solve(self.Kp, T @ PS.T[:, i])
                              for i in range(m)])
        (_, _), (beta, z0), _ = self.friction_levels
        return T, Ez, beta * self.f_op + z0

    def dead_band(self) -> np.ndarray:
        """Half-width (k) [rad] of the friction dead band per DoF at the operating point: the largest error of DoF
        ``j`` alone (the others at their reference) at which the loop can rest (:meth:`rest_error`), i.e. at which
        the friction torque its rest needs, ``tau_f = (I + G)^-1 (tau_op - Kp e)``, stays within every DoF's
        :meth:`friction_bound` ``B`` (``B_l / |((I + G)^-1 Kp)_lj|``, the least over ``l``), plus the motor-side
        hysteresis's ``|Ez| w``.  With the friction compensation ``tau_f`` is cancelled inside ``B``: only the
        motor-side part is left.  Zero on a plant without guide friction and hysteresis."""
        T, Ez, w = self._rest_maps()
        motor = np.abs(Ez) @ w
        B = self.friction_bound(self.f_op)
        if self.friction_compensation or not np.any(B > 0):
            return motor
        Mh = np.abs(np.linalg.solve(T, self.Kp))                   # |(I + G)^-1 Kp|
        with np.errstate(divide="ignore"):
            half = np.min(np.where(Mh > 0, B[:, None] / Mh, np.inf), axis=0)
        return half + motor

    def friction_hold(self, e, dof_load=None) -> np.ndarray:
        """Per DoF, the fraction of its :meth:`friction_bound` that the frictions must hold for the loop to rest at
        the DoF errors ``e`` (k) under the DoF loads ``dof_load`` (k, ``S^T tau_ext``): ``|tau_f| / B`` with the
        rest's ``tau_f = (I + G)^-1 (tau_op - Kp e) + dof_load`` (:meth:`rest_error`; the motor-side hysteresis, 0.2 %
        of it, left out).  All ``<= 1``: the loop can be at rest there, held by friction (its dead band); above 1
        it cannot.  With the friction compensation: ``|e| / dead_band`` (its only rest offset is motor-side)."""
        e = np.asarray(e, dtype=float)
        if self.friction_compensation:
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(np.abs(e) > 0, np.abs(e) / self.design.dead_band, 0.0)
        T, _, _ = self._rest_maps()
        tau = np.linalg.solve(T, self.tau_op - self.Kp @ e)
        if dof_load is not None:
            tau = tau + np.asarray(dof_load, dtype=float)
        B = self.friction_bound(self.f_op)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(B > 0, np.abs(tau) / np.where(B > 0, B, 1.0), np.where(np.abs(tau) > 0, np.inf, 0.0))

    def terms(self, u) -> dict:
        """All intermediate quantities (``z3``, ``z4``, ``e``, ``V``, ``command``) for inputs ``u``."""
        S, Sp = self.S, self.Sp
        q, v = u["joint_angle"], u["joint_velocity"]
        x, th, w = u["elongation"], u["motor_angle"], u["motor_velocity"]
        P = np.asarray(self.coupling.P(q))
        P_val = _values(P)
        PS = P @ S
        W = self._sharing(P_val)                               # m x k, frozen at the value of q
        e = Sp @ (q - u["joint_angle_reference"])
        ed = Sp @ v
        f = self.springs.force(x)                       # each tendon's own law phi_i
        k1 = self.springs.stiffness(x)
        k2 = self.springs.stiffness_derivative(x)
        xd = self.r_m * w + P @ v
        fd = k1 * xd
        tau = -(PS.T @ f)
        a0 = -self.Kp @ e - self.Kd @ ed
        if self.link_torque_estimate:                          # + d_hat = -friction_compensation ((9.2) observer)
            tau = tau - u["friction_compensation"]
            if self.friction_compensation:                     # (9.1): + the estimate, bounded by the frictions
                bound = self.friction_bound(f, P)
                a0 = a0 + clip(u["friction_compensation"], -bound, bound)
        edd = self._Minv @ (tau - self.Bq @ ed)                # link model M_d e'' = -(PS)^T f - B_q e' (+ d_hat)
        eddd = self._Minv @ (-(PS.T @ fd) - self.Bq @ edd)
        a1 = -self.Kp @ ed - self.Kd @ edd
        a2 = -self.Kp @ edd - self.Kd @ eddd
        # (15.88) at the current pose: -(P S)^T f_des = tau_op + a0 (the pretension's own torque -(P S)^T f_op moves
        # with q where P does, the thumb base; zero change on the constant-coupling fingers)
        f_des = self.f_op + W @ (a0 + self.tau_op + PS.T @ self.f_op)
        wd0 = (self.friction_scale * motor_friction_torque(w, self.motor) + motor_ripple_torque(th, self.motor)
               - self.r_m * f) / self.B
        f0 = k2 * xd * xd + k1 * self.r_m * wd0
        if self.link_feedforward:                              # the exact design: phi' P qdd of the link model
            f0 = f0 + k1 * (P @ (S @ edd))
        g = k1 * self.r_m / self.B
        K3, K4 = self.K3, self.K4
        if self.variant == "nonlinear-spring":           # 15.4 steps on the joint torques, null space at f_op
            K3, K4 = K3[0], K4[0]
            z3 = tau - (self.tau_op + a0)
            beta = a1 - K3 * z3 - ed
            taud = -(PS.T @ fd)
            z4 = taud - beta
            beta_d = a2 - K3 * (taud - a1) - edd
            Pi = np.eye(W.shape[0]) + W @ _values(PS).T              # projector on the null space of (P S)^T
            d = f - self.f_op
            f2_des = W @ (beta_d - z3 - K4 * z4) - Pi @ (K3 * fd + d + K4 * (fd + K3 * d))
            cmd = (f2_des - f0) / g
            zn3, zn4 = Pi @ d, Pi @ (fd + K3 * d)
            V = (0.5 * (ed @ (self.M @ ed)) + 0.5 * (e @ (self.Kp @ e)) + 0.5 * (z3 @ z3) + 0.5 * (z4 @ z4)
                 + 0.5 * (zn3 @ zn3) + 0.5 * (zn4 @ zn4))
            return dict(e=e, ed=ed, z3=z3, z4=z4, null_z3=zn3, null_z4=zn4, f_des=f_des, V=V, command=cmd)
        if self.variant == "position":                    # 15.2 steps on the link: z2 = e' + k1 e
            z2 = ed + self.K1 @ e
            cross, cross_d = PS @ z2, PS @ (edd + self.K1 @ ed)
        else:
            cross, cross_d = PS @ ed, PS @ edd
        z3 = f - f_des
        beta = W @ a1 - K3 * z3 + cross
        z4 = fd - beta
        beta_d = W @ a2 - K3 * (fd - W @ a1) + cross_d
        cmd = (beta_d - f0 - z3 - K4 * z4) / g
        if self.variant == "position":
            V = 0.5 * (e @ (self.M @ e)) + 0.5 * (z2 @ (self.M @ z2)) + 0.5 * (z3 @ z3) + 0.5 * (z4 @ z4)
            return dict(e=e, ed=ed, z2=z2, z3=z3, z4=z4, f_des=f_des, V=V, command=cmd)
        else:
            V = 0.5 * (ed @ (self.M @ ed)) + 0.5 * (e @ (self.Kp @ e)) + 0.5 * (z3 @ z3) + 0.5 * (z4 @ z4)
        return dict(e=e, ed=ed, z3=z3, z4=z4, f_des=f_des, V=V, command=cmd)

    def __call__(self, u):
        if self.variant == "antagonistic" and float_inputs(u, self.inputs):
            fast = self.__dict__.get("_fast")
            if fast is None:
                fast = self._fast = self._fast_path()
            if fast:
                return self._compiled_call(u, *fast)
        return self.terms(u)["command"]

    def _fast_path(self):
        """The compiled float path (:mod:`awiwi_drake.control.compiled`, ``backstepping``): polynomial springs
        only (each tendon's coefficient rows); ``()`` when a law is not polynomial."""
        laws = self.springs.laws
        if not all(isinstance(law, PolynomialSpring) for law in laws):
            return ()
        deg = max(law.coefficients.size for law in laws)
        rows = np.zeros((3, len(laws), deg))
        for i, law in enumerate(laws):
            c = law.coefficients
            kk = np.arange(2, c.size + 1)
            rows[0, i, :c.size], rows[1, i, :c.size], rows[2, i, :c.size - 1] = c, law._k, c[1:] * kk * (kk - 1)
        xmax = np.array([law.max_elongation for law in laws], dtype=float)
        kend = np.array([law._k_end for law in laws], dtype=float)
        (C, mu_alpha), (beta, z0), hold = self.friction_levels
        hold = np.zeros(self.S.shape[1]) if hold is None else hold
        levels = tuple(np.ascontiguousarray(a, dtype=float) for a in (C, np.exp(mu_alpha) - 1.0, beta, z0, hold))
        return (motor_law_kernels(self.motor)["backstepping"], rows[0], rows[1], rows[2], xmax, kend,
                np.empty(len(laws)), levels, np.zeros(self.S.shape[1]))

    def _compiled_call(self, u, fn, coef, dcoef, ddcoef, xmax, kend, out, levels, no_estimate):
        q = u["joint_angle"]
        P = np.asarray(self.coupling.P(q), dtype=float)
        W = self._sharing(P, fast=True)
        fc = u["friction_compensation"] if self.link_torque_estimate else no_estimate
        return fn(q, u["joint_velocity"], u["joint_angle_reference"], u["elongation"], u["motor_angle"],
                  u["motor_velocity"], P, self.S, self.Sp, W, self._Minv, self.Bq, self.Kp, self.Kd, self.K3, self.K4,
                  self.f_op, self.tau_op, self.r_m, self.B, self.friction_scale, coef, dcoef, ddcoef, xmax, kend,
                  self.link_feedforward, fc, self.link_torque_estimate, self.friction_compensation, *levels,
                  out).copy()

    def _sharing(self, P_val, fast: bool = False):
        """``W = -((P S)^T)^+`` (m x k), block by finger, frozen at the value of ``P``.  ``fast``: a varying block of
        full column rank as ``-(P S) ((P S)^T (P S))^-1`` (the same matrix; no SVD), else the pseudo-inverse."""
        S = self.S
        W = np.zeros((P_val.shape[0], S.shape[1]))
        for ts, js, ds, W_f in self._blocks:
            if W_f is None:
                A = P_val[ts, js] @ S[js, ds]
                G = A.T @ A
                W_f = None
                if fast:
                    try:
                        W_f = -np.linalg.solve(G, A.T).T
                    except np.linalg.LinAlgError:      # rank lost: the pseudo-inverse
                        pass
                if W_f is None:
                    W_f = -np.linalg.pinv(A.T)
            W[ts, ds] = W_f
        return W


def finger_backstepping_controller(rig: Any, params: HandChainParams | None = None, *, op: Any = None,
                                   rate_hz: float | None = 3000.0, variant: str = "antagonistic",
                                   load_observer: FrictionObserverParams | None = None,
                                   friction_observer: FrictionObserverParams | None = None):
    """Registered factories ``backstepping`` (``variant="antagonistic"``), ``backstepping-position`` and
    ``backstepping-nonlinear-spring`` for fingers and the hand (see the module docstring); ``rate_hz`` is the control
    rate the joint gains are designed for (the registry's 3 kHz).  ``load_observer``: add the (9.2) observer per DoF
    (:class:`ObservedBacksteppingController`), whose estimate of the link-side torque enters the law's link model.
    ``friction_observer`` (registered ``backstepping-friction-observer``; ``NAME:no-observer`` sets it to None, as for
    the chain controllers): the same observer, and its estimate, bounded by the frictions, also added to the desired
    joint torque ((9.1), ``FingerBacksteppingLaw(friction_compensation=True)``)."""
    check_backstepping_springs(rig)
    for name, obs in (("load_observer", load_observer), ("friction_observer", friction_observer)):
        if obs is not None and not isinstance(obs, FrictionObserverParams):
            raise TypeError(f"finger_backstepping_controller: {name} = {obs!r} must be None or a "
                            "FrictionObserverParams")
    if load_observer is not None and friction_observer is not None:
        raise ValueError("finger_backstepping_controller: give load_observer (the estimate in the link model) or "
                         "friction_observer (also compensated), not both")
    observer = load_observer if load_observer is not None else friction_observer
    law = FingerBacksteppingLaw(rig, params, op=op, rate_hz=rate_hz, variant=variant,
                                link_torque_estimate=observer is not None,
                                friction_compensation=friction_observer is not None)
    if variant != "antagonistic":
        law.name = f"finger_backstepping_{variant.replace('-', '_')}"
    if observer is None:
        return StaticLawController(law)
    # the design's slowest mode counts the observer's rest mode on the guides' presliding (the chain's designs do
    # the same, JointDesign.loop): compare's derived step window
    Kg = guide_presliding_stiffness(rig, law.design, full=True)
    rest = law.observer_rest_modes(observer.gain, Kg)
    law.design.observer_rest_modes = rest
    law.design.time_constant = max(law.design.time_constant, float(1.0 / np.min(-rest.real)))
    return ObservedBacksteppingController(rig, law, observer)


class ObservedBacksteppingController(Diagram):
    """The finger backstepping law with the link-side torque of its link model estimated by the joint observer (9.2)
    per DoF (:class:`~awiwi_drake.control.joint_stage.JointFrictionObserver_`, the one place of the observer):
    ``M_d e'' = -(P S)^T f - B_q e' + d_hat`` (module docstring).  The observer reads the spring sensors' tendon forces
    ``phi_i(x_i)`` (the law's own ``f``, a :class:`~awiwi_drake.components.spring.SpringBank_` on ``elongation``) and
    uses the whole ``M_d`` (a diagonal one would count the off-diagonal inertial torques into ``d_hat``).  Inputs: the
    law's measurements; outputs ``motor_torque``, ``friction_compensation`` (``-d_hat``, unclipped) and, with the law's
    ``friction_compensation``, ``friction_compensation_bound`` (:class:`FrictionBound_`); state: the observer's
    ``w_hat``, sampled at the law's ``rate_hz`` (continuous for a continuous design; closed as blocks, not fused)."""

    def __init__(self, rig: Any, law: FingerBacksteppingLaw, observer: FrictionObserverParams):
        super().__init__()
        b = DiagramBuilder()
        ctrl = b.AddNamedSystem("law", StaticLawController(law))
        # sampled at the law's design rate, as the chain's (pole 1 - L h); continuous with a continuous design
        obs = b.AddNamedSystem("load_observer", JointFrictionObserver(
            rig.coupling, law.S, law.M, np.diag(law.Bq), observer.gain,
            None if law.rate_hz is None else 1.0 / law.rate_hz))
        # the observer's joint torque from the law's own tendon forces phi_i(x_i) (the spring sensors; class docstring)
        sensed = b.AddNamedSystem("sensed_tendon_force", SpringBank(law.springs, len(law.springs)))
        b.Connect(sensed.GetOutputPort("tendon_force"), obs.GetInputPort("tendon_force"))
        b.Connect(obs.GetOutputPort("friction_compensation"), ctrl.GetInputPort("friction_compensation"))
        exported = {}
        for sys_ in (ctrl, obs, sensed):
            for i in range(sys_.num_input_ports()):
                port = sys_.get_input_port(i)
                nm = port.get_name()
                if nm == "friction_compensation" or (sys_ is obs and nm == "tendon_force"):
                    continue
                if nm in exported:
                    b.ConnectInput(exported[nm], port)
                else:
                    exported[nm] = b.ExportInput(port, nm)
        if law.friction_compensation:          # compare's "observer at friction bound": the estimate beyond B
            bound = b.AddNamedSystem("friction_bound", FrictionBound(law))
            b.Connect(sensed.GetOutputPort("tendon_force"), bound.GetInputPort("tendon_force"))
            b.ConnectInput(exported["joint_angle"], bound.GetInputPort("joint_angle"))
            b.ExportOutput(bound.get_output_port(0), "friction_compensation_bound")
        b.ExportOutput(ctrl.get_output_port(0), "motor_torque")
        b.ExportOutput(obs.GetOutputPort("friction_compensation"), "friction_compensation")
        b.BuildInto(self)
        self.set_name(law.name + "_observed")
        self.law, self.design, self._observer = law, law.design, obs

    def initialize_state(self, context, rig_state=None) -> None:
        """Start the observer at the joints' velocity in ``rig_state`` (0 at rest)."""
        n = self._observer.S.shape[0]
        self._observer.initialize(self.GetMutableSubsystemContext(self._observer, context),
                                  None if rig_state is None else np.asarray(rig_state, float)[n:2 * n])


@TemplateSystem.define("FrictionBound_", scope=sys.modules[__name__])
def FrictionBound_(T):
    """``friction_compensation_bound`` (k) [Nm]: :meth:`FingerBacksteppingLaw.friction_bound` of ``law`` at the sensed
    ``tendon_force`` (m) and ``P(joint_angle)`` (n), the torque the guides' friction and the lever's hysteresis can
    hold per DoF (compare flags a DoF whose observer estimate ends beyond it: a load the compensation leaves to the
    impedance)."""

    class Impl(LeafSystem_[T]):
        def _construct(self, law, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.law = law
            n, k = law.S.shape
            self._q = self.DeclareVectorInputPort("joint_angle", n)
            self._f = self.DeclareVectorInputPort("tendon_force", law.f_op.size)
            self.DeclareVectorOutputPort("friction_compensation_bound", k, self._calc,
                                         prerequisites_of_calc={self._q.ticket(), self._f.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.law, converter=converter)

        def _calc(self, context, out):
            q = self._q.Eval(context)
            out.SetFromVector(self.law.friction_bound(self._f.Eval(context), self.law.coupling.P(q)))

    return Impl


FrictionBound = FrictionBound_[None]


def link_friction_levels(rig: Any, selection) -> tuple:
    """``((C, mu alpha), (beta, z0), hold)``: the rig's guide friction levels (4.1)/capstan (m each,
    :func:`~awiwi_drake.control.chain.guide_friction_levels`), its lever hysteresis half-width ``beta f + z0``
    per tendon (Fig 4.8b, :class:`~awiwi_drake.parameters.components.HysteresisParams`; zeros when off) and what its
    joints' breakaway levels (:func:`~awiwi_drake.control.chain.joint_friction_levels`) hold on the DoF of
    ``selection`` (k, :func:`~awiwi_drake.components.friction.joint_breakaway_bound`, once; None when off)."""
    m = rig.coupling.num_tendons
    drive = getattr(rig, "drive", None)
    h = None if drive is None else drive.model.hysteresis
    hs = h if isinstance(h, tuple) else (h,) * m
    on = np.array([x is not None and x.enabled for x in hs], dtype=float)
    beta = on * np.array([0.0 if x is None else x.width_ratio for x in hs])
    z0 = on * np.array([0.0 if x is None else x.width_offset for x in hs])
    return guide_friction_levels(rig), (beta, z0), joint_breakaway_bound(joint_friction_levels(rig), selection)


def check_backstepping_springs(rig: Any) -> None:
    """Raise unless every tendon's spring law is strictly increasing (phi' > 0, section 15.4)."""
    for law in rig_springs(rig).laws:
        if not (np.all(np.asarray(law.stiffness(np.linspace(1e-4, 5e-3, 5))) > 0)):
            raise ValueError("finger backstepping needs strictly increasing springs (phi' > 0, section 15.4)")
