"""Thesis ch. 8: stiffness correction held while loads change the mechanical stiffness (Fig 8.3).

The law (8.1)-(8.2) and the controller are :mod:`awiwi_drake.control.stiffness_correction`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.primitives import ConstantVectorSource

from awiwi_drake.analysis import Samples, simulate
from awiwi_drake.control.base import closed_loop
from awiwi_drake.control.stiffness_correction import StiffnessCorrectedImpedance, pretension_elongation
from awiwi_drake.parameters.hand_control import StiffnessCorrectionParams
from awiwi_drake.plotting import plot_traces
from awiwi_drake.rigs import joint_rig

__all__ = ["StiffnessRun", "stiffness_correction_run"]


@dataclass
class StiffnessRun:
    """Time series of a stiffness-correction run: ``t``, link angle ``q``, external torque ``tau_ext``,
    ``k_imp``, ``k_mech``, ``k_eff`` ((8.1) of the logged gains) and the target ``k_target``."""

    t: np.ndarray
    q: np.ndarray
    tau_ext: np.ndarray
    k_imp: np.ndarray
    k_mech: np.ndarray
    k_eff: np.ndarray
    k_target: np.ndarray
    corrected: bool

    def plot(self, ax=None):
        """Fig 8.3: K_imp, K_mech and K_eff (8.1) over time, with the target; ``(fig, ax)``."""
        return plot_traces(self.t, {"K_imp (controller)": self.k_imp, "K_mech (springs)": self.k_mech,
                                    "K_eff (8.1)": self.k_eff}, styles={"K_mech (springs)": ":", "K_eff (8.1)": "-."},
                           reference=self.k_target, ylabel="stiffness [Nm/rad]", ax=ax, legend=dict(fontsize="small"))


def stiffness_correction_run(*, targets=None, loads=(0.0, 0.02, 0.04, 0.0), segment: float = 0.15,
                             corrected: bool = True, params: StiffnessCorrectionParams | None = None,
                             dt: float = 1e-3) -> StiffnessRun:
    """Fig 8.3: K_eff held at each target (1, then 0.7 Nm/rad) while load steps change K_mech.

    Each target is held for ``len(loads)`` segments of ``segment`` s with the external torques
    ``loads`` [Nm]. ``corrected=False`` uses K_imp from the nominal K_mech (no online correction).
    """
    p = params or StiffnessCorrectionParams()
    targets = tuple(p.targets if targets is None else targets)
    rig = joint_rig()
    law = StiffnessCorrectedImpedance(rig.params, rig.spring, p, online=corrected)
    loop = closed_loop(rig, law, rate_hz=None, sources={"joint_angle_reference": ConstantVectorSource([0.0])})
    rq = rig.params.link_pulley_radius
    x_c = pretension_elongation(rig.spring, p.epsilon * targets[0], rq)
    f0 = float(rig.spring.force(np.array([x_c]))[0])
    op = rig.operating_point(pretension=f0)
    ctx = loop.create_context(state=op.state)
    starts = segment * np.arange(len(targets) * len(loads))          # one segment per (target, load)
    k_ref = np.repeat(np.asarray(targets, float), len(loads))
    w = np.tile(np.asarray(loads, float), len(targets))
    res = simulate(loop, ctx, float(starts[-1] + segment),
                   inputs={"effective_stiffness_reference": Samples(starts, k_ref), "external_torque": Samples(starts, w)},
                   log=("state", "controller_stiffness", "external_torque", "effective_stiffness_reference"), log_period=dt,
                   max_step=1e-3, accuracy=1e-6)
    s = res["controller_stiffness"]
    return StiffnessRun(res.t, res["state"][:, 0], res["external_torque"][:, 0], s[:, 0], s[:, 1], s[:, 2],
                        res["effective_stiffness_reference"][:, 0], corrected)
