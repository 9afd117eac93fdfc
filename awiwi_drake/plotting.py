"""Plotting: functions take data (results, laws) and return ``(fig, ax)``; they never simulate."""

from __future__ import annotations

import numpy as np

__all__ = ["figure_axes", "plot_traces", "plot_friction_curve", "plot_spring_curve", "plot_signals", "plot_poles",
           "plot_pole_sweep"]


def _plt():
    import matplotlib.pyplot as plt  # backend chosen by MPLBACKEND / notebook
    return plt


def figure_axes(ax=None, **subplots_kw):
    """``(fig, ax)``: a new figure (``plt.subplots(**subplots_kw)``) when ``ax`` is None, else ``ax``'s figure."""
    if ax is None:
        return _plt().subplots(**subplots_kw)
    return ax.figure, ax


def label_axes(ax, ylabel: str, *, xlabel: str | None = "time [s]", title: str | None = None, grid: bool = True,
               legend: bool | dict | None = True) -> None:
    """Finish a panel: axis labels (units in brackets), optional title, a light grid and the legend
    (``legend``: True, a dict of ``ax.legend`` options, or None for none)."""
    if xlabel is not None:
        ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title is not None:
        ax.set_title(title)
    if grid:
        ax.grid(True, alpha=0.3)
    if legend is not None:
        ax.legend(**(legend if isinstance(legend, dict) else {}))


def plot_traces(t, traces: dict, *, ylabel: str, ax=None, styles: dict | None = None, title: str = ""):
    """Several time series ``{label: y}`` over ``t`` [s]."""
    fig, ax = figure_axes(ax, figsize=(7, 4))
    for label, y in traces.items():
        ax.plot(t, y, (styles or {}).get(label, "-"), label=label)
    label_axes(ax, ylabel, title=title)
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
    label_axes(ax, "friction torque [Nm]", xlabel="output velocity [rad/s]")
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


_EVENT_COLOURS = {"actuator_saturation": "tab:red", "tendon_slack": "tab:purple"}


def plot_signals(result, names, ax=None, labels=None, reference=None, *, components=None, overlay=None,
                 limits=None, xlim=None, legend: bool = True):
    """One subplot per logged signal of a :class:`SimulationResult`, every trace in a legend.

    Parameters
    ----------
    result : SimulationResult
    names : sequence of str
        Logged signals, one subplot each.
    labels : dict, optional
        y-axis label (with unit) per signal, e.g. ``{"motor_torque": "motor torque [Nm]"}``.
    reference : dict, optional
        ``name -> (t, values)`` drawn black dashed as "reference".
    components : dict, optional
        ``name -> [legend label per column]`` (default ``name[i]`` for vector signals).
    overlay : dict, optional
        ``name -> (values (T, k), label)``: a second set of traces on the same time axis,
        dotted in the same colours (e.g. the commanded torque beside the applied one);
        ``label`` is a suffix ("commanded") or one legend label per column.
    limits : dict, optional
        ``name -> limit`` (drawn at +-limit) or ``(low, high)``: dashed grey lines "limit".
    xlim : (float, float), optional
        Time window shown (e.g. a zoom on a step).

    Events of the result (actuator saturation, tendon slack) are shaded per kind and
    named in the legend of each panel they fall into.
    """
    plt = _plt()
    names = list(names)
    if ax is None:
        fig, ax = plt.subplots(len(names), 1, figsize=(7, 2.2 * len(names)), sharex=True, squeeze=False)
        ax = ax[:, 0]
    else:
        fig = np.ravel(ax)[0].figure
    components, overlay, limits = dict(components or {}), dict(overlay or {}), dict(limits or {})
    for a, name in zip(ax, names):
        y = np.asarray(result[name], dtype=float).reshape(len(result.t), -1)
        k = y.shape[1]
        comp = components.get(name) or ([name] if k == 1 else [f"{name}[{i}]" for i in range(k)] if k <= 8
                                        else [f"{name}[0..{k - 1}]"] + ["_nolegend_"] * (k - 1))
        if len(comp) != k:
            raise ValueError(f"plot_signals: components[{name!r}] has {len(comp)} labels for {k} columns")
        lines = a.plot(result.t, y)
        for line, lab in zip(lines, comp):
            line.set_label(lab)
        if name in overlay:
            values, what = overlay[name]
            values = np.asarray(values, dtype=float).reshape(len(result.t), -1)
            olabels = list(what) if not isinstance(what, str) else [f"{lab} ({what})" for lab in comp]
            for line, col, lab in zip(lines, values.T, olabels):
                a.plot(result.t, col, ":", color=line.get_color(), lw=1.2, label=lab)
        if reference is not None and name in reference:
            t_ref, v_ref = reference[name]
            a.plot(t_ref, v_ref, "k--", lw=1, label="reference")
        if name in limits:
            lim = limits[name]
            lo, hi = (-float(lim), float(lim)) if np.isscalar(lim) else (float(lim[0]), float(lim[1]))
            a.axhline(hi, color="0.4", ls="--", lw=0.8, label=f"limit [{lo:g}, {hi:g}]")
            a.axhline(lo, color="0.4", ls="--", lw=0.8)
        a.set_ylabel((labels or {}).get(name, name))
        a.grid(True, alpha=0.3)
        shown = set()
        for ev in result.events:
            colour = _EVENT_COLOURS.get(ev.kind, "tab:orange")
            lab = None
            if ev.kind not in shown:
                lab = ev.kind.replace("_", " ") + " (event)"
                shown.add(ev.kind)
            a.axvspan(ev.t_start, max(ev.t_end, ev.t_start + 1e-3), color=colour, alpha=0.12, label=lab)
        if xlim is not None:
            a.set_xlim(*xlim)
        if legend:
            a.legend(fontsize=7, loc="best", ncol=2 if len(a.get_legend_handles_labels()[0]) > 4 else 1)
    ax[-1].set_xlabel("time [s]")
    return fig, ax


