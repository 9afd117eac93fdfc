"""Thesis ch. 13: LQR regulation of the flexible joint (Fig 13.2-13.3).

The design is :mod:`awiwi_drake.control.lqr` (Drake ``LinearQuadraticRegulator``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from awiwi_drake.analysis import simulate
from awiwi_drake.control.base import closed_loop
from awiwi_drake.control.lqr import design_lqr, lqr_controller
from awiwi_drake.parameters.control import LqrParams
from awiwi_drake.rigs import flexible_joint_rig

__all__ = ["lqr_trajectories"]


def lqr_trajectories(r_values: Sequence[float] = (1e-4, 1e-2, 1.0), *, x0=(0.3, 0.0, 0.3, 0.0),
                     t_final: float = 0.2, params: LqrParams | None = None) -> dict:
    """Fig 13.2-13.3: regulation of the flexible joint (Table 13.1) from ``x0`` for each R (continuous loop)."""
    out = {}
    for r in r_values:
        rig = flexible_joint_rig(backend="python")
        design = design_lqr(rig, params, r=r)
        loop = closed_loop(rig, lqr_controller(rig, params, r=r), rate_hz=None)
        ctx = loop.create_context(state=np.asarray(x0, float), references={"joint_angle_reference": 0.0})
        res = simulate(loop.diagram, ctx, t_final, log=("state", "motor_torque"), max_step=1e-4, accuracy=1e-7)
        out[r] = dict(t=res.t, state=res.signals["state"], u=res.signals["motor_torque"][:, 0], K=design.K,
                      S=design.S, Q=design.Q, R=design.R)
    return out
