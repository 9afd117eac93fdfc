"""Direct pole placement by identification to a double oscillator (ch. 12).

For a single-input plant the characteristic polynomial of ``A - B K`` is affine
in ``K`` (``det(sI - A + BK) = det(sI - A) (1 + K (sI - A)^-1 B)``), so matching
its coefficients to the target (12.13) is the linear system ``J K = mu`` of
(12.14)-(12.16); ``J`` is evaluated numerically from the rig linearisation
(never from hand-copied matrices).  Multi-input plants (the antagonistic joint)
use Drake/scipy-free eigenstructure assignment through ``scipy.signal.place_poles``
with the double-oscillator poles plus the extra modes placed at ``omega1``.

Sign convention: ``u = -K x`` (the thesis writes ``u = K^T x`` in (12.9)-(12.11)
with the opposite sign, see docs/REPRODUCTIONS.md).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from awiwi_drake.control.base import check_gain
from awiwi_drake.analysis.linear import LinearizationResult, clean_poles, closed_loop_poles, linearize
from awiwi_drake.control.linear import state_feedback_controller
from awiwi_drake.parameters.control import PolePlacementParams

__all__ = ["double_oscillator_polynomial", "double_oscillator_poles", "identification_system",
           "place_by_identification", "PolePlacementDesign", "design_pole_placement",
           "pole_placement_controller", "stable_stiffness_interval"]


def double_oscillator_polynomial(omega1: float, xi1: float, omega2: float, xi2: float) -> np.ndarray:
    """Monic coefficients (highest power first) of (12.13)."""
    for nm, v in (("omega1", omega1), ("xi1", xi1), ("omega2", omega2), ("xi2", xi2)):
        check_gain(nm, v, owner="double oscillator")
    return np.polymul([1.0, 2 * xi1 * omega1, omega1 ** 2], [1.0, 2 * xi2 * omega2, omega2 ** 2])


def double_oscillator_poles(p: PolePlacementParams) -> np.ndarray:
    """The four poles of (12.13), sorted (:func:`~awiwi_drake.analysis.linear.clean_poles`)."""
    return clean_poles(np.roots(double_oscillator_polynomial(p.omega1, p.xi1, p.omega2, p.xi2)))


def identification_system(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(J, c0)``: coefficients of ``det(sI - A + B K)`` (without the leading 1) = ``c0 + J K``."""
    A = np.asarray(A, float)
    B = np.asarray(B, float).reshape(A.shape[0], -1)
    if B.shape[1] != 1:
        raise ValueError("identification_system: coefficient identification needs a single input")
    n = A.shape[0]
    c0 = np.real(np.poly(A))[1:]
    J = np.empty((n, n))
    for j in range(n):
        e = np.zeros((1, n))
        e[0, j] = 1.0
        J[:, j] = np.real(np.poly(A - B @ e))[1:] - c0
    return J, c0


def place_by_identification(A: np.ndarray, B: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Gain row ``K`` (``u = -K x``) giving ``A - B K`` the monic characteristic polynomial ``target``."""
    J, c0 = identification_system(A, B)
    target = np.asarray(target, float)
    if target.shape != (A.shape[0] + 1,) or target[0] != 1.0:
        raise ValueError(f"place_by_identification: target must be monic of degree {A.shape[0]}")
    if abs(np.linalg.det(J)) < 1e-300 or np.linalg.cond(J) > 1e14:
        raise ValueError("place_by_identification: J is singular: the plant is not controllable")
    return np.linalg.solve(J, target[1:] - c0).reshape(1, -1)


@dataclass
class PolePlacementDesign:
    """Gains and poles of a pole-placement design on a rig linearisation."""

    K: np.ndarray
    target_poles: np.ndarray
    closed_loop_poles: np.ndarray
    linearization: LinearizationResult
    params: PolePlacementParams


def design_pole_placement(rig: Any, params: PolePlacementParams | None = None, op: Any = None) -> PolePlacementDesign:
    """Pole placement on the rig linearised at ``op`` (Table 12.1 target by default)."""
    p = params or PolePlacementParams()
    lin = linearize(rig, op, outputs=("state", "joint_angle"))
    target = double_oscillator_poles(p)
    m = lin.B.shape[1]
    if m == 1 and lin.A.shape[0] == 4:
        K = place_by_identification(lin.A, lin.B,
                                    double_oscillator_polynomial(p.omega1, p.xi1, p.omega2, p.xi2))
        poles = target
    else:
        from scipy.signal import place_poles
        n = lin.A.shape[0]
        extra = []
        while len(target) + len(extra) < n:  # remaining modes: real poles around omega1
            extra.append(-p.omega1 * (1.0 + 0.1 * len(extra)))
        poles = np.concatenate([target, np.array(extra, dtype=complex)])
        # scipy's YT method places the poles exactly and then iterates to improve the conditioning of the
        # closed-loop eigenvectors (robustness); "Convergence was not reached" concerns only that optional
        # improvement (here: no progress possible, rtol ~ 1).  Silence it and check the placement instead.
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Convergence was not reached", category=UserWarning)
            K = place_poles(lin.A, lin.B, poles).gain_matrix
        got = closed_loop_poles(lin.A, lin.B, K)
        want = clean_poles(poles)
        if np.max(np.abs(got - want)) > 1e-6 * np.max(np.abs(want)):
            raise ValueError(f"design_pole_placement: place_poles did not place the poles {want} (got {got})")
    return PolePlacementDesign(K, poles, closed_loop_poles(lin.A, lin.B, K), lin, p)


def pole_placement_controller(rig: Any, params: PolePlacementParams | None = None, op: Any = None):
    """Registered factory ``pole-placement``: state feedback tracking ``joint_angle_reference``."""
    d = design_pole_placement(rig, params, op)
    return state_feedback_controller(d.linearization, d.K, reference="joint_angle", name="pole_placement")


def stable_stiffness_interval(A_of_k, B: np.ndarray, K: np.ndarray, k0: float, *, half_width: float = 1e-3,
                              num: int = 41, xtol: float = 1e-10) -> tuple[float, float]:
    """The interval of ``k`` around ``k0`` (within ``k0 +- half_width``) where ``A(k) - B K`` is Hurwitz.

    A scan on ``num`` points brackets the first loss of stability on each side; Brent's method
    then finds the boundary, where the largest real part of the closed-loop poles crosses 0, to
    ``xtol``. A side that stays stable up to the scan's end returns that end.
    Raises ValueError when the closed loop is unstable at ``k0`` itself.
    """
    from scipy.optimize import brentq

    def growth(k):
        return float(np.max(closed_loop_poles(A_of_k(k), B, K).real))

    if growth(k0) >= 0:
        raise ValueError(f"stable_stiffness_interval: the closed loop is unstable at k0 = {k0}")
    ends = []
    for side in (-1.0, 1.0):
        inner = k0
        for step in np.linspace(0.0, half_width, int(num))[1:]:
            k = k0 + side * step
            if growth(k) >= 0:
                ends.append(brentq(growth, inner, k, xtol=xtol) if side > 0 else brentq(growth, k, inner, xtol=xtol))
                break
            inner = k
        else:
            ends.append(k0 + side * half_width)
    return float(ends[0]), float(ends[1])
