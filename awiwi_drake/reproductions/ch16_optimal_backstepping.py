"""Thesis ch. 16: optimal backstepping gains, the Table 16.1 case.

The gain selection itself (Algorithm 3, least squares on ``log Omega``) is
:mod:`awiwi_drake.control.optimal_gains`; this module holds the Table 16.1 rig,
the ARE gain of the model printed in Table 16.1, and the plot of a gain fit.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.controllers import LinearQuadraticRegulator

from awiwi_drake.parameters.backstepping import OptimalGainsCase
from awiwi_drake.parameters.rigs import FlexibleJointParams
from awiwi_drake.plotting import figure_axes
from awiwi_drake.rigs import flexible_joint_rig

__all__ = ["table_16_1_rig", "printed_model_feedback", "plot_gain_fit"]


def table_16_1_rig(case: OptimalGainsCase | None = None, **kw):
    """``flexible_joint_rig`` with Table 16.1 values (M, Bm, K; no damping: the table lists none)."""
    c = case or OptimalGainsCase()
    p = FlexibleJointParams(link_inertia=c.link_inertia, motor_inertia=c.motor_inertia, stiffness=c.stiffness,
                            link_damping=0.0, motor_damping=0.0)
    return flexible_joint_rig(params=p, spring="linear", **kw)


def printed_model_feedback(case: OptimalGainsCase | None = None) -> np.ndarray:
    """ARE gain for the A, B printed in Table 16.1 (Drake ``LinearQuadraticRegulator(A, B, Q, R)``).

    Returned as ``u = K x`` (the sign of the printed Kdes) for direct comparison.
    """
    c = case or OptimalGainsCase()
    A = np.array([[0, 1, 0, 0], [0, 0, 1 / c.link_inertia, 0], [0, 0, 0, 1], [0, 0, 0, 0]])
    B = np.array([[0], [0], [0], [c.stiffness / c.motor_inertia]])
    K, _ = LinearQuadraticRegulator(A, B, np.diag(c.q_weights), np.array([[c.r_weight]]))
    return -np.asarray(K).ravel()


def plot_gain_fit(fits, *, ax=None):
    """Relative gain error per state entry of each :class:`~awiwi_drake.control.optimal_gains.GainFit` (ch. 16)."""
    fig, ax = figure_axes(ax)
    labels = ["q", "qd", "tau", "taud"]
    width = 0.8 / max(1, len(fits))
    for i, f in enumerate(fits):
        err = np.abs(f.feedback - f.target) / np.abs(f.target)
        ax.bar(np.arange(4) + i * width, np.maximum(err, 1e-16), width, label=f"{f.method}: d = {f.distance:.2g}")
    ax.set_yscale("log")
    ax.set_xticks(np.arange(4) + 0.4 - width / 2, labels)
    ax.set_ylabel("|K_bs - K_opt| / |K_opt|")
    ax.legend(fontsize="small")
    return fig, ax
