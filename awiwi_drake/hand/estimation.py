"""Link-position estimation from tendon lengths (thesis (5.14)-(5.15), (5.24), Algorithm 1).

The fingers have no joint sensors; the tendon length change at the finger base ``dh = h(q) - h(0)`` is
measured (motor angle and spring sensor).

* Constant coupling: least squares (5.14) by the pseudo-inverse (5.15), ``q = (P S)^+ dh`` on the
  independent DoF (``S`` maps them to the plant joints; identity except for the ring/fifth PIP/DIP).
* Thumb base: ``P(q)`` depends on ``q``; Algorithm 1 is a fixed-step gradient search with step halving
  on ``C(q) = |dh_meas - dh(q)|^2`` over (q10, q11) and the four base tendons: a step along the
  *normalised* gradient (in radians) is accepted when the cost decreases and halved otherwise.  Trial
  points are projected onto ``[-limit, limit]^2``, and the result reports when that acted
  (``GradientSearchResult.projected``, ``at_limit``).  The thumb's PIP/DIP use the pseudo-inverse.

Where this departs from the printed (5.15), (5.24) and Algorithm 1 (its search over ``ker P``, the raw
gradient step) and why: docs/REPRODUCTIONS.md, fingers.  Error bound: a measurement error ``e`` moves a
converged estimate by ``dq ~ P^+ e``, so ``|dq| <= |e| / sigma_min(P)`` (:func:`noise_error_bound`).
The Fig 5.16-5.17 study is :func:`awiwi_drake.reproductions.ch05_fingers.thumb_estimation_study`.
"""

from __future__ import annotations

import math
import sys
import warnings
from dataclasses import dataclass

import numpy as np
from pydrake.autodiffutils import AutoDiffXd
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem_
from pydrake.systems.primitives import LinearSystem
from pydrake.systems.scalar_conversion import TemplateSystem

from .._math import scalar_value
from .coupling import LinearFingerCoupling, ThumbCoupling, dof_selection

__all__ = ["estimate_linear", "GradientSearchResult", "thumb_base_gradient_search",
           "estimate_thumb", "noise_error_bound",
           "LinkPositionEstimator_", "LinkPositionEstimator", "LinkStateEstimator", "link_state_estimator"]


def estimate_linear(coupling: LinearFingerCoupling, dh) -> np.ndarray:
    """(5.15): plant joint angles from measured length changes ``dh = h(q) - h(0)``."""
    dh = np.asarray(dh, dtype=float)
    if dh.shape != (coupling.num_tendons,):
        raise ValueError(f"dh must have shape ({coupling.num_tendons},), got {dh.shape}")
    q_dof = coupling.dof_pseudo_inverse() @ dh
    return coupling.dof_selection @ q_dof


@dataclass
class GradientSearchResult:
    """Outcome of Algorithm 1: estimate, final cost and step, accepted steps; ``projected`` counts the trial points
    the projection onto ``[-limit, limit]^2`` moved, ``at_limit`` says the estimate lies on that bound (the pose
    may lie beyond it)."""

    q: np.ndarray
    cost: float
    step: float
    accepted: int
    iterations: int
    projected: int = 0
    at_limit: bool = False
    limit: float = np.pi / 2


def _search(base, dh, qa, qb, iterations, step0, min_step, limit, x, buf):
    """Algorithm 1's loop (see :func:`thumb_base_gradient_search`), compiled by :func:`_thumb_kernels`: ``base`` is
    the thumb's compiled base kinematics (lengths and their Jacobian at ``x``, :meth:`ThumbCoupling._base_kernel`),
    ``x`` (2) and ``buf`` (28) its work arrays.  Returns ``(qa, qb, cost, step, accepted, projected)``."""
    x[0] = 0.0
    x[1] = 0.0
    base(x, buf)
    h0 = buf[:4].copy()

    def cost_grad(a, b):
        x[0] = a
        x[1] = b
        base(x, buf)                       # h and P: the kinematics once per trial point
        c = g0 = g1 = 0.0
        for i in range(4):
            r = buf[i] - h0[i] - dh[i]
            c += r * r
            g0 += buf[4 + 2 * i] * r
            g1 += buf[5 + 2 * i] * r
        return c, 2.0 * g0, 2.0 * g1

    c_best, g0, g1 = cost_grad(qa, qb)
    step, accepted, projected = step0, 0, 0
    for _ in range(iterations):
        g_norm = math.hypot(g0, g1)
        if g_norm == 0.0 or step < min_step:
            break
        fa, fb = qa - step * g0 / g_norm, qb - step * g1 / g_norm
        ta, tb = min(max(fa, -limit), limit), min(max(fb, -limit), limit)
        projected += int(ta != fa or tb != fb)
        c, h0_, h1_ = cost_grad(ta, tb)
        if c < c_best:
            qa, qb, c_best, g0, g1, accepted = ta, tb, c, h0_, h1_, accepted + 1
        else:
            step *= 0.5
    return qa, qb, c_best, step, accepted, projected


