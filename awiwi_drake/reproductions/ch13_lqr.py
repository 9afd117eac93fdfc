"""Thesis ch. 13: LQR regulation of the flexible joint (Fig 13.2-13.3).

The design is :mod:`awiwi_drake.control.lqr` (Drake ``LinearQuadraticRegulator``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from awiwi_drake.analysis import simulate
from awiwi_drake.control.base import closed_loop
from awiwi_drake.control.lqr import design_lqr, lqr_controller
from awiwi_drake.parameters.control import LqrParams
from awiwi_drake.plotting import figure_axes, plot_traces
from awiwi_drake.rigs import flexible_joint_rig

__all__ = ["LqrRun", "lqr_trajectories"]


@dataclass
class LqrRun:
    """One Fig 13.2-13.3 regulation: time [s], state ``[q, qdot, theta, thetadot]`` [rad, rad/s], input ``u`` [Nm],
    the gain ``K``, Riccati solution ``S`` and weights ``Q``, ``R``."""

    r: float
    t: np.ndarray
    state: np.ndarray
    u: np.ndarray
    K: np.ndarray
    S: np.ndarray
    Q: np.ndarray
    R: np.ndarray

    def plot(self, ax=None):
        """Link and motor positions [rad] and the input [Nm]; returns ``(fig, (ax_pos, ax_u))``."""
        fig, ax = figure_axes(ax, nrows=1, ncols=2, figsize=(11, 3.8))
        motor = f"motor theta, R = {self.r:g}"
        plot_traces(self.t, {f"link q, R = {self.r:g}": self.state[:, 0], motor: self.state[:, 2]}, styles={motor: ":"},
                    ylabel="position [rad]", ax=ax[0], legend=dict(fontsize=8))
        plot_traces(self.t, {f"u, R = {self.r:g}": self.u}, ylabel="input u [Nm]", ax=ax[1], legend=dict(fontsize=8))
        return fig, ax


def lqr_trajectories(r_values: Sequence[float] = (1e-4, 1e-2, 1.0), *, x0=(0.3, 0.0, 0.3, 0.0),
                     t_final: float = 0.2, params: LqrParams | None = None) -> dict[float, LqrRun]:
    """Fig 13.2-13.3: regulation of the flexible joint (Table 13.1) from ``x0`` for each R (continuous loop)."""
    out = {}
    for r in r_values:
        rig = flexible_joint_rig()
        design = design_lqr(rig, params, r=r)
        loop = closed_loop(rig, lqr_controller(rig, params, r=r), rate_hz=None)
        ctx = loop.create_context(state=np.asarray(x0, float), references={"joint_angle_reference": 0.0})
        res = simulate(loop.diagram, ctx, t_final, log=("state", "motor_torque"), max_step=1e-4, accuracy=1e-7)
        out[r] = LqrRun(float(r), res.t, res["state"], res["motor_torque"][:, 0], design.K, design.S, design.Q,
                        design.R)
    return out