def plot_poles(poles, ax=None, label=None, marker="x"):
    """Poles in the complex plane."""
    plt = _plt()
    fig, ax = (ax.figure, ax) if ax is not None else plt.subplots(figsize=(5, 4))
    poles = np.asarray(poles)
    ax.plot(poles.real, poles.imag, marker, ls="", label=label)
    ax.axvline(0, color="k", lw=0.5)
    label_axes(ax, "Im [rad/s]", xlabel="Re [1/s]", legend=None)
    if label:
        ax.legend()
    return fig, ax


def plot_pole_sweep(values, poles, name: str, ax=None, *, symlog: float | None = None):
    """Root locus of a parameter sweep: ``poles[i]`` at ``values[i]``, coloured by value.

    ``symlog`` (a linear threshold in 1/s) draws both axes symmetric-logarithmic, so that
    slow poles near the origin stay visible beside fast ones.
    """
    plt = _plt()
    fig, ax = (ax.figure, ax) if ax is not None else plt.subplots(figsize=(5.5, 4))
    values = np.asarray(values)
    for v, p in zip(values, poles):
        p = np.asarray(p)
        sc = ax.scatter(p.real, p.imag, c=np.full(p.shape, v), vmin=values.min(), vmax=values.max(), s=12,
                        cmap="viridis")
    fig.colorbar(sc, ax=ax, label=name)
    ax.axvline(0, color="k", lw=0.5)
    if symlog is not None:
        ax.set_xscale("symlog", linthresh=symlog, linscale=2.0)
        ax.set_yscale("symlog", linthresh=symlog, linscale=2.0)
        allp = np.concatenate([np.ravel(p) for p in poles])
        re_max = max(float(np.max(np.abs(allp.real))), symlog)
        im_max = max(float(np.max(np.abs(allp.imag))), symlog)
        ax.set_xlim(-3 * re_max, 3 * re_max)
        ax.set_ylim(-3 * im_max, 3 * im_max)
        from matplotlib.ticker import SymmetricalLogLocator

        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_locator(SymmetricalLogLocator(base=100.0, linthresh=symlog))
        ax.axvspan(-symlog, symlog, color="0.9", zorder=0, label=f"|Re| < {symlog:g} 1/s (linear scale)")
        ax.legend(fontsize=7, loc="center right")
    tag = " (symlog)" if symlog is not None else ""
    label_axes(ax, "Im [rad/s]" + tag, xlabel="Re [1/s]" + tag, legend=None)
    return fig, ax
