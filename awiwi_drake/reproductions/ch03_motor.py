"""Thesis ch. 3: motor friction identification (Fig 3.3) and ripple compensation (Fig 3.5-3.6).

* Friction (Fig 3.3): the motor follows piecewise-constant velocities (:func:`friction_identification_data`) and
  (3.8) ``tau(w) = gamma2 atan(gamma1 w) + gamma3 w`` is fitted to the mean commanded torques (:func:`fit_friction`)
  that balance the friction.
* Ripple (Fig 3.5-3.6): at constant speed the position-dependent ripple shows in the controller torque at the motor
  rotation frequency; it is identified from that torque (:func:`identify_ripple`) and fed forward with a
  conservative amplitude (``amplitude_scale`` < 1, ch. 3: over-compensation injects energy); the success metric is
  the attenuation of the first harmonic of the feedback torque (:func:`ripple_compensation_experiment`).

The controller is :class:`awiwi_drake.control.motor_compensation.MotorPdLaw`; the plant
:func:`awiwi_drake.rigs.motor_rig`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from awiwi_drake.analysis import Ramp, simulate
from awiwi_drake.components import atan_friction, motor_friction_torque
from awiwi_drake.control.base import StaticLawController, closed_loop
from awiwi_drake.control.motor_compensation import MotorPdLaw
from awiwi_drake.parameters.components import MotorParams
from awiwi_drake.parameters.control import CONTROL_RATE_HZ, FrictionIdentificationParams, RippleCompensationParams
from awiwi_drake.plotting import figure_axes, label_axes, plot_traces
from awiwi_drake.rigs import motor_rig

__all__ = ["ConstantVelocityRun", "constant_velocity_run", "FrictionData", "FrictionFit", "friction_identification_data", "fit_friction",
           "identify_ripple", "harmonic", "amplitude_spectrum", "RippleCompensationResult",
           "ripple_compensation_experiment", "plot_spectra", "plot_friction_fit", "InertiaIdentification",
           "inertia_identification", "friction_curve_in_ampere"]


@dataclass
class ConstantVelocityRun:
    """A motor run at constant speed, one row per control period ``k`` (``[t_k, t_k+1)``): ``t`` (midpoint)
    [s], ``theta`` [rad] / ``omega`` [rad/s] (midpoint values), ``command`` (the torque applied during the
    period) [Nm], ``feedback`` (its PD part, i.e. without the feed-forward) [Nm], ``acceleration`` (mean over
    the period) [rad/s^2]."""

    t: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    command: np.ndarray
    feedback: np.ndarray
    acceleration: np.ndarray

    def plot(self, ax=None):
        """Applied torque and its PD part over time (Fig 3.5a)."""
        return plot_traces(self.t, {"applied torque": self.command, "PD part (feedback)": self.feedback},
                           ylabel="motor torque [Nm]", ax=ax)


def constant_velocity_run(motor: MotorParams, speed: float, duration: float, *, kp: float, kd: float,
                          theta0: float = 0.0, friction_scale: float = 0.0, ripple: MotorParams | None = None,
                          rate_hz: float = CONTROL_RATE_HZ, start_at_rest: bool = False) -> ConstantVelocityRun:
    """The motor following ``theta0 + speed t`` under a sampled PD (one row per control period).

    ``start_at_rest``: the motor starts at rest with zero torque in the hold buffer (an experiment that
    knows nothing about the friction it is about to identify); otherwise it starts at ``speed`` with the
    (model) friction torque held, which removes the start transient (ripple study).

    Returns a :class:`ConstantVelocityRun` (one row per control period).
    """
    rig = motor_rig(motor)
    law = MotorPdLaw(motor, kp, kd, friction_scale=friction_scale, ripple=ripple)
    loop = closed_loop(rig, StaticLawController(law), rate_hz=rate_hz)
    u0 = 0.0 if start_at_rest else float(-motor_friction_torque(np.array([speed]), motor)[0])
    ctx = loop.create_context(state=[theta0, 0.0 if start_at_rest else speed], motor_torque=u0,
                              references={"motor_angle_reference": theta0, "motor_velocity_reference": speed})
    dt = 1.0 / rate_hz
    log = simulate(loop, ctx, duration, inputs={"motor_angle_reference": Ramp(0.0, duration, theta0, theta0 + speed * duration),
                                                "motor_velocity_reference": speed},
                   log=("motor_angle", "motor_velocity", "motor_torque"), log_period=dt)
    th, w = log["motor_angle"][:, 0], log["motor_velocity"][:, 0]
    applied = log["motor_torque"][1:, 0]  # left limit at t_k+1 = torque held on [t_k, t_k+1)
    ff = np.array([float(np.ravel(law.feedforward(a, b))[0]) for a, b in zip(th[:-1], w[:-1])])
    return ConstantVelocityRun(t=0.5 * (log.t[1:] + log.t[:-1]), theta=0.5 * (th[1:] + th[:-1]),
                               omega=0.5 * (w[1:] + w[:-1]), command=applied, feedback=applied - ff,
                               acceleration=np.diff(w) / dt)


@dataclass
class FrictionData:
    """Mean (min, max) commanded torque per velocity plateau (Fig 3.3b)."""

    speed: np.ndarray
    torque: np.ndarray
    torque_min: np.ndarray
    torque_max: np.ndarray


@dataclass(frozen=True)
class FrictionFit:
    """(3.8) parameters ``gamma1`` [s/rad], ``gamma2`` [Nm], ``gamma3`` [Nm s/rad] and the fit residual."""

    gamma1: float
    gamma2: float
    gamma3: float
    rms_residual: float

    def torque(self, omega):
        """Torque needed to turn at ``omega`` (= minus the friction torque (3.8))."""
        return -atan_friction(np.asarray(omega, float), self.gamma2, self.gamma1, self.gamma3)


def friction_identification_data(motor: MotorParams, params: FrictionIdentificationParams | None = None, *,
                                 seed: int = 0) -> FrictionData:
    """Simulated Fig 3.3 protocol: forward and backward plateaus at log-spaced speeds, noisy torque readings.

    Each plateau starts with the motor at rest and zero torque (nothing about the friction is assumed); the start
    transient is discarded (``settle_fraction``); the mean is over whole periods of the motor-shaft ripple, and the
    backward pass covers the forward pass's angles.
    """
    p = params or FrictionIdentificationParams()
    rng = np.random.default_rng(seed)
    speeds = np.geomspace(p.min_speed, p.max_speed, p.num_speeds)
    period = 2 * math.pi / motor.gear_ratio  # motor-shaft ripple period at the output [rad]
    rows = []      # (speed, mean, min, max torque) per plateau
    for v in speeds:
        travel = v * p.plateau_time
        for sign, th0 in ((1.0, 0.0), (-1.0, travel)):  # forward, then back over the same angles
            run = constant_velocity_run(motor, sign * v, p.plateau_time, kp=p.position_gain, kd=p.velocity_gain,
                                        theta0=th0, start_at_rest=True)
            tau = run.command + rng.normal(0.0, p.torque_noise_std, size=run.command.shape)
            t_steady = p.settle_fraction * p.plateau_time
            steady = run.t >= t_steady
            n_per = math.floor(v * (p.plateau_time - t_steady) / period)
            if n_per >= 1:  # whole ripple periods only
                steady &= run.t < t_steady + n_per * period / v
            rows.append((sign * v, np.mean(tau[steady]), np.min(tau[steady]), np.max(tau[steady])))
    rows = np.array(rows, dtype=float)
    return FrictionData(*rows[np.argsort(rows[:, 0])].T)


def fit_friction(speed, torque) -> FrictionFit:
    """Least-squares fit of (3.8) ``tau = gamma2 atan(gamma1 w) + gamma3 w`` to plateau means."""
    from scipy.optimize import least_squares
    w = np.asarray(speed, float)
    tau = np.asarray(torque, float)
    if w.shape != tau.shape or w.size < 3:
        raise ValueError("fit_friction: need >= 3 (speed, torque) pairs of equal length")
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(tau))):
        raise ValueError("fit_friction: speeds and torques must be finite")
    fast = np.abs(w) >= np.percentile(np.abs(w), 50)
    g3, c = np.polyfit(np.abs(w[fast]), np.sign(w[fast]) * tau[fast], 1)
    x0 = [5.0 / max(np.min(np.abs(w)), 1e-3) ** 0.5, max(2 * c / math.pi, 1e-3), max(g3, 1e-4)]
    sol = least_squares(lambda g: -atan_friction(w, g[1], g[0], g[2]) - tau, x0, bounds=([1e-3, 0, 0], np.inf),
                        x_scale="jac")
    g1, g2, g3 = sol.x
    return FrictionFit(float(g1), float(g2), float(g3), float(np.sqrt(np.mean(sol.fun ** 2))))


def harmonic(t, y, freq_hz: float) -> complex:
    """Complex amplitude of ``y`` at ``freq_hz`` (least squares on sin/cos + mean + linear trend)."""
    t = np.asarray(t, float)
    A = np.column_stack([np.sin(2 * np.pi * freq_hz * t), np.cos(2 * np.pi * freq_hz * t), np.ones_like(t), t])
    c = np.linalg.lstsq(A, np.asarray(y, float), rcond=None)[0]
    return complex(c[0], c[1])


def amplitude_spectrum(t, y) -> tuple[np.ndarray, np.ndarray]:
    """Single-sided amplitude spectrum |Y(f)| of the mean-removed signal (Hann window, amplitude-corrected)."""
    y = np.asarray(y, float) - np.mean(y)
    win = np.hanning(len(y))
    Y = np.fft.rfft(y * win) * 2.0 / np.sum(win)
    return np.fft.rfftfreq(len(y), float(np.median(np.diff(t)))), np.abs(Y)


def identify_ripple(run: ConstantVelocityRun, motor: MotorParams) -> MotorParams:
    """Ripple from a constant-speed run by the torque balance of (3.5): ``motor`` with the identified
    motor-shaft ripple (``ripple_motor_amplitude``, ``ripple_motor_phase``) as its only ripple.

    ``tau_r(theta) = B thdd - u - tau_fric(thd)`` per control period, regressed on
    ``sin(N theta), cos(N theta)`` at the known period (the phase follows from
    the measured angle) plus a constant and a linear term in ``theta`` (they
    absorb the slow output-bearing component over a fraction of a revolution).
    """
    resid = motor.inertia * run.acceleration - run.command - motor_friction_torque(run.omega, motor)
    c = harmonic(run.theta, resid, motor.gear_ratio / (2 * math.pi))    # the angle as "time": sin/cos(N theta)
    return motor.replace(ripple=True, ripple_motor_amplitude=float(abs(c)),
                         ripple_motor_phase=float(math.atan2(c.imag, c.real)), ripple_output_amplitude=0.0,
                         ripple_harmonics=())


@dataclass
class RippleCompensationResult:
    """Spectra of the feedback torque without/with compensation and the first-harmonic attenuation."""

    frequency: np.ndarray
    spectrum_without: np.ndarray
    spectrum_with: np.ndarray
    first_harmonic_hz: float
    amplitude_without: float
    amplitude_with: float
    estimate: MotorParams
    run_without: ConstantVelocityRun | None = None
    run_with: ConstantVelocityRun | None = None

    @property
    def attenuation(self) -> float:
        """|A_with| / |A_without| at the motor rotation frequency (0 = removed, 1 = unchanged)."""
        return self.amplitude_with / self.amplitude_without

    def plot(self, ax=None, **kw):
        """Fig 3.6b (:func:`plot_spectra`)."""
        return plot_spectra(self, ax=ax, **kw)


def ripple_compensation_experiment(motor: MotorParams | None = None,
                                   params: RippleCompensationParams | None = None) -> RippleCompensationResult:
    """Fig 3.5-3.6: constant speed, PD with friction compensation, ripple feed-forward off/on."""
    p = params or RippleCompensationParams()
    m = motor or MotorParams(ripple=True)
    if not m.ripple:
        raise ValueError("ripple_compensation_experiment: motor.ripple is off; nothing to compensate")
    common = dict(kp=p.position_gain, kd=p.velocity_gain, friction_scale=1.0)
    before = constant_velocity_run(m, p.speed, p.duration, **common)
    estimate = identify_ripple(before, m)
    after = constant_velocity_run(m, p.speed, p.duration, **common,
                                  ripple=estimate.replace(ripple_motor_amplitude=p.amplitude_scale
                                                          * estimate.ripple_motor_amplitude))
    f1 = m.gear_ratio * p.speed / (2 * math.pi)  # motor rotation frequency [Hz]
    f, s0 = amplitude_spectrum(before.t, before.feedback)
    _, s1 = amplitude_spectrum(after.t, after.feedback)
    a0 = abs(harmonic(before.t, before.feedback, f1))
    a1 = abs(harmonic(after.t, after.feedback, f1))
    return RippleCompensationResult(f, s0, s1, f1, a0, a1, estimate, before, after)


def plot_spectra(result, *, fmax: float = 60.0, ax=None):
    """Fig 3.6b: amplitude spectrum of the feedback torque without/with ripple compensation."""
    fig, ax = figure_axes(ax, figsize=(7, 4))
    m = result.frequency <= fmax
    ax.plot(result.frequency[m], result.spectrum_without[m], label="without compensation")
    ax.plot(result.frequency[m], result.spectrum_with[m], label="with compensation")
    ax.axvline(result.first_harmonic_hz, color="k", ls=":", lw=0.8, label="motor rotation frequency")
    label_axes(ax, "|Y(f)| [Nm]", xlabel="frequency [Hz]",
               title=f"first harmonic attenuated to {100 * result.attenuation:.0f} %")
    return fig, ax


def plot_friction_fit(data, fit, *, true=None, ax=None):
    """Fig 3.3b: plateau torques (mean, min-max) and the fitted (3.8)."""
    fig, ax = figure_axes(ax, figsize=(7, 4))
    ax.errorbar(data.speed, data.torque, yerr=[data.torque - data.torque_min, data.torque_max - data.torque],
                fmt="o", ms=4, capsize=2, label="plateau mean (min/max)")
    w = np.linspace(np.min(data.speed), np.max(data.speed), 400)
    ax.plot(w, fit.torque(w), label=f"fit (3.8): g1={fit.gamma1:.2f}, g2={fit.gamma2:.3f}, g3={fit.gamma3:.4f}")
    if true is not None:
        ax.plot(w, true(w), "k--", lw=0.8, label="simulated motor")
    label_axes(ax, "motor torque [Nm]", xlabel="motor velocity [rad/s]", legend=dict(fontsize=8))
    return fig, ax


# ----------------------------------------------------------------------------
# (3.6): inertia from a current step; Fig 3.3b in ampere
@dataclass
class InertiaIdentification:
    """(3.6) ``B thdd = tau_m`` fitted to current-step responses of the simulated motor.

    ``current`` [A] per step, ``identified`` [kg m^2] per step (least squares of
    ``theta(t) = theta0 + k_t i t^2 / (2 B)`` over the window, friction neglected as in the
    thesis), ``true`` the motor's B, ``friction_at_start`` the Coulomb torque the fit ignores.
    """

    current: np.ndarray
    identified: np.ndarray
    true: float
    friction_at_start: float
    acceleration: np.ndarray = None

    @property
    def relative_error(self) -> np.ndarray:
        return self.identified / self.true - 1.0

    @property
    def from_difference(self) -> float:
        """B from the slope of acceleration over torque between the steps (least squares): the
        Coulomb friction, equal for all steps of one sign, drops out."""
        tau = self.current * (self.identified * self.acceleration / self.current)   # k_t i
        A = np.vstack([tau, np.ones_like(tau)]).T
        slope = np.linalg.lstsq(A, self.acceleration, rcond=None)[0][0]
        return float(1.0 / slope)


def inertia_identification(currents=(1.0, 1.5, 2.5), *, window: float = 0.01,
                           motor: MotorParams | None = None) -> InertiaIdentification:
    """(3.6): step the motor current from rest, fit B on ``window`` seconds (friction neglected).

    The simulated motor has the (3.8) friction, which the thesis's identification neglects: the fit
    returns ``B k_t i / (k_t i - tau_f)``-ish values, biased up by the Coulomb part at small currents
    (a sizing rule for the experiment, not given in the thesis).
    """
    from awiwi_drake.analysis import simulate
    p = motor or MotorParams()
    rig = motor_rig(p)
    out = []
    for i in currents:
        tau = p.torque_constant * float(i)
        if abs(tau) > p.torque_limit:
            raise ValueError(f"inertia_identification: current {i} A needs {tau:.3g} Nm, beyond the "
                             f"motor's torque_limit {p.torque_limit} Nm")
        ctx = rig.diagram.CreateDefaultContext()
        ctx.SetContinuousState([0.0, 0.0])
        rig.diagram.GetInputPort("motor_torque").FixValue(ctx, [tau])
        res = simulate(rig.diagram, ctx, window, log=("motor_angle",), max_step=window / 500, accuracy=1e-9)
        t, th = res.t, res["motor_angle"][:, 0]
        a = float(np.sum(th * t ** 2 / 2) / np.sum((t ** 2 / 2) ** 2))     # least squares theta = a t^2 / 2
        out.append((tau / a, a))
    out = np.array(out)
    coulomb = -atan_friction(1e3, p.coulomb_torque, p.friction_slope, 0.0) if p.friction else 0.0   # atan saturated
    return InertiaIdentification(np.asarray(currents, float), out[:, 0], p.inertia, float(coulomb), out[:, 1])


def friction_curve_in_ampere(speeds, motor: MotorParams | None = None) -> np.ndarray:
    """Fig 3.3b's axis: the (3.8) friction torque at ``speeds`` [rad/s] as motor current [A]."""
    p = motor or MotorParams()
    return -atan_friction(np.asarray(speeds, float), p.coulomb_torque, p.friction_slope,
                          p.viscous_friction) / p.torque_constant
