"""Plots of a :class:`~awiwi_drake.control.compare.standard_tests.Comparison`: data in, ``(fig, ax)`` out."""

from __future__ import annotations

import math

from awiwi_drake.control.compare.standard_tests import Comparison
from awiwi_drake.plotting import label_axes

__all__ = ["plot_runs", "plot_joint_runs", "plot_gain_diagram"]


def plot_runs(comparison: Comparison, test: str = "step", *, ax=None, ylabel: str | None = None):
    """Output (solid) and reference (dashed) of every controller for one test."""
    import matplotlib.pyplot as plt
    runs = [r for r in comparison.runs if r.test == test]
    if not runs:
        raise ValueError(f"plot_runs: no runs for test {test!r}")
    fig, ax = (plt.subplots(figsize=(7, 4)) if ax is None else (ax.figure, ax))
    for r in runs:
        ax.plot(r.t, r.output, label=r.controller)
    ax.plot(runs[0].t, runs[0].reference, "k--", lw=1, label="reference")
    _mark_stopped(ax, comparison, test)
    label_axes(ax, ylabel or "tracked output [unit of the reference]",
               title=f"{comparison.rig}: {test} test (solid: output, dashed: reference)")
    return fig, ax


def _mark_stopped(ax, comparison: Comparison, test: str, joint: str | None = None) -> None:
    """Name on ``ax`` the controllers whose simulation of ``test`` (``joint``) stopped, with a line at the time."""
    stopped = [r for r in comparison.table.failed() if r.test == test and (joint is None or r.joint == joint)]
    for r in stopped:
        if math.isfinite(r.failed_at):
            ax.axvline(r.failed_at, color="r", ls=":", lw=1)
    if stopped:
        ax.text(0.01, 0.97, "\n".join(f"{r.controller}: {r.status}"
                                      + (f" at t = {r.failed_at:.4g} s" if math.isfinite(r.failed_at) else "")
                                      for r in stopped),
                transform=ax.transAxes, va="top", fontsize=8, color="r")


def plot_joint_runs(comparison: Comparison, test: str, finger: str):
    """One finger of a finger/hand comparison: a panel per joint (DoF), output of every controller
    (solid) and reference (dashed), relative to the operating point."""
    import matplotlib.pyplot as plt
    runs = [r for r in comparison.runs if r.test == test and "joints" in r.meta]
    if not runs:
        raise ValueError(f"plot_joint_runs: no finger/hand runs for test {test!r}")
    cols = [j for j, f in enumerate(runs[0].meta["fingers"]) if f == finger]
    if not cols:
        raise ValueError(f"plot_joint_runs: no joints of finger {finger!r} "
                         f"(fingers: {', '.join(dict.fromkeys(runs[0].meta['fingers']))})")
    outside = len(runs) > 3          # many controllers: the legend beside the panels, not over the traces
    colours = plt.get_cmap("tab20").colors if len(runs) > 10 else [None] * len(runs)   # tab10 repeats after 10
    fig, axes = plt.subplots(len(cols), 1, figsize=(9.5 if outside else 7, 1.9 * len(cols) + 0.8), sharex=True,
                             squeeze=False)
    for ax, j in zip(axes[:, 0], cols):
        for r, colour in zip(runs, colours):
            ax.plot(r.t, r.output[:, j], color=colour, label=r.controller)
        ax.plot(runs[0].t, runs[0].reference[:, j], "k--", lw=1, label="reference")
        ax.set_ylabel(f"{runs[0].meta['joints'][j]} [rad]")
        ax.grid(True, alpha=0.3)
        _mark_stopped(ax, comparison, test, runs[0].meta["joints"][j])
    axes[0, 0].set_title(f"{comparison.rig}, {finger}: {test} (joint angle - operating point)")
    axes[-1, 0].set_xlabel("time [s]")
    if outside:
        fig.legend(*axes[0, 0].get_legend_handles_labels(), fontsize=8, loc="upper left", bbox_to_anchor=(0.755, 0.98))
        fig.tight_layout(rect=(0.0, 0.0, 0.75, 1.0))
    else:
        axes[0, 0].legend(fontsize=8)
        fig.tight_layout()
    return fig, axes


def plot_gain_diagram(comparison: Comparison, *, ax=None, unit: str | None = None):
    """Gain diagrams |Y/R|(f) of the sweep test (Fig 11.4 style) on a log frequency axis,
    with each controller's -3 dB bandwidth marked (dotted, named in the legend with its source:
    the linearisation or the chirp)."""
    import matplotlib.pyplot as plt
    runs = [r for r in comparison.runs if r.test == "sweep"]
    if not runs:
        raise ValueError("plot_gain_diagram: no sweep runs")
    fig, ax = (plt.subplots(figsize=(7, 4)) if ax is None else (ax.figure, ax))
    for r in runs:
        line, = ax.semilogx(r.meta["freq"], r.meta["gain"], label=r.controller)
        try:
            row = comparison.table.get(r.controller, "sweep")
            bw, src = row.bandwidth_hz, row.bandwidth_source
        except KeyError:
            bw, src = math.nan, ""
        if math.isfinite(bw):
            ax.axvline(bw, color=line.get_color(), ls=":", lw=1.2,
                       label=f"{r.controller}: -3 dB at {bw:.3g} Hz" + (f" ({src})" if src else ""))
    ax.set_xlabel("frequency [Hz] (log)")
    ax.set_ylabel(f"gain |Y/R| [{unit}/{unit}]" if unit else "gain |Y/R| [-]")
    ax.set_title(f"{comparison.rig}: closed-loop gain from the chirp test")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    return fig, ax