def _thumb_step(base, dt, qa, qb, iterations, step0, min_step, limit, x, buf, distal, h0b, refine, out):
    """The estimator's whole thumb step (see :func:`_thumb_kernels`): Algorithm 1 (:func:`_search`) warm-started at
    ``(qa, qb)``, optionally one Gauss-Newton step on the base block (its 2 x 2 normal equations in closed form), and
    the PIP/DIP by the pseudo-inverse ``distal`` (2 x 4); writes the four joint angles into ``out``."""
    qa, qb, _, _, _, _ = _search(base, dt[:4], qa, qb, iterations, step0, min_step, limit, x, buf)
    if refine:
        x[0] = qa
        x[1] = qb
        base(x, buf)
        G00 = G01 = G11 = g0 = g1 = 0.0
        for i in range(4):
            r = dt[i] - (buf[i] - h0b[i])
            p0, p1 = buf[4 + 2 * i], buf[5 + 2 * i]
            G00 += p0 * p0
            G01 += p0 * p1
            G11 += p1 * p1
            g0 += p0 * r
            g1 += p1 * r
        det = G00 * G11 - G01 * G01
        qa += (G11 * g0 - G01 * g1) / det
        qb += (G00 * g1 - G01 * g0) / det
    out[0] = qa
    out[1] = qb
    for a in range(distal.shape[0]):
        acc = 0.0
        for b in range(distal.shape[1]):
            acc += distal[a, b] * dt[4 + b]
        out[2 + a] = acc
    return out


def _thumb_kernels(base):
    """:func:`_search` and :func:`_thumb_step` compiled with the thumb's compiled base kinematics ``base``
    (:meth:`ThumbCoupling._base_kernel`) as a global of one generated module (their ``base`` parameter dropped):
    ``{"search": fn, "step": fn}``.  A global callee is a static call, so numba caches both on disk; passed as an
    argument, ``base`` would be a first-class function, typed anew at every call and not cacheable."""
    import inspect

    from ..components.codegen import compile_source

    def unbound(fn):
        return inspect.getsource(fn).replace("(base, ", "(")
    source = "\n".join([
        "import math", "import numba", "import numpy as np", f"from {base.__module__} import {base.__name__} as base",
        "", "", "@numba.njit(cache=True)", unbound(_search), "", "@numba.njit(cache=True)", unbound(_thumb_step)])
    fns = compile_source(source, ["_search", "_thumb_step"], tag="thumb_search")
    return {"search": fns["_search"], "step": fns["_thumb_step"]}


