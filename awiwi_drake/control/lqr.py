"""Linear quadratic regulator on the linearised rig (ch. 13, Table 13.1).

The gain comes from Drake's ``LinearQuadraticRegulator`` applied to the rig
diagram at its operating point (:func:`awiwi_drake.analysis.lqr`); the
controller is a :class:`~awiwi_drake.control.linear.StateFeedbackLaw` that
tracks ``joint_angle_reference`` through the equilibrium family of the linear
model.  Q is given on the flexible-joint state ``[q, qd, theta, thetad]``
((13.9)); for the antagonistic joint rig (two motors) the motor weights are
repeated for both motors (:func:`expand_q`).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from awiwi_drake.analysis.linear import LinearizationResult, LqrResult, linearize, lqr
from awiwi_drake.control.base import check_gain, check_gains
from awiwi_drake.control.linear import state_feedback_controller
from awiwi_drake.parameters.control import LqrParams

__all__ = ["expand_q", "design_lqr", "lqr_controller", "quadratic_cost"]


def expand_q(q_diag: Sequence[float], n: int) -> np.ndarray:
    """Q for an ``n``-state rig from the 4-state flexible-joint weights ``[q, qd, theta, thetad]``.

    ``n = 4``: diag(q_diag).  ``n = 6`` (joint rig ``[q, qd, th1, th2, w1, w2]``):
    diag(q, qd, theta, theta, thetad, thetad).
    """
    q = check_gains("Q diagonal", q_diag, owner="lqr")
    if np.any(q < 0):
        raise ValueError(f"lqr gain 'Q diagonal' must be >= 0, got {q}")
    if len(q) == n:
        return np.diag(q)
    if len(q) == 4 and n == 6:
        return np.diag([q[0], q[1], q[2], q[2], q[3], q[3]])
    raise ValueError(f"lqr: Q diagonal has {len(q)} entries but the rig has {n} states")


def design_lqr(rig: Any, params: LqrParams | None = None, *, r: float | None = None, op: Any = None,
               lin: LinearizationResult | None = None, Q=None, R=None) -> LqrResult:
    """LQR design (:func:`awiwi_drake.analysis.lqr`) on the rig linearised at ``op``.

    Weights: Table 13.1 by default (``params``); ``r`` overrides R = r I;
    full matrices ``Q`` (n x n, on the rig state) / ``R`` (m x m) override both.
    The linearisation includes the ``joint_angle`` output (for the reference maps).
    """
    p = params or LqrParams()
    lin = lin or linearize(rig, op, outputs=("state", "joint_angle"))
    n, m = lin.B.shape
    Q = expand_q(p.q_diag, n) if Q is None else Q                  # lqr checks both (shape, symmetry, definiteness)
    R = check_gain("R", p.r if r is None else r, owner="lqr") * np.eye(m) if R is None else R
    return lqr(None, Q, R, linearization=lin)


def lqr_controller(rig: Any, params: LqrParams | None = None, *, r: float | None = None, op: Any = None,
                   Q=None, R=None):
    """Registered factory ``lqr``: LQR state feedback tracking ``joint_angle_reference``.

    ``u = u_ref(r) - K (x - x_ref(r))`` with ``(x_ref, u_ref)`` the equilibrium of the
    linear model holding the link at ``r`` (equal to ``op`` at ``r`` = the op's link
    angle).  Weights as :func:`design_lqr`.  Close it with
    ``closed_loop(rig, lqr_controller(rig, Q=Q, R=R), rate_hz=None)`` (continuous,
    as ``LinearQuadraticRegulator`` designs it) or at 3 kHz.
    """
    d = design_lqr(rig, params, r=r, op=op, Q=Q, R=R)
    return state_feedback_controller(d.linearization, d.K, reference="joint_angle", name="lqr")


def quadratic_cost(t: np.ndarray, x: np.ndarray, u: np.ndarray, Q: np.ndarray, R: np.ndarray) -> float:
    """``int x'Qx + u'Ru dt`` by the trapezoidal rule (x, u deviations from the set point)."""
    x = np.atleast_2d(np.asarray(x, float))
    u = np.asarray(u, float).reshape(len(t), -1)
    integrand = np.einsum("ti,ij,tj->t", x, Q, x) + np.einsum("ti,ij,tj->t", u, np.atleast_2d(R), u)
    return float(np.trapezoid(integrand, t))
