"""The thesis's studies and experiments, one module per chapter (results are data, plots sit beside them).

Each module rebuilds the runs behind a chapter's figures from the package's
plants (:mod:`awiwi_drake.rigs`, :mod:`awiwi_drake.hand`), controllers
(:mod:`awiwi_drake.control`) and framework wrappers (:mod:`awiwi_drake.analysis`),
and returns data; its ``plot_*`` functions draw that data. docs/REPRODUCTIONS.md
records each figure: the printed value, ours, the verdict.

* ch. 3 motor: friction (Fig 3.3), ripple: :mod:`.ch03_motor`
* ch. 5 fingers: Coriolis (Fig 5.7), poles: :mod:`.ch05_fingers`; fifth finger HMC four-bar vs revolute:
  :mod:`.ch05_fifth_hmc`
* ch. 6 wrist: finger drift under wrist motion: :mod:`.ch06_wrist`
* ch. 5/7/8 stiffness by co-contraction, on the closed loop: :mod:`.ch07_cocontraction`
* ch. 8 stiffness correction (Fig 8.3): :mod:`.ch08_stiffness_correction`
* ch. 9 friction observer (Fig 9.3): :mod:`.ch09_friction_observer`
* ch. 10 tendon force control (Fig 10.1-10.3): :mod:`.ch10_tendon_force`
* ch. 11 impedance control (Fig 11.2-11.4): :mod:`.ch11_impedance`
* ch. 12 pole placement (Fig 12.3-12.4, (12.19)): :mod:`.ch12_pole_placement`
* ch. 13 LQR (Fig 13.2-13.3): :mod:`.ch13_lqr`
* ch. 14 SDRE (Fig 14.3-14.5): :mod:`.ch14_sdre`
* ch. 15 backstepping (Fig 15.2-15.27): :mod:`.ch15_backstepping`, :mod:`.ch15_scalar_example`,
  :mod:`.ch15_pip_experiments` (Fig 15.24-15.25 on a finger's PIP)
* ch. 16 optimal backstepping gains (Tab 16.1): :mod:`.ch16_optimal_backstepping`
* ``awiwi-drake demo`` (joint rig): :mod:`.demo`; invented parameters (figure sensitivity):
  :mod:`.invented_parameters`

Modules are imported on demand (``from awiwi_drake.reproductions import ch15_backstepping``).

:data:`FIGURES` maps a figure id (``fig15.24``, ``cocontraction``, ...) to the study function that computes it;
:func:`reproduce` runs ids and writes each one's figure (``ID.png``), its series (``ID.csv``, units in the column
names) and its numbers (``ID.json``, each with its unit); ``awiwi-drake reproduce`` is the same from the command line.
The entries only call the chapter modules' functions: each study lives in its module.
"""

from __future__ import annotations

import csv
import json
import math
import pathlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from awiwi_drake.plotting import _plt, figure_axes, label_axes, plot_traces

__all__ = ["FigureEntry", "Reproduction", "FIGURES", "reproduce"]


@dataclass
class Reproduction:
    """What one figure id computed: the ``figure`` (matplotlib), ``series`` (column name with its unit in brackets ->
    1-D array, all of one length: the CSV) and ``values`` (name -> ``{"value": ..., "unit": ...}``, or a dict of
    those per case: the JSON)."""

    figure: object
    series: dict = field(default_factory=dict)
    values: dict = field(default_factory=dict)


@dataclass(frozen=True)
class FigureEntry:
    """One reproducible figure: its ``id``, the thesis ``reference``, a one-line ``summary``, the chapter ``module``
    and ``run(short) -> Reproduction`` (``short``: the module's short mode, seconds instead of minutes)."""

    id: str
    reference: str
    summary: str
    module: str
    run: Callable[[bool], Reproduction]


