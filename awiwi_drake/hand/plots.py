"""Plots of the hand's matrices (coupling, stiffness): data in, ``(fig, ax)`` out.

The plots of the chapter 5-6 studies sit beside them in :mod:`awiwi_drake.reproductions.ch05_fingers`
and :mod:`awiwi_drake.reproductions.ch06_wrist`.
"""

from __future__ import annotations

import numpy as np

from awiwi_drake.plotting import figure_axes

__all__ = ["plot_coupling_matrix", "plot_stiffness_map"]


def plot_coupling_matrix(P, *, joint_names=None, tendon_names=None, ax=None, title="P = dh/dq [m]"):
    """Heat map of a coupling matrix (rows: tendons, columns: joints), values printed in mm."""
    fig, ax = figure_axes(ax, figsize=(4, 4.5))
    P = np.asarray(P, dtype=float)
    lim = np.abs(P).max() or 1.0
    ax.imshow(P, cmap="RdBu_r", vmin=-lim, vmax=lim, aspect="auto")
    for (i, j), v in np.ndenumerate(P):
        if v != 0:
            ax.text(j, i, f"{1e3 * v:.1f}", ha="center", va="center", fontsize=7)
    ax.set_xticks(range(P.shape[1]), joint_names or range(P.shape[1]), rotation=45, fontsize=7)
    ax.set_yticks(range(P.shape[0]), tendon_names or range(P.shape[0]), fontsize=7)
    ax.set_title(title + " (numbers in mm)", fontsize=9)
    return fig, ax


def plot_stiffness_map(K, *, joint_names=None, ax=None, title="K_q [N m/rad]"):
    """Heat map of a joint stiffness matrix (5.12)."""
    fig, ax = figure_axes(ax, figsize=(4, 3.5))
    K = np.asarray(K, dtype=float)
    lim = np.abs(K).max() or 1.0
    im = ax.imshow(K, cmap="RdBu_r", vmin=-lim, vmax=lim)
    for (i, j), v in np.ndenumerate(K):
        ax.text(j, i, f"{v:.3g}", ha="center", va="center", fontsize=7)
    names = joint_names or [str(i) for i in range(K.shape[0])]
    ax.set_xticks(range(K.shape[1]), names, fontsize=7)
    ax.set_yticks(range(K.shape[0]), names, fontsize=7)
    fig.colorbar(im, ax=ax)
    ax.set_title(title, fontsize=9)
    return fig, ax


