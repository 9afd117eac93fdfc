"""Standard closed-loop tests, metrics table and plots.

:func:`run_standard_tests` runs, on one :class:`~awiwi_drake.control.base.ClosedLoop`,

* ``step``: reference step ``r0 -> r0 + step`` (rise time 10-90 %, overshoot,
  settling time in ``settling_band`` (2 %; 5 % on the noisy tendon rig), steady-state
  error, damping ratio of a fitted 2nd-order model);
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

from awiwi_drake.analysis import Chirp, Constant, SimulationDivergedError, Sine, Step, simulate
from awiwi_drake.analysis.schedules import Schedule
from awiwi_drake.rigs.base import Rig
from awiwi_drake.control.base import ClosedLoop
from awiwi_drake.control.registry import rig_kind
from awiwi_drake.parameters.control import CompareTestParams

__all__ = ["compare_test_params", "TestRun", "Metrics", "MetricsTable", "Comparison", "settle", "run_test", "flag_run",
           "run_standard_tests", "compare", "compare_controllers", "step_metrics", "sine_metrics", "gain_diagram",
           "plot_runs", "plot_gain_diagram", "plot_metric", "TESTS", "fit_second_order_step"]

TESTS = ("step", "sine", "disturbance", "sweep")


def compare_test_params(rig: Any, **overrides: Any) -> CompareTestParams:
    """Default standard tests for a rig kind (tendon force in N, link angle in rad)."""
    kind = rig_kind(rig)
    if kind == "tendon_rig":
        base = CompareTestParams(initial_reference=10.0, step_size=5.0, step_duration=0.25, sine_amplitude=2.0,
                                 sine_frequency=5.0, sweep_amplitude=1.0, sweep_start=1.0, sweep_stop=60.0,
                                 sweep_duration=2.0, settle_time=0.2, settling_band=0.05)
    else:
        base = CompareTestParams()
    return base.replace(**overrides) if overrides else base


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
    settling_time: float = math.nan      # s, band CompareTestParams.settling_band (2 %; 5 % on the tendon rig)
    steady_state_error: float = math.nan  # reference - output at the end [unit of the output]
    peak_input: float = math.nan         # max |motor_torque_command| [Nm]
    stiffness: float = math.nan          # d external torque / d link angle [Nm/rad]
    damping_ratio: float = math.nan      # of a 2nd-order model fitted to the step response
    tracking_rms: float = math.nan       # RMS tracking error (sine)
    gain: float = math.nan               # |Y/R| at the sine frequency
    phase_deg: float = math.nan          # phase of Y/R at the sine frequency
    peak_gain: float = math.nan          # max |Y/R| over the sweep
    resonance_hz: float = math.nan       # frequency of the peak gain
    bandwidth_hz: float = math.nan       # first frequency where |Y/R| < 1/sqrt(2)
    saturated_fraction: float = math.nan  # fraction of samples with the command beyond the torque limit
    slack_fraction: float = math.nan     # fraction of samples with a slack tendon (tension-only rigs)
    status: str = "ok"                   # "ok", "flagged" (see flags) or "diverged: <reason>" (metrics NaN)
    flags: str = ""                      # "; "-separated: saturated, slack, not settled, negative stiffness


COLUMNS = [f for f in Metrics.__dataclass_fields__]
NUMERIC = [c for c in COLUMNS if c not in ("controller", "test", "status", "flags")]
UNITS = dict(rise_time="s", overshoot="%", settling_time="s", steady_state_error="ref", peak_input="Nm",
             stiffness="Nm/rad", damping_ratio="-", tracking_rms="ref", gain="-", phase_deg="deg",
             peak_gain="-", resonance_hz="Hz", bandwidth_hz="Hz", saturated_fraction="-",
             slack_fraction="-")


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
        if name not in NUMERIC:
            raise ValueError(f"unknown metric {name!r}; known: {', '.join(NUMERIC)}")
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
            cols = [c for c in NUMERIC if any(math.isfinite(getattr(r, c)) for r in rows)]
            lines.append(f"### {test}\n")
            lines.append("| controller | " + " | ".join(f"{c} [{UNITS[c]}]" for c in cols) + " | status |")
            lines.append("|---" * (len(cols) + 2) + "|")
            for r in rows:
                status = f"{r.status}: {r.flags}" if r.flags else r.status
                lines.append(f"| {r.controller} | " + " | ".join(_fmt(getattr(r, c)) for c in cols)
                             + f" | {status} |")
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
def _sample_dt(loop: ClosedLoop, params: CompareTestParams) -> float:
    return 1.0 / loop.rate_hz if loop.rate_hz else params.sample_period


def _simulate(loop: ClosedLoop, context, t_final: float, dt: float, reference: Schedule,
              disturbance: Schedule | None, max_step: float, controller: str, test: str,
              meta: dict | None = None) -> TestRun:
    """One test through :func:`awiwi_drake.analysis.simulate`, logged every ``dt`` (the control period)."""
    inputs = {r: reference for r in loop.references}
    if "external_torque" in loop.disturbances:
        inputs["external_torque"] = disturbance if disturbance is not None else 0.0
    y = loop.tracked_outputs[0]
    log = [y, "motor_torque_command", "state", loop.references[0]]
    if "external_torque" in inputs:
        log.append("external_torque")
    slack = isinstance(loop.rig, Rig) and loop.rig.tension_only and loop.diagram.HasOutputPort("tendon_force")
    if slack and y != "tendon_force":
        log.append("tendon_force")
    res = simulate(loop, context, context.get_time() + t_final, inputs=inputs, log=log, log_period=dt,
                   max_step=max_step, accuracy=1e-6)
    t = res.t - res.t[0]
    w = res["external_torque"][:, 0] if "external_torque" in res else np.zeros(len(t))
    meta = dict(meta or {})
    if slack:
        meta["tendon_force"] = res["tendon_force"]
    return TestRun(controller, test, t, res[loop.references[0]][:, 0], res[y][:, 0],
                   res["motor_torque_command"], w, res["state"], meta)


def settle(loop: ClosedLoop, reference: float, *, t_settle: float, params: CompareTestParams | None = None,
           state=None, motor_torque=None):
    """A context of ``loop`` settled at the constant ``reference`` (time reset to 0).

    The start is the rig's operating point for the tracked output at ``reference``
    (``tendon_force=...``, ``link_angle=...``; else its default one) unless
    ``state`` is given.
    """
    params = params or compare_test_params(loop.rig)
    if state is None and hasattr(loop.rig, "operating_point"):
        try:  # start at the rig's equilibrium for the reference when the rig offers one
            op = loop.rig.operating_point(**{loop.tracked_outputs[0]: reference})
        except (TypeError, ValueError):
            op = loop.rig.operating_point()
        state = np.asarray(op.state, dtype=float)
        motor_torque = op.motor_torque if motor_torque is None else motor_torque
    ctx = loop.create_context(state=state, motor_torque=motor_torque,
                              references={r: reference for r in loop.references})
    if t_settle > 0:
        simulate(loop, ctx, t_settle, log=(), max_step=params.max_step, accuracy=1e-6)  # advances ctx
    ctx.SetTime(0.0)
    return ctx


# ----------------------------------------------------------------------------
# metrics
def _damping_from_overshoot(os_frac: float) -> float:
    if not (os_frac > 1e-4):
        return math.nan
    lg = math.log(os_frac)
    return -lg / math.sqrt(math.pi ** 2 + lg ** 2)


_XI_BOUNDS = (0.05, 3.0)  # damping-ratio bounds of fit_second_order_step
_XI_MARGIN = 1e-3        # relative margin: a fitted value this close to a bound is "at the bound"


def step_metrics(t: np.ndarray, y: np.ndarray, r0: float, r1: float, t_step: float = 0.0,
                 band: float = 0.02, fit: bool = False) -> dict[str, float]:
    """Rise time (10-90 %), overshoot [% of the step], settling time (band), error, damping ratio.

    The damping ratio comes from the overshoot (``-ln(OS) / sqrt(pi^2 + ln^2 OS)``,
    NaN without overshoot) or, with ``fit=True``, from
    :func:`fit_second_order_step` (robust to measurement noise; NaN when the fit
    hits its bounds 0.05 / 3, i.e. the response is not second-order like).

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
    if fit:
        xi = fit_second_order_step(t, y, r0, r1, t_step)["damping_ratio"]
        lo, hi = _XI_BOUNDS
        # at (or within 0.1 % of) a bound of the fit: not a 2nd-order response -> NaN
        out["damping_ratio"] = xi if lo * (1 + _XI_MARGIN) < xi < hi * (1 - _XI_MARGIN) else math.nan
    else:
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


