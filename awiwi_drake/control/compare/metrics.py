"""Metrics of closed-loop responses (step, sine, chirp) and the metrics table: data in, numbers out."""

from __future__ import annotations

import csv
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Metrics", "MetricsTable", "COLUMNS", "NUMERIC", "UNITS", "step_metrics", "sine_metrics", "gain_diagram",
           "sweep_metrics", "disturbance_metrics", "response_bandwidth", "linear_bandwidth", "fit_second_order_step"]


@dataclass
class Metrics:
    """One row of the metrics table (NaN where a metric does not apply)."""

    controller: str
    test: str
    joint: str = ""                      # joint (DoF) of a finger/hand row; "link" / "tendon" on the 1-DoF rigs
    rise_time: float = math.nan          # s, 10-90 % of the step
    overshoot: float = math.nan          # % of the step size
    settling_time: float = math.nan      # s, band CompareTestParams.settling_band (2 %; 5 % on the tendon rig)
    steady_state_error: float = math.nan  # reference - output at the end [unit of the output]
    peak_input: float = math.nan         # max |torque applied to the motors| (after saturation) [Nm]
    peak_command: float = math.nan       # max |motor_torque_command| (before saturation) [Nm]
    stiffness: float = math.nan          # measured: load / deflection [Nm/rad]; NaN when the observer held the load
    design_stiffness: float = math.nan   # load test: the design's static stiffness of the DoF, 1 / (K^-1)_jj [Nm/rad]
    load_torque: float = math.nan        # load test: the external torque step on the DoF [Nm]
    friction_bound: float = math.nan     # load test: the friction observer's bound B of the DoF at the end [Nm]
    drift: float = math.nan              # disturbance test: end slope x time since the load step [unit of the output]
    damping_ratio: float = math.nan      # of a 2nd-order model fitted to the step response
    tracking_rms: float = math.nan       # RMS tracking error (sine)
    gain: float = math.nan               # |Y/R| at the sine frequency
    phase_deg: float = math.nan          # phase of Y/R at the sine frequency
    peak_gain: float = math.nan          # max |Y/R| over the sweep
    resonance_hz: float = math.nan       # frequency of the peak gain (NaN: peak at an end of the sweep)
    bandwidth_hz: float = math.nan       # -3 dB of |Y/R| below its DC / low-frequency value (see bandwidth_source)
    bandwidth_source: str = ""           # "linearization" (continuous loops) or "chirp" (log-spaced estimate)
    saturated_fraction: float = math.nan  # fraction of samples with the command beyond the torque limit
    saturated_time: float = math.nan     # time the command is beyond the torque limit (samples x period) [s]
    slack_fraction: float = math.nan     # fraction of samples with a slack tendon (tension-only rigs)
    estimation_error: float = math.nan   # max |joint angle estimate - true| of the DoF's joint (fingers/hand) [rad];
    #                                      with ideal sensors the estimator's beside the loop (not fed back); NaN:
    #                                      no estimator (a controller that reads no joint angle, e.g. joint-pd)
    dead_band: float = math.nan          # friction dead band of the DoF, closed form of the controller's rest
    #                                      equations (design.dead_band; the 15.5 finger backstepping) [rad]
    failed_at: float = math.nan          # s, test time at which the simulation stopped (status a failure cause)
    status: str = "ok"                   # "ok", "flagged" (see flags), or the cause that stopped the simulation
    #                                      (metrics NaN): "diverged", "infeasible_force", a monitor's event kind
    flags: str = ""                      # "; "-separated: saturated, command peak, slack, not settled, negative
    #                                      stiffness, stiffness off its design, load kept linear, load held,
    #                                      force distribution out of bounds (finger/hand chain), stopped within
    #                                      friction dead band (design.friction_hold <= 1); a stopped
    #                                      row: the error's message


COLUMNS = [f for f in Metrics.__dataclass_fields__]


NUMERIC = [c for c in COLUMNS if c not in ("controller", "test", "joint", "bandwidth_source", "status", "flags")]


UNITS = dict(rise_time="s", overshoot="%", settling_time="s", steady_state_error="ref", peak_input="Nm",
             peak_command="Nm",
             stiffness="Nm/rad", design_stiffness="Nm/rad", load_torque="Nm", friction_bound="Nm", drift="ref", damping_ratio="-", tracking_rms="ref", gain="-", phase_deg="deg",
             peak_gain="-", resonance_hz="Hz", bandwidth_hz="Hz", saturated_fraction="-", saturated_time="s",
             slack_fraction="-", estimation_error="rad", dead_band="rad", failed_at="s")