def _finite(value):
    """``value`` with every non-finite float (NaN: not defined for that run, e.g. no rise) as None (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _v(value, unit: str) -> dict:
    return {"value": _finite(value), "unit": unit}


_PIP_UNITS = dict(peak_torque="Nm", min_tendon_force="N", final_error="rad", rise_time="s", overshoot="%",
                  rms_error="rad", still_time="s", longest_still="s", reversals_per_s="1/s",
                  reference_reversals_per_s="1/s")


def _pip(test: str, short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch15_pip_experiments import pip_experiment, pip_metrics
    names = (("backstepping", "cascaded") if short else
             ("backstepping", "backstepping-friction-observer", "cascaded", "cascaded:no-observer"))
    runs = [pip_experiment(n, test, t_final=0.3 if short else None) for n in names]
    fig, ax = figure_axes(None, figsize=(8, 4))
    for r in runs:
        r.plot(ax=ax)
    for line in [ln for ln in ax.get_lines() if ln.get_label() == "reference"][1:]:   # each run draws it: once
        line.set_label("_reference")
    label_axes(ax, "PIP angle [deg]", title=f"Fig 15.{24 if test == 'step' else 25}: index PIP {test}, joints' "
               "stick-slip on, 3 kHz", legend=dict(fontsize="small"))
    series = {"t [s]": runs[0].t, "reference [rad]": runs[0].reference}
    series.update({f"{r.controller} PIP angle [rad]": r.q for r in runs})
    series.update({f"{r.controller} PIP joint friction torque [Nm]": r.friction for r in runs})
    values = {r.controller: {k: _v(v, _PIP_UNITS[k]) for k, v in pip_metrics(r).items()} for r in runs}
    return Reproduction(fig, series, values)


def _fig15_26(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch15_backstepping import gain_diagram_study
    ds = gain_diagram_study()
    fig = ax = None
    for d in ds:
        fig, ax = d.plot(ax=ax, xscale="log")
    ax.set_title("Fig 15.26: joint rig at 20 N, linearised")
    series = {"frequency [Hz]": ds[0].freq}
    series.update({f"{d.label} gain |q/q_des| [-]": d.gain for d in ds})
    values = {d.label: dict(bandwidth=_v(d.bandwidth, "Hz"), dc_gain=_v(d.dc_gain, "-"),
                                 poles_real=_v(d.linearization.poles.real.tolist(), "1/s"),
                                 poles_imag=_v(d.linearization.poles.imag.tolist(), "1/s")) for d in ds}
    return Reproduction(fig, series, values)


def _cocontraction(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch07_cocontraction import cocontraction_study, stiffness_bound
    runs = cocontraction_study("index", **(dict(pretensions=(20.0, 40.0), scales=()) if short else {}))
    fig = ax = None
    for m in runs:
        fig, ax = m.plot(ax=ax)
    values = {f"{m.controller}, {m.level}": dict(
        dof=_v(list(m.dof_names), "-"), measured=_v(m.diagonal().tolist(), "Nm/rad"),
        predicted=_v(m.diagonal("predicted").tolist(), "Nm/rad"), bound=_v(stiffness_bound(m).tolist(), "Nm/rad"),
        springs_5_12=_v(m.diagonal("mechanical").tolist(), "Nm/rad"), mean_tendon_force=_v(float(m.tendon_force.mean()),
                                                                                           "N")) for m in runs}
    return Reproduction(fig, {}, values)


def _fig5_7(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch05_fingers import coriolis_study
    s = coriolis_study("index", t_final=0.02 if short else 0.2)
    fig, _ = s.plot()
    series = {"t [s]": s.t}
    series.update({f"{n} full minus no-Coriolis [rad]": d for n, d in zip(s.joint_names, s.difference.T)})
    return Reproduction(fig, series, {"max_abs_difference": _v(dict(zip(s.joint_names, s.max_abs_difference.tolist())),
                                                               "rad")})


def _fig6_10(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch06_wrist import wrist_motion_study
    w = wrist_motion_study(num_samples=51 if short else 201)
    fig, _ = w.plot()
    series = {"t [s]": w.t, "q71 [rad]": w.wrist_angle[:, 0], "q73 [rad]": w.wrist_angle[:, 1]}
    series.update({f"tendon {i} displacement [m]": w.offsets[:, i] for i in range(w.offsets.shape[1])})
    return Reproduction(fig, series, dict(
        max_constraint_error=_v(w.max_constraint_error, "m"), flexion_peak=_v(w.flexion_peak, "m"),
        abduction_peak=_v(w.abduction_peak, "m"), abduction_r2=_v(w.abduction_r2, "-")))


def _run_series(runs, signal: str = "link angle [rad]") -> dict:
    """Each :class:`~.ch15_backstepping.BacksteppingRun`'s own time and link angle (grids may differ)."""
    out = {}
    for r in runs:
        out[f"{r.label}: t [s]"], out[f"{r.label}: {signal}"] = r.t, r.q
    return out