def gain_diagram(t, r, y, f_low: float, f_high: float, *, smooth: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Gain |Y/R| of a swept-sine (chirp) test, restricted to [f_low, f_high].

    Ratio of the Fourier transforms of the whole (mean-removed) records, which
    resolves ``1 / T``; a centred moving average over ``smooth`` bins of both
    auto/cross spectra tames the ripple of the finite chirp.
    """
    t, r, y = (np.asarray(a, float) for a in (t, r, y))
    if len(t) < 16:
        raise ValueError("gain_diagram: need at least 16 samples")
    dt = float(np.median(np.diff(t)))
    R = np.fft.rfft(r - np.mean(r))
    Y = np.fft.rfft(y - np.mean(y))
    f = np.fft.rfftfreq(len(t), dt)
    prr, pry = np.abs(R) ** 2, np.conj(R) * Y
    if smooth > 1:
        ker = np.ones(smooth) / smooth
        prr = np.convolve(prr, ker, mode="same")
        pry = np.convolve(pry, ker, mode="same")
    m = (f >= f_low) & (f <= f_high) & (prr > 1e-9 * np.max(prr))
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
        ref = Step(p.step_delay, r0 + p.step_size, before=r0)
        t_final = p.step_duration
    elif test == "sine":
        ref = Sine(p.sine_amplitude, p.sine_frequency, offset=r0)
        t_final = p.sine_periods / p.sine_frequency
    elif test == "disturbance":
        ref = Constant(r0)
        dist = Step(p.step_delay, p.disturbance_torque)
        t_final = p.step_duration
    else:
        f0, f1, T = p.sweep_start, p.sweep_stop, p.sweep_duration
        ref = Chirp(p.sweep_amplitude, f0, f1, T, offset=r0)
        t_final = T
        meta.update(f_low=f0, f_high=f1)
    run = _simulate(loop, ctx, t_final, dt, ref, dist, p.max_step, controller, test, meta)
    m = Metrics(controller, test)
    u = np.abs(run.command)
    m.peak_input = float(np.max(u))
    limit = loop.saturation
    if limit is None and isinstance(loop.rig, Rig) and loop.rig.torque_limit is not None:
        limit = np.full(u.shape[1], float(loop.rig.torque_limit))  # the rig's own amplifier limit
    if limit is not None:
        m.saturated_fraction = float(np.mean(np.any(u > limit[None, :] * (1 + 1e-9), axis=1)))
    if "tendon_force" in run.meta:
        m.slack_fraction = float(np.mean(np.any(run.meta["tendon_force"] <= 0.0, axis=1)))
    if test == "step":
        for k_, v in step_metrics(run.t, run.output, r0, r0 + p.step_size, p.step_delay,
                                 band=p.settling_band, fit=True).items():
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
    flag_run(m, p)
    return run, m


def flag_run(m: Metrics, params: CompareTestParams) -> Metrics:
    """Set ``m.flags`` / ``m.status`` from the metrics: a run that finished is not necessarily a success.

    Flags: ``saturated`` (saturated fraction > ``params.max_saturated_fraction``), ``slack`` (slack
    fraction > ``params.max_slack_fraction``), ``not settled`` (step test never enters the settling band),
    ``negative stiffness`` (disturbance test: the link moves *with* the load).
    """
    flags = []
    if m.saturated_fraction > params.max_saturated_fraction:
        flags.append(f"saturated {100 * m.saturated_fraction:.0f} %")
    if m.slack_fraction > params.max_slack_fraction:
        flags.append(f"slack {100 * m.slack_fraction:.0f} %")
    if m.test == "step" and not math.isfinite(m.settling_time):
        flags.append("not settled")
    if m.test == "disturbance" and m.stiffness < 0:
        flags.append("negative stiffness")
    m.flags = "; ".join(flags)
    if flags and m.status == "ok":
        m.status = "flagged"
    return m


def run_standard_tests(loop: ClosedLoop, *, controller: str = "controller", tests: Sequence[str] | None = None,
                       params: CompareTestParams | None = None,
                       progress: Callable[[str], Any] | None = None) -> tuple[list[TestRun], list[Metrics]]:
    """All applicable standard tests on one closed loop (``disturbance`` only with ``external_torque``).

    ``progress(label)`` is called after each test (e.g. to advance a progress bar).
    """
    p = params or compare_test_params(loop.rig)
    if tests is None:
        tests = [t for t in TESTS if t != "disturbance" or "external_torque" in loop.disturbances]
    settled = settle(loop, p.initial_reference, t_settle=p.settle_time, params=p)
    runs, rows = [], []
    for test in tests:
        try:
            run, m = run_test(loop, test, controller=controller, params=p, settled=settled)
        except SimulationDivergedError as exc:
            rows.append(Metrics(controller, test, status=f"diverged: {exc}"))
            if progress is not None:
                progress(f"{controller}/{test}")
            continue
        runs.append(run)
        rows.append(m)
        if progress is not None:
            progress(f"{controller}/{test}")
    return runs, rows


def compare(loops: Mapping[str, ClosedLoop], *, tests: Sequence[str] | None = None,
            params: CompareTestParams | None = None, progress: Callable[[str], Any] | None = None) -> Comparison:
    """Run the standard tests on every closed loop ``{name: loop}`` (``progress(label)`` after each test)."""
    if not loops:
        raise ValueError("compare: give at least one closed loop")
    runs, rows = [], []
    rig = ""
    for name, loop in loops.items():
        r, m = run_standard_tests(loop, controller=name, tests=tests, params=params, progress=progress)
        runs += r
        rows += m
        rig = getattr(loop.rig, "name", rig)
    return Comparison(runs, MetricsTable(rows), rig)


def compare_controllers(make_rig: Callable[[], Any], names: Sequence[str], *, tests: Sequence[str] | None = None,
                        params: CompareTestParams | None = None, progress: Callable[[str], Any] | None = None,
                        **loop_options: Any) -> Comparison:
    """Build each registered controller on a fresh rig from ``make_rig()`` and :func:`compare` them.

    ``loop_options`` (``rate_hz``, ``delay``, ``saturation``, ``sensors``) override the
    registry's defaults for :func:`awiwi_drake.control.base.closed_loop`.  Names are
    validated (unknown / not fitting the rig: ValueError) before any simulation.
    """
    from awiwi_drake.control.base import closed_loop
    from awiwi_drake.control.registry import get_entry
    names = list(names)
    if not names:
        raise ValueError("compare_controllers: give at least one controller name")
    probe = make_rig()
    entries = [get_entry(n, probe) for n in names]
    loops = {}
    for n, entry in zip(names, entries):
        rig = make_rig()
        opts = {**entry.loop_options, **loop_options}
        loops[n] = closed_loop(rig, entry.factory(rig), **opts)
    return compare(loops, tests=tests, params=params or compare_test_params(probe), progress=progress)


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


def fit_second_order_step(t, y, r0: float, r1: float, t_step: float = 0.0) -> dict[str, float]:
    """Least-squares fit of a delayed 2nd-order step ``r0 -> r1`` to ``y``: ``omega_n``, ``damping_ratio``.

    Robust to measurement noise (the overshoot-based estimate takes a noisy
    maximum).  Fitted parameters: natural frequency, damping ratio (0.05-3),
    final value and a dead time.
    """
    from scipy.optimize import least_squares
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    m = t >= t_step
    tt, e = t[m] - t_step, (y[m] - r0) / (r1 - r0)
    if len(tt) < 8:  # too few samples after the step (e.g. a very slow sampled loop): nothing to fit
        return dict(natural_frequency=math.nan, damping_ratio=math.nan, final=math.nan, dead_time=math.nan)

    def model(p):
        wn, z, fin, td = p
        s = np.clip(tt - td, 0.0, None)
        if z < 1.0:
            wd = wn * math.sqrt(1 - z * z)
            resp = 1 - np.exp(-z * wn * s) * (np.cos(wd * s) + z / math.sqrt(1 - z * z) * np.sin(wd * s))
        elif z == 1.0:
            resp = 1 - np.exp(-wn * s) * (1 + wn * s)
        else:
            a = wn * (z - math.sqrt(z * z - 1))
            b = wn * (z + math.sqrt(z * z - 1))
            resp = 1 - (b * np.exp(-a * s) - a * np.exp(-b * s)) / (b - a)
        return fin * resp

    i10 = int(np.argmax(e >= 0.5)) if np.any(e >= 0.5) else len(e) // 4
    wn0 = 1.7 / max(tt[max(i10, 1)], 1e-4)  # t_50 ~ 1.7 / wn for xi ~ 0.7
    best = None
    for z0 in (0.4, 0.7, 1.2):
        sol = least_squares(lambda p: model(p) - e, [wn0, z0, 1.0, 0.0],
                            bounds=([1e-3, _XI_BOUNDS[0], 0.5, 0.0], [1e5, _XI_BOUNDS[1], 1.5, 0.5 * tt[-1]]))
        if best is None or sol.cost < best.cost:
            best = sol
    wn, z, fin, td = best.x
    return dict(natural_frequency=float(wn), damping_ratio=float(z), final=float(fin), dead_time=float(td))
