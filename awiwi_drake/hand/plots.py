"""Plots of the finger/hand studies: take results (data), return ``(fig, ax)``; never simulate."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_coupling_matrix", "plot_stiffness_map", "plot_estimation_grid", "plot_estimation_study",
           "plot_coriolis_study", "plot_wrist_compensation", "plot_coupling_hold"]


def _plt():
    import matplotlib.pyplot as plt  # backend chosen by MPLBACKEND / the notebook
    return plt


def plot_coupling_matrix(P, *, joint_names=None, tendon_names=None, ax=None, title="P = dh/dq [m]"):
    """Heat map of a coupling matrix (rows: tendons, columns: joints), values printed in mm."""
    plt = _plt()
    fig, ax = (ax.figure, ax) if ax is not None else plt.subplots(figsize=(4, 4.5))
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
    plt = _plt()
    fig, ax = (ax.figure, ax) if ax is not None else plt.subplots(figsize=(4, 3.5))
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


def plot_estimation_grid(study, key, ax=None):
    """Fig 5.16: true (q10, q11) grid (red circles) and estimates (blue crosses) for one case."""
    plt = _plt()
    fig, ax = (ax.figure, ax) if ax is not None else plt.subplots(figsize=(4, 4))
    est = study.estimates[key]
    ax.plot(study.grid[:, 0], study.grid[:, 1], "o", mfc="none", mec="r", ms=5, label="true")
    ax.plot(est[:, 0], est[:, 1], "x", color="b", ms=4, label="estimate")
    it, a, start = key
    ax.set_title(f"{it} it., {1e3 * a:g} mm, {start}", fontsize=9)
    ax.set_xlabel("q10 [rad]")
    ax.set_ylabel("q11 [rad]")
    ax.set_xlim(-1.8, 1.8)
    ax.set_ylim(-1.8, 1.8)
    ax.set_aspect("equal")
    return fig, ax


def plot_estimation_study(study, start="cold"):
    """Fig 5.17: 3 x 3 panels (rows 50/30/15 iterations, columns 0/0.5/1 mm noise)."""
    plt = _plt()
    its = sorted({k[0] for k in study.estimates}, reverse=True)
    noises = sorted({k[1] for k in study.estimates})
    fig, axes = plt.subplots(len(its), len(noises), figsize=(3 * len(noises), 3 * len(its)), squeeze=False)
    for i, it in enumerate(its):
        for j, a in enumerate(noises):
            plot_estimation_grid(study, (it, a, start), ax=axes[i, j])
    fig.tight_layout()
    return fig, axes


def plot_coriolis_study(study, ax=None):
    """Fig 5.7: joint position difference full minus simplified (no Coriolis) model."""
    plt = _plt()
    fig, ax = (ax.figure, ax) if ax is not None else plt.subplots(figsize=(6, 3.5))
    for j, name in enumerate(study.joint_names):
        ax.plot(study.t, study.difference[:, j], label=name)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error [rad]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return fig, ax


def plot_wrist_compensation(study, ax=None):
    """Finger joint drift during a wrist abduction sweep, without and with compensation."""
    plt = _plt()
    if ax is None:
        fig, ax = plt.subplots(1, 2, figsize=(10, 3.5), sharey=True)
    else:
        fig = np.ravel(ax)[0].figure
    for a, drift, title in ((ax[0], study.drift_uncompensated, "uncompensated"),
                            (ax[1], study.drift_compensated, "with wrist feedforward")):
        for j, name in enumerate(study.joint_names):
            if np.max(np.abs(drift[:, j])) > 1e-6:
                a.plot(study.t, drift[:, j], label=name)
        a.set_title(title, fontsize=9)
        a.set_xlabel("time [s]")
        a.grid(True, alpha=0.3)
    ax[0].set_ylabel("q - q_ref [rad]")
    ax[0].legend(fontsize=7, ncol=2)
    return fig, ax


def plot_coupling_hold(study, ax=None):
    """PIP, DIP and the coupling error q_DIP - c q_PIP during a PIP step."""
    plt = _plt()
    fig, ax = (ax.figure, ax) if ax is not None else plt.subplots(figsize=(6, 3.5))
    ax.plot(study.t, study.q_pip, label="q_PIP")
    ax.plot(study.t, study.q_dip, label="q_DIP")
    ax.plot(study.t, study.coupling_error, label="q_DIP - c q_PIP")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("[rad]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return fig, ax
