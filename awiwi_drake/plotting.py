"""Plotting: functions take data (results, laws) and return ``(fig, ax)``; they never simulate."""

from __future__ import annotations

import numpy as np

__all__ = ["figure_axes", "plot_traces", "plot_friction_curve", "plot_spring_curve", "plot_signals",
           "plot_poles"]


def _plt():
    import matplotlib.pyplot as plt  # backend chosen by MPLBACKEND / notebook
    return plt


def figure_axes(ax=None, **subplots_kw):
    """``(fig, ax)``: a new figure (``plt.subplots(**subplots_kw)``) when ``ax`` is None, else ``ax``'s figure (``ax``
    may be several axes, a list or an array, as ``subplots`` returns them)."""
    if ax is None:
        return _plt().subplots(**subplots_kw)
    first = ax.flat[0] if hasattr(ax, "flat") else (ax[0] if isinstance(ax, (list, tuple)) else ax)
    return first.figure, ax


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


def plot_traces(t, traces: dict, *, ylabel: str, ax=None, styles: dict | None = None, title: str | None = None,
                reference=None, legend: bool | dict = True):
    """Several time series ``{label: y}`` over ``t`` [s] (``styles``: a format per label), and the
    ``reference`` (values over ``t``) black dashed; ``legend`` as in :func:`label_axes`."""
    fig, ax = figure_axes(ax, figsize=(7, 4))
    for label, y in traces.items():
        ax.plot(t, y, (styles or {}).get(label, "-"), label=label)
    if reference is not None:
        ax.plot(t, reference, "k--", lw=0.8, label="reference")
    label_axes(ax, ylabel, title=title, legend=legend)
    return fig, ax


def plot_friction_curve(params, omega_max: float = 15.0, ax=None, measured=None):
    """Friction torque (3.8) versus velocity (Fig 3.3b); ``measured`` = (omega, torque) points."""
    from awiwi_drake.components.motor import motor_friction_torque

    fig, ax = figure_axes(ax, figsize=(5, 3.5))
    w = np.linspace(-omega_max, omega_max, 401)
    ax.plot(w, -motor_friction_torque(w, params), label="(3.8), Table 3.3")
    if measured is not None:
        ax.plot(*measured, "o", ms=4, label="measured")
    label_axes(ax, "friction torque [Nm]", xlabel="output velocity [rad/s]")
    return fig, ax


def plot_spring_curve(lever, polynomial=None, max_force: float = 180.0, ax=None):
    """Force versus lever angle (Fig 4.8b) and versus elongation, with the calibration polynomial."""
    fig, ax = figure_axes(ax, ncols=2, figsize=(9, 3.5))
    th, x, f, k = lever.sample_curve(max_force=max_force)
    ax[0].plot(np.degrees(th), f, label="lever model")
    ax[1].plot(1e3 * x, f, label="lever model")
    if polynomial is not None:
        xs = np.linspace(0, polynomial.max_elongation, 300)
        ax[1].plot(1e3 * xs, polynomial.force(xs), "--", label="calibration polynomial (with tendon)")
    label_axes(ax[0], "tendon force [N]", xlabel="lever angle [deg]")
    label_axes(ax[1], "", xlabel="elongation [mm]")
    return fig, ax


_EVENT_COLOURS = {"actuator_saturation": "tab:red", "tendon_slack": "tab:purple", "spring_overrange": "tab:orange"}


