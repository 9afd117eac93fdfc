"""Antagonistic backstepping (thesis 15.5, (15.82)-(15.106)) for a finger or the whole hand.

Section 15.5 keeps the symmetry of the antagonistic joint by letting "the motors not be aware of
one another": the desired link torque is *shared* among the tendons, a pretension is added, and
the backstepping steps on the tendon force are done per tendon; the motor torques come out of the
law directly (no force distribution, no force loop).  Here that construction is written for ``n``
independent DoF and ``m`` tendons with the coupling ``P(q)`` (m x n plant joints) and the DoF
selection ``S`` (``q = S q_d``; ring/fifth: the DIP follows the PIP)::

    e = S^+ (q - q_ref),  e' = S^+ qdot                            DoF errors (references held)
    alpha = tau_op - Kp e - Kd e'                                   (15.54), Kp and Kd k x k
    f_d = f_op + W (alpha - tau_op),  W = -((P S)^T)^+              sharing (15.88): -(PS)^T f_d = alpha
    z3 = f - f_d,  beta = f_d' - K3 z3 + (P S) e',  z4 = f' - beta  (15.90), (15.57)
    u = (beta' - f0 - z3 - K4 z4) / g                               (15.63)

with the tendon force ``f = phi_i(x_i)`` of each tendon's own spring law (``rig.spring_laws``: the
lever mechanism for all, ``params.tendon_springs`` overriding tendons one by one) at its measured
spring elongation ``x_i``, the motor friction
(3.8) compensated by ``HandChainParams.friction_scale`` (ch. 3: under-compensate; 1 = the exact
cancellation of the continuous design), the ripple (3.5) in full, ``f' = phi'(x) x'``, ``f'' = f0 + g u``,
``g = phi'(x) r_m / B`` and ``f0 = phi'' x'^2 + phi' r_m (tau_fric(omega) + tau_ripple(theta) - r_m f) / B``,
where the force steps model the tendon as in ch. 10 ((10.1): fixed at the link end), ``x' = r_m omega``.
The joint accelerations come from the link model ``M_d e'' = -(P S)^T f - B_q e'`` (``M_d = S^T M(q_op) S``,
the DoF inertia matrix at the operating point, ``B_q`` the joint damping; Coriolis terms, second order at
rest, are left out) and their derivative from ``f'``.

``HandChainParams.link_motion_in_force_model=True`` is the exact design: ``x' = r_m omega + P qdot`` and
``f0`` gains ``phi' P S e''``, the tendon force change of the link's modelled motion.  For that model

    V = e'^T M_d e' / 2 + e^T Kp e / 2 + |z3|^2 / 2 + |z4|^2 / 2,   (Kp symmetric positive definite)
    V' = -e'^T (Kd + B_q) e' - K3 |z3|^2 - K4 |z4|^2 <= 0

(the cross term ``e'^T (PS)^T z3`` of the link equation is cancelled by the ``(PS) e'`` in
``beta``), and the linearised loop has exactly the designed error-system poles (tested on the ideal plant).
With one DoF and ``P = [-r_q, r_q]^T`` it is the antagonistic joint of 15.5.  It is not the default,
because on the finger the link's motion is the fastest and least known part of the model (measured with
Drake's ``Linearize``, index, 3 kHz, ZOH):

* the links are light (index DIP ~1e-6 kg m^2): the modelled ``e''`` reacts to every link-side force the
  model lacks with ``M_d^-1 (P S)^T dF``, and ``phi' P S e''`` turns it into motor torque.  The guides'
  friction (4.1) is such a force (at rest a presliding stiffness ``C/delta`` ~5 kN/m per tendon path): the
  continuous loop on the true joint state has a pole at +833 1/s;
* ``P qdot`` comes from the tendon-length estimate, one control period old when the command is sampled
  and differentiated: the sampled loop with the estimator is unstable already without guide friction
  (spectral radius 1.03: a 544 Hz DIP/PIP mode), 1.25 with it (a real mode, the one above).

With the ch. 10 tendon model the link's motion is a disturbance of the force steps, rejected by ``K3``,
``K4``: the sampled loop (the estimator in it) is stable on every finger and the hand, with and without
guide friction (``tests/test_hand_control.py``).  The guide friction then leaves the steady joint offset of a
friction dead band, ``Kp e = -(P S)^T (g + z)`` at rest (``|g_i| <= W_i`` the guides', ``|z_i| <= w_i`` the
lever's friction).  ``terms(u)["V"]`` gives ``V``.

Gains (chosen, 15.5: "the gains have been initially selected to lead to feedback gains for the
tendon force error that is close to the cascaded case"): per tendon ``K3 = K4 = w_f``, so that
the force-error feedback ``(1 + K3 K4) / g ~ w_f^2 B / alpha`` equals the cascaded (10.11) gain at
the same bandwidth (``alpha = r_m phi'``; critically damped). The joint gains are designed on the
modes of the DoF inertia matrix ``M_d = V diag(mu) V^T``: mode i gets the stiffness
``k_i = min(joint_stiffness, mu_i w_max^2)`` and the damping ``2 zeta sqrt(k_i mu_i)``, so
``Kp = V diag(k) V^T``, ``Kd = V diag(d) V^T`` and every mode of ``M_d e'' + Kd e' + Kp e = 0`` has
``|lambda| = sqrt(k_i / mu_i) <= w_max = sampled_pole_limit * rate_hz`` (|h lambda| <= 1/4 at the
control period h = 1/rate_hz): the impedance gain of Fig 15.22 on every mode slow enough to be
sampled, less on the light distal modes (index at 3 kHz: the lightest mode 0.5 -> 0.092 Nm/rad). Why: the
former per-DoF design (``Kd = 2 zeta sqrt(Kp M_jj)`` with the diagonal of ``M_d``) put a pole at
-6838 1/s on the index (h lambda = -2.3 at 3 kHz; sampled spectral radius 1.18: the chatter that had it
registered at 6 kHz). ``rate_hz=None`` designs for continuous time (no limit). ``w_f``, ``zeta`` of
:class:`HandChainParams`.  Unlike the cascade (15.5.3) the joint gain is not limited by the force
loop's bandwidth.

Measurements: ``joint_angle``, ``joint_velocity`` (the tendon-length estimator on the hand),
``elongation`` (the spring sensors), ``motor_angle``, ``motor_velocity``; reference
``joint_angle_reference`` (n plant joints, derivatives taken as zero: a set-point law).
Scalar types float and AutoDiffXd (``W`` is evaluated at the value of ``q``: exact for the
constant-coupling fingers, the thumb base's ``dW/dq`` is not differentiated).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from awiwi_drake.rigs.base import Rig
from awiwi_drake._math import is_float
from awiwi_drake.components import motor_friction_torque, motor_ripple_torque
from awiwi_drake.control.base import StaticLaw, StaticLawController
from awiwi_drake.control.joint_stage import joint_inertia
from awiwi_drake.hand.coupling import dof_selection
from awiwi_drake.parameters.hand_control import HandChainParams

__all__ = ["FingerBacksteppingLaw", "finger_backstepping_controller"]


def _values(a) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype != object:
        return a.astype(float)
    return np.array([float(v.value()) if hasattr(v, "value") else float(v) for v in a.reshape(-1)]).reshape(a.shape)


class FingerBacksteppingLaw(StaticLaw):
    """The law of the module docstring (one call: all DoF and tendons of a finger or the hand)."""

    def __init__(self, rig: Any, params: HandChainParams | None = None, *, op: Any = None,
                 rate_hz: float | None = 3000.0):
        p = params or HandChainParams()
        coupling = rig.coupling if isinstance(rig, Rig) else None
        if coupling is None:
            raise ValueError(f"finger backstepping: rig {getattr(rig, 'name', '?')!r} is not a finger or hand rig")
        op = op or rig.operating_point()
        self.name = "finger_backstepping"
        self.coupling, self.motor = coupling, rig.params.motor
        laws = list(getattr(rig, "spring_laws", None) or [rig.spring] * coupling.num_tendons)
        groups = {}
        for i, law in enumerate(laws):
            groups.setdefault(id(law), (law, []))[1].append(i)
        self._spring_groups = [(law, np.array(ix)) for law, ix in groups.values()]   # tendons sharing a law
        self.S = dof_selection(coupling)
        self.Sp = np.linalg.pinv(self.S)
        n, k = self.S.shape
        m = coupling.num_tendons
        self.r_m, self.B = float(self.motor.pulley_radius), float(self.motor.inertia)
        self.q_op = np.asarray(op.joint_angle, dtype=float)
        self.f_op = np.asarray(op.tendon_force, dtype=float)
        self.tau_op = -(np.asarray(coupling.P(self.q_op), dtype=float) @ self.S).T @ self.f_op
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
        self.K3 = self.K4 = float(wf)
        self.friction_scale = float(p.friction_scale)
        self.link_motion = bool(p.link_motion_in_force_model)
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
        self.output_size = m
        self.design = dict(selection=self.S, inertia=self.M, Kp=self.Kp, Kd=self.Kd, K3=self.K3, K4=self.K4,
                           tendon_force=self.f_op, torque_offset=self.tau_op, link_motion=self.link_motion)

    def terms(self, u) -> dict:
        """All intermediate quantities (``z3``, ``z4``, ``e``, ``V``, ``command``) for inputs ``u``."""
        S, Sp = self.S, self.Sp
        q, v = u["joint_angle"], u["joint_velocity"]
        x, th, w = u["elongation"], u["motor_angle"], u["motor_velocity"]
        P = np.asarray(self.coupling.P(q))
        P_val = _values(P)
        PS = P @ S
        W = np.zeros((P_val.shape[0], S.shape[1]))             # m x k, frozen at the value of q
        for ts, js, ds, W_f in self._blocks:
            W[ts, ds] = W_f if W_f is not None else -np.linalg.pinv((P_val[ts, js] @ S[js, ds]).T)
        e = Sp @ (q - u["joint_angle_reference"])
        ed = Sp @ v
        f = self._springs("force", x)
        k1 = self._springs("stiffness", x)
        k2 = self._springs("stiffness_derivative", x)
        # the elongation rate the force steps model: the motor's (ch. 10, (10.1): tendon fixed at the link end), or
        # with link_motion_in_force_model also the link's P qdot (the exact 15.5 design; see the module docstring)
        xd = self.r_m * w + P @ v if self.link_motion else self.r_m * w
        fd = k1 * xd
        tau = -(PS.T @ f)
        edd = self._Minv @ (tau - self.Bq @ ed)                # link model M_d e'' = -(PS)^T f - B_q e'
        eddd = self._Minv @ (-(PS.T @ fd) - self.Bq @ edd)
        a0 = -self.Kp @ e - self.Kd @ ed
        a1 = -self.Kp @ ed - self.Kd @ edd
        a2 = -self.Kp @ edd - self.Kd @ eddd
        f_des = self.f_op + W @ a0
        z3 = f - f_des
        beta = W @ a1 - self.K3 * z3 + PS @ ed
        z4 = fd - beta
        beta_d = W @ a2 - self.K3 * (fd - W @ a1) + PS @ edd
        wd0 = (self.friction_scale * motor_friction_torque(w, self.motor) + motor_ripple_torque(th, self.motor)
               - self.r_m * f) / self.B
        f0 = k2 * xd * xd + k1 * self.r_m * wd0
        if self.link_motion:                                   # the link model's acceleration: k1 P qdd
            f0 = f0 + k1 * (P @ (S @ edd))
        g = k1 * self.r_m / self.B
        cmd = (beta_d - f0 - z3 - self.K4 * z4) / g
        V = 0.5 * (ed @ (self.M @ ed)) + 0.5 * (e @ (self.Kp @ e)) + 0.5 * (z3 @ z3) + 0.5 * (z4 @ z4)
        return dict(e=e, ed=ed, z3=z3, z4=z4, f_des=f_des, V=V, command=cmd)

    def _springs(self, method: str, x):
        """``law_i.method(x_i)`` with each tendon's own spring law (float or AutoDiffXd arrays)."""
        x = np.asarray(x)
        out = np.empty(x.shape, dtype=x.dtype)
        for law, ix in self._spring_groups:
            out[ix] = np.asarray(getattr(law, method)(x[ix]), dtype=x.dtype)
        return out

    def __call__(self, u):
        return self.terms(u)["command"]


def finger_backstepping_controller(rig: Any, params: HandChainParams | None = None, *, op: Any = None,
                                   rate_hz: float | None = 3000.0):
    """Registered factory ``backstepping`` for fingers and the hand (see the module docstring);
    ``rate_hz`` is the control rate the joint gains are designed for (the registry's 3 kHz)."""
    for law in (getattr(rig, "spring_laws", None) or [rig.spring]):
        if not (np.all(np.asarray(law.stiffness(np.linspace(1e-4, 5e-3, 5))) > 0)):
            raise ValueError("finger backstepping needs strictly increasing springs (phi' > 0, section 15.4)")
    return StaticLawController(FingerBacksteppingLaw(rig, params, op=op, rate_hz=rate_hz))
