"""Hidden-effect truth datasets: the test bench of the discrepancy workflow.

A truth plant (:class:`HiddenEffectPlant_`) runs in closed loop with a discrete
PD motor controller at the logging rate, driven by lab excitations
(multisine, chirp, steps, slow reversals).  Hidden effects are switched into
the plant in forms that deliberately differ from the catalog forms where
physics allows, so that identifying them is not circular:

================== ================================================================
``motor_friction``   Stribeck: ``-(Fc + (Fs - Fc) exp(-(w/vs)^2)) tanh(w/eps) - s2 w``
``motor_ripple``     two harmonics at orders drawn from {1..6, 100} per rev, random phase
``spring_hysteresis`` Bouc-Wen (n = 1, beta = 0.7, gamma = 0.3) offset on the spring force
``joint_friction``   Stribeck at the link
``guide_friction``   capstan ``f (exp(mu_a sgn v) - 1)`` plus constant (4.1) part
``delay``            exact delay of the zero-order-hold command (interval split)
``spring_drift``     creep: spring force scaled by ``1 + c (1 - exp(-t / tau))`` (catalog: linear)
``backlash``         play at the joint, massless pulley solved exactly, hard stops (catalog: one Newton step, rounded)
================== ================================================================

Effects **outside the catalog** (``UNKNOWN_EFFECTS``, the benchmark's ``unknown`` row; no catalog
entry models them, sizes in :class:`~awiwi_drake.parameters.discrepancy.TruthGeneratorParams`):

====================== ============================================================================
``link_spring``          link-side spring (a cable or skin) ``-k_j q`` on the joint (joint rig)
``torque_constant``      applied torque ``(1 + e) u``: dividing the motor equation by ``1 + e`` shows it is
                         exactly ``nominal_motor`` + ``nominal_spring`` + ``nominal_link`` + a ``force_sensor``
                         gain (all calibrations), never one physical effect
``force_nonlinearity``   force sensors read ``f (1 + c f)`` (quadratic gain)
``force_pickup``         mains pickup ``A sin(2 pi 50 t + phi)`` on one force signal (periodic in time,
                         not in motor angle)
====================== ============================================================================

``strength`` scales every hidden effect's size (friction levels, ripple and
hysteresis amplitudes, guide friction, delay, creep) for half-strength studies.

Sensor noise is white at a given SNR (relative to each signal's standard
deviation); forces are quantised to 12 bit over the sensor range.
"""

from __future__ import annotations

import sys

import numpy as np
from pydrake.systems.framework import DiagramBuilder, LeafSystem_
from pydrake.systems.primitives import ZeroOrderHold
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import clip, positive_part
from awiwi_drake.analysis import Samples, simulate
from awiwi_drake.components.friction import guide_friction, stribeck_friction
from awiwi_drake.components.spring import PolynomialSpring
from awiwi_drake.control import closed_loop
from awiwi_drake.control.motor_position import motor_position_controller
from awiwi_drake.discrepancy.catalog import PLACED_EFFECTS
from awiwi_drake.parameters.discrepancy import TruthGeneratorParams
from awiwi_drake.parameters.rigs import MotorPositionGains
from awiwi_drake.rigs.base import OperatingPoint, Rig, state_names

from . import laws
from .catalog import EFFECTS
from .data import RIGS, Dataset
from .model import NominalParameters, rig_kinematics, split_state

__all__ = ["HiddenEffectPlant_", "HIDDEN_EFFECTS", "UNKNOWN_EFFECTS", "draw_truth", "make_truth_dataset",
           "default_nominal", "ripple_draw", "sensor_reading", "stribeck_draw"]

HIDDEN_EFFECTS = ("motor_friction", "motor_ripple", "spring_hysteresis", "joint_friction",
                  "guide_friction", "delay", "spring_drift", "backlash")
NUISANCES = ("force_sensor", "nominal_motor")
UNKNOWN_EFFECTS = ("link_spring", "torque_constant", "force_nonlinearity", "force_pickup")
"""Truth effects no catalog entry models (see the module docstring); ``unknown=`` of :func:`make_truth_dataset`."""


