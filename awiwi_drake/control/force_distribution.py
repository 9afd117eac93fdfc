"""Tendon force distribution (thesis ch. 7, Algorithm 2, and (7.6) solved).

Given a desired joint torque ``tau_des`` (n) and a desired joint stiffness ``K_des`` (n x n), choose tendon
forces ``f`` (m) in ``[f_min, f_max]`` that produce the torque *exactly* and the stiffness as closely as possible.
With the project's sign convention ``tau = -P^T f`` (docs/ARCHITECTURE.md; the thesis writes ``tau = P^T f``)
every ``f = f_p + W alpha``, ``f_p = -(P^T)^+ tau_des``, ``W = ker(P^T)``, produces ``tau_des``; the joint
stiffness is (5.12)/(7.1) ``K_q(f) = P^T diag(k_t(f)) P + sum_i f_i d^2 h_i / dq^2``.

* :class:`TendonForceDistribution` is Algorithm 2: projected gradient descent on ``alpha`` with step halving on

      C(alpha) = gamma1 ||K_des - K_q(f)||_F^2 / ||K_des||_F^2
               + gamma2 sum psi((f - f_min)/delta) + gamma3 sum psi((f_max - f)/delta)

  (the repulsive potential ``psi`` (7.7) acts within ``delta`` of a bound).
* :class:`OptimalForceDistribution` solves (7.6), which the thesis states and drops as too slow: the stiffness
  error under the exact torque (a linear equality) and the bounds, by Gauss-Newton QPs (Drake
  ``MathematicalProgram``, Clarabel) with a line search on the true cost; every iterate is feasible.  Its
  stiffness error against Algorithm 2's: docs/REPRODUCTIONS.md, ch. 7.

``W`` and ``(P^T)^+`` are computed once for a constant coupling and by an SVD per call for the thumb's ``P(q)``.
A start outside the bounds is replaced by the max-margin point of a linear program; a request no force in the
bounds can satisfy returns ``status="infeasible"``: forces are never clipped silently.  Both solvers take a
matrix or a finger coupling of :mod:`awiwi_drake.hand.coupling` (then ``solve(..., q=...)``);
:func:`finger_force_distribution` builds either for one finger of the hand.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from typing import Callable

import numba
import numpy as np
from pydrake.autodiffutils import AutoDiffXd, ExtractValue
from pydrake.solvers import ClarabelSolver, MathematicalProgram, SolverOptions
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem
from scipy.optimize import linprog

from awiwi_drake.components.spring import tendon_spring
from awiwi_drake.components.tendon import joint_stiffness
from awiwi_drake.hand.coupling import FingerCoupling, finger_coupling, reduced_coupling_matrix
from awiwi_drake.parameters.hand import FINGERS, FingerDriveParams
from awiwi_drake.parameters.hand_control import ForceDistributionParams

__all__ = ["DistributionResult", "TendonStiffnessMap", "TendonForceDistribution", "OptimalForceDistribution",
           "coupling_nullspace", "stiffness_cost", "hand_stiffness_map", "law_stiffness_map",
           "finger_force_distribution", "optimum_sensitivity", "TendonForceDistribution_",
           "TendonForceDistributionSystem"]


def _nullspace(P, rtol):
    """:func:`coupling_nullspace` on a float array (plain numpy that numba compiles too: :data:`_nullspace_jit`)."""
    U, s, Vt = np.linalg.svd(P)                       # full matrices: P = U S V^T, P^T = V S U^T
    top = s[0] if s.size else 0.0
    rank = int(np.sum(s > rtol * max(top, 1e-300)))   # s descending
    W = np.ascontiguousarray(U[:, rank:])
    pinv_PT = np.ascontiguousarray(U[:, :rank] / s[:rank]) @ np.ascontiguousarray(Vt[:rank, :])   # (P^T)^+
    return pinv_PT, W, rank


_nullspace_jit = numba.njit(cache=True)(_nullspace)


def coupling_nullspace(P: np.ndarray, *, rtol: float = 1e-10):
    """``(pinv(P^T), W, rank)`` with ``W`` an orthonormal basis of ``ker(P^T)`` (SVD)."""
    return _nullspace(np.asarray(P, dtype=float), float(rtol))


@numba.njit(cache=True)
def _gauss_newton_qp(outer, dk, H, E, f, K_norm2, m, levenberg, Gt, Q, b):
    """``Q``, ``b`` (written in place) of the optimal solver's QP ``min f'^T Q f' / 2 + b^T f'`` at the iterate ``f``.

    ``||E - G (f' - f)||^2 / N + mu ||f' - f||^2`` with ``G[:, i] = vec(dk_i p_i p_i^T + H_i)`` (the
    linearised ``dK_q/df_i``), ``E = K_des - K_q(f)``, ``N = K_norm2``, ``mu = levenberg tr(G^T G / N) / m``
    (``m``: the tendons, not counting a batch's padding); ``outer[i] = p_i p_i^T``, ``Gt`` work space (m x n^2).
    Loops: small matrices, no BLAS call."""
    M, N = outer.shape[0], outer.shape[1]
    NN = N * N
    for i in range(M):
        for a in range(N):
            for c in range(N):
                Gt[i, a * N + c] = dk[i] * outer[i, a, c] + H[i, a, c]
    tr = 0.0
    for i in range(M):
        for j in range(i, M):
            acc = 0.0
            for k in range(NN):
                acc += Gt[i, k] * Gt[j, k]
            Q[i, j] = acc / K_norm2
            Q[j, i] = Q[i, j]
        tr += Q[i, i]
    mu = levenberg * max(tr, 1e-300) / m
    g = np.empty(NN)                                # E + G f (vec)
    for a in range(N):
        for c in range(N):
            g[a * N + c] = E[a, c]
    for i in range(M):
        for k in range(NN):
            g[k] += Gt[i, k] * f[i]
    for i in range(M):
        acc = 0.0
        for k in range(NN):
            acc += Gt[i, k] * g[k]
        b[i] = -2.0 * acc / K_norm2 - 2.0 * mu * f[i]
        for j in range(M):
            Q[i, j] *= 2.0
        Q[i, i] += 2.0 * mu


@numba.njit(cache=True)
def _closed_form_step(Q, b, f, W, pad):
    """Minimiser of ``f'^T Q f' / 2 + b^T f'`` on ``{f + W z}`` (the torque-exact set through ``f``): ``f + W z`` with
    ``(W^T Q W + diag(pad)) z = -W^T (Q f + b)``, the KKT conditions without the bounds (``pad``: 1 on a batch's
    padded columns of ``W``, else 0).  ``W^T Q W`` is symmetric positive definite (``Q`` is, ``W`` has orthonormal
    columns): Cholesky (:func:`_spd_solve`)."""
    M, R = W.shape
    WQ = np.empty((R, M))
    A = np.empty((R, R))
    for r in range(R):
        for j in range(M):
            acc = 0.0
            for i in range(M):
                acc += W[i, r] * Q[i, j]
            WQ[r, j] = acc
        for c in range(R):
            acc = 0.0
            for j in range(M):
                acc += WQ[r, j] * W[j, c]
            A[r, c] = acc
        A[r, r] += pad[r]
    return f + _mv(W, _spd_solve(A, -_mtv(W, _mv(Q, f) + b)))


@numba.njit(cache=True)
def _null_step(W, f, f_target, f_min, f_max):
    """``(d, t)``: the step ``d = W W^T (f_target - f)`` (in the null space: the torque stays exact) and the
    largest ``t <= 1`` keeping ``f + t d`` in the bounds; ``t = 0`` when ``d`` is negligible."""
    d = _mv(W, _mtv(W, f_target - f))
    if not np.sqrt(np.sum(d * d)) > 1e-12 * max(1.0, np.sqrt(np.sum(f * f))):
        return d, 0.0
    t = 1.0
    for i in range(f.shape[0]):
        if d[i] > 0:
            t = min(t, (f_max - f[i]) / d[i])
        elif d[i] < 0:
            t = min(t, (f_min - f[i]) / d[i])
    return d, t


@dataclass
class DistributionResult:
    """Outcome of one force-distribution call.  ``status``: ``"ok"`` (torque exact, forces in bounds),
    ``"infeasible"`` (no force in the bounds produces the torque: the forces returned produce it and violate the
    bounds) or ``"bound_violation"`` (feasible request, the search ended outside the bounds)."""

    forces: np.ndarray                # (m,) [N], never clipped
    status: str
    torque_error: float               # ||-P^T f - tau_des|| [Nm]
    bound_violation: float            # largest excursion beyond [f_min, f_max] [N]
    stiffness: np.ndarray             # achieved K_q (n x n) [Nm/rad]
    stiffness_error: float            # ||K_des - K_q||_F / ||K_des||_F
    iterations: int
    cost: float                       # the final cost (Algorithm 2: C(alpha); optimal: the relative stiffness cost)
    program_qps: int = 0              # optimal: QPs the MathematicalProgram solved (a bound active; not closed form)


def _barrier(d):
    """Repulsive potential psi(d) = (1 - d)^2 / d on (0, 1), 0 beyond (C^1, infinite at the bound)."""
    a = np.maximum(0.0, 1.0 - d)
    return a * a / d


def _barrier_slope(d):
    """d psi / d d = -(1 - d^2)/d^2 on (0, 1), 0 beyond."""
    return np.where(d < 1.0, -(1.0 - d * d) / (d * d), 0.0)


class TendonStiffnessMap:
    """Tendon stiffness as a function of tendon force, ``f -> (k_t(f), dk_t/df)``, by linear interpolation in a
    table, as the thesis tabulates the calibrated spring curve (ch. 4, 15.4.3).

    ``forces`` (an increasing grid [N]), ``stiffness`` (k_t [N/m]) and ``stiffness_slope`` (dk_t/df [1/m]): (G,), one
    table for every tendon, or (m, G), each tendon its own row (:meth:`from_springs`; called with one force per
    tendon)."""

    def __init__(self, forces, stiffness, stiffness_slope):
        self.forces = np.array(forces, dtype=float)
        self.k = np.array(stiffness, dtype=float)
        self.dk = np.array(stiffness_slope, dtype=float)
        for a in (self.forces, self.k, self.dk):    # own read-only copies: hand_stiffness_map shares one map
            a.flags.writeable = False
        if (self.forces.ndim not in (1, 2) or self.forces.shape[-1] < 2
                or np.any(np.diff(self.forces, axis=-1) <= 0)):
            raise ValueError("TendonStiffnessMap.forces must be an increasing grid of at least 2 forces "
                             "(1-D, or one row per tendon)")
        if self.k.shape != self.forces.shape or self.dk.shape != self.forces.shape:
            raise ValueError("TendonStiffnessMap: stiffness and stiffness_slope must match the force grid")
        if np.any(self.k <= 0):
            raise ValueError("TendonStiffnessMap.stiffness must be > 0 on the grid (a slack tendon has no stiffness)")

    @property
    def per_tendon(self) -> bool:
        """True when each tendon has its own row (called with one force per tendon)."""
        return self.forces.ndim == 2

    def rows(self, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(forces, k, dk)`` as ``m`` rows (one per tendon; a shared table repeated)."""
        if self.per_tendon:
            if self.forces.shape[0] != m:
                raise ValueError(f"TendonStiffnessMap has {self.forces.shape[0]} tendon rows, not {m}")
            return self.forces, self.k, self.dk
        return tuple(np.broadcast_to(a, (m, a.size)) for a in (self.forces, self.k, self.dk))

    @classmethod
    def from_springs(cls, springs) -> "TendonStiffnessMap":
        """The map of a :class:`~awiwi_drake.components.spring.TendonSprings` (each tendon its own law):
        one shared table when every tendon has the same law, else one row per tendon, each tabulated
        like :meth:`from_spring` (each distinct law once)."""
        tables = {id(law): law_stiffness_map(law) for law, _ in springs.groups}
        if springs.uniform:
            return tables[id(springs[0])]
        if len({t.forces.size for t in tables.values()}) != 1:
            raise ValueError("TendonStiffnessMap.from_springs: the laws' tables have different lengths")
        rows = [tables[id(law)] for law in springs]
        return cls(np.stack([t.forces for t in rows]), np.stack([t.k for t in rows]), np.stack([t.dk for t in rows]))

    @classmethod
    def from_spring(cls, spring, max_elongation: float, n: int = 2001) -> "TendonStiffnessMap":
        """Tabulate a spring law (``force``, ``stiffness`` and optionally ``stiffness_derivative`` of x)."""
        x = np.linspace(0.0, float(max_elongation), int(n))[1:]
        f = np.asarray(spring.force(x), dtype=float)
        k = np.asarray(spring.stiffness(x), dtype=float)
        if hasattr(spring, "stiffness_derivative"):
            dkdx = np.asarray(spring.stiffness_derivative(x), dtype=float)
        else:
            dkdx = np.gradient(k, x)
        return cls(f, k, dkdx / k)

    def __call__(self, f):
        f = np.asarray(f, dtype=float)
        if not self.per_tendon:
            return np.interp(f, self.forces, self.k), np.interp(f, self.forces, self.dk)
        if f.shape != (self.forces.shape[0],):
            raise ValueError(f"TendonStiffnessMap: one force per tendon ({self.forces.shape[0]}) expected, "
                             f"got shape {f.shape}")
        return _interp_rows(f, self.forces, self.k), _interp_rows(f, self.forces, self.dk)



def stiffness_cost(K_des, K) -> float:
    """Relative stiffness error ``||K_des - K||_F^2 / ||K_des||_F^2`` (the gamma1 term of (7.7))."""
    K_des = np.asarray(K_des, dtype=float)
    return float(np.sum((K_des - K) ** 2) / max(float(np.sum(K_des * K_des)), 1e-300))


def _max_margin_alpha(f_p, W, f_min, f_max):
    """Max-margin alpha with f_min + t <= f_p + W alpha <= f_max - t (LP, HiGHS); None if infeasible."""
    m, r = W.shape
    c = np.zeros(r + 1)
    c[-1] = -1.0                                   # variables [alpha (r), t]; maximise t
    A = np.vstack([np.hstack([-W, np.ones((m, 1))]), np.hstack([W, np.ones((m, 1))])])
    b = np.concatenate([f_p - f_min, f_max - f_p])
    res = linprog(c, A_ub=A, b_ub=b, bounds=[(None, None)] * r + [(None, 0.5 * (f_max - f_min))],
                  method="highs")
    if res.status != 0 or res.x[-1] < 0.0:
        return None
    return res.x[:r]


class _DistributionBase:
    """Shared input handling of the two solvers: coupling (matrix or coupling object), checks."""

    def __init__(self, stiffness_map: Callable, params: ForceDistributionParams | None,
                 coupling, owner: str):
        self.params = params or ForceDistributionParams()
        if not callable(stiffness_map):
            raise ValueError(f"{owner}: stiffness_map must be callable f -> (k_t, dk_t/df)")
        self.stiffness_map = stiffness_map
        self.coupling_object = coupling if isinstance(coupling, FingerCoupling) else None
        if self.coupling_object is not None:     # constant: P at any posture; else evaluated per call
            coupling = coupling.P(np.zeros(coupling.num_joints)) if coupling.is_constant else None
        P = None if coupling is None else self._check_P(coupling)
        self._offline = None if P is None else (P,) + coupling_nullspace(P)

    @staticmethod
    def _check_P(P) -> np.ndarray:
        P = np.asarray(P, dtype=float)
        if P.ndim != 2 or P.shape[0] < P.shape[1]:
            raise ValueError(f"coupling P must be m x n with m tendons >= n joints, got shape {P.shape}")
        if not np.all(np.isfinite(P)):
            raise ValueError("coupling P has non-finite entries")
        return P

    def _coupling_at(self, P, hessian, q):
        """(P, pinv(P^T), W, rank, hessian) for this call (offline, given P, or coupling object at q)."""
        if P is None and q is not None and self.coupling_object is not None and self._offline is None:
            c = self.coupling_object
            q = np.asarray(q, dtype=float)
            if q.shape != (c.num_joints,):
                raise ValueError(f"solve: q has shape {q.shape}; the coupling has {c.num_joints} joints "
                                 f"({', '.join(c.joint_names)})")
            P = c.P(q)
            hessian = c.tension_hessians(q)
        if P is None:
            if self._offline is None:
                need = "q" if self.coupling_object is not None else "P"
                raise ValueError(f"solve: pass {need} (the coupling depends on the posture)")
            P, pinv_PT, W, rank = self._offline
        else:
            P = self._check_P(P)
            pinv_PT, W, rank = coupling_nullspace(P)
        if hessian is not None:
            hessian = np.asarray(hessian, dtype=float)
            m, n = P.shape
            if hessian.shape != (m, n, n):
                raise ValueError(f"solve: hessian has shape {hessian.shape}; expected ({m}, {n}, {n})")
        return P, pinv_PT, W, rank, hessian

    @staticmethod
    def _warm_start(warm_start, m):
        f0 = np.asarray(warm_start, dtype=float).ravel()
        if f0.shape != (m,):
            raise ValueError(f"solve: warm_start has shape {f0.shape}; the coupling has {m} tendons")
        return f0

    @staticmethod
    def _out_of_range(P, f_p, tau_des) -> bool:
        """``tau_des`` is outside the range of ``P^T``: no force produces it (``f_p = -(P^T)^+ tau_des``)."""
        return np.linalg.norm(-P.T @ f_p - tau_des) > 1e-9 * max(1.0, np.linalg.norm(tau_des))

    @staticmethod
    def _check_request(tau_des, K_des, n):
        tau_des = np.asarray(tau_des, dtype=float).ravel()
        K_des = np.asarray(K_des, dtype=float)
        if tau_des.shape != (n,):
            raise ValueError(f"solve: tau_des has shape {tau_des.shape}; the coupling has {n} joints")
        if not np.all(np.isfinite(tau_des)):
            raise ValueError("solve: tau_des has non-finite entries")
        if K_des.shape != (n, n):
            raise ValueError(f"solve: K_des has shape {K_des.shape}; expected ({n}, {n})")
        if not np.all(np.isfinite(K_des)):
            raise ValueError("solve: K_des has non-finite entries")
        if not np.all(np.abs(K_des - K_des.T) <= 1e-12 + 1e-9 * np.abs(K_des.T)):   # np.allclose, 10x cheaper
            raise ValueError("solve: K_des must be symmetric")
        return tau_des, K_des

    def _result(self, f, status, P, hessian, tau_des, K_des, iterations, cost, program_qps=0) -> DistributionResult:
        p = self.params
        K = joint_stiffness(P, self.stiffness_map(f)[0], f, hessian)
        viol = float(max(0.0, np.max(p.f_min - f), np.max(f - p.f_max)))
        if status == "ok" and viol > p.bound_tolerance:
            status = "bound_violation"
        return DistributionResult(
            forces=f, status=status, torque_error=float(np.linalg.norm(-P.T @ f - tau_des)),
            bound_violation=viol, stiffness=K, stiffness_error=float(np.sqrt(stiffness_cost(K_des, K))),
            iterations=iterations, cost=float(cost), program_qps=int(program_qps))

    def timed_solve(self, *args, **kw) -> tuple[DistributionResult, float]:
        """:meth:`solve` and its wall time [s] (for benchmarks)."""
        t0 = time.perf_counter()
        res = self.solve(*args, **kw)
        return res, time.perf_counter() - t0


class TendonForceDistribution(_DistributionBase):
    """Algorithm 2 of the thesis: exact torque, closest stiffness, forces kept off the bounds.

    ``stiffness_map``: ``f -> (k_t(f), dk_t/df)`` (arrays (m,)), e.g. :class:`TendonStiffnessMap`; ``params``:
    bounds, weights, barrier width, iterations, initial step; ``coupling``: a constant (m, n) matrix or
    coupling (``W``, ``(P^T)^+`` computed once), a position-dependent coupling (evaluated at ``solve(..., q=...)``)
    or None (pass ``P`` and ``hessian`` to :meth:`solve`).
    """

    def __init__(self, stiffness_map: Callable, params: ForceDistributionParams | None = None,
                 coupling=None):
        super().__init__(stiffness_map, params, coupling, "TendonForceDistribution")

    # -- cost ---------------------------------------------------------------
    def _cost(self, f, P, hessian, K_des, K_norm2):
        p = self.params
        k, dk = self.stiffness_map(f)
        K = joint_stiffness(P, k, f, hessian)
        E = K_des - K
        d_lo = (f - p.f_min) / p.barrier_width
        d_hi = (p.f_max - f) / p.barrier_width
        if np.any(d_lo <= 0.0) or np.any(d_hi <= 0.0):
            return np.inf, None, K            # outside the bounds: rejected, the step is halved
        C = (p.gamma_stiffness * np.sum(E * E) / K_norm2
             + p.gamma_lower * np.sum(_barrier(d_lo)) + p.gamma_upper * np.sum(_barrier(d_hi)))
        # dC/df_i: d(P^T diag(k) P)/df_i = dk_i P_i^T P_i, contracted with E: dk_i P_i E P_i^T
        EdK = dk * np.sum((P @ E) * P, axis=1)
        if hessian is not None:
            EdK = EdK + np.einsum("jk,ijk->i", E, hessian)
        g = (-2.0 * p.gamma_stiffness / K_norm2 * EdK
             + p.gamma_lower * _barrier_slope(d_lo) / p.barrier_width
             - p.gamma_upper * _barrier_slope(d_hi) / p.barrier_width)
        return C, g, K

    def _search(self, alpha, f_p, W, P, hessian, K_des, K_norm2):
        p = self.params
        C, g_f, K = self._cost(f_p + W @ alpha, P, hessian, K_des, K_norm2)
        g = W.T @ g_f
        s = p.initial_step
        it = 0
        for it in range(1, p.iterations + 1):
            gn = np.linalg.norm(g)
            if gn == 0.0 or s < p.min_step:
                break
            cand = alpha - s * g / gn
            C_new, g_f_new, K_new = self._cost(f_p + W @ cand, P, hessian, K_des, K_norm2)
            if C_new < C:
                alpha, C, K, g = cand, C_new, K_new, W.T @ g_f_new
            else:
                s *= 0.5
        return alpha, C, K, it

    def solve(self, tau_des, K_des, *, P=None, hessian=None, q=None, warm_start=None) -> DistributionResult:
        """Distribute ``tau_des`` (n) [Nm] with the symmetric target stiffness ``K_des`` (n x n) [Nm/rad].

        ``P`` (m, n): the coupling at the current posture (online SVD), ``hessian`` (m, n, n) ``dP_ij/dq_k`` (the
        geometric stiffness term); ``q``: the posture of a position-dependent coupling given to the constructor;
        ``warm_start`` (m,): the previous forces [N], whose null-space part starts the search.
        """
        P, pinv_PT, W, _, hessian = self._coupling_at(P, hessian, q)
        m, n = P.shape
        tau_des, K_des = self._check_request(tau_des, K_des, n)
        p = self.params
        f_p = -pinv_PT @ tau_des
        K_norm2 = max(float(np.sum(K_des * K_des)), 1e-300)
        r = W.shape[1]
        if warm_start is None:
            # start at the pretension that puts the mean force mid-range (the null space of an
            # antagonistic coupling contains the all-positive co-contraction direction)
            alpha = W.T @ (np.full(m, 0.5 * (p.f_min + p.f_max)) - f_p) if r else np.zeros(0)
        else:
            alpha = W.T @ (self._warm_start(warm_start, m) - f_p)
        f_start = f_p + W @ alpha
        inside = np.all(f_start > p.f_min) and np.all(f_start < p.f_max)
        status, iters, C = "ok", 0, np.inf
        if self._out_of_range(P, f_p, tau_des):
            status = "infeasible"
        elif not inside:
            start = _max_margin_alpha(f_p, W, p.f_min, p.f_max)
            if start is None or not np.all((f_p + W @ start > p.f_min) & (f_p + W @ start < p.f_max)):
                status = "infeasible"     # no force strictly inside the bounds produces tau_des
            else:
                alpha = start
        if status == "ok":
            alpha, C, _, iters = self._search(alpha, f_p, W, P, hessian, K_des, K_norm2)
        return self._result(f_p + W @ alpha, status, P, hessian, tau_des, K_des, iters, C)


class OptimalForceDistribution(_DistributionBase):
    """(7.6) solved with Drake's ``MathematicalProgram``: ``min_f ||K_des - K_q(f)||_F^2 / ||K_des||_F^2``
    subject to ``-P^T f = tau_des`` and ``f_min <= f <= f_max``.

    Each iteration linearises ``K_q`` at the feasible ``f_k`` (``dK_q/df_i = dk_t,i p_i p_i^T + H_i``), solves the
    convex QP ``min ||E_k - G (f - f_k)||^2 + mu ||f - f_k||^2`` (``mu = levenberg tr(G^T G) / m`` keeps it strictly
    convex, e.g. on the 4 x 2 thumb base), projects the step onto ``ker P^T``, cuts it at the bounds and halves it
    until the *true* cost decreases; it stops when the relative decrease falls below ``tolerance`` or after
    ``max_iterations`` QPs.  The QP's equality-constrained optimum (closed form on ``ker P^T``) is its optimum
    when it lies in the bounds; only otherwise is the program solved (``fast_path=False``: always).

    ``stiffness_map``, ``params``, ``coupling``: as :class:`TendonForceDistribution` (no barrier: the bounds are
    hard).  Chosen: ``max_iterations`` 30 (converged in the tests), ``levenberg`` 1e-6 (negligible against the
    Gauss-Newton term).  ``solver_options``: a ``pydrake.solvers.SolverOptions`` for Clarabel.
    """

    def __init__(self, stiffness_map: Callable, params: ForceDistributionParams | None = None,
                 coupling=None, *, max_iterations: int = 30, tolerance: float = 1e-10,
                 levenberg: float = 1e-6, fast_path: bool = True, solver_options=None):
        super().__init__(stiffness_map, params, coupling, "OptimalForceDistribution")
        if int(max_iterations) < 1:
            raise ValueError(f"OptimalForceDistribution: max_iterations = {max_iterations} must be >= 1")
        if not tolerance > 0.0:
            raise ValueError(f"OptimalForceDistribution: tolerance = {tolerance} must be > 0")
        if not levenberg > 0.0:
            raise ValueError(f"OptimalForceDistribution: levenberg = {levenberg} must be > 0")
        self.max_iterations = int(max_iterations)
        self.tolerance = float(tolerance)
        self.levenberg = float(levenberg)
        if not isinstance(fast_path, (bool, np.bool_)):
            raise ValueError(f"OptimalForceDistribution: fast_path = {fast_path!r} must be True or False")
        if solver_options is not None and not isinstance(solver_options, SolverOptions):
            raise ValueError(f"OptimalForceDistribution: solver_options must be a pydrake.solvers.SolverOptions, "
                             f"got {type(solver_options).__name__}")
        self.fast_path = bool(fast_path)
        self.solver_options = solver_options
        self._solver = ClarabelSolver()
        self._programs: dict = {}

    def _program(self, m: int, rank: int):
        """The QP, built once per (m, rank); its coefficients are updated at every iteration."""
        key = (m, rank)
        if key not in self._programs:
            p = self.params
            prog = MathematicalProgram()
            f = prog.NewContinuousVariables(m, "f")
            cost = prog.AddQuadraticCost(np.eye(m), np.zeros(m), f, is_convex=True)
            eq = prog.AddLinearEqualityConstraint(np.zeros((rank, m)), np.zeros(rank), f)
            prog.AddBoundingBoxConstraint(np.full(m, p.f_min), np.full(m, p.f_max), f)
            self._programs[key] = (prog, cost.evaluator(), eq.evaluator())
        return self._programs[key]

    def _qp(self, Q, b, f, W, P, tau_des, rank, equality):
        """Minimiser of ``f'^T Q f' / 2 + b^T f'`` on ``{-P^T f' = tau_des, f_min <= f' <= f_max}``
        and whether the program solved it (``f``: a feasible point; see the class docstring);
        None when the program fails.  ``equality``: a one-element list caching the SVD rows.
        """
        p = self.params
        r = W.shape[1]
        if self.fast_path:
            if r == 0:
                return f, False                           # the torque alone fixes the forces
            f_star = _closed_form_step(Q, b, f, W, np.zeros(r))
            if np.all(f_star >= p.f_min) and np.all(f_star <= p.f_max):
                return f_star, False
        m = f.size
        prog, cost_eval, eq_eval = self._program(m, rank)
        if not equality:
            # the torque equality on the range rows: U_r^T f = -S_r^-1 V_r^T tau  (P = U S V^T)
            U, sv, Vt = np.linalg.svd(P, full_matrices=False)
            equality.append((U[:, :rank].T, -(Vt[:rank] @ tau_des) / sv[:rank]))
        eq_eval.UpdateCoefficients(*equality[0])
        cost_eval.UpdateCoefficients(Q, b, 0.0, True)
        result = self._solver.Solve(prog, f, self.solver_options)
        return (result.GetSolution() if result.is_success() else None), True

    def _stiffness(self, f, P, hessian):
        k, dk = self.stiffness_map(f)
        return joint_stiffness(P, k, f, hessian), np.asarray(dk, dtype=float)

    def solve(self, tau_des, K_des, *, P=None, hessian=None, q=None, warm_start=None,
              max_iterations: int | None = None) -> DistributionResult:
        """As :meth:`TendonForceDistribution.solve`; ``warm_start`` is used when, moved onto the exact torque, it
        is inside the bounds; ``max_iterations``: QPs for this call (e.g. 1-3 in a 3 kHz loop).  ``status`` is
        ``"ok"`` or ``"infeasible"``; ``cost`` the relative stiffness cost."""
        P, pinv_PT, W, rank, hessian = self._coupling_at(P, hessian, q)
        m, n = P.shape
        tau_des, K_des = self._check_request(tau_des, K_des, n)
        p = self.params
        iters_max = self.max_iterations if max_iterations is None else int(max_iterations)
        if iters_max < 0:
            raise ValueError(f"solve: max_iterations = {max_iterations} must be >= 0")
        f_p = -pinv_PT @ tau_des
        if self._out_of_range(P, f_p, tau_des):
            return self._result(f_p, "infeasible", P, hessian, tau_des, K_des, 0, np.inf)
        f = None
        if warm_start is not None:                        # the same internal forces, exact torque
            f0 = f_p + W @ (W.T @ self._warm_start(warm_start, m))
            if np.all(f0 >= p.f_min) and np.all(f0 <= p.f_max):
                f = f0
        if f is None:
            alpha = _max_margin_alpha(f_p, W, p.f_min, p.f_max)
            if alpha is None:
                mid = W.T @ (np.full(m, 0.5 * (p.f_min + p.f_max)) - f_p)
                return self._result(f_p + W @ mid, "infeasible", P, hessian, tau_des, K_des, 0, np.inf)
            f = f_p + W @ alpha
            if not (np.all(f >= p.f_min) and np.all(f <= p.f_max)):   # LP tolerance at a tight bound
                return self._result(f, "infeasible", P, hessian, tau_des, K_des, 0, np.inf)
        equality = []
        program_qps = 0
        K_norm2 = max(float(np.sum(K_des * K_des)), 1e-300)
        K, dk = self._stiffness(f, P, hessian)
        C = float(np.sum((K_des - K) ** 2) / K_norm2)
        outer = np.einsum("ij,ik->ijk", P, P)             # p_i p_i^T
        H = np.zeros((m, n, n)) if hessian is None else np.ascontiguousarray(hessian)
        Gt, Q, b = np.empty((m, n * n)), np.empty((m, m)), np.empty(m)
        it = 0
        for it in range(1, iters_max + 1):
            _gauss_newton_qp(outer, dk, H, K_des - K, f, K_norm2, float(m), self.levenberg, Gt, Q, b)
            f_qp, used_program = self._qp(Q, b, f, W, P, tau_des, rank, equality)
            program_qps += used_program
            if f_qp is None:
                break
            d, t = _null_step(W, f, np.asarray(f_qp, dtype=float), p.f_min, p.f_max)
            accepted = False
            while t > 1e-8:
                f_new = f + t * d
                K_new, dk_new = self._stiffness(f_new, P, hessian)
                C_new = float(np.sum((K_des - K_new) ** 2) / K_norm2)
                if C_new < C:
                    accepted = True
                    break
                t *= 0.5
            if not accepted:
                break
            decrease = C - C_new
            f, K, dk, C = f_new, K_new, dk_new, C_new
            if decrease <= self.tolerance * max(C, 1e-12):
                break
        return self._result(f, "ok", P, hessian, tau_des, K_des, it, C, program_qps)


def hand_stiffness_map(drive: FingerDriveParams | None = None) -> TendonStiffnessMap:
    """``k_t(f)`` of the hand's calibrated tendon spring (ch. 4, ``tendon_spring(drive.spring)``), tabulated once per
    spring parameter set (equal parameters give the same law object, so the same map)."""
    return law_stiffness_map(tendon_spring((drive or FingerDriveParams()).spring))


def law_stiffness_map(spring) -> TendonStiffnessMap:
    """``k_t(f)`` of one spring law, tabulated over its calibrated range (:meth:`TendonStiffnessMap.from_spring`);
    once per law object (the rigs share their law objects)."""
    try:
        return _LAW_MAPS[spring]
    except KeyError:
        table = _LAW_MAPS[spring] = TendonStiffnessMap.from_spring(spring, spring.max_elongation)
        return table


_LAW_MAPS: dict = {}     # law object (hashed by identity, kept alive here) -> its table


def finger_force_distribution(finger: str, *, method: str = "optimal", params: ForceDistributionParams | None = None,
                              drive: FingerDriveParams | None = None, finger_params=None, springs=None,
                              **solver_options):
    """Force distribution of one finger (``thumb``, ``index``, ``middle``, ``ring``, ``fifth``) of the hand with its
    own coupling, radii (``finger_params``, default the finger's in ``parameters.hand``) and spring curve.

    ``method``: ``"optimal"`` (:class:`OptimalForceDistribution`) or ``"algorithm2"``
    (:class:`TendonForceDistribution`); ``params``: bounds and search settings; ``drive``: supplies the spring law
    (``drive.spring``, default the hand's) of every tendon, unless ``springs`` (a ``TendonSprings`` of the finger's
    tendons in routing order) gives each tendon its own table (:meth:`TendonStiffnessMap.from_springs`).

    The joints are the finger's *independent* DoF: on the ring and fifth the DIP follows the PIP (5.16), so
    ``tau_des``/``K_des`` are on (abd, MCP, PIP) (the fifth: HMC first) and the coupling is ``P S``.  The thumb's
    coupling depends on the posture: ``solve(tau_des, K_des, q=q)``.
    """
    if finger not in FINGERS:
        raise ValueError(f"finger must be one of {FINGERS}, got {finger!r}")
    methods = {"optimal": OptimalForceDistribution, "algorithm2": TendonForceDistribution}
    if method not in methods:
        raise ValueError(f"method must be one of {sorted(methods)}, got {method!r}")
    coupling = finger_coupling(finger, finger_params)
    m = coupling.num_tendons
    if coupling.is_constant and coupling.dof_selection.shape[0] != coupling.dof_selection.shape[1]:
        coupling = reduced_coupling_matrix(coupling)
    if springs is None:
        table = hand_stiffness_map(drive)
    else:
        if len(springs) != m:
            raise ValueError(f"finger_force_distribution: springs has {len(springs)} laws; the {finger} has "
                             f"{m} tendons")
        table = TendonStiffnessMap.from_springs(springs)
    return methods[method](table, params, coupling, **solver_options)


@numba.njit(cache=True)
def _stiffness_of(P, kt, f, H):
    """(5.12) ``P^T diag(k_t) P + sum_i f_i H_i`` (compiled twin of :func:`joint_stiffness` for the batch)."""
    M, N = P.shape
    K = np.zeros((N, N))
    for i in range(M):
        for a in range(N):
            for b in range(N):
                K[a, b] += kt[i] * P[i, a] * P[i, b] + f[i] * H[i, a, b]
    return K


@numba.njit(cache=True)
def _interp_rows(f, gf, gv):
    """``np.interp(f[i], gf[i], gv[i])`` per tendon (each tendon's own table row): numpy's rule written out (ends
    held, a grid point exact, else ``slope (x - x_j) + y_j`` on the bracketing segment)."""
    out = np.empty(f.shape[0])
    n = gf.shape[1]
    for i in range(f.shape[0]):
        x, xp, fp = f[i], gf[i], gv[i]
        if not x > xp[0]:
            out[i] = fp[0] if x <= xp[0] else np.interp(x, xp, fp)     # NaN: numpy's own
        elif x >= xp[n - 1]:
            out[i] = fp[n - 1]
        else:
            lo = np.searchsorted(xp, x, side="right") - 1      # xp[lo] <= x < xp[lo + 1]
            if xp[lo] == x:
                out[i] = fp[lo]
            else:
                out[i] = (fp[lo + 1] - fp[lo]) / (xp[lo + 1] - xp[lo]) * (x - xp[lo]) + fp[lo]
    return out


@numba.njit(cache=True)
def _mv(A, x):
    """``A x`` by loops (small matrices: no BLAS call, no temporaries)."""
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        s = 0.0
        for j in range(A.shape[1]):
            s += A[i, j] * x[j]
        out[i] = s
    return out


@numba.njit(cache=True)
def _mtv(A, x):
    """``A^T x`` by loops."""
    out = np.zeros(A.shape[1])
    for j in range(A.shape[0]):
        xj = x[j]
        for i in range(A.shape[1]):
            out[i] += A[j, i] * xj
    return out


@numba.njit(cache=True)
def _spd_solve(A, r):
    """``A^-1 r`` for a small symmetric positive definite ``A`` (Cholesky, by loops)."""
    n = A.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            t = A[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / L[j, j]
    y = np.empty(n)
    for i in range(n):
        t = r[i]
        for k in range(i):
            t -= L[i, k] * y[k]
        y[i] = t / L[i, i]
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        t = y[i]
        for k in range(i + 1, n):
            t -= L[k, i] * x[k]
        x[i] = t / L[i, i]
    return x


@numba.njit(cache=True)
def _batch_iterate(P, pinv, W, pad, H, outer, real, m_real, tau, Kd, fp0, fallback, iterations, f_min, f_max,
                   levenberg, tolerance, grid_f, grid_k, grid_dk):
    """The warm-started Gauss-Newton iterations of :meth:`OptimalForceDistribution.solve` for padded fingers,
    compiled: the same start (torque-exact projection of the previous forces), QP (:func:`_gauss_newton_qp`),
    closed form (:func:`_closed_form_step`), step cut at the bounds (:func:`_null_step`) and cost test.  Sets
    ``fallback[k]`` wherever ``solve`` would take another branch (see :class:`_FingerBatch`); returns the forces.
    The small products are loops: no BLAS call per step."""
    F, M, N = P.shape
    out = np.zeros((F, M))
    Gt, Q, b = np.empty((M, N * N)), np.empty((M, M)), np.empty(M)
    for k in range(F):
        if fallback[k]:
            continue
        Pk, Wk, Kdk = P[k], W[k], Kd[k]
        f_p = -_mv(pinv[k], tau[k])
        resid = _mtv(Pk, f_p) + tau[k]
        if np.sqrt(np.sum(resid * resid)) > 1e-9 * max(1.0, np.sqrt(np.sum(tau[k] * tau[k]))):
            fallback[k] = True
            continue
        f = f_p + _mv(Wk, _mtv(Wk, fp0[k]))
        inside = True
        for i in range(M):
            if real[k, i] and (f[i] < f_min or f[i] > f_max):
                inside = False
        if not inside:
            fallback[k] = True
            continue
        Kn = max(np.sum(Kdk * Kdk), 1e-300)
        dk = _interp_rows(f, grid_f[k], grid_dk[k])
        K = _stiffness_of(Pk, _interp_rows(f, grid_f[k], grid_k[k]), f, H[k])
        E = Kdk - K
        C = np.sum(E * E) / Kn
        for _ in range(iterations):
            _gauss_newton_qp(outer[k], dk, H[k], E, f, Kn, m_real[k], levenberg, Gt, Q, b)
            f_star = _closed_form_step(Q, b, f, Wk, pad[k])
            bound = False
            for i in range(M):
                if real[k, i] and (f_star[i] < f_min or f_star[i] > f_max):
                    bound = True
            if bound:                       # the MathematicalProgram's case
                fallback[k] = True
                break
            d, t = _null_step(Wk, f, f_star, f_min, f_max)
            if not t > 1e-8:
                break
            f_new = f + t * d
            dk_new = _interp_rows(f_new, grid_f[k], grid_dk[k])
            K_new = _stiffness_of(Pk, _interp_rows(f_new, grid_f[k], grid_k[k]), f_new, H[k])
            E = Kdk - K_new
            C_new = np.sum(E * E) / Kn
            if not C_new < C:               # solve() would halve the step
                fallback[k] = True
                break
            decrease = C - C_new
            f, K, dk, C = f_new, K_new, dk_new, C_new
            if decrease <= tolerance * max(C, 1e-12):
                break
        out[k] = f
    return out


@numba.njit(cache=True)
def _batch_step(dyn, P_dyn, H_dyn, P, pinv, W, pad, H, outer, real, m_real, tau, Kv, f_prev, d, kk, t, tauP, Kd, fp0,
                iterations, f_min, f_max, levenberg, tolerance, grid_f, grid_k, grid_dk):
    """:meth:`_FingerBatch.update` after the thumb's kinematics, compiled: the varying finger ``dyn`` (-1: none) filled
    from its ``P_dyn``, ``H_dyn`` (null space by :data:`_nullspace_jit`, its outer products), the stacked request
    gathered into the padded arrays (``d``, ``kk``, ``t``: :class:`_FingerBatch`'s index rows), :func:`_batch_iterate`,
    the forces scattered back.  Returns (forces, fallback)."""
    F = P.shape[0]
    fallback = np.zeros(F, dtype=np.bool_)
    if dyn >= 0:
        m, n = P_dyn.shape
        if not np.all(np.isfinite(P_dyn)):
            fallback[dyn] = True
        else:
            pinv_PT, Wn, rank = _nullspace_jit(P_dyn, 1e-10)
            if rank != n:
                fallback[dyn] = True
            else:
                r = Wn.shape[1]
                P[dyn], pinv[dyn], W[dyn] = 0.0, 0.0, 0.0
                P[dyn, :m, :n] = P_dyn
                pinv[dyn, :m, :n] = pinv_PT
                W[dyn, :m, :r] = Wn
                pad[dyn] = 1.0
                pad[dyn, :r] = 0.0
                H[dyn, :m, :n, :n] = H_dyn
                for i in range(P.shape[1]):
                    for a in range(P.shape[2]):
                        for b in range(P.shape[2]):
                            outer[dyn, i, a, b] = P[dyn, i, a] * P[dyn, i, b]
    for j in range(d.shape[1]):
        tauP[d[0, j], d[1, j]] = tau[d[2, j]]
    for j in range(kk.shape[1]):
        Kd[kk[0, j], kk[1, j], kk[2, j]] = Kv[kk[3, j]]
    for j in range(t.shape[1]):
        fp0[t[0, j], t[1, j]] = f_prev[t[2, j]]
    f = _batch_iterate(P, pinv, W, pad, H, outer, real, m_real, tauP, Kd, fp0, fallback, iterations, f_min, f_max,
                       levenberg, tolerance, grid_f, grid_k, grid_dk)
    f_all = np.empty(t.shape[1])
    for j in range(t.shape[1]):
        f_all[t[2, j]] = f[t[0, j], t[1, j]]
    return f_all, fallback


class _FingerBatch:
    """Warm-started (7.6) iterations of several fingers at once (the float path of the loop system), padded to
    common sizes and iterated by one compiled call (:func:`_batch_iterate`) with the formulas of
    :meth:`OptimalForceDistribution.solve`.  A finger is solved by its own ``solve`` instead whenever that would
    take another branch (LP start, infeasible request, an active bound, step halving, the thumb's P(q) losing
    rank), so the result is always the per-finger solver's."""

    def __init__(self, parts, coupling_objects, diagonal: bool = False):
        self.parts = parts
        # gather/scatter indices between the loop's stacked vectors and the padded per-finger arrays
        # (tendons, DoF, stiffness entries: ``diagonal`` n_f per finger, else n_f x n_f row-major)
        t, d, kk = [], [], []          # rows (finger, index[, index], source)
        for k, (_, sd, st, sk, _) in enumerate(parts):
            n = sd.stop - sd.start
            t += [(k, i, st.start + i) for i in range(st.stop - st.start)]
            d += [(k, i, sd.start + i) for i in range(n)]
            kk += [(k, a, b, sk.start + (a if diagonal else a * n + b))
                   for a in range(n) for b in ((a,) if diagonal else range(n))]
        self._t, self._d, self._k = (np.array(rows, dtype=np.int64).T.copy() for rows in (t, d, kk))
        solvers = [pt[0] for pt in parts]
        s0 = solvers[0]
        self.params, self.levenberg, self.tolerance = s0.params, s0.levenberg, s0.tolerance
        F = len(parts)
        dims = [(st.stop - st.start, sd.stop - sd.start) for _, sd, st, _, _ in parts]
        self.M, self.N = max(d[0] for d in dims), max(d[1] for d in dims)
        self.R = max(m - n for m, n in dims)
        M, N, R = self.M, self.N, self.R
        self.dims, self.couplings = dims, coupling_objects
        self.P, self.pinv = np.zeros((F, M, N)), np.zeros((F, M, N))
        self.W, self.pad = np.zeros((F, M, R)), np.ones((F, R))
        self.H = np.zeros((F, M, N, N))
        self.real = np.zeros((F, M), dtype=bool)
        self.m = np.array([d[0] for d in dims], dtype=float)
        self.dynamic = []
        for k, ((s, *_), (m, n)) in enumerate(zip(parts, dims)):
            self.real[k, :m] = True
            if s._offline is None:
                self.dynamic.append(k)
            else:                                       # fresh arrays: P, pinv, W zero and pad 1 beyond the finger
                P, pinv_PT, W = s._offline[:3]
                self.P[k, :m, :n], self.pinv[k, :m, :n], self.W[k, :m, :W.shape[1]] = P, pinv_PT, W
                self.pad[k, :W.shape[1]] = 0.0
        self.outer = np.einsum("fij,fik->fijk", self.P, self.P)
        # each tendon's stiffness table row (a finger's shared table repeated; padded tendons: row 0)
        G = solvers[0].stiffness_map.forces.shape[-1]
        self.grid_f, self.grid_k, self.grid_dk = (np.zeros((F, M, G)) for _ in range(3))
        for k, ((s, *_), (m, _)) in enumerate(zip(parts, dims)):
            for grid, row in zip((self.grid_f, self.grid_k, self.grid_dk), s.stiffness_map.rows(m)):
                grid[k, :m], grid[k, m:] = row, row[0]

    @staticmethod
    def compatible(solvers) -> bool:
        """All optimal solvers on the fast path with one shared setting (bounds, iteration rules) and
        stiffness tables of one length (each finger's own tables, a row per tendon when its laws differ)."""
        s0 = solvers[0]
        if not all(isinstance(s, OptimalForceDistribution) and s.fast_path for s in solvers):
            return False
        return all(s.params == s0.params and s.levenberg == s0.levenberg and s.tolerance == s0.tolerance
                   and isinstance(s.stiffness_map, TendonStiffnessMap)
                   and s.stiffness_map.forces.shape[-1] == s0.stiffness_map.forces.shape[-1]
                   for s in solvers)

    def update(self, tau, Kv, f_prev, q, iterations):
        """New forces (all tendons, stacked as the loop system's) and the fingers left to their own solver
        (bool F), from the stacked torque, stiffness entries and previous forces: the thumb's P(q) and tension
        Hessians from one kernel call, the rest one compiled call (:func:`_batch_step`)."""
        F, M, N = len(self.parts), self.M, self.N
        p = self.params
        if len(self.dynamic) > 1:
            raise ValueError("TendonForceDistribution: the batch takes one finger with a varying P(q)")
        if getattr(self, "_gather", None) is None:      # padded work arrays: the padding stays 0, the rest is set
            self._gather = (np.zeros((F, N)), np.zeros((F, N, N)), np.zeros((F, M)))
            self._none = (np.zeros((1, 1)), np.zeros((1, 1, 1)))
        dyn, (P_dyn, H_dyn) = -1, self._none
        if self.dynamic:
            dyn = self.dynamic[0]
            P_dyn, H_dyn = self.couplings[dyn].coupling_and_hessians(q[self.parts[dyn][4]])
        return _batch_step(dyn, P_dyn, H_dyn, self.P, self.pinv, self.W, self.pad, self.H, self.outer, self.real,
                           self.m, tau, Kv, f_prev, self._d, self._k, self._t, *self._gather, int(iterations),
                           float(p.f_min), float(p.f_max), float(self.levenberg), float(self.tolerance), self.grid_f,
                           self.grid_k, self.grid_dk)


# ----------------------------------------------------------------------------
# sensitivity of the optimum (implicit-function theorem) and the loop system
def optimum_sensitivity(solver: OptimalForceDistribution, result: DistributionResult, tau_des, K_des, *,
                        P=None, hessian=None, q=None, active_tolerance: float = 1e-5):
    """Derivatives ``(df/dtau (m x n), df/dvec(K_des) (m x n^2))`` of a converged optimum of (7.6).

    Implicit-function theorem on the first-order conditions with the active set held: the
    torque equality and the active bounds fix ``f`` on a subspace, the reduced gradient
    ``Z^T grad C`` stays zero on its complement.  The Hessian of the true cost is
    ``2/N (G^T G - diag(d2k_t/df2_i p_i^T E p_i))`` (``G`` as in the solver, ``E = K_des - K_q``,
    ``N = ||K_des||_F^2``); ``d grad C / d vec(K_des) = -2/N G^T`` at a stationary point.
    Valid at a strict (non-degenerate) optimum; ``result`` must come from ``solver`` at these inputs.
    """
    P, _, _, rank, hessian = solver._coupling_at(P, hessian, q)
    m, n = P.shape
    tau_des, K_des = solver._check_request(tau_des, K_des, n)
    p = solver.params
    f = np.asarray(result.forces, dtype=float)
    k, dk = solver.stiffness_map(f)
    grid = getattr(solver.stiffness_map, "forces", None)
    h = 1e-3 if grid is None else float(np.min(np.diff(grid)))
    ddk = (solver.stiffness_map(f + h)[1] - solver.stiffness_map(f - h)[1]) / (2 * h)
    outer = np.einsum("ij,ik->ijk", P, P)
    G = (dk[:, None, None] * outer + (hessian if hessian is not None else 0.0)).reshape(m, n * n).T
    E = K_des - joint_stiffness(P, k, f, hessian)
    N = max(float(np.sum(K_des * K_des)), 1e-300)
    Hc = 2.0 / N * (G.T @ G - np.diag(ddk * np.einsum("ij,jk,ik->i", P, E, P)))
    U, s, Vt = np.linalg.svd(P, full_matrices=False)
    active = np.nonzero((f - p.f_min <= active_tolerance) | (p.f_max - f <= active_tolerance))[0]
    C = np.vstack([U[:, :rank].T, np.eye(m)[active]])
    C_pinv = np.linalg.pinv(C)
    _, sc, Vc = np.linalg.svd(C)
    Z = Vc[int(np.sum(sc > 1e-10 * sc.max())):].T                  # null space of the fixed constraints
    drhs_dtau = np.vstack([-(Vt[:rank].T / s[:rank]).T, np.zeros((len(active), n))])
    df_p = C_pinv @ drhs_dtau                                      # m x n
    if Z.shape[1] == 0:
        return df_p, np.zeros((m, n * n))
    ZHZ = Z.T @ Hc @ Z
    dtau = df_p - Z @ np.linalg.solve(ZHZ, Z.T @ Hc @ df_p)
    dK = Z @ np.linalg.solve(ZHZ, Z.T @ (2.0 / N * G.T))
    return dtau, dK


@TemplateSystem.define("TendonForceDistribution_", scope=sys.modules[__name__], T_list=[float, AutoDiffXd])
def TendonForceDistribution_(T):
    """Tendon force distribution (ch. 7) for one or several fingers, sampled (the thesis's 3 kHz).

    Inputs ``joint_torque_reference`` (n) [Nm] and ``joint_stiffness_reference`` [Nm/rad] on the fingers'
    independent DoF (:func:`finger_force_distribution`), fingers in the order given; the stiffness per DoF
    (``stiffness="diagonal"``) or each finger's row-major block, concatenated (``"full"``); with the thumb,
    ``joint_angle`` (the fingers' plant joint angles, for P(q)).  Output ``tendon_force_reference`` (m) [N] is the
    discrete state (initially mid-range), updated every ``period`` by the finger solvers warm-started at the
    previous forces (``iterations_per_period`` QPs for the optimal one); ``distribution_status`` (one per finger)
    is 0 (ok), 1 (infeasible: reported, never clipped) or 2 (bound violation).  ``springs``: a ``TendonSprings``
    of the fingers' tendons (each tendon's own table; default ``drive.spring`` for all).

    Scalar types float and AutoDiffXd: the solver runs on values; ``"optimal"`` adds the exact derivatives of
    the optimum (:func:`optimum_sensitivity`; the thumb's posture by central differences of the converged
    optimum), ``"algorithm2"`` those of ``-(P^T)^+ tau`` only (its step halving is not smooth in the inputs).
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, fingers=("index",), method: str = "optimal", period: float = 1.0 / 3000.0,
                       iterations_per_period: int = 3, stiffness: str = "diagonal",
                       params: ForceDistributionParams | None = None, drive: FingerDriveParams | None = None,
                       springs=None, converter=None):
            LeafSystem_[T].__init__(self, converter)
            fingers = (fingers,) if isinstance(fingers, str) else tuple(fingers)
            if not fingers or len(set(fingers)) != len(fingers):
                raise ValueError(f"TendonForceDistribution: fingers must be distinct names from {FINGERS}, "
                                 f"got {fingers}")
            if stiffness not in ("diagonal", "full"):
                raise ValueError(f"TendonForceDistribution: stiffness must be 'diagonal' or 'full', got {stiffness!r}")
            if not period > 0:
                raise ValueError(f"TendonForceDistribution: period = {period} must be > 0 [s]")
            if int(iterations_per_period) < 1:
                raise ValueError(f"TendonForceDistribution: iterations_per_period = {iterations_per_period} "
                                 "must be >= 1")
            self.fingers, self.method, self.period = fingers, method, float(period)
            self.iterations_per_period, self.stiffness_kind = int(iterations_per_period), stiffness
            self.params, self.drive, self.springs = params, drive, springs
            m_all = sum(finger_coupling(f).num_tendons for f in fingers)
            if springs is not None and len(springs) != m_all:
                raise ValueError(f"TendonForceDistribution: springs has {len(springs)} laws; the fingers "
                                 f"{', '.join(fingers)} have {m_all} tendons")
            self.solvers = []
            self._parts = []                 # (solver, dof slice, tendon slice, K slice, plant-joint slice)
            dof = ten = kk = pj = 0
            for f in fingers:
                c = finger_coupling(f)
                s = finger_force_distribution(f, method=method, params=params, drive=drive, springs=(
                    None if springs is None else springs.subset(slice(ten, ten + c.num_tendons))))
                self.solvers.append(s)
                n_f = c.dof_selection.shape[1]
                m_f = c.num_tendons
                nk = n_f if stiffness == "diagonal" else n_f * n_f
                self._parts.append((s, slice(dof, dof + n_f), slice(ten, ten + m_f), slice(kk, kk + nk),
                                    slice(pj, pj + c.num_joints)))
                dof, ten, kk, pj = dof + n_f, ten + m_f, kk + nk, pj + c.num_joints
            self.num_dof, self.num_tendons = dof, ten
            self._tau = self.DeclareVectorInputPort("joint_torque_reference", dof)
            self._K = self.DeclareVectorInputPort("joint_stiffness_reference", kk)
            self._q = (self.DeclareVectorInputPort("joint_angle", pj)
                       if any(s._offline is None for s in self.solvers) else None)
            self._state = self.DeclareDiscreteState(self.initial_forces)
            self._status = self.DeclareDiscreteState(np.zeros(len(fingers)))
            self.DeclarePeriodicDiscreteUpdateEvent(self.period, 0.0, self._update)
            self.DeclareStateOutputPort("tendon_force_reference", self._state)
            self.DeclareStateOutputPort("distribution_status", self._status)
            self._batch = None
            if T is float and _FingerBatch.compatible(self.solvers):
                self._batch = _FingerBatch(self._parts, [finger_coupling(f) for f in fingers],
                                           diagonal=stiffness == "diagonal")

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.fingers, other.method, other.period, other.iterations_per_period,
                            other.stiffness_kind, other.params, other.drive, other.springs, converter=converter)

        @staticmethod
        def _posture_jacobian(s, tau, K_des, q, res, h=1e-6):
            """df*/dq (m x n_plant) of the converged optimum by central differences (warm-started)."""
            cols = []
            for e in np.eye(len(q)):
                fp = s.solve(tau, K_des, q=q + h * e, warm_start=res.forces).forces
                fm = s.solve(tau, K_des, q=q - h * e, warm_start=res.forces).forces
                cols.append((fp - fm) / (2 * h))
            return np.stack(cols, axis=1)

        def _K_block(self, Kv, n_f):
            return np.diag(Kv) if self.stiffness_kind == "diagonal" else Kv.reshape(n_f, n_f)

        def _update(self, context, discrete_state):
            f_new, status = self.step(self._tau.Eval(context), self._K.Eval(context),
                                      context.get_discrete_state(self._state).CopyToVector(),
                                      None if self._q is None else self._q.Eval(context))
            discrete_state.set_value(self._state, f_new)
            discrete_state.set_value(self._status, status)

        @property
        def initial_forces(self) -> np.ndarray:
            """The state's default: mid-range forces."""
            p = self.solvers[0].params
            return np.full(self.num_tendons, 0.5 * (p.f_min + p.f_max))

        @property
        def reads_joint_angle(self) -> bool:
            """Whether the distribution needs the plant joint angles (the thumb's P(q))."""
            return self._q is not None

        def step(self, tau_T, K_T, f_prev, q_T):
            """One period of the distribution, context-free: ``(forces (m), status (fingers))`` from the desired
            torques, stiffness entries, the previous forces and (thumb) the plant joint angles (the update of this
            system; :class:`~awiwi_drake.control.fused.FusedChain_` calls it too)."""
            status = np.zeros(len(self.fingers))
            todo = range(len(self._parts))
            if self._batch is not None:       # float, the hot path: all fingers at once; the rest by their own solver
                f_batch, fallback = self._batch.update(tau_T, K_T, f_prev, q_T, self.iterations_per_period)
                if not fallback.any():
                    return f_batch, status
                todo = np.flatnonzero(fallback)
            as_float = (lambda v: np.asarray(v, dtype=float)) if T is float else ExtractValue
            tau, Kv = as_float(tau_T).ravel(), as_float(K_T).ravel()
            f_prev_v = as_float(f_prev).ravel()
            q = None if q_T is None else as_float(q_T).ravel()
            f_new = f_batch if self._batch is not None else np.empty(self.num_tendons, dtype=object if T is not float
                                                                      else float)
            codes = {"ok": 0.0, "infeasible": 1.0, "bound_violation": 2.0}
            for k in todo:
                s, sd, st, sk, sq = self._parts[k]
                n_f = sd.stop - sd.start
                K_des = self._K_block(Kv[sk], n_f)
                kw = {} if s._offline is not None else dict(q=q[sq])
                if isinstance(s, OptimalForceDistribution):
                    res = s.solve(tau[sd], K_des, warm_start=f_prev_v[st], max_iterations=self.iterations_per_period, **kw)
                else:
                    res = s.solve(tau[sd], K_des, warm_start=f_prev_v[st], **kw)
                status[k] = codes[res.status]
                if T is float:
                    f_new[st] = res.forces
                    continue
                # AutoDiffXd: value of the solver plus the derivatives of the optimum
                dtau = tau_T[sd] - tau[sd]
                if isinstance(s, OptimalForceDistribution) and res.status == "ok":
                    J_tau, J_K = optimum_sensitivity(s, res, tau[sd], K_des, **kw)
                    dK = (self._K_block(K_T[sk], n_f) - K_des).ravel()
                    f_new[st] = res.forces + J_tau @ dtau + J_K @ dK
                    if "q" in kw:      # thumb: P(q) moves the optimum; central differences of the optimum
                        f_new[st] = f_new[st] + self._posture_jacobian(s, tau[sd], K_des, kw["q"], res) @ (
                            q_T[sq] - kw["q"])
                else:
                    P, pinv_PT, *_ = s._coupling_at(None, None, kw.get("q"))
                    f_new[st] = res.forces - pinv_PT @ dtau
            return f_new, status

    return Impl


TendonForceDistributionSystem = TendonForceDistribution_[None]
