"""Plots of the controller experiments: data in, ``(fig, ax)`` out (nothing is simulated here)."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_traces", "plot_tendon_steps", "plot_root_locus", "plot_spectra", "plot_friction_fit",
           "plot_gain_diagrams"]


def _axes(ax, figsize=(7, 4)):
    import matplotlib.pyplot as plt
    return plt.subplots(figsize=figsize) if ax is None else (ax.figure, ax)


def plot_traces(t, traces: dict, *, ylabel: str, ax=None, styles: dict | None = None, title: str = ""):
    """Several time series ``{label: y}`` over ``t``."""
    fig, ax = _axes(ax)
    for label, y in traces.items():
        ax.plot(t, y, (styles or {}).get(label, "-"), label=label)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    return fig, ax


def plot_tendon_steps(steps, *, ax=None):
    """Fig 10.3 style: force steps of one controller (a :class:`~awiwi_drake.control.experiments.TendonSteps`)."""
    fig, ax = _axes(ax)
    for f0, f in steps.forces.items():
        m = steps.metrics[f0]
        ax.plot(steps.t, f, label=f"{f0:g} N: xi = {m['damping_ratio']:.2f}, OS = {m['overshoot']:.0f} %")
        ax.plot(steps.t, np.where(steps.t < steps.t_step, f0, f0 + steps.step), "k--", lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("tendon force [N]")
    ax.set_title(f"{steps.controller} gains")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return fig, ax


def plot_root_locus(values, poles, *, nominal=None, ax=None, label: str = "k [Nm/rad]"):
    """Poles (rows of ``poles``) for each parameter value, coloured by value; squares at ``nominal``."""
    fig, ax = _axes(ax, (6, 5))
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


def plot_spectra(result, *, fmax: float = 60.0, ax=None):
    """Fig 3.6b: amplitude spectrum of the feedback torque without/with ripple compensation."""
    fig, ax = _axes(ax)
    m = result.frequency <= fmax
    ax.plot(result.frequency[m], result.spectrum_without[m], label="without compensation")
    ax.plot(result.frequency[m], result.spectrum_with[m], label="with compensation")
    ax.axvline(result.first_harmonic_hz, color="k", ls=":", lw=0.8, label="motor rotation frequency")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("|Y(f)| [Nm]")
    ax.set_title(f"first harmonic attenuated to {100 * result.attenuation:.0f} %")
    ax.legend()
    ax.grid(True, alpha=0.3)
    return fig, ax


def plot_friction_fit(data, fit, *, true=None, ax=None):
    """Fig 3.3b: plateau torques (mean, min-max) and the fitted (3.8)."""
    fig, ax = _axes(ax)
    ax.errorbar(data.speed, data.torque, yerr=[data.torque - data.torque_min, data.torque_max - data.torque],
                fmt="o", ms=4, capsize=2, label="plateau mean (min/max)")
    w = np.linspace(np.min(data.speed), np.max(data.speed), 400)
    ax.plot(w, fit.torque(w), label=f"fit (3.8): g1={fit.gamma1:.2f}, g2={fit.gamma2:.3f}, g3={fit.gamma3:.4f}")
    if true is not None:
        ax.plot(w, true(w), "k--", lw=0.8, label="simulated motor")
    ax.set_xlabel("motor velocity [rad/s]")
    ax.set_ylabel("motor torque [Nm]")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    return fig, ax


def plot_gain_diagrams(curves: dict, *, ax=None):
    """Fig 11.4: ``{label: (freq, gain)}``."""
    fig, ax = _axes(ax)
    for label, (f, g) in curves.items():
        ax.plot(f, g, label=label)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("gain |q / q_des|")
    ax.legend()
    ax.grid(True, alpha=0.3)
    return fig, ax
