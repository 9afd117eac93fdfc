"""Standard closed-loop tests, metrics table and plots.

:func:`run_standard_tests` runs, on one :class:`~awiwi_drake.control.base.ClosedLoop`,

* ``step``: reference step ``r0 -> r0 + step`` (rise time 10-90 %, overshoot,
  2 % settling time, steady-state error, damping ratio from the overshoot);
* ``sine``: sinusoidal tracking (RMS error, gain and phase at the frequency);
* ``disturbance``: an ``external_torque`` step at constant reference
  (achieved stiffness ``dtau / dq``; link rigs only);
* ``sweep``: a linear chirp of the reference, gain diagram ``|Y/R|(f)``
  estimated with Welch cross spectra (as in Fig 11.4);

and :func:`compare` does so for several controllers and returns a
:class:`Comparison` (runs + :class:`MetricsTable`).  Each test starts from the
closed loop settled at the initial reference.  References and disturbances are
applied as inputs held between samples of period ``sample_dt`` (the control
period for sampled loops).  Plotting functions take the data and return
``(fig, ax)``.
"""

from __future__ import annotations

import csv
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.analysis import ResetIntegratorFromFlags

from awiwi_drake.control.base import ClosedLoop
from awiwi_drake.parameters.control import CompareTestParams, compare_test_params

__all__ = ["TestRun", "Metrics", "MetricsTable", "Comparison", "settle", "run_test",
           "run_standard_tests", "compare", "step_metrics", "sine_metrics", "gain_diagram",
           "plot_runs", "plot_gain_diagram", "plot_metric", "TESTS"]

TESTS = ("step", "sine", "disturbance", "sweep")


class SimulationDivergedError(RuntimeError):
    """Raised when the closed-loop state becomes non-finite."""


@dataclass
class TestRun:
    """Time series of one test on one closed loop (t = 0 at the test start)."""

    controller: str
    test: str
    t: np.ndarray
    reference: np.ndarray
    output: np.ndarray
    command: np.ndarray
    disturbance: np.ndarray
    state: np.ndarray
    meta: dict = field(default_factory=dict)


@dataclass
class Metrics:
    """One row of the metrics table (NaN where a metric does not apply)."""

    controller: str
    test: str
    rise_time: float = math.nan          # s, 10-90 % of the step
    overshoot: float = math.nan          # % of the step size
    settling_time: float = math.nan      # s, 2 % band of the step size
    steady_state_error: float = math.nan  # reference - output at the end [unit of the output]
    peak_input: float = math.nan         # max |motor_torque_command| [Nm]
    stiffness: float = math.nan          # d external torque / d link angle [Nm/rad]
    damping_ratio: float = math.nan      # from the overshoot of a step (NaN: no overshoot)
    tracking_rms: float = math.nan       # RMS tracking error (sine)
    gain: float = math.nan               # |Y/R| at the sine frequency
    phase_deg: float = math.nan          # phase of Y/R at the sine frequency
    peak_gain: float = math.nan          # max |Y/R| over the sweep
    resonance_hz: float = math.nan       # frequency of the peak gain
    bandwidth_hz: float = math.nan       # first frequency where |Y/R| < 1/sqrt(2)
    saturated_fraction: float = math.nan  # fraction of samples with the command beyond the limit


COLUMNS = [f for f in Metrics.__dataclass_fields__]
UNITS = dict(rise_time="s", overshoot="%", settling_time="s", steady_state_error="ref", peak_input="Nm",
             stiffness="Nm/rad", damping_ratio="-", tracking_rms="ref", gain="-", phase_deg="deg",
             peak_gain="-", resonance_hz="Hz", bandwidth_hz="Hz", saturated_fraction="-")


