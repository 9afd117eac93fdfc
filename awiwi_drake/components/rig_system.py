"""A single-joint rig as C++ systems generated from the law functions.

The continuous dynamics of a link-carrying drive (:class:`~awiwi_drake.components.fused_drive.DriveModel`
with ``link_inertia``: the joint rig, the flexible joint; or without joints: the tendon rig) are
:func:`~awiwi_drake.components.fused_drive.drive_laws` evaluated *once* on ``pydrake.symbolic`` variables
and handed to Drake's C++ ``SymbolicVectorSystem`` (:func:`rig_dynamics_system`): its only output is the
state, so no Python runs in the integrator's derivative path (README, "How the plants are built, and
speed"), and Drake differentiates the same expressions for ``AutoDiffXd``.  The quantities that are not
state slices come from the stateless :class:`LinkRigOutputs_`, evaluated only when a port is read.
"""

from __future__ import annotations

import sys

import numpy as np
import pydrake.symbolic as sym
from pydrake.systems.analysis import DiscreteTimeApproximation, SimulatorConfig
from pydrake.systems.framework import LeafSystem_, System
from pydrake.systems.primitives import SymbolicVectorSystem
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import symbolic_vector
from awiwi_drake.components.fused_drive import DriveModel, build_kernels, drive_laws
from awiwi_drake.components.motor import saturate_torque
from awiwi_drake.components.routing import ConstantCoupling

__all__ = ["rig_dynamics_system", "rig_integration_system", "integration_state",
           "sampled_dynamics", "SAMPLED_INTEGRATOR",
           "LinkRigOutputs_", "tendon_force_of_states"]

# the integration scheme of a sampled rig: one fixed step per control period, the scheme and step
# analysis.simulate uses for sampled loops by default (so the two give the same trajectory to round-off)
SAMPLED_INTEGRATOR = "runge_kutta3"


def _check(model) -> None:
    if not isinstance(model, DriveModel) or not (model.has_link or model.num_joints == 0):
        raise ValueError("rig_dynamics_system: model must be a DriveModel whose state is the whole rig: with "
                         "link_inertia/link_damping, or without joints (the tendon rig)")
    model.require_symbolic("rig_dynamics_system", "use their calibration polynomial")


def _no_joints(model: DriveModel) -> dict:
    """The joint input of :func:`drive_laws` for a drive without joints (the tendon rig), none with a link."""
    return {} if model.has_link else {"q": np.zeros(0)}


def _input_vector(m: int, n: int):
    """The symbolic input ``[motor_torque (m), external_torque (n)]`` of a rig: ``(variables, expressions)``."""
    (uv, u), (ev, e) = symbolic_vector("u", m), symbolic_vector("tau_ext", n)
    return uv + ev, np.concatenate([u, e])


def rig_dynamics_system(model: DriveModel) -> SymbolicVectorSystem:
    """One C++ ``SymbolicVectorSystem``: state of ``model``, input ``[motor_torque, external_torque]`` (without
    joints: ``motor_torque``), dynamics :func:`drive_laws`, output the state (no direct feedthrough).

    The expressions are handed over ``Expand()``-ed (the springs' Horner products in power form): Drake's
    evaluator calls ``pow`` for every factor of every product node, so fewer product nodes are cheaper.
    """
    _check(model)
    m, n = model.num_tendons, model.num_joints
    xs, X = symbolic_vector("x", model.num_states)
    us, U = _input_vector(m, n)
    with np.errstate(invalid="ignore"):     # symbolic object arrays leave meaningless FPU flags
        xdot = drive_laws(model, X, U[:m], tau_ext=U[m:], want=("derivatives",), **_no_joints(model))["derivatives"]
    return SymbolicVectorSystem(state=xs, input=us, dynamics=[e.Expand() for e in xdot], output=xs)


def _integration_parts(model: DriveModel):
    """``(P, I, B, r_m)`` of a link-carrying model whose routing matrix is constant (the single-joint rigs)."""
    if not isinstance(model.coupling, ConstantCoupling):
        raise ValueError(f"rig_integration_system: the routing must be a ConstantCoupling (constant P), got "
                         f"{type(model.coupling).__name__}")
    P = np.asarray(model.coupling.P(), dtype=float)
    motors = model.motor if isinstance(model.motor, tuple) else (model.motor,) * model.num_tendons
    B = np.array([mp.inertia for mp in motors], dtype=float)
    return P, np.asarray(model.link_inertia or (), float), B, float(model.motor_pulley_radius)


