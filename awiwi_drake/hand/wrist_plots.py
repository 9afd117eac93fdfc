"""Plots of the wrist study (thesis Fig 6.9, 6.10).

The data come from :func:`awiwi_drake.hand.wrist.wrist_motion_study`; these
functions only draw and return ``(fig, ax)``.
"""

from __future__ import annotations

import numpy as np

from awiwi_drake.hand.wrist import WristMotionResult

__all__ = ["plot_wrist_displacements", "plot_wrist_constraint_errors", "FINGER_COLORS"]

#: One colour per finger for tendon plots.
FINGER_COLORS = {"thumb": "tab:red", "index": "tab:blue", "middle": "tab:green",
                 "ring": "tab:orange", "fifth": "tab:purple"}


def _start(result, ax):
    """Validate the data and return (fig, ax), creating them when ax is None."""
    import matplotlib.pyplot as plt

    if not isinstance(result, WristMotionResult):
        raise ValueError(f"result must be a WristMotionResult, got {type(result).__name__}")
    if ax is None:
        fig, ax = plt.subplots(figsize=(7.0, 4.0))
    else:
        fig = ax.figure
    return fig, ax


def plot_wrist_displacements(result: WristMotionResult, ax=None):
    """Tendon displacement through the wrist vs time (Fig 6.10).

    One line per tendon (Table 6.2 order), coloured by finger; the flexion
    and abduction phases are shaded and annotated with the proportionality
    fit of the abduction peak.

    Parameters
    ----------
    result : WristMotionResult
        From :func:`~awiwi_drake.hand.wrist.wrist_motion_study` (uses ``offsets``).
    ax : matplotlib Axes, optional
        Axes to draw into (default: a new figure).

    Returns
    -------
    (fig, ax) : the figure and the axes holding one line per tendon.
    """
    fig, ax = _start(result, ax)
    seen = set()
    for i, finger in enumerate(result.fingers):
        label = finger if finger not in seen else None
        seen.add(finger)
        ax.plot(result.t, result.offsets[:, i], color=FINGER_COLORS.get(finger, "k"), lw=0.9, label=label)
    flex = result.phase == "flexion"
    if np.any(flex):
        ax.axvspan(result.t[flex][0], result.t[flex][-1], color="0.92", zorder=0)
    peak_q = np.degrees(np.max(np.abs(result.wrist_angle), axis=0))
    ax.set_xlabel("t [s]")
    ax.set_ylabel("tendon displacement [m]")
    ax.set_title(f"wrist: flexion {peak_q[1]:.0f} deg (shaded), then abduction {peak_q[0]:.0f} deg")
    ax.text(0.99, 0.02,
            f"abduction peak vs distance from median axis: slope {result.abduction_slope:.3f} m/m, "
            f"R$^2$ = {result.abduction_r2:.4f}\nflexion/abduction peak ratio "
            f"{result.flexion_to_abduction_ratio:.2f}",
            transform=ax.transAxes, ha="right", va="bottom", fontsize=8)
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(True, alpha=0.3)
    return fig, ax


def plot_wrist_constraint_errors(result: WristMotionResult, ax=None):
    """Largest distance-constraint error vs time (Fig 6.9); ``ax`` optional, returns ``(fig, ax)``."""
    fig, ax = _start(result, ax)
    ax.plot(result.t, np.max(np.abs(result.constraint_errors), axis=1), color="k")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("max constraint error [m]")
    ax.set_title("max(|AA0|, |BB0|, |CC0|, |AB|, |AC|, |BC|) errors")
    ax.ticklabel_format(axis="y", style="sci", scilimits=(0, 0))
    ax.grid(True, alpha=0.3)
    return fig, ax
