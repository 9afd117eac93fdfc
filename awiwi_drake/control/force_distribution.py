"""Tendon force distribution (thesis ch. 7, Algorithm 2).

Given a desired joint torque ``tau_des`` (n) and a desired joint stiffness
``K_des`` (n x n), choose tendon forces ``f`` (m) in ``[f_min, f_max]`` that
produce the torque *exactly* and the stiffness as closely as possible.

With the project's sign convention ``tau = -P^T f`` (docs/ARCHITECTURE.md;
the thesis writes ``tau = P^T f``), every force of the form

    f = f_p + W alpha,   f_p = -(P^T)^+ tau_des,   W = ker(P^T)  (m x (m - rank P))

produces ``tau_des``; Algorithm 2 searches ``alpha`` by projected gradient
descent with step halving on

    C(alpha) = gamma1 ||K_des - K_q(f)||_F^2 / ||K_des||_F^2
             + gamma2 sum psi((f - f_min)/delta) + gamma3 sum psi((f_max - f)/delta),

where ``psi(d) = max(0, 1 - d)^2`` is a repulsive potential acting within
``delta`` of a bound (7.7) and the joint stiffness is (5.12)/(7.1)

    K_q(f) = P^T diag(k_t(f)) P + sum_i f_i d^2 h_i / dq^2.

The search direction is the normalised gradient, the step ``s`` [N] is halved
whenever the cost does not decrease (Algorithm 2). For a constant coupling
``W`` and ``(P^T)^+`` are computed once (offline); for a position-dependent
coupling (the thumb) they are recomputed by an SVD at every call (online).

The search starts at the mid-range co-contraction or, when that is not
inside the bounds, at the max-margin feasible point of a linear program.
Requests that no force in the bounds can satisfy are detected by that program and returned with ``status="infeasible"``: forces are never clipped
silently.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import linprog

from awiwi_drake.parameters.hand_control import ForceDistributionParams

__all__ = ["DistributionResult", "TendonStiffnessMap", "TendonForceDistribution", "coupling_nullspace",
           "joint_stiffness", "index_finger_coupling"]


def index_finger_coupling(radii=(0.008, 0.008, 0.007, 0.006)) -> np.ndarray:
    """Coupling ``P = dh/dq`` (8 x 4) of the index finger from the tendon lengths (5.5).

    Radii ``(r20, r21, r22, r23)`` [m] are not given in the thesis (MODEL_NOTES ch. 5);
    the default is a plausible 6-8 mm choice (see :class:`ForceDistributionParams`).
    """
    r20, r21, r22, r23 = radii
    return np.array([
        [r20, r21, 0, 0],
        [r20, -r21, 0, 0],
        [-r20, r21, 0, 0],
        [-r20, -r21, 0, 0],
        [0, 0, r22, 0],
        [0, 0, -r22, 0],
        [0, 0, r22, -r23],
        [0, 0, -r22, r23],
    ], dtype=float)


def coupling_nullspace(P: np.ndarray, *, rtol: float = 1e-10):
    """``(pinv(P^T), W, rank)`` with ``W`` an orthonormal basis of ``ker(P^T)`` (SVD)."""
    P = np.asarray(P, dtype=float)
    U, s, Vt = np.linalg.svd(P, full_matrices=True)  # P = U S V^T, P^T = V S U^T
    rank = int(np.sum(s > rtol * max(s.max(initial=0.0), 1e-300)))
    W = U[:, rank:]
    pinv_PT = U[:, :rank] @ np.diag(1.0 / s[:rank]) @ Vt[:rank, :]   # (P^T)^+ = U S^-1 V^T (m x n)
    return pinv_PT, W, rank


def joint_stiffness(P: np.ndarray, k_t: np.ndarray, f: np.ndarray, hessian: np.ndarray | None = None) -> np.ndarray:
    """Joint stiffness ``K_q = P^T diag(k_t) P + sum_i f_i d^2 h_i/dq^2`` (5.12), (7.1).

    ``hessian[i, j, k] = d P_ij / d q_k`` (m x n x n), omitted for a constant coupling.
    """
    K = P.T @ (k_t[:, None] * P)
    if hessian is not None:
        K = K + np.einsum("i,ijk->jk", f, hessian)
    return K


@dataclass
class DistributionResult:
    """Outcome of one force-distribution call.

    Attributes
    ----------
    forces : ndarray (m,)
        Tendon forces [N] (never clipped: check ``status`` and ``bound_violation``).
    status : str
        ``"ok"`` (torque exact, forces in bounds), ``"infeasible"`` (no force in the bounds
        produces the torque: the returned forces produce it but violate the bounds), or
        ``"bound_violation"`` (feasible request, but the search ended outside the bounds).
    torque_error : float
        ``||-P^T f - tau_des||`` [Nm].
    bound_violation : float
        Largest excursion beyond ``[f_min, f_max]`` [N] (0 when inside).
    stiffness : ndarray (n, n)
        Achieved joint stiffness [Nm/rad].
    stiffness_error : float
        ``||K_des - K_q||_F / ||K_des||_F`` (relative).
    iterations : int
        Gradient iterations performed.
    cost : float
        Final cost C(alpha).
    """

    forces: np.ndarray
    status: str
    torque_error: float
    bound_violation: float
    stiffness: np.ndarray
    stiffness_error: float
    iterations: int
    cost: float


def _barrier(d):
    """Repulsive potential psi(d) = (1 - d)^2 / d on (0, 1), 0 beyond (C^1, infinite at the bound)."""
    a = np.maximum(0.0, 1.0 - d)
    return a * a / d


def _barrier_slope(d):
    """d psi / d d = -(1 - d^2)/d^2 on (0, 1), 0 beyond."""
    return np.where(d < 1.0, -(1.0 - d * d) / (d * d), 0.0)


class TendonStiffnessMap:
    """Tendon stiffness as a function of tendon force, ``f -> (k_t(f), dk_t/df)``, by table lookup.

    The thesis tabulates the calibrated spring curve (ch. 4, 15.4.3); so does this map:
    ``k_t`` and ``dk_t/df`` are sampled on a force grid and interpolated linearly.

    Parameters
    ----------
    forces, stiffness, stiffness_slope : array
        Increasing force grid [N], k_t [N/m] and dk_t/df [1/m] at those forces.
    """

    def __init__(self, forces, stiffness, stiffness_slope):
        self.forces = np.asarray(forces, dtype=float)
        self.k = np.asarray(stiffness, dtype=float)
        self.dk = np.asarray(stiffness_slope, dtype=float)
        if self.forces.ndim != 1 or self.forces.size < 2 or np.any(np.diff(self.forces) <= 0):
            raise ValueError("TendonStiffnessMap.forces must be an increasing 1-D grid of at least 2 forces")
        if self.k.shape != self.forces.shape or self.dk.shape != self.forces.shape:
            raise ValueError("TendonStiffnessMap: stiffness and stiffness_slope must match the force grid")
        if np.any(self.k <= 0):
            raise ValueError("TendonStiffnessMap.stiffness must be > 0 on the grid (a slack tendon has no stiffness)")

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

    @classmethod
    def from_function(cls, fn: Callable, f_low: float, f_high: float, n: int = 2001) -> "TendonStiffnessMap":
        """Tabulate ``fn(f) -> k_t`` on ``[f_low, f_high]`` (slope by central differences)."""
        f = np.linspace(float(f_low), float(f_high), int(n))
        k = np.asarray(fn(f), dtype=float)
        return cls(f, k, np.gradient(k, f))

    def __call__(self, f):
        f = np.asarray(f, dtype=float)
        return np.interp(f, self.forces, self.k), np.interp(f, self.forces, self.dk)


class TendonForceDistribution:
    """Algorithm 2 of the thesis: exact torque, closest stiffness, forces kept off the bounds.

    Parameters
    ----------
    stiffness_map : callable
        ``f -> (k_t(f), dk_t/df)`` (arrays of shape (m,)), e.g. :class:`TendonStiffnessMap`.
    params : ForceDistributionParams
        Bounds, weights, barrier width, iteration count, initial step.
    coupling : array (m, n), optional
        Constant coupling: ``W`` and ``(P^T)^+`` are computed once here (offline).
        Omit it for a position-dependent coupling and pass ``P`` (and ``hessian``) to :meth:`solve`.
    """

    def __init__(self, stiffness_map: Callable, params: ForceDistributionParams | None = None,
                 coupling: np.ndarray | None = None):
        self.params = params or ForceDistributionParams()
        if not callable(stiffness_map):
            raise ValueError("TendonForceDistribution: stiffness_map must be callable f -> (k_t, dk_t/df)")
        self.stiffness_map = stiffness_map
        self._offline = None
        if coupling is not None:
            P = self._check_P(coupling)
            self._offline = (P,) + coupling_nullspace(P)

    @staticmethod
    def _check_P(P) -> np.ndarray:
        P = np.asarray(P, dtype=float)
        if P.ndim != 2 or P.shape[0] < P.shape[1]:
            raise ValueError(f"coupling P must be m x n with m tendons >= n joints, got shape {P.shape}")
        if not np.all(np.isfinite(P)):
            raise ValueError("coupling P has non-finite entries")
        return P

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

    def _feasible_start(self, f_p, W):
        """Max-margin alpha with f_min + t <= f_p + W alpha <= f_max - t (LP); None if infeasible."""
        p = self.params
        m, r = W.shape
        # variables [alpha (r), t]; maximise t
        c = np.zeros(r + 1)
        c[-1] = -1.0
        A = np.vstack([np.hstack([-W, np.ones((m, 1))]), np.hstack([W, np.ones((m, 1))])])
        b = np.concatenate([f_p - p.f_min, p.f_max - f_p])
        res = linprog(c, A_ub=A, b_ub=b, bounds=[(None, None)] * r + [(None, 0.5 * (p.f_max - p.f_min))],
                      method="highs")
        if res.status != 0 or res.x[-1] <= 0.0:
            return None
        return res.x[:r]

    def solve(self, tau_des, K_des, *, P=None, hessian=None, alpha0=None) -> DistributionResult:
        """Distribute ``tau_des`` (n) with target stiffness ``K_des`` (n x n).

        Parameters
        ----------
        tau_des : array (n,)
            Desired joint torque [Nm].
        K_des : array (n, n)
            Desired joint stiffness [Nm/rad] (symmetric).
        P : array (m, n), optional
            Coupling at the current posture (required without a constant coupling; online SVD).
        hessian : array (m, n, n), optional
            ``dP_ij/dq_k`` for a position-dependent coupling (geometric stiffness term).
        alpha0 : array, optional
            Warm start in the null space (e.g. the previous call's solution).
        """
        if P is None:
            if self._offline is None:
                raise ValueError("solve: pass P (no constant coupling was given to the constructor)")
            P, pinv_PT, W, _ = self._offline
        else:
            P = self._check_P(P)
            pinv_PT, W, _ = coupling_nullspace(P)
        m, n = P.shape
        tau_des = np.asarray(tau_des, dtype=float).ravel()
        K_des = np.asarray(K_des, dtype=float)
        if tau_des.shape != (n,):
            raise ValueError(f"solve: tau_des has shape {tau_des.shape}; the coupling has {n} joints")
        if K_des.shape != (n, n):
            raise ValueError(f"solve: K_des has shape {K_des.shape}; expected ({n}, {n})")
        if not np.allclose(K_des, K_des.T, rtol=1e-9, atol=1e-12):
            raise ValueError("solve: K_des must be symmetric")
        if hessian is not None:
            hessian = np.asarray(hessian, dtype=float)
            if hessian.shape != (m, n, n):
                raise ValueError(f"solve: hessian has shape {hessian.shape}; expected ({m}, {n}, {n})")
        p = self.params
        f_p = -pinv_PT @ tau_des
        K_norm2 = max(float(np.sum(K_des * K_des)), 1e-300)
        r = W.shape[1]
        if alpha0 is None:
            # start at the pretension that puts the mean force mid-range (the null space of an
            # antagonistic coupling contains the all-positive co-contraction direction)
            alpha = W.T @ (np.full(m, 0.5 * (p.f_min + p.f_max)) - f_p) if r else np.zeros(0)
        else:
            alpha = np.asarray(alpha0, dtype=float).ravel()
            if alpha.shape != (r,):
                raise ValueError(f"solve: alpha0 has shape {alpha.shape}; the null space has dimension {r}")
        def violation(a):
            f = f_p + W @ a
            return float(max(0.0, np.max(p.f_min - f), np.max(f - p.f_max)))

        f_start = f_p + W @ alpha
        inside = np.all(f_start > p.f_min) and np.all(f_start < p.f_max)
        status, iters, C, K = "ok", 0, np.inf, None
        if not inside:
            start = self._feasible_start(f_p, W)
            if start is None:
                status = "infeasible"     # no force in the bounds produces tau_des
            else:
                alpha = start
        if status == "ok":
            alpha, C, K, iters = self._search(alpha, f_p, W, P, hessian, K_des, K_norm2)
        f = f_p + W @ alpha
        if K is None:
            K = joint_stiffness(P, self.stiffness_map(f)[0], f, hessian)
        viol = violation(alpha)
        if status == "ok" and viol > p.bound_tolerance:
            status = "bound_violation"
        return DistributionResult(
            forces=f, status=status, torque_error=float(np.linalg.norm(-P.T @ f - tau_des)),
            bound_violation=viol, stiffness=K,
            stiffness_error=float(np.linalg.norm(K_des - K) / np.sqrt(K_norm2)), iterations=iters, cost=float(C))

    def timed_solve(self, *args, **kw) -> tuple[DistributionResult, float]:
        """:meth:`solve` and its wall time [s] (for benchmarks)."""
        t0 = time.perf_counter()
        res = self.solve(*args, **kw)
        return res, time.perf_counter() - t0
