"""Linear state feedback on a rig linearisation (shared by ch. 12, 13, 14).

* :func:`linearize_rig` -- Drake's ``FirstOrderTaylorApproximation`` of a rig
  diagram at an operating point, with the rows of the named outputs;
* :func:`reference_maps` -- ``x_ref = x0 + Nx (r - r0)``, ``u_ref = u0 + Nu (r - r0)``
  from ``[A B; C 0] [Nx; Nu] = [0; 1]`` (equilibrium family of the linear model);
* :class:`StateFeedbackLaw` -- ``u = u_ref - K (x - x_ref)``, used by the
  pole-placement and LQR controllers (and SDRE with state-dependent K).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from pydrake.systems.primitives import FirstOrderTaylorApproximation

from awiwi_drake.control.base import COMMAND_PORT, REFERENCE_SUFFIX, StaticLaw, StaticLawController, check_gains

__all__ = ["RigLinearization", "linearize_rig", "rig_context", "reference_maps", "StateFeedbackLaw",
           "state_feedback_controller", "closed_loop_poles"]


@dataclass
class RigLinearization:
    """``xdot = f0 + A dx + B du``; output rows ``C[name]`` (each ``(p, n)``) and values ``y0[name]``."""

    A: np.ndarray
    B: np.ndarray
    f0: np.ndarray
    C: dict
    y0: dict
    x0: np.ndarray
    u0: np.ndarray
    state_names: tuple

    @property
    def poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.A)


def rig_context(rig: Any, op: Any = None, *, state: Sequence[float] | None = None,
                motor_torque: Sequence[float] | None = None):
    """A rig context at ``op`` (default: the rig's default operating point), inputs fixed.

    ``state`` / ``motor_torque`` override the operating point's values.
    """
    diagram = rig.diagram
    if op is None and hasattr(rig, "operating_point"):
        op = rig.operating_point()
    x = np.asarray(state if state is not None else (op.state if op is not None else
                   diagram.CreateDefaultContext().get_continuous_state_vector().CopyToVector()), float)
    u = np.asarray(motor_torque if motor_torque is not None else
                   (op.motor_torque if op is not None else np.zeros(diagram.GetInputPort(COMMAND_PORT).size())),
                   float).reshape(-1)
    ctx = diagram.CreateDefaultContext()
    ctx.SetContinuousState(x)
    for i in range(diagram.num_input_ports()):
        port = diagram.get_input_port(i)
        port.FixValue(ctx, u if port.get_name() == COMMAND_PORT else np.zeros(port.size()))
    return ctx


def linearize_rig(rig: Any, op: Any = None, *, outputs: Sequence[str] = ("state",),
                  state: Sequence[float] | None = None,
                  motor_torque: Sequence[float] | None = None) -> RigLinearization:
    """Linear model of ``rig`` w.r.t. ``motor_torque`` at an operating point.

    ``A, B`` come from the framework (:func:`awiwi_drake.analysis.linearize`,
    Drake's ``Linearize``) at an operating point; with ``state`` /
    ``motor_torque`` given (a non-equilibrium point, e.g. for SDRE) Drake's
    ``FirstOrderTaylorApproximation`` is used.  The rows ``C[name]`` of the named
    outputs come from ``FirstOrderTaylorApproximation`` at the same point.
    """
    from awiwi_drake.analysis import linearize

    d = rig.diagram
    if op is None and hasattr(rig, "operating_point"):
        op = rig.operating_point()
    ctx = rig_context(rig, op, state=state, motor_torque=motor_torque)
    in_idx = d.GetInputPort(COMMAND_PORT).get_index()
    C, y0 = {}, {}
    A = B = f0 = None
    for name in outputs:
        if not d.HasOutputPort(name):
            raise ValueError(f"linearize_rig: rig {getattr(rig, 'name', '?')!r} has no output port {name!r}")
        lin = FirstOrderTaylorApproximation(d, ctx, input_port_index=in_idx,
                                            output_port_index=d.GetOutputPort(name).get_index())
        A, B, f0 = np.array(lin.A()), np.array(lin.B()), np.array(lin.f0())
        C[name] = np.array(lin.C())
        y0[name] = np.asarray(lin.y0(), float)
    if state is None and motor_torque is None and op is not None and hasattr(rig, "context"):
        fw = linearize(rig, op)  # the framework's linearisation (checks that op is an equilibrium)
        A, B = fw.A, fw.B
    x0 = ctx.get_continuous_state_vector().CopyToVector()
    u0 = d.GetInputPort(COMMAND_PORT).Eval(ctx)
    names = tuple(getattr(rig, "state_names", ()) or ())
    return RigLinearization(A, B, f0, C, y0, x0, np.asarray(u0, float), names)


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

    def __init__(self, K, *, x0, u0, Nx, Nu, r0: float = 0.0, reference: str = "link_angle",
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


def state_feedback_controller(lin: RigLinearization, K, *, reference: str = "link_angle",
                              name: str = "state_feedback"):
    """A :class:`StaticLawController` for gain ``K`` around the linearisation ``lin``."""
    c = lin.C[reference] if reference in lin.C else None
    if c is None:
        raise ValueError(f"state_feedback_controller: the linearisation has no output {reference!r} "
                         f"(has {', '.join(lin.C)})")
    Nx, Nu = reference_maps(lin.A, lin.B, c)
    r0 = float(np.ravel(lin.y0[reference])[0])
    law = StateFeedbackLaw(K, x0=lin.x0, u0=lin.u0, Nx=Nx, Nu=Nu, r0=r0, reference=reference, name=name)
    return StaticLawController(law)


def closed_loop_poles(A: np.ndarray, B: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Eigenvalues of ``A - B K`` sorted by real part then imaginary part."""
    ev = np.linalg.eigvals(A - B @ np.atleast_2d(K))
    return ev[np.lexsort((ev.imag, ev.real))]