def plot_signals(result, names=None, ax=None, labels=None, reference=None, *, channels=None, components=None,
                 overlay=None, limits=None, xlim=None, legend: bool = True, events: bool = True):
    """One subplot per logged signal of a :class:`SimulationResult` (per unit for mixed signals such as
    ``state``), every trace in a legend, every axis with its unit; returns ``(fig, axes)``.

    ``names``: the logged signals drawn (default: all).  Per signal name: ``labels`` the y-axis label with unit
    (default ``name [unit]``), ``reference`` ``(t, values)`` drawn black dashed, ``channels`` the channel indices
    drawn (default all), ``components`` one legend label per column (default the result's channel labels),
    ``overlay`` ``(values (T, k), label)``: a second set of traces dotted in the same colours (e.g. the commanded
    torque beside the applied one; ``label`` a suffix or one label per column), ``limits`` a limit (drawn at +-limit)
    or ``(low, high)`` as dashed grey lines instead of the monitor thresholds.  Monitor thresholds on a logged signal
    (torque limit, spring range, slack; recorded by ``simulate``) are dashed black lines; the result's events are
    shaded per kind and named in each panel's legend (``events=False``: not drawn).  ``xlim``: the time window shown.
    """
    names = list(result.signals) if names is None else list(names)
    panels = []   # (name, channels, unit)
    for name in names:
        by_unit: dict = {}
        for j in (channels or {}).get(name, range(result[name].shape[1])):
            by_unit.setdefault(result.unit(name, j), []).append(j)
        panels += [(name, js, u) for u, js in by_unit.items()]
    fig, ax = figure_axes(ax, nrows=len(panels), figsize=(7.5, 2.3 * len(panels) + 0.4), sharex=True, squeeze=False)
    ax = np.ravel(ax)
    if len(ax) < len(panels):
        raise ValueError(f"plot_signals: {len(panels)} panels need {len(panels)} axes, got {len(ax)}")
    components, overlay, limits = dict(components or {}), dict(overlay or {}), dict(limits or {})
    for a, (name, js, unit) in zip(ax, panels):
        y = np.asarray(result[name], dtype=float).reshape(len(result.t), -1)
        comp = components.get(name) or result.channel_labels(name)
        if len(comp) != y.shape[1]:
            raise ValueError(f"plot_signals: components[{name!r}] has {len(comp)} labels for {y.shape[1]} columns")
        if len(js) > 8:
            comp = {j: f"{name}[{js[0]}..{js[-1]}]" if i == 0 else "_nolegend_" for i, j in enumerate(js)}
        lines = a.plot(result.t, y[:, js])
        for line, j in zip(lines, js):
            line.set_label(comp[j])
        if name in overlay:
            values, what = overlay[name]
            values = np.asarray(values, dtype=float).reshape(len(result.t), -1)
            olabels = list(what) if not isinstance(what, str) else [f"{comp[j]} ({what})" for j in js]
            for line, j, lab in zip(lines, js, olabels):
                a.plot(result.t, values[:, j], ":", color=line.get_color(), lw=1.2, label=lab)
        if reference is not None and name in reference:
            t_ref, v_ref = reference[name]
            a.plot(t_ref, v_ref, "k--", lw=1, label="reference")
        if name in limits:
            lim = limits[name]
            lo, hi = (-float(lim), float(lim)) if np.isscalar(lim) else (float(lim[0]), float(lim[1]))
            a.axhline(hi, color="0.4", ls="--", lw=0.8, label=f"limit [{lo:g}, {hi:g}]")
            a.axhline(lo, color="0.4", ls="--", lw=0.8)
        shown = set()
        for desc, val in result.limits.get(name, []) if not limits else ():
            a.axhline(val, color="k", ls="--", lw=0.8, label=None if desc in shown else desc)
            shown.add(desc)
        a.set_ylabel((labels or {}).get(name, f"{name} [{unit}]"))
        a.grid(True, alpha=0.3)
        for ev in result.events if events else ():
            lab = None if ev.kind in shown else ev.kind.replace("_", " ") + " (event)"
            shown.add(ev.kind)
            a.axvspan(ev.t_start, max(ev.t_end, ev.t_start + 1e-3), color=_EVENT_COLOURS.get(ev.kind, "tab:gray"),
                      alpha=0.12, label=lab)
        if xlim is not None:
            a.set_xlim(*xlim)
        if legend:
            a.legend(fontsize=7, loc="best", ncol=2 if len(a.get_legend_handles_labels()[0]) > 4 else 1)
    ax[len(panels) - 1].set_xlabel("time [s]")
    return fig, ax


