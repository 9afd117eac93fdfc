"""The augmented rig model: nominal dynamics plus every catalog effect as a switch.

:class:`DiscrepancyModel_` is one TemplateSystem that integrates ``copies``
independent instances of a rig (``tendon``: one motor; ``joint``: two motors
and a link) side by side, each with its own catalog parameter vector (a Drake
numeric parameter).  The workflow runs every multiple-shooting window and
every finite-difference perturbation of a fit as one copy, so a whole
residual/Jacobian evaluation is one pass of one Drake ``Simulator``
("banks, not swarms": one Python call per step for all copies).

State of copy ``j`` (``n`` motors): the rigs' order ``[(q, q'), theta_1..n, omega_1..n, z_1..n]``
(``tendon_rig``/``joint_rig``, :func:`awiwi_drake.rigs.base.state_names`) where ``z`` [N] is the
Dahl hysteresis force of each spring mechanism; stored
variable-major (index ``s * copies + j``).  Input ``motor_torque``
(``n * copies``, applied torque, already delayed).  Output ``measurement``:
``[theta_1..n, f_1..n, (q)]`` per copy, ``f`` the spring-mechanism force as the
force sensor reports it.

Generated from the package's components, not a copy of the rig dynamics
(issue 12): :func:`replay_laws` is the dataset's nominal rig as the package
builds it (:func:`drive_model`, the :class:`~awiwi_drake.components.fused_drive.DriveModel`
of ``tendon_rig``/``joint_rig`` with the dataset's polynomial spring, evaluated
by :func:`~awiwi_drake.components.fused_drive.drive_laws`), with every catalog
effect a law of :mod:`.laws` switched in through the drive's motor-torque and
link-torque inputs.  The float path runs a numba kernel that
:mod:`awiwi_drake.components.codegen` generates from :func:`replay_laws`
(symbolic -> compiled, each effect behind an ``if_then_else`` switch so copies
where it is off skip it); AutoDiffXd/Expression evaluate :func:`replay_laws`.
Tests: kernel = laws for every switch to 1e-12; with the rig's effects the model
equals the ``joint_rig`` diagram at random states to 1e-9.
"""

from __future__ import annotations

import functools
import sys
from dataclasses import dataclass

import numpy as np
import pydrake.symbolic as sym
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector_, LeafSystem_, ValueProducer
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import is_float
from awiwi_drake.components.codegen import compile_kernels
from awiwi_drake.components.fused_drive import DriveModel, drive_laws
from awiwi_drake.components.routing import ConstantCoupling, antagonistic_coupling, joint_backlash_angle
from awiwi_drake.components.spring import PolynomialSpring
from awiwi_drake.parameters.components import MotorParams

from . import laws
from .catalog import PARAM_INDEX, PARAM_NAMES, default_vector

__all__ = ["NominalParameters", "DiscrepancyModel_", "DiscrepancyModel", "drive_model", "replay_laws",
           "replay_kernels"]


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
        if rig == "joint-rig":
            extra = dict(link_inertia=p["link_inertia"], link_damping=p["link_damping"],
                         link_pulley_radius=p["link_pulley_radius"])
        return cls(rig, float(p["motor_inertia"]), float(p["motor_damping"]),
                   float(p["motor_pulley_radius"]), tuple(float(c) for c in p["spring_poly"]), **extra)

    @property
    def num_motors(self) -> int:
        return 2 if self.rig == "joint-rig" else 1

    @property
    def has_link(self) -> bool:
        return self.rig == "joint-rig"

    @property
    def num_states(self) -> int:
        return 3 * self.num_motors + (2 if self.has_link else 0)

    @property
    def num_measurements(self) -> int:
        return 2 * self.num_motors + (1 if self.has_link else 0)

    def state_names(self) -> list[str]:
        """The rigs' state order ``[(q, q'), theta, omega, z]`` with the dataset's column names."""
        n = self.num_motors
        sfx = [f"_{i + 1}" for i in range(n)] if n > 1 else [""]
        names = ["joint_angle", "joint_velocity"] if self.has_link else []
        names += [f"motor_angle{s}" for s in sfx] + [f"motor_velocity{s}" for s in sfx]
        return names + [f"hysteresis_force{s}" for s in sfx]

    def measurement_names(self) -> list[str]:
        n = self.num_motors
        sfx = [f"_{i + 1}" for i in range(n)] if n > 1 else [""]
        names = [f"motor_angle{s}" for s in sfx] + [f"tendon_force{s}" for s in sfx]
        return names + (["joint_angle"] if self.has_link else [])


def _p(P, name):
    return P[PARAM_INDEX[name]]