def integration_state(model: DriveModel, state) -> np.ndarray:
    """The physical rig state ``[q, qdot, theta, omega, (z), (g)]`` (float) in the integration coordinates
    of :func:`rig_integration_system`: ``[q, p, x, omega, (z), (g)]`` with the momentum
    ``p = I qdot - P^T B omega / r_m`` and the elongations ``x`` of the elongation law
    (:func:`drive_laws`); the other entries are unchanged (no joints, the tendon rig: ``[x, omega, (z)]``)."""
    _check(model)
    P, I, B, r = _integration_parts(model)
    x = np.asarray(state, dtype=float).reshape(-1)
    if x.size != model.num_states:
        raise ValueError(f"integration_state: state has {x.size} entries, the rig has {model.num_states}")
    n, m = model.num_joints, model.num_tendons
    z = x.copy()
    z[n:2 * n] = I * x[n:2 * n] - P.T @ (B * x[2 * n + m:2 * n + 2 * m]) / r
    z[2 * n:2 * n + m] = drive_laws(model, x, want=("elongation",), **_no_joints(model))["elongation"]
    return z


def rig_integration_system(model: DriveModel) -> SymbolicVectorSystem:
    """The rig of :func:`rig_dynamics_system` in integration coordinates, for its sampled form.

    State ``[q, p, x, omega, (z), (g)]`` (:func:`integration_state`: the momentum of link and motors
    ``p = I qdot - P^T B omega / r_m`` in place of ``qdot``, the elongations ``x`` in place of ``theta``);
    input ``[motor_torque, external_torque]``; output the physical state ``[q, qdot, theta, omega, ...]``
    (``qdot = (p + P^T B omega / r_m) / I``, ``theta = (x - h(q) + h(0) - x0) / r_m``). The dynamics are
    :func:`drive_laws` on these variables (``elongation`` given, ``momentum_rate``), with
    ``x' = r_m omega + P qdot`` (without joints, the tendon rig: state ``[x, omega, (z)]``). The coordinates are a constant linear map of the physical ones, so any
    Runge-Kutta step commutes with it: the sampled rig integrated in them is the physical rig's
    trajectory to round-off (tests/test_rig_system.py). Why: Drake's expression evaluator shares no
    sub-expressions; here each spring law appears once per tendon, on one variable.
    """
    _check(model)
    P, I, B, r = _integration_parts(model)
    n, m = model.num_joints, model.num_tendons
    zs, Z = symbolic_vector("z", model.num_states)
    us, U = _input_vector(m, n)
    q, p, e, omega = Z[:n], Z[n:2 * n], Z[2 * n:2 * n + m], Z[2 * n + m:2 * n + 2 * m]
    with np.errstate(invalid="ignore"):     # symbolic object arrays leave meaningless FPU flags
        qd = (p + P.T @ (B * omega) / r) / I
        theta = (e - (np.asarray(model.coupling.h(q)) - model._h0 + model.offsets)) / r
        x = np.concatenate([q, qd, theta, Z[2 * n + m:]])
        laws = drive_laws(model, x, U[:m], tau_ext=U[m:], elongation=e,
                          want=("derivatives",) + (("momentum_rate",) if model.has_link else ()), **_no_joints(model))
        d = laws["derivatives"]
        zdot = np.concatenate([d[:n], laws.get("momentum_rate", d[:0]), r * omega + P @ qd, d[2 * n + m:]])
    return SymbolicVectorSystem(state=zs, input=us, dynamics=[_expression(v).Expand() for v in zdot],
                                output=[_expression(v).Expand() for v in x])


def _expression(v) -> sym.Expression:
    return v if isinstance(v, sym.Expression) else sym.Expression(float(v))


