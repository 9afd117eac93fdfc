"""Plots of the backstepping and hand-level studies: data in, ``(fig, ax)`` out."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_link_angle", "plot_phase_portrait", "plot_lyapunov", "plot_command", "plot_stiffness_run",
           "plot_friction_runs", "plot_gain_fit"]


def _axes(ax, **kw):
    import matplotlib.pyplot as plt
    if ax is None:
        fig, ax = plt.subplots(**kw)
    else:
        fig = ax.figure
    return fig, ax


def _time_series(runs, signal, ylabel, *, ax, title, log=False, reference=False):
    fig, ax = _axes(ax)
    plot = ax.semilogy if log else ax.plot
    for r in runs:
        plot(r.t, signal(r), label=r.label)
    if reference and len(runs) and np.all(np.isfinite(runs[0].reference)):
        ax.plot(runs[0].t, runs[0].reference, "k--", lw=0.8, label="reference")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize="small")
    return fig, ax


def plot_link_angle(runs, *, ax=None, reference: bool = True, title: str = ""):
    """Link angle of each run (Fig 15.7, 15.8, 15.10, 15.13, 15.16, 15.17, 15.19)."""
    return _time_series(runs, lambda r: r.q, "link angle [rad]", ax=ax, title=title, reference=reference)


def plot_command(runs, *, ax=None, title: str = ""):
    """Motor torque entering the plant (Fig 15.11)."""
    return _time_series(runs, lambda r: r.command[:, 0], "motor torque [Nm]", ax=ax, title=title)


def plot_lyapunov(runs, *, ax=None, title: str = "Lyapunov function"):
    """The controller's Lyapunov function along each run (log scale)."""
    return _time_series(runs, lambda r: np.maximum(r.lyapunov, 1e-300), "V", ax=ax, title=title, log=True)


def plot_phase_portrait(runs, *, ax=None, title: str = ""):
    """Phase diagram ``x1' (x1)`` of the scalar example (Fig 15.2-15.4); crosses mark the starts."""
    from awiwi_drake.control.backstepping_example import example_dynamics
    fig, ax = _axes(ax)
    for r in runs:
        x1 = r.state[:, 0]
        x1d = np.array([example_dynamics(x, 0.0)[0] for x in r.state])
        ax.plot(x1, x1d, lw=1)
        ax.plot(x1[0], x1d[0], "kx")
    ax.set_xlabel("x1")
    ax.set_ylabel("dx1/dt")
    ax.set_title(title)
    return fig, ax


def plot_stiffness_run(run, *, ax=None):
    """Fig 8.3: K_imp, K_mech and K_eff (8.1) over time, with the target."""
    fig, ax = _axes(ax)
    ax.plot(run.t, run.k_imp, label="K_imp (controller)")
    ax.plot(run.t, run.k_mech, ":", label="K_mech (springs)")
    ax.plot(run.t, run.k_eff, "-.", label="K_eff (8.1)")
    ax.plot(run.t, run.k_target, "k--", lw=0.8, label="target")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("stiffness [Nm/rad]")
    ax.legend(fontsize="small")
    return fig, ax


def plot_friction_runs(runs, *, ax=None):
    """Fig 9.3: tracking error with/without friction compensation."""
    fig, ax = _axes(ax)
    for r in runs:
        ax.plot(r.t, r.q - r.reference, label=r.label)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("tracking error [rad]")
    ax.legend(fontsize="small")
    return fig, ax


def plot_gain_fit(fits, *, ax=None):
    """Relative gain error per state entry of each fit (ch. 16)."""
    fig, ax = _axes(ax)
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