@functools.lru_cache(maxsize=32)
def drive_model(nom: NominalParameters) -> DriveModel:
    """The package's tendon drive of the dataset's nominal rig (:class:`~awiwi_drake.components.fused_drive.DriveModel`,
    the law function of ``tendon_rig``/``joint_rig``): motor (3.5) with the dataset's ``B``, ``d`` and no
    friction/ripple/saturation, :class:`~awiwi_drake.components.spring.PolynomialSpring` per tendon, the rig's
    coupling and (joint) the link ``I q'' = tau - d_q q' + tau_ext``. Catalog effects enter through its inputs."""
    motor = MotorParams(inertia=nom.motor_inertia, damping=nom.motor_damping, friction=False, ripple=False,
                        saturation=False, pulley_radius=nom.motor_pulley_radius)
    spring = PolynomialSpring(nom.spring_poly)
    if nom.has_link:
        coupling = antagonistic_coupling(nom.link_pulley_radius)
        link = dict(link_inertia=(nom.link_inertia,), link_damping=(nom.link_damping,))
    else:
        coupling, link = ConstantCoupling(np.zeros((1, 0))), {}
    n = nom.num_motors
    return DriveModel(motor, (spring,) * n, coupling, np.zeros(n), nom.motor_pulley_radius, **link)


def _switch(gates, term, like):
    """A catalog effect as a switch: ``term()`` when any of its ``gates`` (amplitude parameters) is
    nonzero, else zero. Symbolic: ``if_then_else``, so the generated kernel evaluates an effect's
    transcendental functions only in copies where it is on (the replay's hot path)."""
    if any(isinstance(g, sym.Expression) for g in gates):
        on = sum(g * g for g in gates) > 0.0
        value = term()
        return sym.if_then_else(on, value if isinstance(value, sym.Expression) else sym.Expression(float(value)),
                                sym.Expression(0.0))
    return term() if any(g != 0.0 for g in gates) else 0.0 * like


def split_state(nom: NominalParameters, X):
    """``(theta, omega, q, q', z)`` from a state in the rigs' order ``[(q, q'), theta, omega, z]``
    (``q``, ``q'`` are None without a link)."""
    n = nom.num_motors
    q = qd = None
    k = 0
    if nom.has_link:
        q, qd, k = X[0], X[1], 2
    return X[k:k + n], X[k + n:k + 2 * n], q, qd, X[k + 2 * n:k + 3 * n]


def rig_kinematics(nom: NominalParameters, theta, omega, q=None, qd=None):
    """Spring elongations and their rates ``(x, xd)`` per motor (lists), from the drive's routing
    (``x = r theta + h(q) - h(0)``, ``x' = r omega + P(q) q'``, :mod:`awiwi_drake.components.routing`);
    ``theta``/``omega`` rows may be arrays over copies or samples."""
    r = nom.motor_pulley_radius
    x = [r * theta[i] for i in range(nom.num_motors)]
    xd = [r * omega[i] for i in range(nom.num_motors)]
    if nom.has_link:
        P = drive_model(nom).coupling.P()
        x = [x[i] + P[i, 0] * q for i in range(nom.num_motors)]
        xd = [xd[i] + P[i, 0] * qd for i in range(nom.num_motors)]
    return x, xd


def _to_drive(nom, theta, omega, q, qd):
    """Drive state order ``[(q, q'), theta, omega]`` (no drive hysteresis: the catalog's is its own state)."""
    parts = ([q, qd] if nom.has_link else []) + list(theta) + list(omega)
    return np.array(parts, dtype=object if not all(is_float(v) for v in parts) else float)


def _backlash_offset(nom, model, theta, omega, q, qd, b):
    """Pulley angle minus link angle with joint backlash ``b``
    (:func:`~awiwi_drake.components.routing.joint_backlash_angle` on the drive's tendon torque and stiffness)."""
    P = model.coupling.P()[:, 0]

    def torque_and_stiffness(a):
        got = drive_laws(model, _to_drive(nom, theta, omega, a, qd), want=("tendon_force", "tendon_stiffness"))
        f, k = got["tendon_force"], got["tendon_stiffness"]
        return (-sum(P[i] * f[i] for i in range(nom.num_motors)),
                sum(P[i] * P[i] * k[i] for i in range(nom.num_motors)))
    return joint_backlash_angle(q, torque_and_stiffness, b, laws.BACKLASH_SMOOTHING, laws.BACKLASH_NEWTON_STEPS) - q