@dataclass
class MetricsTable:
    """Rows of :class:`Metrics`; CSV/Markdown export and lookup."""

    rows: list[Metrics] = field(default_factory=list)

    def get(self, controller: str, test: str) -> Metrics:
        for r in self.rows:
            if r.controller == controller and r.test == test:
                return r
        raise KeyError(f"no metrics for controller {controller!r} and test {test!r}")

    def column(self, name: str, test: str) -> dict[str, float]:
        if name not in COLUMNS:
            raise ValueError(f"unknown metric {name!r}; known: {', '.join(COLUMNS[2:])}")
        return {r.controller: getattr(r, name) for r in self.rows if r.test == test}

    def to_csv(self, path: str | Path) -> Path:
        path = Path(path)
        with path.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=COLUMNS)
            w.writeheader()
            for r in self.rows:
                w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in asdict(r).items()})
        return path

    def to_markdown(self) -> str:
        lines = []
        for test in dict.fromkeys(r.test for r in self.rows):
            rows = [r for r in self.rows if r.test == test]
            cols = [c for c in COLUMNS[2:] if any(math.isfinite(getattr(r, c)) for r in rows)]
            lines.append(f"### {test}\n")
            lines.append("| controller | " + " | ".join(f"{c} [{UNITS[c]}]" for c in cols) + " |")
            lines.append("|---" * (len(cols) + 1) + "|")
            for r in rows:
                lines.append(f"| {r.controller} | " + " | ".join(_fmt(getattr(r, c)) for c in cols) + " |")
            lines.append("")
        return "\n".join(lines)


def _fmt(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{v:.4g}"


@dataclass
class Comparison:
    """Result of :func:`compare`: all runs and the metrics table."""

    runs: list[TestRun]
    table: MetricsTable
    rig: str = ""

    def run(self, controller: str, test: str) -> TestRun:
        for r in self.runs:
            if r.controller == controller and r.test == test:
                return r
        raise KeyError(f"no run for controller {controller!r} and test {test!r}")


# ----------------------------------------------------------------------------
# simulation
def _make_simulator(loop: ClosedLoop, context, max_step: float):
    sim = Simulator(loop.diagram, context)
    ResetIntegratorFromFlags(sim, "runge_kutta3", max_step)
    sim.get_mutable_integrator().set_target_accuracy(1e-6)
    sim.Initialize()
    return sim


def _sample_dt(loop: ClosedLoop, params: CompareTestParams) -> float:
    return 1.0 / loop.rate_hz if loop.rate_hz else params.sample_period


def _simulate(loop: ClosedLoop, context, t_final: float, dt: float, reference: Callable[[float], float],
              disturbance: Callable[[float], float] | None, max_step: float, controller: str, test: str,
              meta: dict | None = None) -> TestRun:
    """Advance ``context`` (from time 0) to ``t_final`` sampling every ``dt``, holding the inputs."""
    d = loop.diagram
    ref_ports = [d.GetInputPort(r) for r in loop.references]
    dist_port = d.GetInputPort("external_torque") if "external_torque" in loop.disturbances else None
    out_port = d.GetOutputPort(loop.tracked_outputs[0])
    cmd_port = d.GetOutputPort("motor_torque_command")
    n = int(round(t_final / dt)) + 1
    ts = np.arange(n) * dt
    ys, us, rs, ws, xs = [], [], [], [], []

    def _apply(t):
        r = reference(t)
        for p in ref_ports:
            p.FixValue(context, np.full(p.size(), r))
        w = disturbance(t) if disturbance is not None else 0.0
        if dist_port is not None:
            dist_port.FixValue(context, np.full(dist_port.size(), w))
        return r, w

    context.SetTime(0.0)
    r, w = _apply(0.0)
    sim = _make_simulator(loop, context, max_step)
    for i, t in enumerate(ts):
        if i > 0:
            sim.AdvanceTo(t)
        y = out_port.Eval(context)
        u = cmd_port.Eval(context)
        x = context.get_continuous_state_vector().CopyToVector()
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u))):
            raise SimulationDivergedError(f"{controller}/{test}: state not finite at t = {t:.4g} s")
        ys.append(float(y[0]))
        us.append(np.array(u, dtype=float))
        rs.append(r)
        ws.append(w)
        xs.append(x)
        r, w = _apply(t + dt)
    return TestRun(controller, test, ts, np.array(rs), np.array(ys), np.array(us), np.array(ws),
                   np.array(xs), dict(meta or {}))