def _fig15_7(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch15_backstepping import plot_joint_angle, position_gain_study
    kw = dict(t_final=5.0, values=(1.0, 5.0)) if short else {}
    runs = {w: position_gain_study(w, **kw) for w in ("k1", "k2")}
    fig, axes = figure_axes(None, ncols=2, figsize=(11, 3.5))
    plot_joint_angle(runs["k1"], ax=axes[0], title="K1 (K2 = 1), Fig 15.7")
    plot_joint_angle(runs["k2"], ax=axes[1], title="K2 (K1 = 5), Fig 15.8")
    every = runs["k1"] + runs["k2"]
    return Reproduction(fig, _run_series(every), {r.label: dict(
        final_angle=_v(float(r.q[-1]), "rad"), overshoot=_v(float(100 * max(0.0, r.q.max() / r.reference[-1] - 1)), "%"))
        for r in every})


def _fig15_27(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch15_backstepping import antagonistic_stiffness_check
    chk = antagonistic_stiffness_check(np.array([0.01, 0.02, 0.05, 0.1]), deflection=0.3)
    fig, _ = chk.plot()
    return Reproduction(fig, {"Kp_imp [Nm/rad]": chk.stiffness, "effective stiffness [Nm/rad]": chk.effective_stiffness,
                              "torque [Nm]": chk.torque}, dict(deflection=_v(chk.deflection, "rad")))


def _fig13_2(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch13_lqr import lqr_trajectories
    runs = lqr_trajectories(t_final=0.1 if short else 0.2)
    fig, axes = figure_axes(None, ncols=2, figsize=(11, 3.8))
    series = {}
    for r, d in runs.items():
        d.plot(ax=axes)
        series.update({f"R={r:g}: t [s]": d.t, f"R={r:g}: link q [rad]": d.state[:, 0],
                       f"R={r:g}: motor theta [rad]": d.state[:, 2], f"R={r:g}: u [Nm]": d.u})
    return Reproduction(fig, series, {f"R={r:g}": dict(K=_v(np.ravel(d.K).tolist(), "Nm/rad, Nm s/rad (u = -K x)"),
                                                      peak_u=_v(float(np.max(np.abs(d.u))), "Nm")) for r, d in runs.items()})


def _fig12_3(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch12_pole_placement import open_loop_pole_sweep
    sw = open_loop_pole_sweep(num=15 if short else 40)
    fig, _ = sw.plot()
    series = {"k [Nm/rad]": sw.stiffness, "d_q [Nm s/rad]": sw.link_damping}
    for i in range(sw.poles_vs_stiffness.shape[1]):
        series.update({f"pole {i} vs k: real [1/s]": sw.poles_vs_stiffness[:, i].real,
                       f"pole {i} vs k: imag [1/s]": sw.poles_vs_stiffness[:, i].imag,
                       f"pole {i} vs d_q: real [1/s]": sw.poles_vs_damping[:, i].real,
                       f"pole {i} vs d_q: imag [1/s]": sw.poles_vs_damping[:, i].imag})
    return Reproduction(fig, series, {})


def _fig8_3(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch08_stiffness_correction import stiffness_correction_run
    kw = dict(loads=(0.0, 0.15), segment=0.2) if short else dict(loads=(0.0, 0.075, 0.15, 0.0), segment=0.3)
    runs = [stiffness_correction_run(corrected=c, **kw) for c in (True, False)]
    fig, axes = figure_axes(None, ncols=2, figsize=(12, 3.5))
    runs[0].plot(ax=axes[0])
    plot_traces(runs[0].t, {"corrected" if r.corrected else "fixed K_imp": r.q for r in runs},
                ylabel="link angle [rad]", ax=axes[1])
    r = runs[0]
    series = {"t [s]": r.t, "external torque [Nm]": r.tau_ext, "K target [Nm/rad]": r.k_target,
              "K_imp [Nm/rad]": r.k_imp, "K_mech [Nm/rad]": r.k_mech, "K_eff (8.1) [Nm/rad]": r.k_eff,
              "link angle, corrected [rad]": r.q, "link angle, fixed K_imp [rad]": runs[1].q}
    return Reproduction(fig, series, {})


def _fig10_2(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch10_tendon_force import tendon_step_experiment
    runs = [tendon_step_experiment(sched, t_final=0.15 if short else 0.25) for sched in (False, True)]
    fig, axes = figure_axes(None, ncols=2, figsize=(12, 4), sharey=True)
    series = {"t [s]": runs[0].t}
    for r, ax in zip(runs, axes):
        r.plot(ax=ax)
        series.update({f"{r.controller}, from {f0:g} N: tendon force [N]": f for f0, f in r.forces.items()})
    units = dict(overshoot="%", settling_time="s", damping_ratio="-", rise_time="s", steady_state_error="N",
                 natural_frequency="rad/s", final="N", dead_time="s")      # step_metrics' keys: a new one fails here
    values = {r.controller: {f"from {f0:g} N": {k: _v(float(v), units[k]) for k, v in m.items()}
                             for f0, m in r.metrics.items()} for r in runs}
    return Reproduction(fig, series, values)


def _fig11_4(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch11_impedance import impedance_frequency_response
    d = impedance_frequency_response("two-time-scale")
    fig, _ = d.plot()
    return Reproduction(fig, {"frequency [Hz]": d.freq, "gain |q/q_des| [-]": d.gain}, dict(
        resonance=_v(d.resonance_hz, "Hz"), peak_gain=_v(float(np.max(d.gain)), "-"),
        eigenvalues_real=_v(np.real(d.eigenvalues).tolist(), "1/s"),
        eigenvalues_imag=_v(np.imag(d.eigenvalues).tolist(), "1/s")))


def _fig9_3(short: bool) -> Reproduction:
    from awiwi_drake.reproductions.ch09_friction_observer import chattering, friction_tracking_run, plot_friction_runs
    runs = [friction_tracking_run(compensate=c, t_final=1.2 if short else 4.0) for c in (False, True)]
    fig, _ = plot_friction_runs(runs)
    series = {"t [s]": runs[0].t, "reference [rad]": runs[0].reference}
    series.update({f"{r.label} link angle [rad]": r.q for r in runs})
    values = {r.label: dict(
        rms_error_after_0_4s=_v(float(np.sqrt(np.mean((r.q - r.reference)[r.t > 0.4] ** 2))), "rad"),
        chattering=_v(chattering(r, after=0.4), "Nm/s")) for r in runs}
    return Reproduction(fig, series, values)


FIGURES: dict[str, FigureEntry] = {e.id: e for e in (
    FigureEntry("fig5.7", "Fig 5.7", "index finger released from a 0.1 rad MCP deflection, motors "
                "fixed: full minus no-Coriolis model", "ch05_fingers", _fig5_7),
    FigureEntry("fig6.10", "Fig 6.9-6.10", "wrist flexion then abduction: constraint errors and the "
                "tendons' displacement", "ch06_wrist", _fig6_10),
    FigureEntry("cocontraction", "(5.12), ch. 7, (8.1)", "index joint stiffness measured on the closed loop at two "
                "co-contraction levels (joint-pd at 20/40 N; full: the force chain too)", "ch07_cocontraction",
                _cocontraction),
    FigureEntry("fig8.3", "Fig 8.3", "stiffness correction (8.1) on the joint rig: K_eff held at its targets under "
                "load steps, beside a fixed K_imp", "ch08_stiffness_correction", _fig8_3),
    FigureEntry("fig9.3", "Fig 9.3", "slow sine on the joint rig with link stick-slip friction, "
                "with and without the observer's compensation", "ch09_friction_observer", _fig9_3),
    FigureEntry("fig10.2", "Fig 10.2-10.3", "tendon force steps of 5 N from 10-40 N, fixed vs scheduled gains "
                "(friction, ripple, quantised delayed sensor)", "ch10_tendon_force", _fig10_2),
    FigureEntry("fig11.4", "Fig 11.4", "gain diagram of the two-time-scale impedance on the joint rig (Kp,imp = 4 Nm/rad), "
                "Drake Linearize", "ch11_impedance", _fig11_4),
    FigureEntry("fig12.3", "Fig 12.3", "open-loop poles of the flexible joint (Table 12.1) against its stiffness and "
                "link damping (Drake Linearize)", "ch12_pole_placement", _fig12_3),
    FigureEntry("fig13.2", "Fig 13.2-13.3", "LQR regulation of the flexible joint (Table 13.1) for R = 1e-4, 1e-2, 1: "
                "positions and input", "ch13_lqr", _fig13_2),
    FigureEntry("fig15.7", "Fig 15.7-15.8", "position backstepping 0.8 rad steps on the Table 15.1 joint for several "
                "K1 and K2", "ch15_backstepping", _fig15_7),
    FigureEntry("fig15.24", "Fig 15.24 (section 15.5.3)", "index PIP 30 deg step at 10 N, backstepping vs cascaded, "
                "joints' stick-slip on", "ch15_pip_experiments", lambda short: _pip("step", short)),
    FigureEntry("fig15.25", "Fig 15.25 (section 15.5.3)", "index PIP 10-50 deg sine at 15 N, backstepping vs "
                "cascaded, joints' stick-slip on", "ch15_pip_experiments", lambda short: _pip("sine", short)),
    FigureEntry("fig15.27", "Fig 15.27", "antagonistic backstepping under an imposed 0.3 rad deflection: joint torque "
                "against Kp,imp", "ch15_backstepping", _fig15_27),
    FigureEntry("fig15.26", "Fig 15.26 (section 15.5.3)", "gain diagrams of backstepping and two-time-scale on the "
                "joint rig at 20 N (Drake Linearize), -3 dB bandwidths", "ch15_backstepping", _fig15_26),
)}


def _write_csv(path: pathlib.Path, series: dict) -> None:
    """One column per series (shorter ones end in empty cells: runs on their own time grids)."""
    cols = [np.asarray(v, dtype=float) for v in series.values()]
    bad = [k for k, c in zip(series, cols) if c.ndim != 1]
    if bad:
        raise ValueError(f"{path.name}: series {bad[0]!r} is not 1-D")
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(series))
        w.writerows([repr(float(c[i])) if i < c.size else "" for c in cols] for i in range(max(c.size for c in cols)))


def reproduce(ids, out, *, short: bool = False, progress: Callable[[str], None] | None = None) -> dict[str, list]:
    """Run the figure ``ids`` (keys of :data:`FIGURES`; a single id or a list) and write ``ID.png``, ``ID.csv``
    (when the figure has series) and ``ID.json`` into the folder ``out`` (created); returns ``{id: [paths]}``.
    An unknown id raises ``KeyError`` naming it (before anything runs); ``progress(id)`` is called before each."""
    ids = [ids] if isinstance(ids, str) else list(ids)
    unknown = [i for i in ids if i not in FIGURES]
    if unknown or not ids:
        raise KeyError(f"unknown figure id {unknown[0]!r}; known: {', '.join(FIGURES)}" if unknown else
                       f"give at least one figure id; known: {', '.join(FIGURES)}")
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = {}
    for i in ids:
        e = FIGURES[i]
        if progress is not None:
            progress(i)
        r = e.run(bool(short))
        paths = [out / f"{i}.png"]
        r.figure.savefig(paths[0], dpi=100)
        _plt().close(r.figure)
        if r.series:
            paths.append(out / f"{i}.csv")
            _write_csv(paths[-1], r.series)
        paths.append(out / f"{i}.json")
        paths[-1].write_text(json.dumps(dict(id=i, reference=e.reference, summary=e.summary,
                                             module=f"awiwi_drake.reproductions.{e.module}", short=bool(short),
                                             values=r.values), indent=1) + "\n")
        written[i] = paths
    return written
