"""Linear state feedback on a rig linearisation (shared by ch. 12, 13, 14).

The linear model is :func:`awiwi_drake.analysis.linearize` (Drake's ``Linearize``):

* :func:`reference_maps` -- ``x_ref = x0 + Nx (r - r0)``, ``u_ref = u0 + Nu (r - r0)``
  from ``[A B; C 0] [Nx; Nu] = [0; 1]`` (equilibrium family of the linear model);
* :class:`StateFeedbackLaw` -- ``u = u_ref - K (x - x_ref)``, used by the
  pole-placement and LQR controllers (and SDRE with state-dependent K).
"""

from __future__ import annotations

import numpy as np

from awiwi_drake.analysis.linear import LinearizationResult
from awiwi_drake.control.base import REFERENCE_SUFFIX, StaticLaw, StaticLawController, check_gains

__all__ = ["reference_maps", "StateFeedbackLaw", "state_feedback_controller"]


def reference_maps(A: np.ndarray, B: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(Nx, Nu)`` with ``A Nx + B Nu = 0`` and ``c Nx = 1`` (least-norm when not unique)."""
    n, m = B.shape
    c = np.asarray(c, float).reshape(1, n)
    M = np.block([[A, B], [c, np.zeros((1, m))]])
    rhs = np.zeros(n + 1)
    rhs[-1] = 1.0
    sol, *_ = np.linalg.lstsq(M, rhs, rcond=None)
    if np.linalg.norm(M @ sol - rhs) > 1e-6 * max(1.0, np.linalg.norm(M)):
        raise ValueError("reference_maps: the tracked output cannot be held at a steady state by the input")
    return sol[:n], sol[n:]


class StateFeedbackLaw(StaticLaw):
    """``u = u0 + Nu (r - r0) - K (x - x0 - Nx (r - r0))`` (float and AutoDiffXd)."""

    def __init__(self, K, *, x0, u0, Nx, Nu, r0: float = 0.0, reference: str = "joint_angle",
                 state_port: str = "state", name: str = "state_feedback"):
        K = np.atleast_2d(check_gains("K", K, owner=name))
        m, n = K.shape
        self.K = K
        self.x0 = check_gains("x0", np.reshape(x0, -1), shape=(n,), owner=name)
        self.u0 = check_gains("u0", np.reshape(u0, -1), shape=(m,), owner=name)
        self.Nx = check_gains("Nx", np.reshape(Nx, -1), shape=(n,), owner=name)
        self.Nu = check_gains("Nu", np.reshape(Nu, -1), shape=(m,), owner=name)
        self.r0 = float(r0)
        self.reference = reference
        self.state_port = state_port
        self.name = name
        self.inputs = {reference + REFERENCE_SUFFIX: 1, state_port: n}
        self.output_size = m

    def __call__(self, u):
        x = u[self.state_port]
        dr = u[self.reference + REFERENCE_SUFFIX][0] - self.r0
        err = x - self.x0 - self.Nx * dr
        return self.u0 + self.Nu * dr - self.K @ err


def state_feedback_controller(lin: LinearizationResult, K, *, reference: str = "joint_angle",
                              name: str = "state_feedback"):
    """A :class:`StaticLawController` for gain ``K`` around the linearisation ``lin``.

    ``lin`` must include the output ``reference`` (``linearize(rig, op, outputs=("state", reference))``).
    """
    out = lin.output(reference)
    Nx, Nu = reference_maps(lin.A, lin.B, out.C)
    law = StateFeedbackLaw(K, x0=lin.x0, u0=lin.u0, Nx=Nx, Nu=Nu, r0=float(out.y0[0]), reference=reference, name=name)
    return StaticLawController(law)