def replay_laws(nom: NominalParameters, x, u, p):
    """Time derivatives and measurements of one copy, generic in the scalar type.

    The nominal rig is :func:`~awiwi_drake.components.fused_drive.drive_laws` of :func:`drive_model`;
    each catalog effect is a law of :mod:`.laws` entering through the drive's inputs, as a block in
    front of the drive would: torques on the motor input (friction, ripple, the guide friction's
    and the spring correction's reaction ``-r (g + df)``, added damping), torques on the link input
    (``-P^T df``, link Coulomb friction, added damping); the inertia corrections scale the drive's
    accelerations. ``df = s f_el + z tanh(f_el)`` is the spring-scale and hysteresis force on top
    of the drive's elastic force ``f_el``. Joint backlash replaces the link angle the drive sees by the
    tendon pulley's (:func:`~awiwi_drake.components.routing.joint_backlash_angle`); the link encoder
    still reads the link.

    Parameters
    ----------
    x : (num_states,) ``[(q, q'), theta, omega, z]``
    u : (num_motors,) applied motor torques
    p : (num_params,) catalog parameters

    Returns
    -------
    (xdot (num_states,), y (num_measurements,))
    """
    n = nom.num_motors
    model = drive_model(nom)
    r = nom.motor_pulley_radius
    theta, omega, q_link, qd, z = split_state(nom, x)
    q_in = None if nom.has_link else np.zeros(0)   # the tendon rig's drive has no joint
    q = q_link
    if nom.has_link:   # backlash: the tendons wrap a pulley with play on the link; the drive sees its angle
        b = _p(p, "backlash")
        q = q_link + _switch((b,), lambda: _backlash_offset(nom, model, theta, omega, q_link, qd, b), q_link)
    s = _to_drive(nom, theta, omega, q, qd)
    f_el = drive_laws(model, s, q=q_in, want=("tendon_force",))["tendon_force"]
    xs, xds = rig_kinematics(nom, theta, omega, q, qd)
    df, force, zdot, v = [], [], [], []
    for i in range(n):
        m = i + 1
        place = _p(p, f"place_{m}")   # the per-tendon effects (PLACED_EFFECTS) on this tendon or not
        width = _p(p, "hysteresis_width") * place
        f = (1.0 + _p(p, "spring_scale_rel")) * f_el[i] + _switch(
            (width,), lambda: laws.hysteresis_force(z[i], f_el[i]), f_el[i])
        force.append(f)
        df.append(f - f_el[i])
        zdot.append(_switch((width,), lambda: laws.hysteresis_force_rate(
            z[i], xs[i], xds[i], f_el[i], width, _p(p, "hysteresis_length")), f_el[i]))
        tau = -_p(p, "motor_damping_add") * omega[i]
        coulomb, viscous = _p(p, "motor_coulomb") * place, _p(p, "motor_viscous") * place
        tau = tau + _switch((coulomb, viscous), lambda: laws.motor_friction(
            omega[i], coulomb, _p(p, "motor_slope"), viscous), omega[i])
        for k in (1, 2):
            a, b = _p(p, f"ripple_sin{k}_m{m}"), _p(p, f"ripple_cos{k}_m{m}")
            tau = tau + _switch((a, b), lambda: laws.ripple(theta[i], [(_p(p, f"ripple_order_{k}"), a, b)]),
                                theta[i])
        c0, mu = _p(p, "guide_c0") * place, _p(p, "guide_mu") * place
        g = _switch((c0, mu), lambda: laws.guide_friction(r * omega[i], f, c0, mu, laws.GUIDE_VELOCITY), omega[i])
        v.append(u[i] + tau - r * (g + df[i]))
    ext = None
    if nom.has_link:
        P = model.coupling.P()
        ext = [-(P[0, 0] * df[0] + P[1, 0] * df[1]) - _p(p, "link_damping_add") * qd
               + _switch((_p(p, "joint_coulomb"),), lambda: laws.joint_friction(
                   qd, _p(p, "joint_coulomb"), _p(p, "joint_velocity")), qd)]
    like = np.array(v, dtype=object) if not all(is_float(w) for w in v) else np.array(v, float)
    xdot = drive_laws(model, s, like, q=q_in, tau_ext=None if ext is None else np.array(ext, dtype=like.dtype),
                      want=("derivatives",))["derivatives"]
    k = 2 if nom.has_link else 0   # the drive's order is the rigs' order: [(q, q'), theta, omega]
    out = [xdot[0], xdot[1] / (1.0 + _p(p, "link_inertia_rel"))] if nom.has_link else []
    out += [xdot[k + i] for i in range(n)] + [xdot[k + n + i] / (1.0 + _p(p, "motor_inertia_rel")) for i in range(n)]
    out += zdot
    y = [theta[i] + _p(p, f"motor_bias_{i + 1}") for i in range(n)]  # encoder bias
    y += [(1.0 + _p(p, "force_gain")) * force[i] + _p(p, f"force_offset_{i + 1}") for i in range(n)]
    if nom.has_link:
        y.append((1.0 + _p(p, "link_scale_rel")) * q_link + _p(p, "link_bias"))  # link encoder calibration
    return np.array(out, dtype=like.dtype), np.array(y, dtype=like.dtype)


