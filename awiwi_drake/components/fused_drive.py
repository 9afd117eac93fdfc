"""The tendon drive's model: motors + springs + routing + guide friction + hysteresis.

Its physics is one function, :func:`drive_laws`, calling the law functions of this package (motor,
each tendon's spring, ``coupling.h``/``P``, hysteresis, guide friction), generic in the scalar type.
The rigs (:mod:`awiwi_drake.components.rig_system`), the batched joint rigs (:class:`TendonDriveBatch_`)
and the fingers/hand (:class:`~awiwi_drake.hand.dynamics.HandDynamics_`) evaluate its
:class:`DriveModel`: directly for ``AutoDiffXd`` and ``Expression``, and for ``float`` through numba
kernels traced once from :func:`drive_laws` on symbolic variables (:func:`build_kernels`,
:mod:`awiwi_drake.components.codegen`; tests: kernel = laws at random states to 1e-12).

Model (docs/ARCHITECTURE.md sign convention), per tendon i::

    x_i   = r_m theta_i + h_i(q) - h_i(0) + x0_i              elongation
    f_i   = max(f_el,i(x_i) + z_i, 0)                         spring force (z: hysteresis, Fig 4.8b)
    dz_i  = hysteresis_rate(z_i, x_i, xdot_i, f_el,i)         xdot = r_m omega + P(q) qdot
    dg_i  = guide_friction_rate(g_i, (P(q) qdot)_i, f_i, C_i, mu alpha_i, delta_g)   Dahl state, -> +-W_i sliding
    B thdd_i = sat(u_i) + tau_fric(omega_i) + tau_ripple(theta_i) - r_m f_i      (3.5), (3.8)
    tau   = -P(q)^T (f + g)                                   generalised force on the joints

With ``link_inertia``/``link_damping`` the model also carries the joints as decoupled links
``I_j qdd_j = tau_j - d_j qdot_j + tau_ext,j`` (the single-joint rigs, no MultibodyPlant).  State order:
``[q, qdot]`` (with a link), ``[theta (m), omega (m)]``, then ``z (m)`` with hysteresis, then ``g (m)``
with guide friction.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np
from pydrake.systems.framework import Diagram, LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import asarray_like, is_float, positive_part, symbolic_vector
from awiwi_drake.components.motor import motor_acceleration, motor_drive_torque, saturate_torque
from awiwi_drake.components.spring import TendonSprings, hysteresis_rate
from awiwi_drake.components.friction import guide_friction_force, guide_friction_rate
from awiwi_drake.parameters.components import GuideFrictionParams, HysteresisParams, MotorParams

__all__ = ["GuideFrictionModel", "DriveModel", "TendonDrive", "drive_laws", "build_kernels", "TendonDriveBatch_"]


@dataclass(frozen=True)
class GuideFrictionModel:
    """Guide friction on every tendon path (:func:`~awiwi_drake.components.friction.guide_friction`).

    ``bending_angles`` (m,) [rad]: total wrap of each tendon on its guides; (4.1) or, with ``capstan``, the
    capstan form.  Each tendon's friction force is a Dahl state driven by its sliding speed
    ``v = (P(q) qdot)_i`` (:func:`~awiwi_drake.components.friction.guide_friction_rate`).
    """

    bending_angles: tuple
    params: GuideFrictionParams = field(default_factory=GuideFrictionParams)
    capstan: bool = False
    smoothing_velocity: float = 1e-3
    presliding_length: float = 4e-4
    overrides: tuple = ()       # ((tendon index, constant C [N], capstan exponent mu alpha), ...): own guides

    def levels(self):
        """``(C, mu alpha)`` per tendon (m,): (4.1) at each bending angle, or the capstan exponent, then the
        tendons of :attr:`overrides` with their own two numbers."""
        alpha = np.asarray(self.bending_angles, dtype=float)
        constant = np.zeros_like(alpha) if self.capstan else np.asarray(guide_friction_force(alpha, self.params))
        exponent = self.params.mu * alpha if self.capstan else np.zeros_like(alpha)
        for i, c, e in self.overrides:
            constant[i], exponent[i] = c, e
        return constant, exponent

    def __post_init__(self):
        a = np.asarray(self.bending_angles, dtype=float)
        if a.ndim != 1 or np.any(a < 0) or not np.all(np.isfinite(a)):
            raise ValueError(f"GuideFrictionModel.bending_angles must be finite and >= 0 [rad], got {self.bending_angles}")
        if not self.smoothing_velocity > 0:
            raise ValueError(f"GuideFrictionModel.smoothing_velocity = {self.smoothing_velocity} must be > 0 [m/s]")
        if not self.presliding_length > 0:
            raise ValueError(f"GuideFrictionModel.presliding_length = {self.presliding_length} must be > 0 [m]")


@dataclass(frozen=True, eq=False)
class DriveModel:
    """Everything :func:`drive_laws` needs (see the module docstring).

    ``springs`` holds one spring law per tendon (the same object may repeat); ``rate_joints`` leading
    coupling joints have a velocity, further coupling "joints" (the wrist's length offsets) are quasi-static.
    """

    motor: MotorParams | tuple     # one set for all motors, or one per tendon (motor.tendon_motor_params)
    springs: tuple
    coupling: object
    offsets: np.ndarray
    motor_pulley_radius: float
    hysteresis: HysteresisParams | tuple = field(default_factory=HysteresisParams)   # or one per tendon
    guide_friction: GuideFrictionModel | None = None
    rate_joints: int | None = None
    link_inertia: tuple | None = None
    link_damping: tuple | None = None

    def __post_init__(self):
        m, n = int(self.coupling.num_tendons), int(self.coupling.num_joints)
        if not isinstance(self.motor, MotorParams) and (
                len(self.motor) != m or not all(isinstance(mp, MotorParams) for mp in self.motor)):
            raise ValueError(f"DriveModel: motor must be one MotorParams or one per tendon ({m})")
        if isinstance(self.hysteresis, tuple) and (
                len(self.hysteresis) != m or not all(isinstance(h, HysteresisParams) for h in self.hysteresis)):
            raise ValueError(f"DriveModel: hysteresis must be one HysteresisParams or one per tendon ({m})")
        if len(self.springs) != m:
            raise ValueError(f"DriveModel: springs must hold one spring law per tendon ({m}), got {len(self.springs)}")
        object.__setattr__(self, "laws", TendonSprings(self.springs))    # the one per-tendon evaluation
        off = np.asarray(self.offsets, dtype=float)
        if off.shape != (m,) or not np.all(np.isfinite(off)):
            raise ValueError(f"DriveModel: offsets must be {m} finite numbers [m], got {self.offsets!r}")
        off = off.copy()
        off.setflags(write=False)       # the kernels bake the offsets in (traced once per content): no in-place change
        object.__setattr__(self, "offsets", off)
        if not self.motor_pulley_radius > 0:
            raise ValueError(f"DriveModel: motor_pulley_radius = {self.motor_pulley_radius} must be > 0 [m]")
        nr = n if self.rate_joints is None else int(self.rate_joints)
        if not 0 <= nr <= n:
            raise ValueError(f"DriveModel: rate_joints = {self.rate_joints} must be in [0, {n}]")
        object.__setattr__(self, "rate_joints", nr)
        if self.guide_friction is not None and len(self.guide_friction.bending_angles) != m:
            raise ValueError(f"DriveModel: guide_friction.bending_angles must have {m} entries, "
                             f"got {len(self.guide_friction.bending_angles)}")
        if (self.link_inertia is None) != (self.link_damping is None):
            raise ValueError("DriveModel: give both link_inertia and link_damping, or neither")
        if self.link_inertia is not None:
            li, ld = np.asarray(self.link_inertia, float), np.asarray(self.link_damping, float)
            if li.shape != (n,) or ld.shape != (n,) or np.any(li <= 0) or np.any(ld < 0):
                raise ValueError(f"DriveModel: link_inertia (> 0) and link_damping (>= 0) need {n} entries each")
        object.__setattr__(self, "_h0", np.asarray(self.coupling.h(np.zeros(n)), dtype=float))
        # content key of the kernels (taken now, before any lazily cached attribute of the coupling or
        # the springs changes the pickle): equal models built apart share one trace
        object.__setattr__(self, "_content_key", _content_digest(self))

    # sizes -------------------------------------------------------------------------
    @property
    def num_tendons(self) -> int:
        return int(self.coupling.num_tendons)

    @property
    def num_joints(self) -> int:
        return int(self.coupling.num_joints)

    @property
    def has_link(self) -> bool:
        return self.link_inertia is not None

    @property
    def has_hysteresis(self) -> bool:
        h = self.hysteresis
        return any(x.enabled for x in h) if isinstance(h, tuple) else bool(h.enabled)

    @property
    def has_guide_friction(self) -> bool:
        return self.guide_friction is not None

    @property
    def needs_joint_velocity(self) -> bool:
        return (self.has_hysteresis or self.has_guide_friction) and self.rate_joints > 0

    @property
    def num_states(self) -> int:
        per_tendon = 2 + int(self.has_hysteresis) + int(self.has_guide_friction)
        return (2 * self.num_joints if self.has_link else 0) + per_tendon * self.num_tendons

    @property
    def supports_symbolic(self) -> bool:
        return self.laws.supports_symbolic

    def require_symbolic(self, what: str, hint: str) -> None:
        """Raise a ValueError naming the spring laws that cannot be evaluated symbolically (so neither
        traced nor compiled); ``what`` names the caller, ``hint`` the way out."""
        if not self.supports_symbolic:
            bad = sorted({type(s).__name__ for s in self.springs if not getattr(s, "supports_symbolic", False)})
            raise ValueError(f"{what}: spring law(s) {', '.join(bad)} cannot be evaluated symbolically; {hint}")

    def split_state(self, state):
        """(q, qdot, theta, omega, z, g) views of a drive state (q, qdot None without a link; z None
        without hysteresis, g None without guide friction)."""
        n, m = self.num_joints, self.num_tendons
        k = 2 * n if self.has_link else 0
        q, qd = (state[:n], state[n:k]) if self.has_link else (None, None)
        theta, omega = state[k:k + m], state[k + m:k + 2 * m]
        k += 2 * m
        z = state[k:k + m] if self.has_hysteresis else None
        k += m if self.has_hysteresis else 0
        g = state[k:k + m] if self.has_guide_friction else None
        return q, qd, theta, omega, z, g


@dataclass(frozen=True)
class TendonDrive:
    """Handle of a rig's drive: the diagram holding it and its :class:`DriveModel`."""

    diagram: Diagram
    model: DriveModel


def _full_rates(model: DriveModel, qd):
    """Velocities of all coupling joints (zeros beyond ``rate_joints``)."""
    n, nr = model.num_joints, model.rate_joints
    if qd is None or nr == n:
        return qd
    pad = np.zeros(n - nr, dtype=object if not is_float(qd) else float)
    if not is_float(qd):
        pad = pad + 0.0 * qd[0]
    return np.concatenate([qd, pad])


def drive_laws(model: DriveModel, state, u=None, q=None, qd=None, tau_ext=None, *, want=("all",),
               elongation=None):
    """All quantities of the drive at a state, generic in the scalar type.

    Returns a dict with ``elongation``, ``tendon_force``, ``tendon_stiffness``, ``generalized_force`` and
    (with ``u``) ``derivatives``, ``applied_torque``.  Without a link, ``q`` (n) and ``qd`` (``rate_joints``)
    are the joint inputs; with a link they come from ``state`` and ``tau_ext`` is the external torque.
    ``elongation`` (m), when given, stands for the elongation law's value at ``state`` (the caller guarantees
    they agree).  With a link and ``u``, ``want=("momentum_rate",)`` adds the rate of the momentum
    ``p = I qdot - P^T B omega / r_m``: ``p' = -P^T g - d qdot + tau_ext - P^T tau_m / r_m`` (the spring forces
    cancel; ``tau_m``: :func:`~awiwi_drake.components.motor.motor_drive_torque`; ``P`` constant).
    """
    qs, qds, theta, omega, z, g_state = model.split_state(state)
    if model.has_link:
        q, qd = qs, qds
    qd_all = _full_rates(model, qd)
    if elongation is None:
        x = model.motor_pulley_radius * theta + np.asarray(model.coupling.h(q)) - model._h0 + model.offsets
    else:
        x = elongation
    x = asarray_like(x, theta)
    f_el = model.laws.force(x)
    f = positive_part(f_el + z) if model.has_hysteresis else f_el
    out = dict(elongation=x, tendon_force=asarray_like(f, x))
    if "all" in want or "tendon_stiffness" in want:
        out["tendon_stiffness"] = model.laws.stiffness(x)
    need_P = any(w in want for w in ("all", "generalized_force", "derivatives"))
    if need_P:
        P = np.asarray(model.coupling.P(q))
        slide = P @ qd_all if qd_all is not None and model.num_joints else None
        tension = f + g_state if model.has_guide_friction else f
        tau = -(P.T @ tension) if model.num_joints else np.zeros(0, dtype=x.dtype)
        out["generalized_force"] = asarray_like(tau, x)
    if u is not None and ("all" in want or "derivatives" in want):
        r_m = model.motor_pulley_radius
        acc = motor_acceleration(theta, omega, u, r_m * f, model.motor)
        parts = []
        if model.has_link:
            I = np.asarray(model.link_inertia, float)
            d = np.asarray(model.link_damping, float)
            ext = 0.0 if tau_ext is None else tau_ext
            qdd = (out["generalized_force"] - d * qd + ext) / I
            parts += [qd, qdd]
        parts += [omega, acc]
        if model.has_hysteresis:
            xdot = r_m * omega + (slide if slide is not None else 0.0 * omega)
            parts.append(hysteresis_rate(z, x, xdot, f_el, model.hysteresis))
        if model.has_guide_friction:
            gm = model.guide_friction
            constant, exponent = gm.levels()
            v = slide if slide is not None else 0.0 * omega
            parts.append(guide_friction_rate(g_state, v, f, constant, exponent, gm.presliding_length,
                                             gm.smoothing_velocity))
        out["derivatives"] = np.concatenate([asarray_like(p_, x) for p_ in parts])
        out["applied_torque"] = saturate_torque(u, model.motor)
    if "momentum_rate" in want:
        if not (model.has_link and u is not None):
            raise ValueError("drive_laws: momentum_rate needs a link-carrying model and u")
        P = np.asarray(model.coupling.P(q))
        ext = 0.0 if tau_ext is None else tau_ext
        rate = -(P.T @ (motor_drive_torque(theta, omega, u, model.motor) / model.motor_pulley_radius)) \
            - np.asarray(model.link_damping, float) * qd + ext
        if model.has_guide_friction:
            rate = rate - P.T @ g_state
        out["momentum_rate"] = asarray_like(rate, x)
    return out


def build_kernels(model: DriveModel, *, jit: bool = True, vectorized: bool = False):
    """numba kernels of :func:`drive_laws` (float path), one per output group.

    Returns ``{name: fn}`` with signatures (all float64 1-D arrays, ``out`` last):
    ``derivatives(state, u, q, qd, out)`` / with a link ``derivatives(state, u, tau_ext, out)``;
    ``tendon_force``, ``tendon_stiffness``, ``elongation`` ``(state, q, out)`` / ``(state, out)``;
    ``generalized_force(state, q, qd, out)`` / ``(state, out)``.
    ``jit`` and ``vectorized``: as :func:`~awiwi_drake.components.codegen.compile_kernels`.
    """
    model.require_symbolic("compiled tendon drive", "use their calibration polynomial "
                           "(e.g. LeverSpringMechanism.to_polynomial())")
    m, n, nr = model.num_tendons, model.num_joints, model.rate_joints
    key = None if model._content_key is None else (model._content_key, "vectorized" if vectorized else jit)
    if key is not None and key in _KERNELS:
        return _KERNELS[key]
    with np.errstate(invalid="ignore"):     # symbolic object arrays leave meaningless FPU flags
        kernels = _build_kernels(model, m, n, nr, jit, vectorized)
    if key is not None:
        _KERNELS[key] = kernels
    return kernels


# Kernels of drive models already traced in this process, by the model's content: every new diagram (and every
# scalar-converted or cloned copy) would otherwise trace the laws again.
_KERNELS: dict = {}


def _content_digest(model) -> str | None:
    """sha1 of the pickled model, or None when it cannot be pickled (e.g. a spring law holding a lambda)."""
    import hashlib
    import pickle
    try:
        return hashlib.sha1(pickle.dumps(model, protocol=4)).hexdigest()
    except Exception:
        return None


def _build_kernels(model, m, n, nr, jit, vectorized=False):
    sv, s = symbolic_vector("s", model.num_states)
    uv, u = symbolic_vector("u", m)
    if model.has_link:
        ev, e = symbolic_vector("e", n)
        res = drive_laws(model, s, u, tau_ext=e)
        ins = dict(derivatives=[sv, uv, ev], tendon_force=[sv], tendon_stiffness=[sv], elongation=[sv],
                   generalized_force=[sv])
    else:
        qv, q = symbolic_vector("q", n)
        dv, d = symbolic_vector("qd", nr)
        res = drive_laws(model, s, u, q, d if model.needs_joint_velocity else None)
        ins = dict(derivatives=[sv, uv, qv, dv], tendon_force=[sv, qv], tendon_stiffness=[sv, qv],
                   elongation=[sv, qv], generalized_force=[sv, qv, dv])
    functions = {name: (ins[name], list(res[name])) for name in ins}
    from awiwi_drake.components.codegen import compile_kernels
    return compile_kernels(functions, tag=f"drive_m{m}_n{n}", jit=jit, vectorized=vectorized)


@TemplateSystem.define("TendonDriveBatch_", scope=sys.modules[__name__])
def TendonDriveBatch_(T):
    """N copies of one link-carrying drive (a single-joint rig) in one system: ``TendonDriveBatch_[T](model, N)``.

    State: the copies' states one after the other, each in the single rig's order.  Inputs ``motor_torque``
    (N m) and ``external_torque`` (N n), copy-major; outputs ``state``, ``joint_angle`` (N n), ``tendon_force``
    (N m).  Float runs the generated kernel's ``_batch`` twin (one compiled loop over the copies).
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, model: DriveModel = None, num_copies: int = 1, converter=None):
            LeafSystem_[T].__init__(self, converter)
            if not isinstance(model, DriveModel) or not model.has_link:
                raise ValueError("TendonDriveBatch: model must be a DriveModel with link_inertia/link_damping")
            if int(num_copies) != num_copies or num_copies < 1:
                raise ValueError(f"TendonDriveBatch: num_copies = {num_copies!r} must be a positive integer")
            self.model, self.num_copies = model, int(num_copies)
            N, k, m, n = self.num_copies, model.num_states, model.num_tendons, model.num_joints
            self._shape = (N, k, m, n)
            self._float = T is float
            self._kernels = None
            xc = self.DeclareContinuousState(N * k)
            self._u = self.DeclareVectorInputPort("motor_torque", N * m)
            self._ext = self.DeclareVectorInputPort("external_torque", N * n)
            state = {self.all_state_ticket()}
            self.DeclareStateOutputPort("state", xc)          # copied in C++ (read at every control sample)
            self.DeclareVectorOutputPort("joint_angle", N * n, self._calc_joint_angle, prerequisites_of_calc=state)
            self.DeclareVectorOutputPort("tendon_force", N * m, self._calc_force, prerequisites_of_calc=state)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.model, other.num_copies, converter=converter)

        def _x(self, context):
            return context.get_continuous_state_vector().CopyToVector()

        def kernels(self):
            if self._kernels is None:
                self._kernels = build_kernels(self.model)
            return self._kernels

        def _calc_joint_angle(self, context, out):
            N, k, m, n = self._shape
            out.SetFromVector(self._x(context).reshape(N, k)[:, :n].ravel())

        def _calc_force(self, context, out):
            N, k, m, n = self._shape
            X = self._x(context).reshape(N, k)
            if self._float:
                out.SetFromVector(self.kernels()["tendon_force_batch"](X, np.empty((N, m))).ravel())
                return
            out.SetFromVector(np.concatenate([drive_laws(self.model, X[i], want=("tendon_force",))["tendon_force"]
                                              for i in range(N)]))

        def DoCalcTimeDerivatives(self, context, derivatives):
            N, k, m, n = self._shape
            X = self._x(context).reshape(N, k)
            U = self._u.Eval(context).reshape(N, m)
            E = self._ext.Eval(context).reshape(N, n)
            if self._float:
                d = self.kernels()["derivatives_batch"](X, U, E, np.empty((N, k)))
            else:
                d = np.concatenate([drive_laws(self.model, X[i], U[i], tau_ext=E[i], want=("derivatives",))
                                    ["derivatives"] for i in range(N)])
            derivatives.SetFromVector(np.ravel(d))

    return Impl