@dataclass
class MetricsTable:
    """Rows of :class:`Metrics`; CSV/Markdown export and lookup."""

    rows: list[Metrics] = field(default_factory=list)

    def get(self, controller: str, test: str, joint: str | None = None) -> Metrics:
        for r in self.rows:
            if r.controller == controller and r.test == test and (joint is None or r.joint == joint):
                return r
        raise KeyError(f"no metrics for controller {controller!r}, test {test!r}"
                       + (f", joint {joint!r}" if joint is not None else ""))

    def column(self, name: str, test: str, joint: str | None = None) -> dict[str, float]:
        if name not in NUMERIC:
            raise ValueError(f"unknown metric {name!r}; known: {', '.join(NUMERIC)}")
        return {r.controller: getattr(r, name) for r in self.rows
                if r.test == test and (joint is None or r.joint == joint)}

    def failed(self) -> list[Metrics]:
        """The rows whose simulation stopped on a physical failure (status neither ``ok`` nor ``flagged``)."""
        return [r for r in self.rows if r.status not in ("ok", "flagged")]

    def joints(self) -> list[str]:
        """The joints of the rows, in order of appearance."""
        return list(dict.fromkeys(r.joint for r in self.rows))

    def to_csv(self, path: str | Path) -> Path:
        path = Path(path)
        with path.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=COLUMNS)
            w.writeheader()
            for r in self.rows:
                w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in asdict(r).items()})
        return path

    def to_markdown(self, ref_unit: str = "ref") -> str:
        """Markdown tables per test; ``ref_unit`` names the unit of the tracked output
        (``rad`` for the link rigs, ``N`` for the tendon rig) in the column headers."""
        def unit(c):
            u = UNITS[c]
            if c in ("gain", "peak_gain"):
                return f"{ref_unit}/{ref_unit}" if ref_unit != "ref" else u
            return ref_unit if u == "ref" else u

        lines = []
        for test in dict.fromkeys(r.test for r in self.rows):
            rows = [r for r in self.rows if r.test == test]
            cols = [c for c in NUMERIC if any(math.isfinite(getattr(r, c)) for r in rows)]
            lines.append(f"### {test}\n")
            src = any(r.bandwidth_source for r in rows)
            header = ["controller", "joint", *(f"{c} [{unit(c)}]" for c in cols),
                      *(["bandwidth_source"] if src else []), "status"]
            lines.append("| " + " | ".join(header) + " |")
            lines.append("|---" * len(header) + "|")
            for r in rows:
                status = f"{r.status}: {r.flags}" if r.flags else r.status
                cells = [r.controller, r.joint, *(_fmt(getattr(r, c)) for c in cols),
                         *([r.bandwidth_source or "-"] if src else []), status]
                lines.append("| " + " | ".join(cells) + " |")
            lines.append("")
        return "\n".join(lines)


