"""Thesis ch. 12: pole placement on the flexible joint, open-loop pole sweeps (Fig 12.3) and root loci (Fig 12.4).

The design, ``pole_sensitivity`` and ``stable_stiffness_interval`` are :mod:`awiwi_drake.control.pole_placement`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from awiwi_drake.analysis import linearize
from awiwi_drake.parameters import FlexibleJointParams
from awiwi_drake.parameters.control import PolePlacementParams
from awiwi_drake.plotting import figure_axes
from awiwi_drake.rigs import flexible_joint_rig

__all__ = ["OpenLoopPoleSweep", "open_loop_pole_sweep", "plot_root_locus"]


@dataclass
class OpenLoopPoleSweep:
    """Fig 12.3: open-loop poles of the flexible joint (rows) over a stiffness grid and a link-damping grid."""

    stiffness: np.ndarray
    poles_vs_stiffness: np.ndarray
    link_damping: np.ndarray
    poles_vs_damping: np.ndarray

    def plot(self, axes=None):
        """Both root loci side by side (:func:`plot_root_locus`); returns ``(fig, axes)``."""
        if axes is None:
            fig, axes = figure_axes(None, ncols=2, figsize=(12, 5))
        plot_root_locus(self.stiffness, self.poles_vs_stiffness, ax=axes[0])
        plot_root_locus(self.link_damping, self.poles_vs_damping, ax=axes[1], label="d_q [Nm s/rad]")
        axes[0].set_title("Fig 12.3: open-loop poles vs k")
        axes[1].set_title("Fig 12.3: open-loop poles vs d_q")
        return axes[0].figure, axes


def _sorted_poles(A: np.ndarray) -> np.ndarray:
    ev = np.linalg.eigvals(A)
    return ev[np.lexsort((ev.imag, ev.real))]


def open_loop_pole_sweep(params: PolePlacementParams | None = None, *, num: int = 25,
                         base: Any = None) -> OpenLoopPoleSweep:
    """Fig 12.3: poles of the framework linearisation (``Linearize``) of the flexible-joint rig, varying one
    parameter of Table 12.1 at a time: ``k`` in [stiffness_low, stiffness_high] and ``d_q`` in
    [link_damping_low, link_damping_high] (:class:`PolePlacementParams`)."""
    p = params or PolePlacementParams()
    base = base or FlexibleJointParams()
    ks = np.linspace(p.stiffness_low, p.stiffness_high, int(num))
    ds = np.linspace(p.link_damping_low, p.link_damping_high, int(num))
    pk = np.array([_sorted_poles(linearize(flexible_joint_rig(params=base.replace(stiffness=k))).A) for k in ks])
    pd = np.array([_sorted_poles(linearize(flexible_joint_rig(params=base.replace(link_damping=d))).A) for d in ds])
    return OpenLoopPoleSweep(ks, pk, ds, pd)


def plot_root_locus(values, poles, *, nominal=None, ax=None, label: str = "k [Nm/rad]"):
    """Poles (rows of ``poles``) for each parameter value, coloured by value; squares at ``nominal``."""
    fig, ax = figure_axes(ax, figsize=(6, 5))
    values = np.asarray(values, float)
    poles = np.asarray(poles)
    sc = None
    for j in range(poles.shape[1]):
        sc = ax.scatter(poles[:, j].real, poles[:, j].imag, c=values, s=10, cmap="viridis")
    if nominal is not None:
        nominal = np.asarray(nominal)
        ax.plot(nominal.real, nominal.imag, "rs", mfc="none", ms=9, label="nominal")
        ax.legend()
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel("Re(s) [1/s]")
    ax.set_ylabel("Im(s) [rad/s]")
    fig.colorbar(sc, ax=ax, label=label)
    ax.grid(True, alpha=0.3)
    return fig, ax