def settle(loop: ClosedLoop, reference: float, *, t_settle: float, params: CompareTestParams | None = None,
           state=None, motor_torque=None):
    """A context of ``loop`` settled at the constant ``reference`` (time reset to 0).

    The start is the rig's default operating point unless ``state`` is given.
    """
    params = params or compare_test_params(loop.rig)
    if state is None and hasattr(loop.rig, "operating_point"):
        op = loop.rig.operating_point()
        state = np.asarray(op.state, dtype=float)
        motor_torque = op.motor_torque if motor_torque is None else motor_torque
    ctx = loop.create_context(state=state, motor_torque=motor_torque,
                              references={r: reference for r in loop.references})
    if t_settle > 0:
        sim = _make_simulator(loop, ctx, params.max_step)
        sim.AdvanceTo(t_settle)
        if not np.all(np.isfinite(ctx.get_continuous_state_vector().CopyToVector())):
            raise SimulationDivergedError(f"closed loop diverged while settling at reference {reference}")
    ctx.SetTime(0.0)
    return ctx


# ----------------------------------------------------------------------------
# metrics
def _damping_from_overshoot(os_frac: float) -> float:
    if not (os_frac > 1e-4):
        return math.nan
    lg = math.log(os_frac)
    return -lg / math.sqrt(math.pi ** 2 + lg ** 2)