def sampled_dynamics(system: System, period: float) -> System:
    """``system`` (continuous, e.g. :func:`rig_dynamics_system`) as Drake's nonlinear
    ``DiscreteTimeApproximation`` at ``period`` [s]: ``x[n+1] = x[n] + integral of f(x, u[n]) dt``
    over one period with the input held (zero-order hold), integrated by Drake's
    :data:`SAMPLED_INTEGRATOR` with one fixed step per period.

    In a sampled loop this is the continuous ``system`` integrated with fixed-step RK3 at the period, to
    round-off (tests/test_rig_system.py), with one discrete update per period for the outer ``Simulator``.
    Scalar types: float and AutoDiffXd (Drake's approximation has no symbolic form).
    """
    period = float(period)
    if not period > 0.0:
        raise ValueError(f"sampled_dynamics: period = {period!r} s must be > 0")
    config = SimulatorConfig(integration_scheme=SAMPLED_INTEGRATOR, max_step_size=period, use_error_control=False)
    sampled = DiscreteTimeApproximation(system, period, config)
    sampled._continuous_system = system    # the approximation refers to `system` without owning it
    return sampled


class tendon_force_of_states:
    """``states (T, num_states) -> tendon forces (T, m)``: the generated ``tendon_force`` kernel of
    ``model`` (= :func:`drive_laws`) over many samples at once (monitors on logged states), in numpy's
    elementwise forms (``build_kernels(vectorized=True)``): all samples in one pass, without numba's import.
    A class, not a closure, so a rig holding it pickles (process pools)."""

    def __init__(self, model: DriveModel):
        if not isinstance(model, DriveModel) or not (model.has_link or model.num_joints == 0):
            raise ValueError("tendon_force_of_states: model must be a DriveModel whose forces depend on its state "
                             "only (a link-carrying drive, or no joints: the tendon rig)")
        if not model.supports_symbolic:
            raise ValueError("tendon_force_of_states: the model's spring laws cannot be compiled")
        self.model = model
        self._kernel = None

    def __getstate__(self):
        return {"model": self.model, "_kernel": None}

    def __call__(self, states):
        model = self.model
        if self._kernel is None:
            self._kernel = build_kernels(model, vectorized=True)["tendon_force"]
        X = np.asarray(states, dtype=float).reshape(-1, model.num_states).T      # one row per state entry
        out = np.empty((model.num_tendons, X.shape[1]))
        with np.errstate(all="ignore"):     # numpy's forms evaluate both branches of a law's if-then-else
            if model.has_link:
                self._kernel(X, out)
            else:
                self._kernel(X, np.zeros((0, X.shape[1])), out)     # no joints: the kernel's empty q input
        return out.T


@TemplateSystem.define("LinkRigOutputs_", scope=sys.modules[__name__])
def LinkRigOutputs_(T):
    """The non-state outputs of a drive whose state is the whole rig (a link rig, the tendon rig);
    ``LinkRigOutputs_[T](model)``.

    Inputs ``state``, ``motor_torque`` (m); outputs ``tendon_force`` (m) [N], ``tendon_stiffness`` (m) [N/m],
    ``joint_torque`` (n) [N m] (``-P^T f``) from the state, and ``applied_torque`` (m) [N m] (the saturated
    ``motor_torque``).
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, model: DriveModel = None, converter=None):
            LeafSystem_[T].__init__(self, converter)
            _check(model)
            self.model = model
            self._float = T is float
            self._kernels = None
            self._q = _no_joints(model)            # the kernels' and laws' empty joint input without a link
            m, n = model.num_tendons, model.num_joints
            self._x = self.DeclareVectorInputPort("state", model.num_states)
            self._u = self.DeclareVectorInputPort("motor_torque", m)
            deps = {self._x.ticket()}
            for port, law, size in (("tendon_force", "tendon_force", m), ("tendon_stiffness", "tendon_stiffness", m),
                                    ("joint_torque", "generalized_force", n)):
                self.DeclareVectorOutputPort(port, size, self._law_output(law, size), prerequisites_of_calc=deps)
            self.DeclareVectorOutputPort("applied_torque", m, self._calc_applied,
                                         prerequisites_of_calc={self._u.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.model, converter=converter)

        def _law_output(self, law, size):
            # without a link the kernels take the (empty) joint inputs: q, and qd for the generalised force
            joints = () if self.model.has_link else (np.zeros(0),) * (2 if law == "generalized_force" else 1)

            def calc(context, out):
                x = self._x.Eval(context)
                if self._float:
                    if self._kernels is None:
                        self._kernels = build_kernels(self.model)
                    out.SetFromVector(self._kernels[law](x, *joints, np.empty(size)))
                    return
                out.SetFromVector(drive_laws(self.model, x, want=(law,), **self._q)[law])
            return calc

        def _calc_applied(self, context, out):
            out.SetFromVector(saturate_torque(self._u.Eval(context), self.model.motor))

    return Impl