def model_derivatives(nom: NominalParameters, X, U, P):
    """Time derivatives of all copies by the law functions (:func:`replay_laws` per copy).

    Parameters
    ----------
    X : array (num_states, copies)
    U : array (num_motors, copies) applied motor torques [Nm]
    P : array (num_params, copies) catalog parameters

    Returns
    -------
    array (num_states, copies), generic in the scalar type.
    """
    return np.stack([replay_laws(nom, X[:, j], U[:, j], P[:, j])[0] for j in range(X.shape[1])], axis=1)


def model_measurements(nom: NominalParameters, X, P):
    """Measured signals ``[theta..., f_meas..., (q)]`` of all copies (num_measurements, copies)."""
    U = np.zeros((nom.num_motors, X.shape[1]), dtype=X.dtype)
    return np.stack([replay_laws(nom, X[:, j], U[:, j], P[:, j])[1] for j in range(X.shape[1])], axis=1)


@functools.lru_cache(maxsize=8)
def replay_kernels(nom: NominalParameters, jit: bool = True) -> dict:
    """Compiled float kernels of :func:`replay_laws` (:func:`~awiwi_drake.components.codegen.compile_kernels`):
    ``derivatives(x, u, p, out)``, ``measurements(x, p, out)`` and their ``_batch`` twins
    (2-D arguments, one row per copy). The laws are evaluated once on symbolic variables, so the
    kernel is the same physics, not a copy; a test checks kernel = laws at random states."""
    xv = [sym.Variable(f"x{i}") for i in range(nom.num_states)]
    uv = [sym.Variable(f"u{i}") for i in range(nom.num_motors)]
    pv = [sym.Variable(f"p{i}") for i in range(len(PARAM_NAMES))]
    E = lambda vs: np.array([sym.Expression(v) for v in vs], dtype=object)  # noqa: E731
    with np.errstate(invalid="ignore"):
        xdot, _ = replay_laws(nom, E(xv), E(uv), E(pv))
        _, y = replay_laws(nom, E(xv), E(uv) * 0.0, E(pv))
    return compile_kernels({"derivatives": ([xv, uv, pv], list(xdot)), "measurements": ([xv, pv], list(y))},
                           tag="replay_joint" if nom.has_link else "replay_tendon", jit=jit)


@TemplateSystem.define("DiscrepancyModel_", scope=sys.modules[__name__])
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
            self._float = T is float
            self._kernels = None
            self._hot = None
            self._dbuf = np.empty((self._copies, self._ns))
            self._ybuf = np.empty((self._copies, nominal.num_measurements))
            self.DeclareContinuousState(self._ns * M)
            self.DeclareNumericParameter(BasicVector_[T](np.tile(default_vector()[:, None], (1, M)).ravel()))
            if self._float:   # the parameters one row per copy, as the kernel reads them (recomputed on change)
                self._p_rows = self.DeclareCacheEntry(
                    "parameters_by_copy", ValueProducer(
                        allocate=AbstractValue.Make(np.zeros((M, self._np))).Clone,
                        calc=lambda ctx, val: val.set_value(np.ascontiguousarray(
                            ctx.get_numeric_parameter(0).CopyToVector().reshape(self._np, M).T))),
                    prerequisites_of_calc={self.all_parameters_ticket()})
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

        def _kernel(self, name):
            if self._kernels is None:
                self._kernels = replay_kernels(self._nom)
            return self._kernels[f"{name}_batch"]

        def DoCalcTimeDerivatives(self, context, derivatives):
            if self._float:   # hot path: the kernel generated from replay_laws, all copies in one call
                if self._hot is None:   # looked up once: the per-call overhead is most of a small batch's cost
                    self._hot = (self._kernel("derivatives"), self.get_input_port(0), self._nom.num_motors)
                kernel, port, n = self._hot
                X = context.get_continuous_state_vector().CopyToVector().reshape(self._ns, self._copies)
                U = port.Eval(context).reshape(n, self._copies)
                derivatives.SetFromVector(kernel(X.T, U.T, self._p_rows.Eval(context), self._dbuf).T.ravel())
                return
            X, P = self._arrays(context)
            U = self.get_input_port(0).Eval(context).reshape(self._nom.num_motors, self._copies)
            derivatives.get_mutable_vector().SetFromVector(np.ravel(model_derivatives(self._nom, X, U, P)))

        def _calc_measurement(self, context, output):
            if self._float:
                X = context.get_continuous_state_vector().CopyToVector().reshape(self._ns, self._copies)
                y = self._kernel("measurements")(X.T, self._p_rows.Eval(context), self._ybuf)
                output.SetFromVector(y.T.ravel())
                return
            X, P = self._arrays(context)
            output.SetFromVector(np.asarray(model_measurements(self._nom, X, P)).ravel())

        def _calc_state(self, context, output):
            output.SetFromVector(context.get_continuous_state_vector().CopyToVector())

    return Impl


DiscrepancyModel = DiscrepancyModel_[None]
