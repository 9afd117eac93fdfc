"""Plotting: functions take data (results, laws) and return ``(fig, ax)``; they never simulate."""

from __future__ import annotations

import numpy as np

__all__ = ["figure_axes", "plot_traces", "plot_friction_curve", "plot_spring_curve", "plot_signals", "plot_poles",
           "plot_pole_sweep"]


def _plt():
    import matplotlib
    import matplotlib.pyplot as plt  # noqa: F401  (backend chosen by MPLBACKEND / notebook)
    return matplotlib.pyplot


def figure_axes(ax=None, **subplots_kw):
    """``(fig, ax)``: a new figure (``plt.subplots(**subplots_kw)``) when ``ax`` is None, else ``ax``'s figure."""
    if ax is None:
        return _plt().subplots(**subplots_kw)
    return ax.figure, ax


def plot_traces(t, traces: dict, *, ylabel: str, ax=None, styles: dict | None = None, title: str = ""):
    """Several time series ``{label: y}`` over ``t`` [s]."""
    fig, ax = figure_axes(ax, figsize=(7, 4))
    for label, y in traces.items():
        ax.plot(t, y, (styles or {}).get(label, "-"), label=label)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    return fig, ax


def plot_friction_curve(params, omega_max: float = 15.0, ax=None, measured=None):
    """Friction torque (3.8) versus velocity (Fig 3.3b); ``measured`` = (omega, torque) points."""
    from awiwi_drake.components.motor import motor_friction_torque

    plt = _plt()
    fig, ax = (ax.figure, ax) if ax is not None else plt.subplots(figsize=(5, 3.5))
    w = np.linspace(-omega_max, omega_max, 401)
    ax.plot(w, -motor_friction_torque(w, params), label="(3.8), Table 3.3")
    if measured is not None:
        ax.plot(*measured, "o", ms=4, label="measured")
    ax.set_xlabel("output velocity [rad/s]")
    ax.set_ylabel("friction torque [Nm]")
    ax.grid(True, alpha=0.3)
    ax.legend()
    return fig, ax


def plot_spring_curve(lever, polynomial=None, max_force: float = 180.0, ax=None):
    """Force versus lever angle (Fig 4.8b) and versus elongation, with the calibration polynomial."""
    plt = _plt()
    if ax is None:
        fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
    else:
        fig = np.ravel(ax)[0].figure
    th, x, f, k = lever.sample_curve(max_force=max_force)
    ax[0].plot(np.degrees(th), f, label="lever model")
    ax[0].set_xlabel("lever angle [deg]")
    ax[0].set_ylabel("tendon force [N]")
    ax[1].plot(1e3 * x, f, label="lever model")
    if polynomial is not None:
        xs = np.linspace(0, polynomial.max_elongation, 300)
        ax[1].plot(1e3 * xs, polynomial.force(xs), "--", label="calibration polynomial (with tendon)")
    ax[1].set_xlabel("elongation [mm]")
    for a in ax:
        a.grid(True, alpha=0.3)
        a.legend()
    return fig, ax


def plot_signals(result, names, ax=None, labels=None, reference=None):
    """One subplot per logged signal of a :class:`SimulationResult`."""
    plt = _plt()
    names = list(names)
    if ax is None:
        fig, ax = plt.subplots(len(names), 1, figsize=(7, 2.2 * len(names)), sharex=True, squeeze=False)
        ax = ax[:, 0]
    else:
        fig = np.ravel(ax)[0].figure
    for a, name in zip(ax, names):
        a.plot(result.t, result[name])
        if reference is not None and name in reference:
            t_ref, v_ref = reference[name]
            a.plot(t_ref, v_ref, "k--", lw=1, label="reference")
            a.legend()
        a.set_ylabel((labels or {}).get(name, name))
        a.grid(True, alpha=0.3)
        for ev in result.events:
            a.axvspan(ev.t_start, max(ev.t_end, ev.t_start + 1e-3), color="r", alpha=0.08)
    ax[-1].set_xlabel("time [s]")
    return fig, ax


def plot_poles(poles, ax=None, label=None, marker="x"):
    """Poles in the complex plane."""
    plt = _plt()
    fig, ax = (ax.figure, ax) if ax is not None else plt.subplots(figsize=(5, 4))
    poles = np.asarray(poles)
    ax.plot(poles.real, poles.imag, marker, ls="", label=label)
    ax.axvline(0, color="k", lw=0.5)
    ax.set_xlabel("Re [1/s]")
    ax.set_ylabel("Im [rad/s]")
    ax.grid(True, alpha=0.3)
    if label:
        ax.legend()
    return fig, ax


def plot_pole_sweep(values, poles, name: str, ax=None):
    """Root locus of a parameter sweep: ``poles[i]`` at ``values[i]``, coloured by value."""
    plt = _plt()
    fig, ax = (ax.figure, ax) if ax is not None else plt.subplots(figsize=(5.5, 4))
    values = np.asarray(values)
    for v, p in zip(values, poles):
        p = np.asarray(p)
        sc = ax.scatter(p.real, p.imag, c=np.full(p.shape, v), vmin=values.min(), vmax=values.max(), s=12,
                        cmap="viridis")
    fig.colorbar(sc, ax=ax, label=name)
    ax.axvline(0, color="k", lw=0.5)
    ax.set_xlabel("Re [1/s]")
    ax.set_ylabel("Im [rad/s]")
    ax.grid(True, alpha=0.3)
    return fig, ax