def step_metrics(t: np.ndarray, y: np.ndarray, r0: float, r1: float, t_step: float = 0.0,
                 band: float = 0.02) -> dict[str, float]:
    """Rise time (10-90 %), overshoot [% of the step], settling time (band), error, damping ratio.

    ``y`` is a step response with the step at ``t_step``; the final value is
    the reference ``r1`` (the steady-state error is reported separately).
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    size = r1 - r0
    if size == 0:
        raise ValueError("step_metrics: the step size r1 - r0 must be non-zero")
    m = t >= t_step
    tt, e = t[m] - t_step, (y[m] - r0) / size  # normalised response 0 -> 1
    tail = max(3, len(e) // 10)
    final = float(np.mean(e[-tail:]))
    out = dict(steady_state_error=float(size * (1.0 - final)))
    i10 = np.argmax(e >= 0.1) if np.any(e >= 0.1) else None
    i90 = np.argmax(e >= 0.9) if np.any(e >= 0.9) else None
    out["rise_time"] = float(tt[i90] - tt[i10]) if (i10 is not None and i90 is not None) else math.nan
    os_frac = max(0.0, float(np.max(e)) - 1.0)
    out["overshoot"] = 100.0 * os_frac
    out["damping_ratio"] = _damping_from_overshoot(os_frac)
    outside = np.nonzero(np.abs(e - 1.0) > band)[0]
    if len(outside) == 0:
        out["settling_time"] = 0.0
    elif outside[-1] == len(e) - 1:
        out["settling_time"] = math.nan  # never settles within the run
    else:
        out["settling_time"] = float(tt[outside[-1] + 1])
    return out


def sine_metrics(t, r, y, freq_hz: float) -> dict[str, float]:
    """RMS error and the complex ratio Y/R at ``freq_hz`` (least-squares fit over whole periods)."""
    t, r, y = (np.asarray(a, float) for a in (t, r, y))
    basis = np.column_stack([np.sin(2 * np.pi * freq_hz * t), np.cos(2 * np.pi * freq_hz * t), np.ones_like(t)])
    cr = np.linalg.lstsq(basis, r, rcond=None)[0]
    cy = np.linalg.lstsq(basis, y, rcond=None)[0]
    zr, zy = complex(cr[0], cr[1]), complex(cy[0], cy[1])
    h = zy / zr
    return dict(tracking_rms=float(np.sqrt(np.mean((r - y) ** 2))), gain=abs(h),
                phase_deg=math.degrees(math.atan2(h.imag, h.real)))


def gain_diagram(t, r, y, f_low: float, f_high: float) -> tuple[np.ndarray, np.ndarray]:
    """Gain |Y/R| from a chirp (Welch cross spectra), restricted to [f_low, f_high]."""
    from scipy.signal import csd, welch
    t, r, y = (np.asarray(a, float) for a in (t, r, y))
    fs = 1.0 / float(np.median(np.diff(t)))
    nper = min(len(t), int(2 ** math.floor(math.log2(max(16, len(t) // 4)))))
    r0, y0 = r - np.mean(r), y - np.mean(y)
    f, prr = welch(r0, fs=fs, nperseg=nper)
    _, pry = csd(r0, y0, fs=fs, nperseg=nper)
    m = (f >= f_low) & (f <= f_high) & (prr > 1e-12 * np.max(prr))
    return f[m], np.abs(pry[m] / prr[m])


def _sweep_metrics(f, g) -> dict[str, float]:
    if len(f) == 0:
        return {}
    i = int(np.argmax(g))
    below = np.nonzero(g < 1.0 / math.sqrt(2.0))[0]
    return dict(peak_gain=float(g[i]), resonance_hz=float(f[i]),
                bandwidth_hz=float(f[below[0]]) if len(below) else math.nan)


# ----------------------------------------------------------------------------
def run_test(loop: ClosedLoop, test: str, *, controller: str = "controller",
             params: CompareTestParams | None = None, settled=None) -> tuple[TestRun, Metrics]:
    """Run one standard test (``step``, ``sine``, ``disturbance``, ``sweep``) on a closed loop."""
    if test not in TESTS:
        raise ValueError(f"unknown test {test!r}; known: {', '.join(TESTS)}")
    if not loop.references:
        raise ValueError(f"controller {controller!r} has no *_reference input: cannot run {test!r}")
    p = params or compare_test_params(loop.rig)
    if test == "disturbance" and "external_torque" not in loop.disturbances:
        raise ValueError(f"test 'disturbance' needs a rig input 'external_torque'; rig "
                         f"{getattr(loop.rig, 'name', '?')!r} has none")
    dt = _sample_dt(loop, p)
    r0 = p.initial_reference
    ctx = (settled.Clone() if settled is not None else settle(loop, r0, t_settle=p.settle_time, params=p))
    ctx.SetTime(0.0)
    meta: dict[str, Any] = {}
    dist = None
    if test == "step":
        t0, r1 = p.step_delay, r0 + p.step_size
        ref = (lambda t: r1 if t >= t0 - 1e-12 else r0)
        t_final = p.step_duration
    elif test == "sine":
        ref = (lambda t: r0 + p.sine_amplitude * math.sin(2 * math.pi * p.sine_frequency * t))
        t_final = p.sine_periods / p.sine_frequency
    elif test == "disturbance":
        t0 = p.step_delay
        ref = (lambda t: r0)
        dist = (lambda t: p.disturbance_torque if t >= t0 - 1e-12 else 0.0)
        t_final = p.step_duration
    else:
        f0, f1, T = p.sweep_start, p.sweep_stop, p.sweep_duration
        k = (f1 - f0) / T
        ref = (lambda t: r0 + p.sweep_amplitude * math.sin(2 * math.pi * (f0 * t + 0.5 * k * t * t)))
        t_final = T
        meta.update(f_low=f0, f_high=f1)
    run = _simulate(loop, ctx, t_final, dt, ref, dist, p.max_step, controller, test, meta)
    m = Metrics(controller, test)
    u = np.abs(run.command)
    m.peak_input = float(np.max(u))
    if loop.saturation is not None:
        m.saturated_fraction = float(np.mean(np.any(u > loop.saturation[None, :] * (1 + 1e-9), axis=1)))
    if test == "step":
        for k_, v in step_metrics(run.t, run.output, r0, r0 + p.step_size, p.step_delay).items():
            setattr(m, k_, v)
    elif test == "sine":
        skip = run.t >= 1.0 / p.sine_frequency  # drop the first period (transient)
        for k_, v in sine_metrics(run.t[skip], run.reference[skip], run.output[skip], p.sine_frequency).items():
            setattr(m, k_, v)
    elif test == "disturbance":
        pre = run.t < p.step_delay
        tail = run.t >= run.t[-1] - 0.1 * run.t[-1]
        dq = float(np.mean(run.output[tail]) - np.mean(run.output[pre]))
        m.stiffness = p.disturbance_torque / dq if dq != 0 else math.inf
        m.steady_state_error = float(r0 - np.mean(run.output[tail]))
    else:
        f, g = gain_diagram(run.t, run.reference, run.output, p.sweep_start, p.sweep_stop)
        run.meta.update(freq=f, gain=g)
        for k_, v in _sweep_metrics(f, g).items():
            setattr(m, k_, v)
    return run, m


def run_standard_tests(loop: ClosedLoop, *, controller: str = "controller", tests: Sequence[str] | None = None,
                       params: CompareTestParams | None = None) -> tuple[list[TestRun], list[Metrics]]:
    """All applicable standard tests on one closed loop (``disturbance`` only with ``external_torque``)."""
    p = params or compare_test_params(loop.rig)
    if tests is None:
        tests = [t for t in TESTS if t != "disturbance" or "external_torque" in loop.disturbances]
    settled = settle(loop, p.initial_reference, t_settle=p.settle_time, params=p)
    runs, rows = [], []
    for test in tests:
        run, m = run_test(loop, test, controller=controller, params=p, settled=settled)
        runs.append(run)
        rows.append(m)
    return runs, rows


def compare(loops: Mapping[str, ClosedLoop], *, tests: Sequence[str] | None = None,
            params: CompareTestParams | None = None) -> Comparison:
    """Run the standard tests on every closed loop ``{name: loop}``."""
    if not loops:
        raise ValueError("compare: give at least one closed loop")
    runs, rows = [], []
    rig = ""
    for name, loop in loops.items():
        r, m = run_standard_tests(loop, controller=name, tests=tests, params=params)
        runs += r
        rows += m
        rig = getattr(loop.rig, "name", rig)
    return Comparison(runs, MetricsTable(rows), rig)


# ----------------------------------------------------------------------------
# plotting (data in, (fig, ax) out)
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
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel or "tracked output")
    ax.set_title(f"{comparison.rig}: {test}")
    ax.legend()
    ax.grid(True, alpha=0.3)
    return fig, ax


def plot_gain_diagram(comparison: Comparison, *, ax=None):
    """Gain diagrams |Y/R|(f) of the sweep test (Fig 11.4 style)."""
    import matplotlib.pyplot as plt
    runs = [r for r in comparison.runs if r.test == "sweep"]
    if not runs:
        raise ValueError("plot_gain_diagram: no sweep runs")
    fig, ax = (plt.subplots(figsize=(7, 4)) if ax is None else (ax.figure, ax))
    for r in runs:
        ax.plot(r.meta["freq"], r.meta["gain"], label=r.controller)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("gain |Y/R|")
    ax.legend()
    ax.grid(True, alpha=0.3)
    return fig, ax


def plot_metric(table: MetricsTable, metric: str, test: str, *, ax=None):
    """Bar chart of one metric over controllers."""
    import matplotlib.pyplot as plt
    col = table.column(metric, test)
    fig, ax = (plt.subplots(figsize=(6, 3.5)) if ax is None else (ax.figure, ax))
    ax.bar(list(col), [v if math.isfinite(v) else 0.0 for v in col.values()])
    ax.set_ylabel(f"{metric} [{UNITS[metric]}]")
    ax.set_title(test)
    return fig, ax
