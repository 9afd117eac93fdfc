"""State-dependent Riccati equation control (ch. 14).

The pointwise-linear form ``xdot = A(x) x + B(x) u`` of (14.3) is taken as the
Jacobian of the rig dynamics at the current measured state, evaluated with
Drake's automatic differentiation of the rig diagram (:class:`RigJacobian`);
this is the linearisation w.r.t. the motor position of (14.8) for the tendon
and the stiffness factorisation (14.10) with the local (tangent) stiffness for
the flexible joint.  The gain ``K = R^-1 B^T S`` ((14.4)-(14.5), Drake's
``LinearQuadraticRegulator``) is recomputed at ``update_rate`` (~200 Hz,
section 14.4) and held in the controller's discrete state; between updates
the law is ``u = u_ref(r) - K (x - x_ref(r))``.  At the linearisation point
the SDRE gain equals the LQR gain (tested).

With ``update_rate=None`` the gain stays at its design value: the fixed-gain
LQR comparator of Fig 14.3-14.5.

Two pointwise-linear forms (``params.factorisation``):

* ``"jacobian"`` (default): the tangent of the whole rig at the measured state
  (:class:`RigJacobian`).  For the tendon rig this includes the slope of the (3.8)
  motor friction, ``-(gamma1 gamma2 / (1 + (gamma1 w)^2) + gamma3) / B`` in ``A[1, 1]``:
  5.6 Nm s/rad at rest, ~0 at speed, which is what moves K_omega (6.0 at rest ->
  10.2 in motion with Table 14.1), not the spring stiffness.
* ``"printed"``: (14.9) for the tendon (``A = [[0, 1], [-r_m alpha(theta) / B, 0]]``,
  ``B = [0, 1/B]``, alpha = df/dtheta of the spring at the measured motor angle, no
  friction) and (14.10) for the flexible joint with the *secant* stiffness
  ``k(x1 - x3) = tau_s(x3 - x1) / (x3 - x1)`` (so that ``A(x) x`` is the spring torque
  exactly), link/motor damping as in (12.8): :class:`PrintedJointFactorisation` with Drake's LQR (:class:`LqrGain`).

The tendon SDRE is one law, :class:`TendonSdreLaw` (and its compiled float twin ``sdre_law``), for the tendon rig
and the hand: the rig's ``tendon-sdre`` is that law for one tendon whose state is its motor angle, with the
printed gains in closed form or the Jacobian form's gain source; the joints' SDRE is :class:`SdreController` on the
linearised reference model.

For the hand's chain (ch. 7-11 with "SDRE ch. 14" as the per-tendon force law) the tendon SDRE is one bank for
all m tendons (:class:`TendonSdreLaw`, held gains in :class:`TendonSdreController_` or the fused chain): each
tendon's 2-state pointwise-linear model (14.9) has the closed-form Riccati solution :func:`tendon_sdre_gains`
(tested equal to Drake's ``LinearQuadraticRegulator``), so the 200 Hz re-solve is a few numpy operations.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, InitializeAutoDiff
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import clip, is_float, scalar_value
from awiwi_drake.control.base import COMMAND_PORT, REFERENCE_SUFFIX, StaticLaw, check_gain, check_gains
from awiwi_drake.analysis.linear import linearize, lqr_gain
from awiwi_drake.control.linear import LinearReferenceModel
from awiwi_drake.control.lqr import expand_q
from awiwi_drake.control.compiled import float_inputs, motor_law_kernels
from awiwi_drake.control.tendon_force import interp
from awiwi_drake.parameters.control import SdreJointParams, SdreTendonParams

__all__ = ["RigJacobian", "LqrGain", "PrintedJointFactorisation", "SdreController_", "SdreController",
           "tendon_sdre_controller", "joint_sdre_controller", "tendon_sdre_gains", "TendonSdreLaw",
           "TendonSdreController_", "TendonSdreController", "SDRE_GAIN"]

#: the held gains of the tendon SDRE bank: ``[K_theta (m), K_omega (m)]`` (a state, not a measurement)
SDRE_GAIN = "tendon_sdre_gain"


class RigJacobian:
    """``(A, B)`` of a rig's continuous dynamics w.r.t. (state, motor_torque) by Drake autodiff."""

    def __init__(self, rig: Any):
        self.diagram = rig.diagram.ToAutoDiffXd()
        self.context = self.diagram.CreateDefaultContext()
        self.n = self.context.num_continuous_states()
        self.port = self.diagram.GetInputPort(COMMAND_PORT)
        self.m = self.port.size()
        self._others = [self.diagram.get_input_port(i) for i in range(self.diagram.num_input_ports())
                        if self.diagram.get_input_port(i).get_name() != COMMAND_PORT]

    def __call__(self, x, u, external: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        n = self.n
        xu = InitializeAutoDiff(np.concatenate([np.asarray(x, float).reshape(-1), np.asarray(u, float).reshape(-1)]))
        xu = xu.reshape(-1)
        self.context.SetContinuousState(xu[:n])
        self.port.FixValue(self.context, xu[n:])
        for p in self._others:
            p.FixValue(self.context, np.array([AutoDiffXd(float(external))] * p.size()))
        xdot = self.diagram.EvalTimeDerivatives(self.context).CopyToVector()
        J = ExtractGradient(xdot)
        return J[:, :n], J[:, n:]


class PrintedJointFactorisation:
    """(14.10): the flexible joint's ``A(x)`` with the secant stiffness ``k(x1 - x3)``.

    ``k = tau_s(delta) / delta``, ``delta = theta - q`` (tangent ``tau_s'(0)`` at ``delta = 0``), so
    ``A(x) x`` equals the spring torques exactly; ``d_q``, ``d_theta``, ``m``, ``b`` from the rig's
    parameters.  Only for ``flexible_joint_rig`` (state ``[q, qd, theta, thetad]``, (12.8)).
    """

    def __init__(self, rig: Any):
        if getattr(rig, "name", None) != "flexible-joint":
            raise ValueError(f"sdre factorisation 'printed' (14.10) needs the flexible_joint_rig; rig "
                             f"{getattr(rig, 'name', '?')!r} is not a 4-state flexible joint (use 'jacobian')")
        p = rig.params
        self.spring, self.m_, self.b = rig.spring, p.link_inertia, p.motor_inertia
        self.d_q, self.d_th = p.link_damping, p.motor_damping
        self.n, self.m = 4, 1

    def stiffness(self, x) -> float:
        """Secant stiffness ``tau_s(delta) / delta`` [Nm/rad] at state ``x``."""
        x = np.asarray(x, float).reshape(-1)
        delta = x[2] - x[0]
        if abs(delta) < 1e-9:
            return float(np.ravel(self.spring.stiffness(np.array([delta])))[0])
        return float(np.ravel(self.spring.force(np.array([delta])))[0]) / delta

    def __call__(self, x, u, external: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        k, m, b = self.stiffness(x), self.m_, self.b
        A = np.array([[0.0, 1.0, 0.0, 0.0], [-k / m, -self.d_q / m, k / m, 0.0],
                      [0.0, 0.0, 0.0, 1.0], [k / b, 0.0, -k / b, -self.d_th / b]])
        return A, np.array([[0.0], [0.0], [0.0], [1.0 / b]])


class LqrGain:
    """The SDRE gain ``K(x, u)`` from a pointwise-linear form ``(A, B) = form(x, u)`` (:class:`RigJacobian`,
    :class:`PrintedJointFactorisation`) by Drake's ``LinearQuadraticRegulator`` ((14.4)-(14.5))."""

    def __init__(self, form: Any, Q, R, owner: str):
        self.form = form
        self.Q = check_gains("Q", Q, owner=owner)
        self.R = np.atleast_2d(check_gains("R", R, owner=owner))

    def __call__(self, x, u) -> np.ndarray:
        return lqr_gain(*self.form(x, u), self.Q, self.R)[0]


@TemplateSystem.define("SdreController_", scope=sys.modules[__name__], T_list=[float, AutoDiffXd])
def SdreController_(T):
    """SDRE state feedback with the gain held in discrete state, refreshed periodically."""

    class Impl(LeafSystem_[T]):
        def _construct(self, model, gain, update_period: float | None, K0, name: str = "sdre", converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.model, self.gain, self.name_ = model, gain, name
            if update_period is not None:
                check_gain("update_period", update_period, owner=name)
            self.update_period = update_period
            self.K0 = np.atleast_2d(check_gains("K0", K0, owner=name))
            m, n = self.K0.shape
            self.m, self.n = m, n
            self._ports = {nm: self.DeclareVectorInputPort(nm, sz) for nm, sz in model.inputs.items()}
            self.gain_index = self.DeclareDiscreteState(self.K0.reshape(-1))
            tickets = {p.ticket() for p in self._ports.values()} | {self.discrete_state_ticket(self.gain_index)}
            self.DeclareVectorOutputPort(COMMAND_PORT, m, self._calc, prerequisites_of_calc=tickets)
            self.DeclareStateOutputPort("gain", self.gain_index)
            if update_period is not None:
                self.DeclarePeriodicDiscreteUpdateEvent(update_period, 0.0, self._update)
            self.set_name(name)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.model, other.gain, other.update_period, other.K0, other.name_,
                            converter=converter)

        def _values(self, context):
            return {nm: p.Eval(context) for nm, p in self._ports.items()}

        def gain_at(self, x, u) -> np.ndarray:
            """The SDRE gain at state ``x`` with input ``u`` (float)."""
            return np.atleast_2d(self.gain(x, u))

        def _update(self, context, discrete_state):
            vals = self._values(context)
            x = self.model.state(vals)
            r = vals[self.model.reference + REFERENCE_SUFFIX][0]
            _, u_ref = self.model.equilibrium(r)
            xf = np.array([v if is_float(v) else v.value() for v in np.asarray(x).reshape(-1)], float)
            uf = np.array([v if is_float(v) else v.value() for v in np.asarray(u_ref).reshape(-1)], float)
            K = self.gain_at(xf, uf)
            k = K.reshape(-1)
            if T != float:
                k = np.array([AutoDiffXd(float(v)) for v in k], dtype=object)
            discrete_state.set_value(self.gain_index, k)

        def _calc(self, context, output):
            vals = self._values(context)
            K = context.get_discrete_state(self.gain_index).CopyToVector().reshape(self.m, self.n)
            x = self.model.state(vals)
            r = vals[self.model.reference + REFERENCE_SUFFIX][0]
            x_ref, u_ref = self.model.equilibrium(r)
            output.SetFromVector(np.asarray(u_ref - K @ (x - x_ref)).reshape(-1))

    return Impl


SdreController = SdreController_[None]


def tendon_sdre_controller(rig: Any, params: SdreTendonParams | None = None, *, design_force: float = 30.0,
                           fixed: bool = False, fmap=None):
    """Registered factory ``tendon-sdre`` (Table 14.1): the bank's law (:class:`TendonSdreLaw`) for the rig's one
    tendon, whose state is its motor angle (the far end is fixed, (14.9)), no feed-forward; gains of
    ``params.factorisation`` ("printed": (14.9) in closed form at the map's force at the measured angle; "jacobian":
    Drake's LQR of the rig's autodiff Jacobian at ``[theta, omega]``, its friction slope included); ``fixed=True``:
    the gains frozen at ``design_force`` (the LQR)."""
    from awiwi_drake.control.tendon_force import _motor, force_map
    p = params or SdreTendonParams()
    jacobian = (LqrGain(RigJacobian(rig), np.diag(p.q_diag), np.array([[p.r]]), "tendon sdre")
                if p.factorisation == "jacobian" else None)
    law = TendonSdreLaw([fmap or force_map(rig)], _motor(rig), q_diag=p.q_diag, r=p.r, design_forces=[design_force],
                        update_period=None if fixed else 1.0 / p.update_rate, friction_scale=0.0,
                        state="motor_angle", jacobian=jacobian, name="tendon_lqr_fixed" if fixed else "tendon_sdre")
    return TendonSdreController(law)


def joint_sdre_controller(rig: Any, params: SdreJointParams | None = None, *, op: Any = None, fixed: bool = False):
    """Registered factory ``sdre`` for the joint rigs (Table 14.2); ``fixed=True``: LQR at ``op``."""
    p = params or SdreJointParams()
    lin = linearize(rig, op, outputs=("state", "joint_angle"))
    model = LinearReferenceModel(lin)
    n, m = lin.B.shape
    gain = LqrGain(RigJacobian(rig) if p.factorisation == "jacobian" else PrintedJointFactorisation(rig),
                   expand_q(p.q_diag, n), p.r * np.eye(m), "sdre")
    K0 = gain(lin.x0, lin.u0) if p.factorisation == "printed" else lqr_gain(lin.A, lin.B, gain.Q, gain.R)[0]
    return SdreController(model, gain, None if fixed else 1.0 / p.update_rate, K0,
                          "joint_lqr_fixed" if fixed else "sdre")


def tendon_sdre_gains(stiffness, inertia, q_diag, r, damping=0.0) -> tuple[np.ndarray, np.ndarray]:
    """The LQR gains ``(K_theta, K_omega)`` of each tendon's pointwise-linear model, in closed form (vectorised).

    Model (14.9) with an optional viscous slope: ``x = [theta - theta_0, omega]``,
    ``A = [[0, 1], [-s / B, -d / B]]``, ``B_u = [0, 1 / B]``, with ``s = r_m alpha`` [Nm/rad] the load torque's slope
    (``alpha = df/dtheta`` of the tendon at its state), ``d`` [Nm s/rad] the friction's slope (0: (14.9) as
    printed), ``B`` the motor inertia; cost ``Q = diag(q_theta, q_omega)``, ``R = r``.  With ``a = s / B``,
    ``c = 1 / (B^2 r)`` the Riccati equation (14.5) ``A^T P + P A - P B_u R^-1 B_u^T P + Q = 0`` reads, entry by
    entry (``P = [[p1, p2], [p2, p3]]``): ``c p2^2 + 2 a p2 - q_theta = 0`` and
    ``c p3^2 + 2 (d / B) p3 - (2 p2 + q_omega) = 0``, whose positive roots give the stabilising ``P`` and
    ``K = R^-1 B_u^T P = [p2, p3] / (B r)``::

        K_theta = B (sqrt(a^2 + c q_theta) - a),   K_omega = B (sqrt((d/B)^2 + c (2 p2 + q_omega)) - d/B).

    The closed loop is ``s^2 + sqrt((d/B)^2 + c (2 p2 + q_omega)) s + sqrt(a^2 + c q_theta)``.  Arrays broadcast
    (one entry per tendon); float only (the gains are held as constants).
    """
    b = float(inertia)
    q_t, q_w = (float(v) for v in q_diag)
    if not (b > 0 and r > 0 and q_t > 0 and q_w >= 0):
        raise ValueError(f"tendon_sdre_gains: needs inertia > 0, r > 0, q_theta > 0, q_omega >= 0 "
                         f"(got {b}, {r}, {q_t}, {q_w})")
    a = np.asarray(stiffness, dtype=float) / b
    dd = np.asarray(damping, dtype=float) / b
    c = 1.0 / (b * b * float(r))
    p2 = (np.sqrt(a * a + c * q_t) - a) / c
    return b * c * p2, b * (np.sqrt(dd * dd + c * (2.0 * p2 + q_w)) - dd)


class TendonSdreLaw(StaticLaw):
    """The SDRE tendon force law (ch. 14, (14.7)-(14.9)) for a bank of ``size`` tendons, with held gains.

    Per tendon ``i`` (its own spring curve through its :class:`~awiwi_drake.control.tendon_force.ForceMap`, the
    motor's inertia ``B`` and pulley radius ``r_m``)::

        u_i = r_m f_ref,i - K_theta,i (theta_i(f_i) - theta_i(f_ref,i)) - K_omega,i omega_el,i
              - s_f tau_fric(omega_i) - s_r tau_ripple(theta_motor,i)

    ``r_m f_ref`` is (14.8)'s feed-forward ``u = f_t(theta_0) + v`` at the reference's equilibrium; the state error is
    (14.9)'s ``xi = theta - theta_0`` "linearised w.r.t. the tendon forces" (section 14.2.1): ``theta_i(f)`` the
    map's motor angle holding ``f`` with the far end fixed (a measured force below 0 is the slack point, above the
    table its top), so that on a finger the joints' share of the elongation is in it (``state="tendon_force"``);
    on a tendon whose far end is fixed (the tendon rig, ``state="motor_angle"``) the state angle is the measured
    motor angle itself (also when slack or beyond the table); ``omega_el = omega +
    v_path / r_m`` (``path_velocity``: the rate of ``r_m theta + h(q)``, as :class:`TendonForceLaw`).  Friction (3.8)
    and ripple (3.5) are fed forward with the fractions ``friction_scale``, ``ripple_scale``.

    The gains ``[K_theta, K_omega]`` are an input (``SDRE_GAIN``, 2 ``size``), held by the system that owns the law
    (:class:`TendonSdreController_`, or the fused chain); :meth:`gains_at` re-solves them at the measured inputs
    ``gain_inputs``: the pointwise-linear model (14.9) of each tendon at its state's force (the measured force, or
    the map's force at the measured motor angle, 0 when slack), ``alpha_i(f_i)``, no friction (the law feeds the
    friction model forward, so the compensated plant is (14.9) up to the fraction ``1 - friction_scale``), in closed
    form (:meth:`gains`, :func:`tendon_sdre_gains`); or, given ``jacobian`` (one tendon, ``state="motor_angle"``), that
    gain source ``K(x, u_ref)`` (1 x 2) at ``x = [theta, omega]``, ``u_ref = r_m f_ref`` (the rig's Jacobian form,
    :class:`LqrGain` of :class:`RigJacobian`).  ``update_period``: the re-solve period (section 14.4: ~200 Hz), None
    for gains fixed at ``design_forces`` (the SDRE's own linearisation at that equilibrium: the LQR).
    """

    def __init__(self, fmaps, motor: Any, *, q_diag, r: float, design_forces, update_period: float | None,
                 friction_scale: float = 1.0, ripple_scale: float = 0.0, path_velocity: bool = False,
                 state: str = "tendon_force", jacobian=None, name: str = "tendon_sdre"):
        from awiwi_drake.control.tendon_force import ForceMap
        self.name = name
        self.fmaps = tuple(fmaps)
        m = len(self.fmaps)
        if m < 1 or not all(isinstance(fm, ForceMap) for fm in self.fmaps):
            raise ValueError(f"{name}: fmaps must be one ForceMap per tendon")
        groups: dict = {}
        for i, fm in enumerate(self.fmaps):
            groups.setdefault(id(fm), (fm, []))[1].append(i)
        self._groups = [(fm, np.array(ix)) for fm, ix in groups.values()]
        self.motor, self.q_diag, self.r = motor, tuple(float(v) for v in q_diag), float(r)
        self.inertia = check_gain("inertia", motor.inertia, owner=name)
        self.r_m = check_gain("pulley_radius", motor.pulley_radius, owner=name)
        self.friction_scale = check_gain("friction_scale", friction_scale, allow_zero=True, owner=name)
        self.ripple_scale = check_gain("ripple_scale", ripple_scale, allow_zero=True, owner=name)
        if update_period is not None:
            check_gain("update_period", update_period, owner=name)
        self.update_period = update_period
        self.gain_name = SDRE_GAIN
        self.path_velocity = bool(path_velocity)
        if state not in ("tendon_force", "motor_angle"):
            raise ValueError(f"{name}: state must be 'tendon_force' or 'motor_angle', got {state!r}")
        if jacobian is not None and (state != "motor_angle" or m != 1):
            raise ValueError(f"{name}: a jacobian gain source needs one tendon with state='motor_angle'")
        self.state, self.jacobian = state, jacobian
        self.inputs = {"tendon_force_reference": m, state: m, "motor_velocity": m}
        if self.ripple_scale > 0:
            self.inputs["motor_angle"] = m
        if self.path_velocity:
            self.inputs["tendon_path_velocity"] = m
        self.output_size = m
        self.gain_inputs = (("tendon_force_reference", "motor_angle", "motor_velocity") if jacobian is not None
                            else (state,))
        f0 = check_gains("design_forces", design_forces, shape=(m,), owner=name)
        th0 = np.zeros(m)
        if state == "motor_angle":                  # the design equilibrium's motor angles
            for fm, ix in self._groups:
                fm.check_force(f0[ix], f"{name}: design_forces")
            th0 = self.angle_of_force(f0, reference=False)
        self.initial_gain = self.gains_at({"tendon_force_reference": f0, "tendon_force": f0, "motor_angle": th0,
                                           "motor_velocity": np.zeros(m)})

    def _by_group(self, fn, f):
        """``fn(fmap, f[ix])`` scattered back by tendon (one call per distinct map)."""
        if len(self._groups) == 1:
            return fn(self._groups[0][0], f)
        out = np.empty(len(f), dtype=float if is_float(f) else object)
        for fm, ix in self._groups:
            out[ix] = fn(fm, f[ix])
        return out

    def slopes(self, f) -> np.ndarray:
        """``alpha_i = df/dtheta`` [N/rad] of each tendon at the measured forces ``f`` (float)."""
        return self._by_group(lambda fm, x: np.asarray(fm.alpha_of_force(x), dtype=float).reshape(-1),
                              np.asarray(f, dtype=float).reshape(-1))

    def gains(self, f) -> np.ndarray:
        """``[K_theta, K_omega]`` (2 m) of the pointwise-linear models (14.9) at the measured forces ``f``."""
        k_t, k_w = tendon_sdre_gains(self.r_m * self.slopes(f), self.inertia, self.q_diag, self.r)
        return np.concatenate([k_t, k_w])

    def gains_at(self, u) -> np.ndarray:
        """``[K_theta, K_omega]`` (2 m) re-solved at the measured float inputs ``u`` (those in ``gain_inputs``)."""
        if self.jacobian is not None:
            x = np.array([u["motor_angle"][0], u["motor_velocity"][0]], dtype=float)
            return np.ravel(self.jacobian(x, self.r_m * np.asarray(u["tendon_force_reference"], dtype=float)))
        if self.state == "tendon_force":
            return self.gains(u["tendon_force"])
        return self.gains(self._by_group(lambda fm, x: np.where(x > fm.slack_angle, fm.force_at(x), 0.0),
                                         np.asarray(u["motor_angle"], dtype=float).reshape(-1)))

    def angle_of_force(self, f, *, reference: bool):
        """Each tendon's motor angle holding ``f`` (far end fixed); ``reference``: ``f`` must lie in its table
        (else :class:`~awiwi_drake.analysis.InfeasibleForceError` naming the tendon), a measurement is clamped to it."""
        f = np.asarray(f) if isinstance(f, np.ndarray) else np.asarray(f, dtype=object)
        if reference:
            for fm, ix in self._groups:
                vals = f[ix]
                try:
                    fm.check_force(vals if vals.size > 1 else vals.reshape(-1), "tendon_force_reference")
                except ValueError:
                    for i in ix:
                        fm.check_force(np.asarray([f[i]]), f"tendon_force_reference[{int(i)}]")

        def one(fm, x):
            if not reference:
                x = clip(x, 0.0, fm.max_force)
            return interp(x, np.concatenate([[0.0], fm.force]), np.concatenate([[fm.slack_angle], fm.theta]))
        return self._by_group(one, f)

    def __call__(self, u):
        if self.output_size > 1 and float_inputs(u, self.inputs) and float_inputs(u, (SDRE_GAIN,)):
            k = self.__dict__.get("_kernel") or self._build_kernel()
            fn, tabs, out = k
            zeros = tabs[-1]
            bad = fn(u["tendon_force_reference"], u.get("tendon_force", zeros), u["motor_velocity"],
                     u.get("motor_angle", zeros), u["tendon_path_velocity"] if self.path_velocity else zeros,
                     u[SDRE_GAIN], *tabs[:-1], self.path_velocity, self.state == "motor_angle", self.friction_scale,
                     self.ripple_scale, self.r_m, out)
            if bad < 0:
                return out.copy()
        return self.evaluate(u)       # AutoDiffXd, or raises naming the tendon

    def _build_kernel(self):
        """The float bank's fast path: ``sdre_law`` of :func:`~awiwi_drake.control.compiled.motor_law_kernels`, one
        compiled call equal to :meth:`evaluate` (tests/test_chain_sdre.py)."""
        group = np.zeros(self.output_size, dtype=np.int64)
        for k, (_, ix) in enumerate(self._groups):
            group[ix] = k
        rows = [(np.concatenate([[0.0], fm.force]), np.concatenate([[fm.slack_angle], fm.theta]))
                for fm, _ in self._groups]
        L = max(r[0].size for r in rows)

        def table(j):
            t = np.zeros((len(rows), L))
            for k, r in enumerate(rows):
                t[k, :r[j].size], t[k, r[j].size:] = r[j], r[j][-1]
            return t
        tabs = (group, np.array([r[0].size for r in rows], dtype=np.int64), table(0), table(1),
                np.array([fm.max_force for fm, _ in self._groups]), np.zeros(self.output_size))
        self._kernel = (motor_law_kernels(self.motor)["sdre_law"], tabs, np.empty(self.output_size))
        return self._kernel

    def evaluate(self, u):
        """The law as written (float, AutoDiffXd); :meth:`__call__` takes a compiled fast path for a float bank."""
        from awiwi_drake.components import motor_friction_torque, motor_ripple_torque
        m = self.output_size
        fd, w = u["tendon_force_reference"], u["motor_velocity"]
        g = u[SDRE_GAIN]
        theta = (u["motor_angle"] if self.state == "motor_angle"
                 else self.angle_of_force(u["tendon_force"], reference=False))
        err = theta - self.angle_of_force(fd, reference=True)
        w_el = w + u["tendon_path_velocity"] / self.r_m if self.path_velocity else w
        tau = self.r_m * fd - g[:m] * err - g[m:] * w_el
        if self.friction_scale > 0:
            tau = tau - self.friction_scale * motor_friction_torque(w, self.motor)
        if self.ripple_scale > 0:
            tau = tau - self.ripple_scale * motor_ripple_torque(u["motor_angle"], self.motor)
        return np.asarray(tau).reshape(-1)


@TemplateSystem.define("TendonSdreController_", scope=sys.modules[__name__], T_list=[float, AutoDiffXd])
def TendonSdreController_(T):
    """A :class:`TendonSdreLaw` bank with its gains held in discrete state, re-solved every ``law.update_period``
    from the measured inputs (:meth:`TendonSdreLaw.gains_at`; ``update_period=None``: constant gains, no state, so
    that a continuous loop stays continuous for ``Linearize``).  Output ``motor_torque``, and the held gains
    ``tendon_sdre_gain`` ``[K_theta (m), K_omega (m)]``."""

    class Impl(LeafSystem_[T]):
        def _construct(self, law: TendonSdreLaw, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.law = law
            self._ports = {nm: self.DeclareVectorInputPort(nm, int(sz)) for nm, sz in law.inputs.items()}
            tickets = {p.ticket() for p in self._ports.values()}
            if law.update_period is not None:      # held and re-solved; else constant (no state: a continuous loop)
                self._xg = self.DeclareDiscreteState(law.initial_gain)
                tickets.add(self.discrete_state_ticket(self._xg))
                self.DeclareStateOutputPort(SDRE_GAIN, self._xg)
                self.DeclarePeriodicDiscreteUpdateEvent(law.update_period, 0.0, self._update)
            else:
                self._xg = None
                self._k = law.initial_gain if T is float else np.array([AutoDiffXd(v) for v in law.initial_gain])
                self.DeclareVectorOutputPort(SDRE_GAIN, self._k.size, lambda c, o: o.SetFromVector(self._k),
                                             prerequisites_of_calc={self.nothing_ticket()})
            self.DeclareVectorOutputPort(COMMAND_PORT, law.output_size, self._calc, prerequisites_of_calc=tickets)
            self.set_name(law.name)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.law, converter=converter)

        def _update(self, context, discrete_state):
            k = self.law.gains_at({nm: np.array([scalar_value(v) for v in self._ports[nm].Eval(context)])
                                   for nm in self.law.gain_inputs})
            discrete_state.set_value(self._xg, k if T is float else np.array([AutoDiffXd(v) for v in k], dtype=object))

        def _calc(self, context, output):
            vals = {nm: p.Eval(context) for nm, p in self._ports.items()}
            vals[SDRE_GAIN] = (self._k if self._xg is None
                               else context.get_discrete_state(self._xg).CopyToVector())
            output.SetFromVector(self.law(vals))

    return Impl


TendonSdreController = TendonSdreController_[None]
