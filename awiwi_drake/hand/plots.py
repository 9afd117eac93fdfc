"""Plots of the hand's matrices (coupling, stiffness): data in, ``(fig, ax)`` out.

The plots of the chapter 5-6 studies sit beside them in :mod:`awiwi_drake.reproductions.ch05_fingers`
and :mod:`awiwi_drake.reproductions.ch06_wrist`.
"""

from __future__ import annotations

import numpy as np

from awiwi_drake.plotting import figure_axes

__all__ = ["plot_coupling_matrix", "plot_stiffness_map"]


def _heat_map(M, rows, cols, ax, figsize, title, text, *, rotation=0, colorbar=False):
    """``M`` in red/blue around 0 with ``text(v)`` printed in each cell (None: nothing)."""
    fig, ax = figure_axes(ax, figsize=figsize)
    M = np.asarray(M, dtype=float)
    lim = np.abs(M).max() or 1.0
    im = ax.imshow(M, cmap="RdBu_r", vmin=-lim, vmax=lim, aspect="auto")
    for (i, j), v in np.ndenumerate(M):
        if text(v) is not None:
            ax.text(j, i, text(v), ha="center", va="center", fontsize=7)
    ax.set_xticks(range(M.shape[1]), cols or range(M.shape[1]), rotation=rotation, fontsize=7)
    ax.set_yticks(range(M.shape[0]), rows or range(M.shape[0]), fontsize=7)
    if colorbar:
        fig.colorbar(im, ax=ax)
    ax.set_title(title, fontsize=9)
    return fig, ax


def plot_coupling_matrix(P, *, joint_names=None, tendon_names=None, ax=None, title="P = dh/dq [m]"):
    """Heat map of a coupling matrix (rows: tendons, columns: joints), values printed in mm."""
    return _heat_map(P, tendon_names, joint_names, ax, (4, 4.5), title + " (numbers in mm)",
                     lambda v: f"{1e3 * v:.1f}" if v != 0 else None, rotation=45)


def plot_stiffness_map(K, *, joint_names=None, ax=None, title="K_q [N m/rad]"):
    """Heat map of a joint stiffness matrix (5.12)."""
    return _heat_map(K, joint_names, joint_names, ax, (4, 3.5), title, lambda v: f"{v:.3g}", colorbar=True)