def _fmt(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{v:.4g}"


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


def disturbance_metrics(t: np.ndarray, y: np.ndarray, r0: float, t_step: float, torque: float) -> dict[str, float]:
    """Stiffness, end error and end drift of the response to a load step ``torque`` at ``t_step``.

    The deflection is the mean over the last 10 % of the run minus the mean before the step; ``drift`` is
    the least-squares slope over that last 10 % times the time since the step: how far the output would
    still move at its end rate over the whole test. A loop without static stiffness (an integrator in the
    joint's torque path) keeps drifting, and :func:`flag_run` flags it ``not settled`` instead of
    reporting its end value as a steady-state error.
    """
    t, y = np.asarray(t, float), np.asarray(y, float)
    pre, tail = t < t_step, t >= t[-1] - 0.1 * t[-1]
    y_end = float(np.mean(y[tail]))
    dq = y_end - float(np.mean(y[pre]))
    slope = float(np.polyfit(t[tail], y[tail], 1)[0]) if np.count_nonzero(tail) > 1 else 0.0
    return dict(stiffness=torque / dq if dq != 0 else math.inf, steady_state_error=float(r0 - y_end),
                drift=abs(slope) * (t[-1] - t_step))


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


def gain_diagram(t, r, y, f_low: float, f_high: float, *, per_decade: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Gain |Y/R| of a swept-sine (chirp) test at ``per_decade`` log-spaced frequencies in [f_low, f_high].

    At each frequency ``f`` the Fourier transforms of the whole (mean-removed)
    records are evaluated directly (not on the FFT's linear ``1 / T`` bins), and
    the auto/cross spectra are averaged over ``f - 1/T, f, f + 1/T`` to tame the
    ripple of the finite chirp; ``|Y/R| = |P_ry| / P_rr``.  Frequencies where
    the reference carries no energy (``P_rr`` below 1e-9 of its maximum) are
    dropped.
    """
    t, r, y = (np.asarray(a, float) for a in (t, r, y))
    if len(t) < 16:
        raise ValueError("gain_diagram: need at least 16 samples")
    if not (0.0 < f_low < f_high):
        raise ValueError(f"gain_diagram: need 0 < f_low < f_high, got f_low={f_low}, f_high={f_high}")
    span = t[-1] - t[0] + float(np.median(np.diff(t)))
    n = max(2, int(math.ceil(per_decade * math.log10(f_high / f_low))) + 1)
    f = np.logspace(math.log10(f_low), math.log10(f_high), n)
    r0, y0 = r - np.mean(r), y - np.mean(y)
    prr = np.zeros(n)
    pry = np.zeros(n, complex)
    tt = t - t[0]
    shift = np.exp(-2j * np.pi * np.outer(tt, (-1.0 / span, 0.0, 1.0 / span)))  # f -> f - 1/T, f, f + 1/T
    rs, ys = r0[:, None] * shift, y0[:, None] * shift
    for i in range(0, n, 64):                                      # DTFT at arbitrary frequencies, in chunks
        E = np.exp(-2j * np.pi * np.outer(f[i:i + 64], tt))
        R, Y = E @ rs, E @ ys
        prr[i:i + 64] = np.sum(np.abs(R) ** 2, axis=1)
        pry[i:i + 64] = np.sum(np.conj(R) * Y, axis=1)
    m = prr > 1e-9 * np.max(prr)
    return f[m], np.abs(pry[m] / prr[m])


def response_bandwidth(f, g, level: float) -> float:
    """First frequency where the gain ``g(f)`` falls below ``level``, interpolated in log frequency
    between the grid points; NaN when it never does (never the first grid point)."""
    f, g = np.asarray(f, float), np.asarray(g, float)
    below = np.nonzero(g < level)[0]
    below = below[below > 0]
    if not len(below):
        return math.nan
    k = int(below[0])
    a = (g[k - 1] - level) / (g[k - 1] - g[k])
    return float(np.exp(np.log(f[k - 1]) + a * (np.log(f[k]) - np.log(f[k - 1]))))


def sweep_metrics(f, g) -> dict[str, float]:
    """Peak gain, its frequency (the resonance; NaN when the peak sits at the top end of the sweep or
    in its lowest 5 % of the log-frequency span, i.e. the diagram has no interior maximum) and the -3 dB bandwidth of a measured gain diagram ``g(f)``
    (``f`` log-spaced, as :func:`gain_diagram` returns it).

    The bandwidth is where ``|Y/R|`` first falls below ``1/sqrt(2)`` of its
    low-frequency value (the mean over the lowest 5 % of the log-frequency span),
    interpolated in log frequency (:func:`response_bandwidth`); NaN when the gain
    never falls that low in the sweep.  (A corner within the lowest 5 % of the
    span reads high: the sweep does not see the DC gain; a loop that can be
    linearised gets :func:`linear_bandwidth` instead.)
    """
    if len(f) == 0:
        return {}
    f, g = np.asarray(f, float), np.asarray(g, float)
    i = int(np.argmax(g))
    low = f <= f[0] * (f[-1] / f[0]) ** 0.05
    bw = response_bandwidth(f, g, float(np.mean(g[low])) / math.sqrt(2.0))
    # a peak at the top end of the sweep or within its low-frequency band (where the level is taken and the
    # chirp's start ripples) is no resonance inside it (a monotone diagram): NaN, not a grid point there
    res = float(f[i]) if (not low[i]) and i < len(f) - 1 else math.nan
    return dict(peak_gain=float(g[i]), resonance_hz=res, bandwidth_hz=bw)


def linear_bandwidth(lin, output=None, *, per_decade: int = 100) -> float:
    """-3 dB bandwidth [Hz] of a linearised loop (a
    :class:`~awiwi_drake.analysis.LinearizationResult` from the reference to the tracked output).

    ``|H(j w)|`` (:meth:`~awiwi_drake.analysis.LinearizationResult.bode`) on a log-spaced grid
    from a decade below the slowest pole to a decade above the fastest (``per_decade`` points
    per decade) brackets the first frequency where it falls below ``|H(0)| / sqrt(2)``; Brent's
    method on ``|H(j w)|`` then finds it to 1e-10.  NaN when ``H(0)`` is not finite and non-zero
    (a pole at the origin) or the gain never falls that low.
    """
    from scipy.optimize import brentq

    def H(w: float) -> complex:
        return complex(lin.bode(0, output, omega=[w]).response[0])

    mags = np.abs(np.asarray(lin.poles))
    if mags.size and mags.min() == 0.0:      # a pole at the origin: no finite DC gain
        return math.nan
    lo, hi = (0.1 * mags.min(), 10.0 * mags.max()) if mags.size else (1e-3, 1e3)
    dc = abs(H(1e-6 * lo))                    # |H(0)| to ~1e-12 relative
    if not (math.isfinite(dc) and dc > 0.0):
        return math.nan
    w = np.logspace(math.log10(lo), math.log10(hi), max(2, int(per_decade * math.log10(hi / lo)) + 1))
    g = np.abs(lin.bode(0, output, omega=w).response)
    level = dc / math.sqrt(2.0)
    below = np.nonzero(g < level)[0]
    if not len(below) or below[0] == 0:
        return math.nan
    k = int(below[0])
    wb = brentq(lambda x: abs(H(x)) - level, w[k - 1], w[k], xtol=1e-12, rtol=1e-10)
    return float(wb / (2 * math.pi))


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