def thumb_base_gradient_search(coupling: ThumbCoupling, dh_base, q_start=(0.0, 0.0), *,
                               iterations: int = 30, step0: float = 0.1,
                               min_step: float = 1e-7,
                               limit: float = np.pi / 2) -> GradientSearchResult:
    """Algorithm 1: fixed-step gradient search with step halving on (q10, q11).

    ``dh_base`` (4): the measured base tendon length changes ``h_i(q) - h_i(0)`` [m]; ``q_start``: ``(0, 0)``
    is the cold start of Fig 5.16-5.17, the previous estimate the real-time warm start; ``iterations``: 15,
    30, 50 in Fig 5.17; ``step0`` [rad] along the normalised gradient (chosen: 0.1 rad, so that 15
    iterations cannot reach the grid corners from the origin, as the thesis observes), halved down to
    ``min_step``.  Trial points are projected onto ``[-limit, limit]^2`` (the "projected gradient" of
    section 5.6); default pi/2: beyond it the metacarpal crosses the plane of the (coplanar) palm points
    A0..D0, where each pose has a mirror image with the same four tendon lengths.
    """
    dh_base = np.asarray(dh_base, dtype=float)
    if dh_base.shape != (4,):
        raise ValueError(f"dh_base must have shape (4,), got {dh_base.shape}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    if not limit > 0:
        raise ValueError(f"limit must be > 0 [rad], got {limit}")
    qa, qb, c_best, step, accepted, projected = _thumb_kernels(coupling._base_kernel())["search"](
        dh_base, float(q_start[0]), float(q_start[1]), int(iterations), float(step0),
        float(min_step), float(limit), np.empty(2), np.empty(28))
    q = np.array([qa, qb])
    return GradientSearchResult(q=q, cost=c_best, step=step, accepted=accepted,
                                iterations=iterations, projected=projected,
                                at_limit=bool(np.any(np.abs(q[:2]) >= limit)), limit=float(limit))


def estimate_thumb(coupling: ThumbCoupling, dh, q_start=(0.0, 0.0), **kw):
    """All four thumb joints: Algorithm 1 for the base (``kw``: :func:`thumb_base_gradient_search`'s),
    pseudo-inverse for PIP/DIP."""
    dh = np.asarray(dh, dtype=float)
    if dh.shape != (8,):
        raise ValueError(f"dh must have shape (8,), got {dh.shape}")
    search = thumb_base_gradient_search(coupling, dh[:4], q_start, **kw)
    return np.concatenate([search.q, coupling.distal_pseudo_inverse() @ dh[4:]])


def noise_error_bound(coupling: ThumbCoupling, q_base, amplitude: float) -> float:
    """First-order bound on the base estimate error [rad] for per-tendon noise ``|e_i| <= amplitude``:
    ``|dq| <= |P^+| |e| <= 2 amplitude / sigma_min(P_base(q))``."""
    P = coupling.P(np.array([q_base[0], q_base[1], 0.0, 0.0]))[:4, :2]
    return 2.0 * amplitude / np.linalg.svd(P, compute_uv=False)[-1]


# ---------------------------------------------------------------------------------------------
# The estimator as a system (3 kHz, warm-started Algorithm 1 for the thumb base)

@TemplateSystem.define("LinkPositionEstimator_", scope=sys.modules[__name__], T_list=[float, AutoDiffXd])
def LinkPositionEstimator_(T):
    """Joint angles from the measured tendon length changes (no joint sensors, section 5.2.3).

    Inputs ``motor_angle`` (m) [rad] and ``elongation`` (m) [m] (the spring sensors) give the length change
    at the finger base ``dh = elongation - r_m theta - x0 = h(q) - h(0)`` (the optional input ``wrist_offset``
    (m) removes the wrist's).  Output ``joint_angle_estimate`` (n plant joints): the estimate from the
    *current* measurements (module docstring), the thumb base warm-started from the stored estimate, which
    the discrete state updates every ``period``.  Not a state output: one period older than the forces a
    controller reads with it, that lag destabilised the DIP's link mode in every chain design at 3 kHz
    (:func:`~awiwi_drake.control.joint_design.sampled_loop_poles`); a computation delay is the loop's.

    Scalar types: float and AutoDiffXd (the search runs on values, then one Gauss-Newton step
    ``q + P(q)^+ (dh - dh(q))`` in the scalar type carries the derivatives, ``dq/d dh = P^+`` at
    convergence).  Not symbolic: Algorithm 1 branches on cost values.  A thumb base estimate on (or
    beyond) the search's ``+-pi/2`` bound is stored, counted in ``limit_hits`` and warned about once.
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, coupling, motor_pulley_radius: float, offsets, period: float = 1.0 / 3000,
                       iterations: int = 15, step0: float = 0.1, refine: bool = False, converter=None):
            LeafSystem_[T].__init__(self, converter)
            m, n = coupling.num_tendons, coupling.num_joints
            offsets = np.asarray(offsets, dtype=float)
            if offsets.shape != (m,):
                raise ValueError(f"LinkPositionEstimator: offsets must have {m} entries, got {offsets.shape}")
            if not period > 0:
                raise ValueError(f"LinkPositionEstimator: period = {period} must be > 0 [s]")
            self.coupling, self.r_m, self.offsets = coupling, float(motor_pulley_radius), offsets
            self.period, self.iterations, self.step0 = float(period), int(iterations), float(step0)
            self.refine = bool(refine)
            self.limit_hits = 0
            self._h0 = np.asarray(coupling.h(np.zeros(n)), dtype=float)
            # the float path: (S (P S)^+) of every constant-coupling finger as one block matrix (n x m), the
            # thumbs (nonlinear, identity S) by estimate_thumb; a test checks it equals the law functions
            js, ts = coupling.joint_slices, coupling.tendon_slices
            self._linear = np.zeros((n, m))
            self._thumbs = []
            for name, c in coupling.parts.items():
                if c.is_constant:
                    self._linear[js[name], ts[name]] = c.dof_selection @ c.dof_pseudo_inverse()
                else:
                    self._thumbs.append((name, c, js[name], ts[name]))
            # float: Algorithm 1's compiled search called directly (estimate_thumb's own call, without its checks)
            self._search = ({name: _thumb_kernels(c._base_kernel())["step"] for name, c, _, _ in self._thumbs}
                            if T is float else None)
            self._work = (np.empty(2), np.empty(28), np.empty(4))
            self._distal = {name: c.distal_pseudo_inverse() for name, c, _, _ in self._thumbs}
            self._theta = self.DeclareVectorInputPort("motor_angle", m)
            self._x = self.DeclareVectorInputPort("elongation", m)
            self._w = self.DeclareVectorInputPort("wrist_offset", m)
            self._state = self.DeclareDiscreteState(n)
            self.DeclarePeriodicDiscreteUpdateEvent(self.period, 0.0, self._update)
            self._out = self.DeclareVectorOutputPort(
                "joint_angle_estimate", n, self._calc,
                prerequisites_of_calc={self.xd_ticket(), self._theta.ticket(), self._x.ticket(), self._w.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.coupling, other.r_m, other.offsets, other.period, other.iterations,
                            other.step0, other.refine, converter=converter)

        def _update(self, context, discrete_state):
            q = self._out.Eval(context)
            self.note_limit(q)
            discrete_state.set_value(0, q)

        def note_limit(self, q) -> None:
            """Count (and warn once about) a thumb base estimate on the search's projection bound."""
            if not (self._thumbs and T is float):
                return
            for name, c, j, t in self._thumbs:
                limit = GradientSearchResult.limit
                if abs(float(q[j.start])) >= limit or abs(float(q[j.start + 1])) >= limit:
                    self.limit_hits += 1
                    if self.limit_hits == 1:
                        warnings.warn(f"LinkPositionEstimator: the {name} base estimate "
                                      f"{np.round(q[j][:2], 4)} rad sits on the search bound "
                                      f"+-{limit:.4g} rad (the pose may lie beyond it); "
                                      "further hits are counted in limit_hits", RuntimeWarning,
                                      stacklevel=3)

        def _calc(self, context, out):
            w = self._w.Eval(context) if self._w.HasValue(context) else None
            out.SetFromVector(self.estimate(self._theta.Eval(context), self._x.Eval(context), w,
                                            context.get_discrete_state(0).CopyToVector()))

        def estimate(self, theta, elongation, wrist_offset, q_prev):
            """The joint angles (n) from the measurements and the stored estimate ``q_prev`` (the warm start),
            context-free (the output ``joint_angle_estimate``; :class:`~awiwi_drake.control.fused.FusedChain_`
            calls it too).  ``wrist_offset`` None: no wrist."""
            dh = elongation - self.r_m * theta - self.offsets
            if wrist_offset is not None:
                dh = dh - wrist_offset
            if T is float:
                q_val, dh_val = np.asarray(q_prev, dtype=float), np.asarray(dh, dtype=float)
            else:
                q_val = np.array([scalar_value(v) for v in q_prev])
                dh_val = np.array([scalar_value(v) for v in dh])
            q_new = self._linear @ dh_val         # every constant-coupling finger (5.15) in one product
            for name, c, j, t in self._thumbs:    # thumb: Algorithm 1 warm-started at the previous estimate
                if self._search is not None:      # float: Algorithm 1, the Gauss-Newton step and PIP/DIP compiled
                    self._search[name](dh_val[t], float(q_val[j.start]), float(q_val[j.start + 1]), self.iterations,
                                       self.step0, 1e-7, GradientSearchResult.limit, self._work[0], self._work[1],
                                       self._distal[name], self._h0[t][:4], self.refine, self._work[2])
                    q_new[j] = self._work[2]
                    continue
                q_new[j] = estimate_thumb(c, dh_val[t], q_val[j][:2], iterations=self.iterations, step0=self.step0)
            if T is not float:  # one Gauss-Newton step in the scalar type: carries the derivatives
                r = dh - (self.coupling.h(q_new) - self._h0)
                S = dof_selection(self.coupling)
                PS = np.asarray(self.coupling.P(q_new), dtype=float) @ S
                q_new = q_new + S @ (np.linalg.pinv(PS) @ r)
            return q_new

    return Impl


LinkPositionEstimator = LinkPositionEstimator_[None]


@dataclass
class LinkStateEstimator:
    """The hand's joint-state "sensor": :class:`LinkPositionEstimator_` + a discrete derivative.

    ``system`` is a Diagram with inputs named after the rig outputs it reads (``motor_angle``,
    ``elongation`` and, with the wrist, ``wrist_tendon_offset``) and outputs ``joint_angle`` (n) [rad] and
    ``joint_velocity`` (n) [rad/s], the "dirty derivative" ``s / (T s + 1)`` of the estimate discretised at
    the period ``h``: ``z+ = z + h/T (q - z)``, ``v = (q - z) / T`` (``T = h``: the backward difference).
    :meth:`initialize` starts both discrete states at a known pose (after homing).
    """

    system: Diagram
    num_joints: int
    period: float
    velocity_time_constant: float | None = None     # T of the velocity filter (None: the period)

    def fused_spec(self) -> dict:
        """The estimator's part of a :class:`~awiwi_drake.control.fused.FusedChain_` spec (its position
        estimator's arguments and float instance, the velocity filter's time constant, the wrist input)."""
        e = self.system.GetSubsystemByName("link_position_estimator")
        return dict(estimator=dict(coupling=e.coupling, motor_pulley_radius=e.r_m, offsets=e.offsets, period=e.period,
                                   iterations=e.iterations, step0=e.step0, refine=e.refine),
                    estimator_system=e, wrist=self.system.HasInputPort("wrist_tendon_offset"),
                    velocity_time_constant=self.period if self.velocity_time_constant is None
                    else self.velocity_time_constant)

    def initialize(self, context, joint_angles) -> None:
        """Write the start pose into the estimator's (sub)context ``context``."""
        q = np.asarray(joint_angles, dtype=float).reshape(-1)
        if q.shape != (self.num_joints,):
            raise ValueError(f"LinkStateEstimator.initialize: joint_angles must have {self.num_joints} "
                             f"entries, got {q.size}")
        est = self.system.GetSubsystemByName("link_position_estimator")
        self.system.GetMutableSubsystemContext(est, context).SetDiscreteState(q)
        der = self.system.GetSubsystemByName("joint_velocity_filter")
        self.system.GetMutableSubsystemContext(der, context).SetDiscreteState(q)


def link_state_estimator(coupling, motor_pulley_radius: float, offsets, *, period: float = 1.0 / 3000,
                         wrist: bool = False, iterations: int = 15, step0: float = 0.1, refine: bool = False,
                         velocity_time_constant: float | None = None) -> LinkStateEstimator:
    """Build the :class:`LinkStateEstimator` of a finger/hand coupling (see there).

    ``velocity_time_constant`` T [s] of the velocity filter (>= ``period``; default: ``period``,
    the plain backward difference).
    """
    b = DiagramBuilder()
    est = b.AddNamedSystem("link_position_estimator", LinkPositionEstimator(
        coupling, motor_pulley_radius, offsets, period=period, iterations=iterations, step0=step0, refine=refine))
    n = coupling.num_joints
    T = float(period if velocity_time_constant is None else velocity_time_constant)
    if not T >= period * (1 - 1e-12):
        raise ValueError(f"link_state_estimator: velocity_time_constant = {T} s must be >= the period {period} s")
    a, I = period / T, np.eye(n)
    der = b.AddNamedSystem("joint_velocity_filter", LinearSystem((1 - a) * I, a * I, -I / T, I / T, period))
    b.Connect(est.get_output_port(0), der.get_input_port())
    b.ExportInput(est.GetInputPort("motor_angle"), "motor_angle")
    b.ExportInput(est.GetInputPort("elongation"), "elongation")
    if wrist:
        b.ExportInput(est.GetInputPort("wrist_offset"), "wrist_tendon_offset")
    b.ExportOutput(est.get_output_port(0), "joint_angle")
    b.ExportOutput(der.get_output_port(), "joint_velocity")
    d = b.Build()
    d.set_name("link_state_estimator")
    return LinkStateEstimator(d, n, float(period), T)
