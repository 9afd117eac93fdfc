"""Thesis ch. 12: pole placement on the flexible joint, open-loop pole sweeps (Fig 12.3) and the robustness
analysis of section 12.3 ((12.19), Fig 12.4).

The design and ``stable_stiffness_interval`` are :mod:`awiwi_drake.control.pole_placement`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from awiwi_drake.analysis import PHYSICAL_FAILURES, linearize, simulate
from awiwi_drake.control.base import closed_loop
from awiwi_drake.control.linear import state_feedback_controller
from awiwi_drake.control.pole_placement import design_pole_placement, stable_stiffness_interval
from awiwi_drake.parameters import FlexibleJointParams
from awiwi_drake.parameters.control import PolePlacementParams
from awiwi_drake.plotting import figure_axes, label_axes, plot_poles
from awiwi_drake.rigs import flexible_joint_rig

__all__ = ["OpenLoopPoleSweep", "open_loop_pole_sweep", "StiffnessRobustness",
           "stiffness_robustness"]

#: (12.19) as printed: the poles of the Table 12.1 design on the plant with k = 0.600 Nm/rad [1/s].
PRINTED_12_19 = np.array([-318.78, 53.27 + 225.14j, 53.27 - 225.14j, -0.058])
#: (12.18) as printed: alpha = [4395, 6.177, -4395, 288.99]; Fig 12.4's printed locus is that of u = -alpha x.
PRINTED_12_18 = np.array([[4395.0, 6.177, -4395.0, 288.99]])


@dataclass
class OpenLoopPoleSweep:
    """Fig 12.3: open-loop poles of the flexible joint (rows) over a stiffness grid and a link-damping grid."""

    stiffness: np.ndarray
    poles_vs_stiffness: np.ndarray
    link_damping: np.ndarray
    poles_vs_damping: np.ndarray

    def plot(self, axes=None):
        """Both root loci side by side (:func:`~awiwi_drake.plotting.plot_poles`); returns ``(fig, axes)``."""
        fig, axes = figure_axes(axes, ncols=2, figsize=(12, 5))
        plot_poles(self.poles_vs_stiffness, axes[0], values=self.stiffness, name="k [Nm/rad]")
        plot_poles(self.poles_vs_damping, axes[1], values=self.link_damping, name="d_q [Nm s/rad]")
        axes[0].set_title("Fig 12.3: open-loop poles vs k")
        axes[1].set_title("Fig 12.3: open-loop poles vs d_q")
        return fig, axes


def open_loop_pole_sweep(params: PolePlacementParams | None = None, *, num: int = 25,
                         base: Any = None) -> OpenLoopPoleSweep:
    """Fig 12.3: poles of the framework linearisation (``Linearize``) of the flexible-joint rig, varying one
    parameter of Table 12.1 at a time: ``k`` in [stiffness_low, stiffness_high] and ``d_q`` in
    [link_damping_low, link_damping_high] (:class:`PolePlacementParams`)."""
    p = params or PolePlacementParams()
    base = base or FlexibleJointParams()
    ks = np.linspace(p.stiffness_low, p.stiffness_high, int(num))
    ds = np.linspace(p.link_damping_low, p.link_damping_high, int(num))
    pk = np.array([linearize(flexible_joint_rig(params=base.replace(stiffness=k))).poles for k in ks])
    pd = np.array([linearize(flexible_joint_rig(params=base.replace(link_damping=d))).poles for d in ds])
    return OpenLoopPoleSweep(ks, pk, ds, pd)


@dataclass
class StiffnessRobustness:
    """Section 12.3: the Table 12.1 pole-placement design (fixed gain ``K``, ``u = -K x``) on plants whose spring
    stiffness differs from the design's.

    Poles are of Drake's linearisation of the closed loop (``closed_loop`` of the rig with that stiffness and the
    nominal controller), sorted by real part [1/s].  ``stable_interval`` is the interval of plant stiffness
    [Nm/rad] around ``design_stiffness`` where that loop is stable; ``target_intervals`` is the same for designs
    whose targets are Table 12.1's (omega1, omega2) times ``target_scales`` (rows ``[low, high]``; an end equal to
    the searched range's end, ``search_range``, means "at least").  ``t``/``state`` (keys ``nominal``, ``perturbed``;
    columns ``[q, qdot, theta, thetadot]``) are the simulated responses to a ``step`` [rad] of the joint-angle reference from rest, on the nominal and on the perturbed
    plant; ``diverged_at`` (same keys) is when ``simulate`` stopped that run as diverged (None: it did not), its
    trajectory is then the run up to 95 % of that time.  ``printed_gain_poles_vs_stiffness`` is the same locus as
    ``poles_vs_stiffness`` under the printed gains (12.18) applied as ``u = -alpha x`` (the printed Fig 12.4)."""

    design_stiffness: float
    perturbed_stiffness: float
    K: np.ndarray
    nominal_poles: np.ndarray
    perturbed_poles: np.ndarray
    stiffness: np.ndarray
    poles_vs_stiffness: np.ndarray
    stable_interval: tuple[float, float]
    target_scales: np.ndarray
    targets: np.ndarray
    target_intervals: np.ndarray
    search_range: tuple[float, float]
    step: float
    t: dict
    state: dict
    diverged_at: dict
    printed_gain_poles_vs_stiffness: np.ndarray
    printed_perturbed_poles: np.ndarray = field(default_factory=PRINTED_12_19.copy)

    def summary(self) -> str:
        """Ours beside the printed values, one line each."""
        fmt = lambda p: ", ".join(f"{z.real:.4g}" + (f" {'+' if z.imag > 0 else '-'} {abs(z.imag):.4g}i"
                                                      if abs(z.imag) > 1e-9 else "") for z in p)
        lo, hi = self.stable_interval
        lines = [f"design k = {self.design_stiffness} Nm/rad, K = {np.array2string(self.K.ravel(), precision=5)}",
                 f"nominal closed-loop poles: {fmt(self.nominal_poles)}",
                 f"(12.19) k = {self.perturbed_stiffness}: ours {fmt(self.perturbed_poles)}; "
                 f"printed {fmt(self.printed_perturbed_poles)}",
                 f"stable for k in [{lo:.6f}, {hi:.6f}] Nm/rad",
                 *(f"{name} step: " + (f"diverged at {t:.4f} s" if t is not None else "did not diverge")
                   for name, t in self.diverged_at.items())]
        for s, (w1, w2), (a, b) in zip(self.target_scales, self.targets, self.target_intervals):
            ends = ("<= " if a <= self.search_range[0] else "") + f"{a:.4g}", \
                ("at least " if b >= self.search_range[1] else "") + f"{b:.4g}"
            lines.append(f"targets x{s:g} (omega1 {w1:g}, omega2 {w2:g} rad/s): stable for k in [{ends[0]}, {ends[1]}]")
        return "\n".join(lines)

    def plot(self, axes=None):
        """Fig 12.4 (closed-loop root locus over k) for the gains that realise (12.13) and for the printed (12.18),
        (12.19) ours vs printed, the simulated steps (|q - q_ref|, log scale, with the envelope e^(max Re s t) of
        the perturbed loop) and the tolerated stiffness error per target scale; returns ``(fig, axes)`` (2 x 3,
        the last panel unused)."""
        fig, axes = figure_axes(axes, nrows=2, ncols=3, figsize=(18, 9))
        axes = np.asarray(axes).reshape(2, 3)
        krange = f"k in [{self.stiffness[0]:g}, {self.stiffness[-1]:g}] Nm/rad"
        plot_poles(self.poles_vs_stiffness, axes[0, 0], values=self.stiffness, name="k [Nm/rad]")
        plot_poles(self.nominal_poles, axes[0, 0], marker="s", color="r", mfc="none", ms=9, label="nominal", damping=())
        axes[0, 0].set_title(f"Fig 12.4, gains placing (12.13): {krange}", fontsize=10)
        plot_poles(self.printed_gain_poles_vs_stiffness, axes[0, 1], values=self.stiffness, name="k [Nm/rad]")
        axes[0, 1].set_title(f"Fig 12.4, printed gains (12.18) as u = -alpha x: {krange}", fontsize=10)
        axes[0, 1].ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
        ax = axes[0, 2]
        plot_poles(self.nominal_poles, ax, marker="s", mfc="none", ms=9, label=f"design, k = {self.design_stiffness}")
        plot_poles(self.perturbed_poles, ax, ms=9, label=f"ours, k = {self.perturbed_stiffness}", damping=())
        plot_poles(self.printed_perturbed_poles, ax, marker="+", ms=11, damping=(),
                   label=f"printed (12.19), k = {self.perturbed_stiffness}")
        ax.set_title("(12.19): the design under a 0.8 % stiffness error")
        ax = axes[1, 0]
        for name in ("nominal", "perturbed"):
            k = self.design_stiffness if name == "nominal" else self.perturbed_stiffness
            ax.semilogy(self.t[name], np.abs(self.state[name][:, 0] - self.step) + 1e-12, label=f"{name}, k = {k}")
        sigma = float(np.max(self.perturbed_poles.real))
        tt, err = self.t["perturbed"], np.abs(self.state["perturbed"][:, 0] - self.step)
        late = tt >= tt[0] + 0.8 * (tt[-1] - tt[0])
        anchor = int(np.flatnonzero(late)[np.argmax(err[late])])
        ax.semilogy(tt, err[anchor] * np.exp(sigma * (tt - tt[anchor])), "k:", label=f"e^({sigma:.1f} t) envelope")
        for name, when in self.diverged_at.items():
            if when is not None:
                ax.axvline(when, color="r", lw=0.8, label=f"{name} diverged at {when * 1e3:.1f} ms")
        ax.set_ylim(1e-7, None)
        label_axes(ax, "|q - q_ref| [rad]", title=f"simulated {self.step:g} rad step of the reference")
        ax = axes[1, 1]
        w1, k0 = self.targets[:, 0], self.design_stiffness
        ax.loglog(w1, (k0 - self.target_intervals[:, 0]) / k0, "o-", label="below the design k")
        ax.loglog(w1, (self.target_intervals[:, 1] - k0) / k0, "s-", label="above the design k")
        ax.axhline((k0 - self.perturbed_stiffness) / k0, color="r", lw=0.8, ls=":", label="(12.19): 0.8 %")
        label_axes(ax, "tolerated relative stiffness error [-]", xlabel="target omega1 [rad/s] (omega2 = 0.3 omega1)",
                   title="stable stiffness interval vs the target dynamics")
        axes[1, 2].set_axis_off()
        fig.tight_layout()
        return fig, axes


def _robustness_loop(base: FlexibleJointParams, stiffness: float, controller_of):
    rig = flexible_joint_rig(params=base.replace(stiffness=float(stiffness)))
    return closed_loop(rig, controller_of(), rate_hz=None, name=f"pole_placement_k_{stiffness:g}")


def _closed_loop_poles(loop) -> np.ndarray:
    ctx = loop.create_context(references={"joint_angle_reference": 0.0})
    return linearize(loop.diagram, context=ctx, input="joint_angle_reference", outputs=("joint_angle",)).poles


def stiffness_robustness(params: PolePlacementParams | None = None, *, num: int = 60,
                         base: FlexibleJointParams | None = None, window: float | None = None) -> StiffnessRobustness:
    """Section 12.3: the pole-placement design of Table 12.1 (targets (12.13)) under a stiffness error.

    The gains are designed once on the rig with Table 12.1's k; each plant stiffness then gets its own
    flexible-joint rig closed by that fixed controller (``closed_loop``, continuous as in the thesis), and the
    poles come from Drake's ``Linearize`` of the closed-loop diagram: at ``params.perturbed_stiffness`` ((12.19),
    k 0.605 -> 0.600) and on ``num`` points of [stiffness_low, stiffness_high] (Fig 12.4).  The stable interval of
    k is found by root finding on the largest real part (:func:`stable_stiffness_interval`), for the thesis's
    targets and for the targets scaled by ``params.robustness_target_scales`` (section 12.4: the sensitivity
    depends on the target dynamics).  A ``params.robustness_reference_step`` reference step is simulated (``simulate``) on
    the nominal and the perturbed plant over ``window`` (default ``params.robustness_window``)."""
    if isinstance(num, bool) or not isinstance(num, (int, np.integer)) or num < 2:
        raise ValueError(f"stiffness_robustness: num = {num!r} must be an integer >= 2 (points of Fig 12.4's k range)")
    if window is not None and not (np.isfinite(window) and window > 0):
        raise ValueError(f"stiffness_robustness: window = {window!r} s must be finite and > 0")
    p = params or PolePlacementParams()
    base = base or FlexibleJointParams()
    k0, k1 = float(base.stiffness), float(p.perturbed_stiffness)
    rig0 = flexible_joint_rig(params=base)
    design = design_pole_placement(rig0, p)
    controller = functools.partial(state_feedback_controller, design.linearization, design.K,
                                   reference="joint_angle", name="pole_placement")
    loops = {"nominal": _robustness_loop(base, k0, controller), "perturbed": _robustness_loop(base, k1, controller)}
    nominal, perturbed = (_closed_loop_poles(loops[n]) for n in ("nominal", "perturbed"))
    ks = np.linspace(p.stiffness_low, p.stiffness_high, int(num))
    table = np.array([_closed_loop_poles(_robustness_loop(base, k, controller)) for k in ks])
    printed_controller = functools.partial(state_feedback_controller, design.linearization, PRINTED_12_18,
                                           reference="joint_angle", name="pole_placement_12_18")
    printed_table = np.array([_closed_loop_poles(_robustness_loop(base, k, printed_controller)) for k in ks])

    def A_of_k(k):
        return linearize(flexible_joint_rig(params=base.replace(stiffness=float(k)))).A
    half = max(k0 - p.stiffness_low, p.stiffness_high - k0)     # Fig 12.4's range, symmetric around k0
    search = (k0 - half, k0 + half)
    interval = stable_stiffness_interval(A_of_k, design.linearization.B, design.K, k0)
    scales = np.asarray(p.robustness_target_scales, float)
    targets = np.array([[p.omega1 * s, p.omega2 * s] for s in scales])
    intervals = []
    for w1, w2 in targets:
        d = design_pole_placement(rig0, p.replace(omega1=float(w1), omega2=float(w2)))
        intervals.append(stable_stiffness_interval(A_of_k, d.linearization.B, d.K, k0, half_width=half))
    window = float(p.robustness_window if window is None else window)
    t, q, diverged_at = {}, {}, {}
    for name, loop in loops.items():
        diverged_at[name] = None

        def run(end):
            ctx = loop.create_context(references={"joint_angle_reference": p.robustness_reference_step})
            return simulate(loop, ctx, end, log=("state",), mode="fixed_step", step=p.robustness_integration_step)
        try:
            res = run(window)
        except PHYSICAL_FAILURES as exc:      # an unstable loop: reported, and its run kept up to 95 % of that time
            diverged_at[name] = float(exc.t)
            res = run(0.95 * diverged_at[name])
        t[name], q[name] = res.t, res["state"]
    return StiffnessRobustness(k0, k1, design.K, nominal, perturbed, ks, table, interval, scales, targets,
                               np.array(intervals), search, float(p.robustness_reference_step), t, q, diverged_at,
                               printed_table)
