"""Linearisation and LQR from the framework (Drake's ``Linearize`` and
``LinearQuadraticRegulator``) on composed rig diagrams."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.controllers import LinearQuadraticRegulator
from pydrake.systems.primitives import Linearize

from awiwi_drake.rigs.base import OperatingPoint, Rig

__all__ = ["LinearizationResult", "LqrResult", "linearize", "lqr", "poles_table"]


@dataclass(frozen=True)
class LinearizationResult:
    """``xdot = A dx + B du``, ``y = C dx + D du`` around an operating point.

    Attributes
    ----------
    A, B, C, D : ndarray
        From ``pydrake.systems.primitives.Linearize`` of the rig diagram,
        input ``motor_torque``, output ``state``.
    poles : ndarray (complex)
        Eigenvalues of A, sorted by real part then imaginary part.
    state_names : tuple of str
    operating_point : OperatingPoint
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    poles: np.ndarray
    state_names: tuple
    operating_point: OperatingPoint

    def to_json(self) -> dict:
        return dict(A=self.A.tolist(), B=self.B.tolist(), state_names=list(self.state_names),
                    poles=[[float(p.real), float(p.imag)] for p in self.poles])


@dataclass(frozen=True)
class LqrResult:
    """LQR design at an operating point: ``u = u0 - K (x - x0)``.

    ``S`` solves the continuous algebraic Riccati equation; the optimal cost
    from an initial deviation ``dx`` is ``dx^T S dx``.
    """

    K: np.ndarray
    S: np.ndarray
    closed_loop_poles: np.ndarray
    linearization: LinearizationResult
    Q: np.ndarray
    R: np.ndarray

    def to_json(self) -> dict:
        return dict(K=self.K.tolist(), closed_loop_poles=[[float(p.real), float(p.imag)]
                                                          for p in self.closed_loop_poles])


def _sorted_eig(M):
    ev = np.linalg.eigvals(M)
    return ev[np.lexsort((ev.imag, ev.real))]


def linearize(rig: Rig, op: OperatingPoint | None = None, *, equilibrium_tolerance: float | None = 1e-6
              ) -> LinearizationResult:
    """Linearise ``rig.diagram`` at ``op`` (default operating point if None) with Drake's ``Linearize``.

    Input ``motor_torque``, output ``state``; other inputs are held at the
    operating point. ``equilibrium_tolerance`` makes Drake check that ``op`` is
    an equilibrium (None: skip the check, e.g. for trajectories).
    """
    op = rig.operating_point() if op is None else op
    ctx = rig.context(op)
    sys = Linearize(rig.diagram, ctx,
                    input_port_index=rig.diagram.GetInputPort("motor_torque").get_index(),
                    output_port_index=rig.diagram.GetOutputPort("state").get_index(),
                    equilibrium_check_tolerance=equilibrium_tolerance)
    A, B, C, D = (np.array(m) for m in (sys.A(), sys.B(), sys.C(), sys.D()))
    return LinearizationResult(A, B, C, D, _sorted_eig(A), tuple(rig.state_names), op)


def _check_weights(Q, R, n, m):
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    R = np.atleast_2d(np.asarray(R, dtype=float))
    if Q.shape == (1, n) or Q.shape == (n, 1):
        Q = np.diag(Q.ravel())
    if R.shape == (1, m) and m > 1:
        R = np.diag(R.ravel())
    if Q.shape != (n, n):
        raise ValueError(f"lqr: Q must be {n}x{n} (or {n} diagonal entries), got shape {Q.shape}")
    if R.shape != (m, m):
        raise ValueError(f"lqr: R must be {m}x{m} (or {m} diagonal entries), got shape {R.shape}")
    if not (np.all(np.isfinite(Q)) and np.all(np.isfinite(R))):
        raise ValueError("lqr: Q and R must be finite")
    if np.min(np.linalg.eigvalsh(0.5 * (Q + Q.T))) < -1e-12:
        raise ValueError("lqr: Q must be symmetric positive semi-definite")
    if np.min(np.linalg.eigvalsh(0.5 * (R + R.T))) <= 0:
        raise ValueError("lqr: R must be symmetric positive definite")
    return Q, R


def lqr(rig: Rig, Q, R, op: OperatingPoint | None = None) -> LqrResult:
    """LQR gain from Drake's ``LinearQuadraticRegulator(system, context, Q, R)`` at ``op``."""
    op = rig.operating_point() if op is None else op
    lin = linearize(rig, op)
    Q, R = _check_weights(Q, R, lin.A.shape[0], lin.B.shape[1])
    ctx = rig.context(op)
    controller = LinearQuadraticRegulator(rig.diagram, ctx, Q, R,
                                          input_port_index=rig.diagram.GetInputPort("motor_torque").get_index())
    K = -np.array(controller.D())  # controller: u = u0 + D (x - x0), D = -K
    # Drake's LinearQuadraticRegulator(system, ...) returns the controller only; S from the same
    # linearisation via the (A, B) overload.
    from pydrake.systems.controllers import LinearQuadraticRegulator as _lqr_ab
    _, S = _lqr_ab(lin.A, lin.B, Q, R)
    return LqrResult(K, np.array(S), _sorted_eig(lin.A - lin.B @ K), lin, Q, R)


def poles_table(result: LinearizationResult) -> str:
    """Poles as text lines ``re +- im j`` (for the CLI)."""
    return "\n".join(f"  {p.real: .6g} {'+' if p.imag >= 0 else '-'} {abs(p.imag):.6g}j" for p in result.poles)