def plot_poles(poles, ax=None, *, values=None, name: str | None = None, label: str | None = None, marker: str = "x",
               symlog: float | None = None, damping=(0.1, 0.3, 0.5, 0.7, 0.9), **style):
    """Pole map in the s-plane (Re [1/s], Im [rad/s]), the imaginary axis drawn; returns ``(fig, ax)``.

    ``poles``: one set (markers ``marker``, legend ``label``, ``style`` passed to ``ax.plot``), or, with
    ``values``, a sweep: set ``poles[i]`` at ``values[i]``, coloured by value with a colour bar named ``name``
    (a root locus over a parameter).  ``damping``: rays of constant damping ratio ``zeta`` through the origin
    (``Im = +-Re sqrt(1 - zeta^2) / zeta``, left half plane; None or () for none).  ``symlog`` (a linear
    threshold in 1/s) draws both axes symmetric-logarithmic, so that slow poles near the origin stay visible
    beside fast ones (no damping rays then: they are not straight on those axes).
    """
    fig, ax = figure_axes(ax, figsize=(5.5, 4))
    sets = [np.ravel(np.asarray(p, dtype=complex)) for p in (poles if values is not None else [poles])]
    allp = np.concatenate(sets) if sets else np.zeros(0, complex)
    if values is not None:
        values = np.asarray(values, dtype=float)
        if len(values) != len(sets):
            raise ValueError(f"plot_poles: {len(values)} values for {len(sets)} pole sets")
        for v, p in zip(values, sets):
            sc = ax.scatter(p.real, p.imag, c=np.full(p.shape, v), vmin=values.min(), vmax=values.max(), s=12,
                            cmap="viridis", label=label if v == values[0] else None)
        fig.colorbar(sc, ax=ax, label=name)
    else:
        ax.plot(allp.real, allp.imag, marker, ls="none", ms=style.pop("ms", 8), label=label, **style)
    ax.axvline(0, color="k", lw=0.5)
    ax.axhline(0, color="k", lw=0.3)
    if symlog is not None:
        ax.set_xscale("symlog", linthresh=symlog, linscale=2.0)
        ax.set_yscale("symlog", linthresh=symlog, linscale=2.0)
        re_max = max(float(np.max(np.abs(allp.real), initial=0.0)), symlog)
        im_max = max(float(np.max(np.abs(allp.imag), initial=0.0)), symlog)
        ax.set_xlim(-3 * re_max, 3 * re_max)
        ax.set_ylim(-3 * im_max, 3 * im_max)
        from matplotlib.ticker import SymmetricalLogLocator

        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_locator(SymmetricalLogLocator(base=100.0, linthresh=symlog))
        ax.axvspan(-symlog, symlog, color="0.9", zorder=0, label=f"|Re| < {symlog:g} 1/s (linear scale)")
    elif damping:
        from matplotlib.patches import Rectangle

        r = 1e3 * max(float(np.max(np.abs(allp), initial=0.0)), 1.0)
        lhp = Rectangle((-r, -r), r, 2 * r, transform=ax.transData)   # the rays end at the imaginary axis
        for k, z in enumerate(damping):
            for y in (1.0, -1.0):           # axline: drawn across the view, not part of its autoscaling
                ax.axline((0.0, 0.0), (-z, y * np.sqrt(1.0 - z * z)), color="0.8", lw=0.6, zorder=0,
                          clip_path=lhp, label=f"damping ratio {', '.join(f'{d:g}' for d in damping)}"
                          if k == 0 and y > 0 else None)
    tag = " (symlog)" if symlog is not None else ""
    has_labels = bool(ax.get_legend_handles_labels()[0])
    label_axes(ax, "Im [rad/s]" + tag, xlabel="Re [1/s]" + tag,
               legend=dict(fontsize=7, loc="best") if has_labels else None)
    return fig, ax
