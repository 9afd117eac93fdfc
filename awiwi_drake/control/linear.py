"""Linear state feedback on a rig linearisation (shared by ch. 12, 13, 14).

The linear model is :func:`awiwi_drake.analysis.linearize` (Drake's ``Linearize``):

* :func:`reference_maps` -- ``x_ref = x0 + Nx (r - r0)``, ``u_ref = u0 + Nu (r - r0)``
  from ``[A B; C 0] [Nx; Nu] = [0; 1]`` (equilibrium family of the linear model);
* :class:`LinearReferenceModel` -- that family around a linearisation;
* :class:`StateFeedbackLaw` -- ``u = u_ref - K (x - x_ref)``, used by the
  pole-placement and LQR controllers (and SDRE with state-dependent K).
"""

from __future__ import annotations

import numpy as np

from awiwi_drake.analysis.linear import LinearizationResult
from awiwi_drake.control.base import REFERENCE_SUFFIX, StaticLaw, StaticLawController, check_gains

__all__ = ["reference_maps", "LinearReferenceModel", "StateFeedbackLaw", "state_feedback_controller"]


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


class LinearReferenceModel:
    """The equilibrium family of a linearisation that holds its output ``reference`` at ``r``:
    ``x_ref = x0 + Nx (r - r0)``, ``u_ref = u0 + Nu (r - r0)`` (:func:`reference_maps`; ``r0``: the output at
    the point). Inputs of a law on it: ``<reference>_reference`` (1) and ``state`` (n)."""

    def __init__(self, lin: LinearizationResult, reference: str = "joint_angle"):
        out = lin.output(reference)
        self.Nx, self.Nu = reference_maps(lin.A, lin.B, out.C)
        self.x0, self.u0, self.r0 = np.asarray(lin.x0, float), np.asarray(lin.u0, float), float(out.y0[0])
        self.reference = reference
        self.inputs = {reference + REFERENCE_SUFFIX: 1, "state": lin.A.shape[0]}

    def state(self, values):
        return values["state"]

    def equilibrium(self, r):
        """``(x_ref, u_ref)`` at the reference ``r`` (float or AutoDiffXd)."""
        dr = r - self.r0
        return self.x0 + self.Nx * dr, self.u0 + self.Nu * dr


class StateFeedbackLaw(StaticLaw):
    """``u = u_ref(r) - K (x - x_ref(r))`` around the equilibrium family ``model`` (a :class:`LinearReferenceModel`;
    float and AutoDiffXd)."""

    def __init__(self, K, model: LinearReferenceModel, *, name: str = "state_feedback"):
        self.K = np.atleast_2d(check_gains("K", K, shape=(model.Nu.size, model.Nx.size), owner=name))
        self.model, self.name = model, name
        self.inputs, self.output_size = dict(model.inputs), self.K.shape[0]

    def __call__(self, u):
        x_ref, u_ref = self.model.equilibrium(u[self.model.reference + REFERENCE_SUFFIX][0])
        return u_ref - self.K @ (u["state"] - x_ref)


def state_feedback_controller(lin: LinearizationResult, K, *, reference: str = "joint_angle",
                              name: str = "state_feedback"):
    """A :class:`StaticLawController` for gain ``K`` around the linearisation ``lin``.

    ``lin`` must include the output ``reference`` (``linearize(rig, op, outputs=("state", reference))``).
    """
    return StaticLawController(StateFeedbackLaw(np.atleast_2d(K), LinearReferenceModel(lin, reference), name=name))
