"""Thesis ch. 16: optimal backstepping gains, the Table 16.1 case.

The gain selection itself (Algorithm 3, least squares on ``log Omega``) is
:mod:`awiwi_drake.control.optimal_gains`; this module holds the Table 16.1 rig,
the ARE gain of the model printed in Table 16.1, and the plot of a gain fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from awiwi_drake.analysis.linear import lqr_gain
from awiwi_drake.parameters.backstepping import OptimalGainsCase, OptimalGainsStudy
from awiwi_drake.parameters.rigs import FlexibleJointParams
from awiwi_drake.plotting import figure_axes, plot_traces
from awiwi_drake.rigs import flexible_joint_rig

__all__ = ["table_16_1_rig", "printed_model_feedback", "plot_gain_fit", "GainSamples", "fig_16_3_gain_samples"]


def table_16_1_rig(case: OptimalGainsCase | None = None, **kw):
    """``flexible_joint_rig`` with Table 16.1 values (M, Bm, K; no damping: the table lists none)."""
    c = case or OptimalGainsCase()
    p = FlexibleJointParams(link_inertia=c.link_inertia, motor_inertia=c.motor_inertia, stiffness=c.stiffness,
                            link_damping=0.0, motor_damping=0.0)
    return flexible_joint_rig(params=p, spring="linear", **kw)


def printed_model_feedback(case: OptimalGainsCase | None = None) -> np.ndarray:
    """ARE gain for the A, B printed in Table 16.1 (:func:`~awiwi_drake.analysis.linear.lqr_gain`: Drake's LQR).

    Returned as ``u = K x`` (the sign of the printed Kdes) for direct comparison.
    """
    c = case or OptimalGainsCase()
    A = np.array([[0, 1, 0, 0], [0, 0, 1 / c.link_inertia, 0], [0, 0, 0, 1], [0, 0, 0, 0]])
    B = np.array([[0], [0], [0], [c.stiffness / c.motor_inertia]])
    K, _ = lqr_gain(A, B, np.diag(c.q_weights), [[c.r_weight]])
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


@dataclass
class GainSamples:
    """Fig 16.3 / Table 16.2: link angle ``q`` [rad] (runs x len(t)) over ``t`` [s] for each gain selection
    (``gains``, relative gain ``distance`` to the LQR target), ``deviation`` (max |q - median trajectory|
    per run [rad]), the weight ``r_weight`` and the ``step`` [rad]."""

    t: np.ndarray
    q: np.ndarray
    distance: np.ndarray
    gains: list
    deviation: np.ndarray
    r_weight: float
    step: float

    def plot(self, ax=None):
        return plot_traces(self.t, {f"run {i}: distance {d:.2g}": q for i, (q, d) in enumerate(zip(self.q, self.distance))},
                           reference=np.full_like(self.t, self.step), ylabel="link angle [rad]", ax=ax,
                           title=f"Fig 16.3: R = {self.r_weight:g}", legend=dict(fontsize="x-small"))


def fig_16_3_gain_samples(study: OptimalGainsStudy | None = None, *, r_weight: float | None = None,
                          executor="serial") -> GainSamples:
    """Fig 16.3 / Table 16.2: ``study.runs`` independent Algorithm 3 gain selections (seeds 0..runs-1,
    ``study.samples`` draws each) and the link response of each to a ``study.step`` reference on the
    Table 16.2 model (= Table 16.1; continuous loop, no damping), sampled at ``study.num`` points up to
    ``study.t_final`` (defaults: :class:`~awiwi_drake.parameters.backstepping.OptimalGainsStudy`).

    ``r_weight`` None: Table 16.2's R = 0.1.
    """
    from awiwi_drake.analysis import simulate
    from awiwi_drake.control.backstepping import impedance_controller
    from awiwi_drake.control.base import closed_loop
    from awiwi_drake.control.optimal_gains import monte_carlo_gains
    s = study or OptimalGainsStudy()
    case = OptimalGainsCase() if r_weight is None else OptimalGainsCase(r_weight=r_weight)
    t = np.linspace(0.0, s.t_final, s.num)
    Q, dist, gains = [], [], []
    for seed in range(int(s.runs)):
        fit = monte_carlo_gains(table_16_1_rig(case), case, samples=s.samples, seed=seed, executor=executor)
        rig = table_16_1_rig(case)
        loop = closed_loop(rig, impedance_controller(rig, fit.gains, external_torque="none"), rate_hz=None)
        ctx = loop.create_context(references={"joint_angle_reference": s.step})
        res = simulate(loop.diagram, ctx, s.t_final, log=("joint_angle",), max_step=s.max_step, accuracy=s.accuracy)
        Q.append(np.interp(t, res.t, res["joint_angle"][:, 0]))
        dist.append(fit.distance)
        gains.append(fit.gains)
    Q = np.array(Q)
    return GainSamples(t, Q, np.array(dist), gains, np.max(np.abs(Q - np.median(Q, axis=0)), axis=1),
                       case.r_weight, s.step)