def default_nominal(rig: str) -> dict:
    """Nominal dataset ``parameters`` of ``rig`` (centre of the random draw), from :class:`TruthGeneratorParams`."""
    g = TruthGeneratorParams()
    p = {"motor_inertia": g.motor_inertia, "motor_damping": g.motor_damping,
         "motor_pulley_radius": g.motor_pulley_radius, "spring_poly": list(g.spring_poly)}
    if rig == "joint-rig":
        p.update(link_inertia=g.link_inertia, link_damping=g.link_damping, link_pulley_radius=g.link_pulley_radius)
    return p


@TemplateSystem.define("HiddenEffectPlant_", scope=sys.modules[__name__])
def HiddenEffectPlant_(T):

    class Impl(LeafSystem_[T]):
        """Truth rig with hidden effects; state ``[(q, q'), theta, omega, z]`` (the rigs' order), input
        ``motor_torque`` (applied), outputs ``measurement`` ``[theta, f, (q)]``, ``state``, and the
        controller's measurements ``motor_angle``, ``motor_velocity``, ``tendon_force``."""

        def _construct(self, nominal: NominalParameters, truth: dict, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self._nom = nominal
            self._truth = dict(truth)
            n = nominal.num_motors
            self._ns = nominal.num_states
            self.DeclareContinuousState(self._ns)
            self.DeclareVectorInputPort("motor_torque", n)
            self.DeclareVectorOutputPort("measurement", nominal.num_measurements, self._calc_y,
                                         prerequisites_of_calc={self.all_state_ticket()})
            self.DeclareVectorOutputPort("state", self._ns, self._calc_x,
                                         prerequisites_of_calc={self.all_state_ticket()})
            for name, calc in (("motor_angle", lambda X, c: self._split(X)[0]),
                               ("motor_velocity", lambda X, c: self._split(X)[1]),
                               ("tendon_force", lambda X, c: self._forces(X, c.get_time())[0])):
                self.DeclareVectorOutputPort(
                    name, n, lambda c, o, calc=calc: o.SetFromVector(
                        np.array(calc(c.get_continuous_state_vector().CopyToVector(), c))),
                    prerequisites_of_calc={self.all_state_ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._nom, other._truth, converter=converter)

        def _split(self, X):
            return split_state(self._nom, X)

        def _pulley_angle(self, theta, q, b):
            """Joint backlash, exact for a massless pulley with hard stops (the catalog: one Newton
            step and rounded stops): the tendons' torque on the pulley vanishes at ``q_p0`` (Newton
            to convergence from the link angle), the stops hold it within ``q +- b``."""
            nom = self._nom
            r, rq = nom.motor_pulley_radius, nom.link_pulley_radius
            spring = PolynomialSpring(nom.spring_poly)
            qp = q
            for _ in range(6):
                x = np.array([r * theta[0] - rq * qp, r * theta[1] + rq * qp])
                f, k = spring.force(x), spring.stiffness(x)
                qp = qp + rq * (f[0] - f[1]) / (rq * rq * (k[0] + k[1]) + 1e-6)
            return clip(qp, q - b, q + b)

        def _forces(self, X, t):
            nom, tr = self._nom, self._truth
            theta, omega, q, qd, z = self._split(X)
            if "backlash" in tr:
                q = self._pulley_angle(theta, q, tr["backlash"])
            x, xd = rig_kinematics(nom, theta, omega, q, qd)
            scale = tr.get("spring_scale", 1.0)
            if "spring_drift" in tr:
                p = tr["spring_drift"]
                scale = scale * (1.0 + p["creep"] * (1.0 - np.exp(-t / p["tau"])))
            f = []
            for i in range(nom.num_motors):
                f0 = laws.spring_force(x[i], nom.spring_poly) * scale
                if "spring_hysteresis" in tr and _here(tr, i):
                    f0 = f0 + laws.hysteresis_force(tr["spring_hysteresis"]["width"] * z[i], f0)
                f.append(f0)
            return f, x, xd

        def DoCalcTimeDerivatives(self, context, derivatives):
            X = context.get_continuous_state_vector().CopyToVector()
            U = self.get_input_port(0).Eval(context)
            nom, tr, n = self._nom, self._truth, self._nom.num_motors
            theta, omega, q, qd, z = self._split(X)
            f, x, xd = self._forces(X, context.get_time())
            B = nom.motor_inertia * tr.get("inertia_scale", 1.0)
            r = nom.motor_pulley_radius
            acc, zd = [], []
            gain = 1.0 + tr.get("torque_constant", 0.0)
            for i in range(n):
                tau = gain * U[i] - nom.motor_damping * omega[i]
                if "motor_friction" in tr and _here(tr, i):
                    p = tr["motor_friction"]
                    tau = tau + stribeck_friction(omega[i], p["fc"], p["fs"], p["vs"], p["eps"], p["viscous"])
                if "motor_ripple" in tr:
                    p = tr["motor_ripple"]
                    tau = tau + laws.ripple(theta[i], [(o, a, b) for o, a, b in p["harmonics"][i]])
                tension = f[i]
                if "guide_friction" in tr and _here(tr, i):
                    p = tr["guide_friction"]
                    tension = tension + guide_friction(r * omega[i], positive_part(f[i]), p["c0"],
                                                       p["mu_angle"], p["v0"])
                tau = tau - r * tension
                acc.append(tau / B)
                if "spring_hysteresis" in tr and _here(tr, i):
                    p = tr["spring_hysteresis"]
                    v = xd[i]
                    av = np.sqrt(v * v + 1e-12)
                    zd.append((v - p["beta"] * av * z[i] - p["gamma"] * v * np.sqrt(z[i] * z[i] + 1e-12))
                              / p["length"])
                else:
                    zd.append(0.0 * z[i])
            out = []
            if nom.has_link:
                tq = nom.link_pulley_radius * (f[0] - f[1]) - nom.link_damping * qd - tr.get("link_spring", 0.0) * q
                if "joint_friction" in tr:
                    p = tr["joint_friction"]
                    tq = tq + stribeck_friction(qd, p["fc"], p["fs"], p["vs"], p["eps"])
                out += [qd, tq / nom.link_inertia]
            out += [omega[i] for i in range(n)] + acc + zd
            derivatives.get_mutable_vector().SetFromVector(np.array(out))

        def _calc_y(self, context, output):
            X = context.get_continuous_state_vector().CopyToVector()
            f, _, _ = self._forces(X, context.get_time())
            theta, omega, q, qd, z = self._split(X)
            y = list(theta) + list(f) + ([q] if self._nom.has_link else [])
            output.SetFromVector(np.array(y))

        def _calc_x(self, context, output):
            output.SetFromVector(context.get_continuous_state_vector().CopyToVector())

    return Impl


def _here(tr: dict, i: int) -> bool:
    """Whether the per-tendon hidden effects (catalog PLACED_EFFECTS) act on tendon ``i`` (0-based)."""
    return tr.get("place") in (None, i + 1)


def stribeck_draw(coulomb: float, viscous_range, rng: np.random.Generator, viscous_scale: float = 1.0) -> dict:
    """A hidden Stribeck friction (:func:`~awiwi_drake.components.friction.stribeck_friction`) with Coulomb level
    ``coulomb``: its shape drawn from the ``stribeck_*`` ranges of
    :class:`~awiwi_drake.parameters.discrepancy.TruthGeneratorParams`, the viscous part from ``viscous_range`` times
    ``viscous_scale`` (the rigs' and the fingers' truths)."""
    g, u = TruthGeneratorParams(), rng.uniform
    return dict(fc=coulomb, fs=coulomb * u(*g.stribeck_static_ratio_range), vs=u(*g.stribeck_velocity_range),
                eps=u(*g.stribeck_smoothing_range), viscous=viscous_scale * u(*viscous_range))


def ripple_draw(amplitude_range, motors: int, rng: np.random.Generator, scale: float = 1.0) -> list:
    """A hidden ripple: two harmonics ``(order, a_sin, a_cos)`` per motor, the two orders drawn once from
    {1..6, 100} per revolution, each amplitude ``scale`` times a draw from ``amplitude_range`` [N m], random phase."""
    orders, harm = rng.choice([1, 2, 3, 4, 5, 6, 100], size=2, replace=False), []
    for _ in range(motors):
        hm = []
        for o in orders:
            amp, ph = scale * rng.uniform(*amplitude_range), rng.uniform(0, 2 * np.pi)
            hm.append((float(o), float(amp * np.cos(ph)), float(amp * np.sin(ph))))
        harm.append(hm)
    return harm


def sensor_reading(name: str, y: np.ndarray, sigma: float, rng: np.random.Generator,
                   gen: TruthGeneratorParams | None = None) -> np.ndarray:
    """``y`` plus white noise of standard deviation ``sigma``; a tendon force also quantised to
    ``gen.force_bits`` over ``gen.force_range``."""
    y = y + rng.normal(0.0, sigma, len(y))
    if name.startswith("tendon_force"):
        g = gen or TruthGeneratorParams()
        lsb = g.force_range / 2 ** g.force_bits
        y = np.round(y / lsb) * lsb
    return y


def draw_truth(rig: str, hidden, rng: np.random.Generator, nuisance=(), strength: float = 1.0,
               place: int | None = None, unknown=(), unknown_rng: np.random.Generator | None = None) -> dict:
    """Random truth parameters for the hidden effects (and optional miscalibrations);
    ``strength`` scales each effect's size; ``place`` (1 or 2, joint rig) puts the per-tendon
    effects (motor friction, guide friction, spring hysteresis) on that tendon only; ``unknown``:
    effects outside the catalog (:data:`UNKNOWN_EFFECTS`), drawn from ``unknown_rng`` (default ``rng``)."""
    hidden, unknown = list(hidden), list(unknown)
    for h in unknown:
        if h not in UNKNOWN_EFFECTS:
            raise ValueError(f"unknown= {h!r}: not an out-of-catalog truth effect (known: {', '.join(UNKNOWN_EFFECTS)})")
        if h == "link_spring" and rig != "joint-rig":
            raise ValueError(f"unknown= 'link_spring' needs a link: rig {rig!r} has none (use rig 'joint-rig')")
    if place is not None and (rig != "joint-rig" or place not in (1, 2)):
        raise ValueError(f"place = {place!r}: a per-tendon place is 1 or 2 on the joint rig")
    if place is not None and not set(hidden) & set(PLACED_EFFECTS):
        raise ValueError(f"--place {place}: only a hidden per-tendon effect ({', '.join(PLACED_EFFECTS)}) takes a "
                         f"place; hidden: {', '.join(hidden) or 'none'}")
    for h in hidden:
        if h not in HIDDEN_EFFECTS:
            raise ValueError(f"unknown hidden effect {h!r} (known: {', '.join(HIDDEN_EFFECTS)})")
        if rig not in EFFECTS[h].rigs:
            raise ValueError(f"hidden effect {h!r} does not exist on rig {rig!r} "
                             f"(it needs {' or '.join(EFFECTS[h].rigs)})")
    for h in nuisance:
        if h not in NUISANCES:
            raise ValueError(f"unknown nuisance {h!r} (known: {', '.join(NUISANCES)})")
    n = 2 if rig == "joint-rig" else 1
    tr: dict = {}
    u = rng.uniform
    if "motor_friction" in hidden:
        g = TruthGeneratorParams()
        tr["motor_friction"] = stribeck_draw(u(0.06, 0.2), g.motor_viscous_range, rng)
    if "motor_ripple" in hidden:
        tr["motor_ripple"] = dict(harmonics=ripple_draw((0.04, 0.12), n, rng))
    if "spring_hysteresis" in hidden:
        tr["spring_hysteresis"] = dict(width=u(4.0, 10.0), length=u(1e-4, 4e-4), beta=0.7, gamma=0.3)
    if "joint_friction" in hidden:
        fc = u(0.01, 0.03)
        tr["joint_friction"] = dict(fc=fc, fs=fc * u(1.2, 1.6), vs=u(0.1, 0.4), eps=u(0.08, 0.15))
    if "guide_friction" in hidden:
        tr["guide_friction"] = dict(mu_angle=u(0.08, 0.2), c0=u(0.3, 1.5), v0=2e-4)
    if "delay" in hidden:
        tr["delay"] = float(u(0.002, 0.006))
    if "backlash" in hidden:
        tr["backlash"] = float(u(*TruthGeneratorParams().backlash_range))
    if "spring_drift" in hidden:
        tr["spring_drift"] = dict(creep=float(u(0.08, 0.2) * rng.choice([-1, 1])), tau=float(u(3.0, 8.0)))
    if strength != 1.0:
        _scale_truth(tr, strength)
    if "force_sensor" in nuisance:
        tr["force_gain"] = float(1.0 + u(0.05, 0.12) * rng.choice([-1, 1]))
        tr["force_offset"] = float(u(1.0, 3.0) * rng.choice([-1, 1]))
    if "nominal_motor" in nuisance:
        tr["inertia_scale"] = float(1.0 + u(0.15, 0.3) * rng.choice([-1, 1]))
    g, ur = TruthGeneratorParams(), unknown_rng or rng
    sign = lambda: float(ur.choice([-1.0, 1.0]))   # noqa: E731
    if "link_spring" in unknown:
        tr["link_spring"] = float(ur.uniform(*g.unknown_link_spring_range))
    if "torque_constant" in unknown:
        tr["torque_constant"] = sign() * float(ur.uniform(*g.unknown_torque_constant_range))
    if "force_nonlinearity" in unknown:
        tr["force_nonlinearity"] = sign() * float(ur.uniform(*g.unknown_force_quadratic_range))
    if "force_pickup" in unknown:
        tr["force_pickup"] = dict(amplitude=float(ur.uniform(*g.unknown_pickup_amplitude_range)),
                                  frequency=g.unknown_pickup_frequency, phase=float(ur.uniform(0.0, 2 * np.pi)),
                                  channel=int(ur.integers(1, n + 1)))
    tr["hidden"] = hidden
    tr["unknown"] = unknown
    tr["nuisance"] = list(nuisance)
    if place is not None:
        tr["place"] = int(place)
    return tr


def _scale_truth(tr: dict, k: float) -> None:
    """Scale every hidden effect's size by ``k`` in place (shapes unchanged)."""
    sizes = {"motor_friction": ("fc", "fs", "viscous"), "joint_friction": ("fc", "fs"),
             "spring_hysteresis": ("width",), "guide_friction": ("c0", "mu_angle"), "spring_drift": ("creep",)}
    for eff, keys in sizes.items():
        if eff in tr:
            for key in keys:
                tr[eff][key] = tr[eff][key] * k
    if "motor_ripple" in tr:
        tr["motor_ripple"]["harmonics"] = [[(o, a * k, b * k) for o, a, b in hm]
                                           for hm in tr["motor_ripple"]["harmonics"]]
    for eff in ("delay", "backlash"):
        if eff in tr:
            tr[eff] = tr[eff] * k
    tr["strength"] = k


def _reference_filter(a: np.ndarray, dt: float, time_constant: float, passes: int = 1) -> np.ndarray:
    """``a`` (in place) through ``passes`` first-order filters of ``time_constant`` [s] sampled every ``dt`` [s]."""
    alpha = dt / (time_constant + dt)
    for _ in range(passes):
        for k in range(1, a.size):
            a[k] = a[k - 1] + alpha * (a[k] - a[k - 1])
    return a


def _excitation(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Normalised lab excitation in [-1, 1]: multisine, chirp, steps, slow reversals."""
    T = t[-1] - t[0] + (t[1] - t[0])
    s = (t - t[0]) / T
    a = np.zeros_like(t)
    # multisine 0.3-6 Hz, Schroeder phases
    m = s < 0.3
    freqs = np.linspace(0.3, 6.0, 12)
    ph = -np.pi * np.arange(12) * (np.arange(12) + 1) / 12 + rng.uniform(0, 0.5)
    ms = sum(np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, ph))
    a[m] = ms[m] / np.max(np.abs(ms[m]))
    # chirp 0.2 -> 6 Hz
    m2 = (s >= 0.3) & (s < 0.55)
    if m2.any():
        tc = t[m2] - t[m2][0]
        a[m2] = np.sin(2 * np.pi * (0.2 * tc + (6.0 - 0.2) * tc ** 2 / (2 * (tc[-1] + 1e-9))))
    # steps every 0.3 s
    m3 = (s >= 0.55) & (s < 0.8)
    if m3.any():
        k = ((t[m3] - t[m3][0]) / 0.3).astype(int)
        levels = rng.uniform(-1, 1, k.max() + 1)
        a[m3] = levels[k]
    # slow reversals (triangle 0.3 Hz)
    m4 = s >= 0.8
    if m4.any():
        tt = t[m4] - t[m4][0]
        a[m4] = 2 * np.abs(2 * ((0.3 * tt + 0.25) % 1.0) - 1) - 1
    return a


def _truth_loop(plant_sys, nom: NominalParameters, gen: TruthGeneratorParams, delay: float, th0: float):
    """The truth rig (a :class:`~awiwi_drake.rigs.Rig` in the rigs' state order; its operating point is the nominal
    rest, link at 0 and every motor at the pretension angle ``th0`` [rad] held by ``r_m f_pre``: an equilibrium of
    the plant without its hidden effects) under the lab's motor PD
    (:func:`~awiwi_drake.control.motor_position.motor_position_controller`,
    ``u_k = r_m f_pre + kp (theta_ref,k - theta_k) - kd omega_k``), closed by :func:`~awiwi_drake.control.closed_loop`
    at the logging rate: the command reaches the plant ``delay`` [s] later, whole periods through the loop's
    ``DiscreteTimeDelay``, the fraction through a hold in front of the plant sampling at ``k dt + frac dt``
    (the interval split of the ``delay`` effect).  Returns the loop and that hold (or None)."""
    dt = 1.0 / gen.sample_rate
    nd = int(np.floor(delay / dt + 1e-12))
    frac = delay / dt - nd
    b = DiagramBuilder()
    plant = b.AddNamedSystem("truth_plant", plant_sys)
    split = None
    if frac > 1e-9:
        split = b.AddNamedSystem("delay_split", ZeroOrderHold(dt, nom.num_motors, frac * dt))
        b.Connect(split.get_output_port(), plant.GetInputPort("motor_torque"))
    b.ExportInput((split or plant).get_input_port(0), "motor_torque")
    for name in ("measurement", "motor_angle", "motor_velocity", "tendon_force"):
        b.ExportOutput(plant.GetOutputPort(name), name)
    n, off = nom.num_motors, 2 if nom.has_link else 0

    def rest() -> OperatingPoint:
        x = np.zeros(nom.num_states)
        x[off:off + n] = th0
        return OperatingPoint(x, np.full(n, nom.motor_pulley_radius * gen.pretension), pretension=gen.pretension)
    rig = Rig(f"truth-{nom.rig}", b.Build(), nom, state_names(joints=off // 2, motors=n, hysteresis=True), rest)
    gains = MotorPositionGains(kp=gen.kp, kd=gen.kd, rate_hz=gen.sample_rate)
    ctrl = motor_position_controller(rig, gains, pulley_radius=nom.motor_pulley_radius)
    return closed_loop(rig, ctrl, rate_hz=gen.sample_rate, delay=nd * dt if nd else None), split


def make_truth_dataset(rig: str = "joint-rig", hidden=(), *, snr_db: float | None = 30.0, seed: int = 0,
                       nuisance=(), gen: TruthGeneratorParams | None = None, name: str | None = None,
                       keep_clean: bool = True, progress=None, strength: float = 1.0,
                       place: int | None = None, unknown=()) -> Dataset:
    """Simulate one closed-loop experiment on a truth rig with hidden effects.

    ``progress(t, duration)`` (optional) is called every ~2 % of the run, e.g.
    :class:`awiwi_drake.config.SimulationProgress`.

    Parameters
    ----------
    rig : "tendon-rig" | "joint-rig"
    hidden : sequence of catalog names hidden in the truth plant
    snr_db : float or None
        Sensor SNR [dB] per output (None: noise-free, no quantisation).
    seed : int
        Random physical parameters, effect parameters, excitation and noise.
    nuisance : sequence of "force_sensor" | "nominal_motor"
        Miscalibrations: the JSON's nominal values or the sensor differ from the truth.
    strength : float
        Scale of every hidden effect's size (1: the generator's ranges; 0.5: half strength).
    place : 1, 2 or None
        Joint rig: the per-tendon effects (motor friction, guide friction, spring hysteresis) act on
        that tendon (its motor, guide path and spring) only; None: on both.
    unknown : sequence of :data:`UNKNOWN_EFFECTS`
        Effects outside the catalog (a link spring, a torque-constant error, a force-sensor
        quadratic gain, 50 Hz pickup on one force signal), recorded in ``meta["truth"]``; drawn from
        their own random stream, so a seed's other draws (parameters, excitation, noise) do not change.

    Returns
    -------
    Dataset whose ``meta["truth"]`` records the hidden effects and whose
    ``meta["clean_outputs"]`` (in memory only, when ``keep_clean``) holds the
    noise-free outputs.
    """
    if rig not in ("tendon-rig", "joint-rig"):
        raise ValueError(f"unknown rig {rig!r} (known: tendon-rig, joint-rig)")
    gen = gen or TruthGeneratorParams()
    rng = np.random.default_rng(seed)
    base = default_nominal(rig)
    spread = gen.parameter_spread
    params = {}
    for k, v in base.items():
        if k == "spring_poly":
            sc = rng.uniform(1 - spread, 1 + spread)
            params[k] = [float(c * sc) for c in v]
        elif k in ("motor_pulley_radius", "link_pulley_radius"):
            params[k] = float(v)
        else:
            params[k] = float(v * rng.uniform(1 - spread, 1 + spread))
    nom = NominalParameters.from_dataset(rig, params)
    # the out-of-catalog effects from their own stream: the seed's parameters, excitation and noise stay the
    # same with and without them
    truth = draw_truth(rig, hidden, rng, nuisance, strength, place, unknown, np.random.default_rng([seed, 1]))
    plant_sys = HiddenEffectPlant_[float](nom, truth)
    dt = 1.0 / gen.sample_rate
    N = int(round(gen.duration / dt))
    t = np.arange(N) * dt
    n = nom.num_motors
    r = nom.motor_pulley_radius
    xs = np.linspace(0, 0.05, 20001)
    x0 = float(np.interp(gen.pretension, laws.spring_force(xs, nom.spring_poly), xs))
    th0 = x0 / r
    a = _reference_filter(_excitation(t, rng), dt, gen.reference_time_constant)
    if rig == "joint-rig":
        rq = nom.link_pulley_radius
        qref = gen.link_excursion * a
        cc = 0.2 * th0 * np.sin(2 * np.pi * 0.13 * t + rng.uniform(0, 2 * np.pi))
        ref = np.stack([th0 + rq / r * qref + cc, th0 - rq / r * qref + cc], axis=1)
    else:
        ref = (th0 + 0.6 * th0 * a)[:, None]
    loop, split = _truth_loop(plant_sys, nom, gen, float(truth.get("delay", 0.0)), th0)
    X0 = loop.rig.operating_point().state
    th_0, om_0 = split_state(nom, X0)[:2]
    u0 = r * gen.pretension + gen.kp * (ref[0] - th_0) - gen.kd * om_0   # the bench starts at rest at u_0
    ctx = loop.create_context(state=X0, motor_torque=u0)
    if split is not None:
        split.SetVectorState(split.GetMyMutableContextFromRoot(ctx), u0)
    res = simulate(loop, ctx, t[-1], inputs={"motor_angle_reference": Samples(t, ref, hold="zoh"),
                                             "tendon_force_reference": gen.pretension},
                   log=("measurement", "motor_torque_command"), log_period=dt, mode="error_controlled",
                   max_step=dt, accuracy=1e-6, progress=progress)
    Y, Ucmd = res["measurement"], res["motor_torque_command"]
    if Y.shape[0] != N:
        raise RuntimeError(f"truth simulation logged {Y.shape[0]} samples, expected {N}")
    names = nom.measurement_names()
    clean = {nm: Y[:, j].copy() for j, nm in enumerate(names)}
    names_force = [nm for nm in names if nm.startswith("tendon_force")]
    meas = {}
    for j, nm in enumerate(names):
        y = Y[:, j].copy()
        if nm.startswith("tendon_force") and "force_gain" in truth:
            y = truth["force_gain"] * y + truth["force_offset"]
        sigma = Y[:, j].std() * 10 ** (-(30.0 if snr_db is None else snr_db) / 20.0)
        if nm.startswith("tendon_force") and "force_nonlinearity" in truth:
            y = y * (1.0 + truth["force_nonlinearity"] * y)
        if "force_pickup" in truth and nm == names_force[truth["force_pickup"]["channel"] - 1]:
            p = truth["force_pickup"]   # amplitude in noise std (of 30 dB when noise-free)
            y = y + p["amplitude"] * sigma * np.sin(2 * np.pi * p["frequency"] * t + p["phase"])
        meas[nm] = y if snr_db is None else sensor_reading(nm, y, sigma, rng, gen)
    inputs = {nm: Ucmd[:, i] for i, nm in enumerate(RIGS[rig].inputs)}
    init = {nm: float(X0[i]) for i, nm in enumerate(nom.state_names()[:-n])}
    tag = "-".join(list(hidden) + list(unknown)) or "none"
    name = name or f"{rig}_{tag}_snr{'inf' if snr_db is None else int(snr_db)}_s{seed}"
    meta = {"truth": dict(truth), "generator": {"snr_db": snr_db, "seed": seed, "sample_rate": gen.sample_rate,
                                                "duration": gen.duration}}
    ds = Dataset(name, rig, t, inputs, meas, params, init, meta)
    if keep_clean:
        ds.meta["clean_outputs"] = clean
    return ds
