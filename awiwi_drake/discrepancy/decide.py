"""Decisions: which fitted candidate is accepted, which effects cannot be told apart,
and whether a discrepancy remains that the catalog does not explain (issue 12).

A candidate is accepted only if all of these hold:

* **significant** on held-out windows: gain above ``min_z`` null standard
  deviations, most windows improve (``min_rank_z``), at least ``min_gain`` of the
  excess and ``min_floor_gain`` of the noise floor;
* **better than the simpler model** on training data by BIC (``delta_bic < 0``);
* **identifiable**: no fitted parameter rests on a bound (a bound is not an estimate);
* **separable from a recalibration** (``motor_ripple`` only, :func:`ripple_adds_to_recalibration`): a
  ripple whose largest harmonic completes fewer than ``parameters.discrepancy.RIPPLE_MIN_PERIODS`` periods over the motor
  angle the data cover is a generic smooth function of the angle there, and so is the spring-force part
  of a drive-gain (torque-constant) error, which is exactly a recalibration (dividing the motor equation
  by ``1 + e``: :data:`DRIVE_GAIN_RECALIBRATION`).  When that recalibration passes every test and the
  ripple's correction, added on top of it, removes nothing significant on held-out windows, the two are
  not separable with these data and the simpler explanation, the calibration, leads: the ripple is not
  named, and the recalibration is added as one calibration step ``drive_gain`` ("not separable" from
  ``motor_ripple``, with the experiment that would separate them) unless another candidate explains more.
  Likewise when a calibration candidate of the same step explains as much as such a ripple, even one that
  fails a test itself (then the step decides among the other candidates);
* **material**: the fitted effect is larger than what the sensor noise can show
  (:func:`materiality`: a delay of at least one sample; a hysteresis half-width,
  guide friction, force-sensor error above the noise-equivalent force; a friction
  or ripple torque above the noise-equivalent torque).

Candidates that explain the same residual equally well (held-out gain within
``ambiguous_ratio`` and no significant paired difference) form one class "not
separable with these data"; the lowest-BIC member is listed first and an
experiment that would separate them is suggested (:func:`separating_experiment`).
"""

from __future__ import annotations

import numpy as np

from awiwi_drake.parameters.discrepancy import RIPPLE_MIN_PERIODS, DiscrepancySettings

from . import laws
from .catalog import EFFECTS, Effect
from .replay import ReplayEngine
from .screen import gain_z

__all__ = ["NoiseEquivalent", "materiality", "rejection_reason", "separating_experiment",
           "SEPARATING_EXPERIMENTS", "EQUIVALENT_EFFECTS", "ripple_periods",
           "DRIVE_GAIN_RECALIBRATION", "recalibration_effect", "ripple_adds_to_recalibration"]


class NoiseEquivalent:
    """What the sensor noise of one dataset can show, per quantity.

    Attributes
    ----------
    force : float
        Noise-equivalent tendon force [N]: the per-sample noise floor of the force
        sensors (smallest of them); without a force sensor, the motor-angle noise
        through the spring stiffness at the median elongation, ``k r sigma_theta``.
    motor_torque : float
        ``r * force`` [Nm]: the motor torque the noise-equivalent force exerts.
    link_torque : float
        ``r_q * force`` [Nm] (joint rig).
    joint_angle : float
        Link-encoder noise floor [rad]; without a link encoder, the link angle that moves one
        spring by the noise-equivalent force, ``force / (k r_q)`` (joint rig).
    sample : float
        Sample period [s].
    """

    def __init__(self, eng: ReplayEngine):
        nom = eng.nom
        sig = dict(zip(eng.out_names, eng.sigma))
        forces = [s for n, s in sig.items() if n.startswith("tendon_force")]
        x, h = float(np.median(eng.elong)), 1e-6   # spring stiffness at the median elongation
        k = float((laws.spring_force(x + h, nom.spring_poly) - laws.spring_force(x - h, nom.spring_poly)) / (2 * h))
        if forces:
            f = float(min(forces))
        else:
            th = min(s for n, s in sig.items() if n.startswith("motor_angle"))
            f = k * nom.motor_pulley_radius * th
        self.force = f
        self.motor_torque = nom.motor_pulley_radius * f
        self.link_torque = nom.link_pulley_radius * f if nom.has_link else float("nan")
        # link angle: the link encoder's noise floor, else the angle the noise force moves one spring by
        if "joint_angle" in sig:
            self.joint_angle = float(sig["joint_angle"])
        elif nom.has_link:
            self.joint_angle = f / max(k * nom.link_pulley_radius, 1e-12)
        else:
            self.joint_angle = float("nan")
        self.sample = eng.dt
        n = nom.num_motors
        self.omega_rms = float(np.sqrt(np.mean(eng.xhat[n:2 * n] ** 2)))
        self.force_rms = float(np.sqrt(np.mean([np.mean(eng.ds.outputs[k] ** 2) for k in eng.out_names
                                                 if k.startswith("tendon_force")] or [0.0])))
        # RMS motor / link accelerations and link speed of the estimated states (sizes of inertia and
        # damping corrections in torque units)
        rms = (lambda v: float(np.sqrt(np.mean(np.asarray(v) ** 2))) if np.size(v) else 0.0)
        self.omega_dot_rms = rms(np.diff(eng.xhat[n:2 * n], axis=1) / eng.dt)
        if nom.has_link:
            self.qd_rms = rms(eng.xhat[2 * n + 1])
            self.qdd_rms = rms(np.diff(eng.xhat[2 * n + 1]) / eng.dt)
        else:
            self.qd_rms = self.qdd_rms = float("nan")
        self.nom = nom


def _ripple_size(p: dict) -> float:
    amps = [np.hypot(p.get(f"ripple_sin{k}_m{m}", 0.0), p.get(f"ripple_cos{k}_m{m}", 0.0))
            for k in (1, 2) for m in (1, 2)]
    return float(max(amps))


def materiality(effect: str, params: dict, ne: NoiseEquivalent) -> dict:
    """Size of a fitted effect against its floor: ``{"size", "floor", "unit", "material", "measure"}``.

    The floors are stated per effect (issue 12): a delay of one sample; hysteresis
    half-width, guide friction and force-sensor errors against the noise-equivalent
    force; motor friction, ripple and motor-parameter errors against the
    noise-equivalent motor torque; joint friction and link-parameter errors against
    the noise-equivalent link torque; backlash against the link-angle noise.  Spring-scale errors are forces at the RMS force;
    inertia and damping corrections (``nominal_motor``, ``nominal_link``) are the
    torques they change at the dataset's RMS acceleration and speed.
    """
    g = params.get
    if effect == "delay":
        size, floor, unit, what = g("delay", 0.0), ne.sample, "s", "delay vs one sample"
    elif effect == "spring_hysteresis":
        size, floor, unit, what = g("hysteresis_width", 0.0), ne.force, "N", "loop half-width vs noise force"
    elif effect == "motor_friction":
        size = g("motor_coulomb", 0.0) + g("motor_viscous", 0.0) * ne.omega_rms
        floor, unit, what = ne.motor_torque, "Nm", "friction torque at RMS speed vs noise torque"
    elif effect == "motor_ripple":
        size, floor, unit, what = _ripple_size(params), ne.motor_torque, "Nm", "ripple amplitude vs noise torque"
    elif effect == "joint_friction":
        size, floor, unit, what = g("joint_coulomb", 0.0), ne.link_torque, "Nm", "link friction vs noise torque"
    elif effect == "backlash":
        size, floor, unit, what = g("backlash", 0.0), ne.joint_angle, "rad", "play half-width vs link-angle noise"
    elif effect == "guide_friction":
        size = g("guide_c0", 0.0) + g("guide_mu", 0.0) * ne.force_rms
        floor, unit, what = ne.force, "N", "path friction at RMS tension vs noise force"
    elif effect == "force_sensor":
        size = max(abs(g("force_gain", 0.0)) * ne.force_rms, abs(g("force_offset_1", 0.0)),
                   abs(g("force_offset_2", 0.0)))
        floor, unit, what = ne.force, "N", "sensor error vs noise force"
    elif effect == "nominal_spring":
        size, floor, unit, what = abs(g("spring_scale_rel", 0.0)) * ne.force_rms, ne.force, "N", \
            "spring-force error at RMS force vs noise force"
    elif effect == "nominal_motor":  # inertia and damping corrections as torques at the RMS motion
        size = (abs(g("motor_inertia_rel", 0.0)) * ne.nom.motor_inertia * ne.omega_dot_rms
                + abs(g("motor_damping_add", 0.0)) * ne.omega_rms)
        floor, unit, what = ne.motor_torque, "Nm", "inertia/damping correction torque at RMS motion vs noise torque"
    elif effect == "nominal_link":
        size = (abs(g("link_inertia_rel", 0.0)) * ne.nom.link_inertia * ne.qdd_rms
                + abs(g("link_damping_add", 0.0)) * ne.qd_rms)
        floor, unit, what = ne.link_torque, "Nm", "inertia/damping correction torque at RMS motion vs noise torque"
    else:  # no single size (e.g. sensor biases): the significance tests decide
        return {"size": float("nan"), "floor": float("nan"), "unit": "", "material": True,
                "measure": "no materiality floor (parameter correction)"}
    return {"size": float(size), "floor": float(floor), "unit": unit, "material": bool(size >= floor),
            "measure": what}


def rejection_reason(c, st, settings: DiscrepancySettings) -> str:
    """Why the fitted candidate ``c`` (:class:`~awiwi_drake.discrepancy.result.CandidateResult`)
    cannot be accepted against the state ``st``; ``""`` when it passes every test."""
    if c.z_gain < settings.min_z:
        return f"held-out gain {c.z_gain:.1f} null std < {settings.min_z:g}"
    if c.z < settings.min_rank_z:
        return f"window rank z {c.z:.1f} < {settings.min_rank_z:g}"
    if c.relative_gain < settings.min_gain:
        return f"removes {100 * c.relative_gain:.1f} % of the excess < {100 * settings.min_gain:g} %"
    if c.gain < settings.min_floor_gain * st.floor_test:
        return f"gain below {100 * settings.min_floor_gain:g} % of the noise floor"
    if not c.delta_bic < 0:
        return f"BIC not better than the simpler model (dBIC {c.delta_bic:+.0f})"
    if c.at_bound:
        return f"parameter at a bound: {', '.join(c.at_bound)}"
    m = c.materiality
    if m and not m["material"]:
        return f"not material: {m['measure']} ({m['size']:.3g} < {m['floor']:.3g} {m['unit']})"
    return ""


def ripple_periods(params: dict, angle_span: float) -> float:
    """Periods the fitted ripple's largest harmonic (largest amplitude on either motor) completes over
    ``angle_span`` [rad] of motor angle: a small high-order harmonic beside a large low-order one does not
    make the fit periodic."""
    amp = {k: max(np.hypot(params.get(f"ripple_sin{k}_m{m}", 0.0), params.get(f"ripple_cos{k}_m{m}", 0.0))
                  for m in (1, 2)) for k in (1, 2)}
    k = max(amp, key=amp.get)
    return float(params.get(f"ripple_order_{k}", 0.0) * angle_span / (2 * np.pi))


DRIVE_GAIN_RECALIBRATION = ("motor_inertia_rel", "motor_damping_add", "spring_scale_rel", "link_inertia_rel",
                            "link_damping_add", "force_gain")
"""The calibration parameters a drive-gain error ``(1 + e) u`` is exactly: divided through by ``1 + e`` it is
the model with every mass, damping and the spring force scaled by ``1 / (1 + e)`` and a force-sensor gain ``e``
(tests/test_discrepancy.py::test_torque_constant_error_is_exactly_a_recalibration, 1e-9)."""


def recalibration_effect(rig: str, accepted=()) -> Effect:
    """The :data:`DRIVE_GAIN_RECALIBRATION` parameters that exist on ``rig`` and are not already free in the
    ``accepted`` effects, as one calibration candidate ``drive_gain`` fitted jointly: the simpler model a
    low-order ripple must add to.  Not a catalog entry: it is fitted only against such a ripple, and added
    as a calibration when it leads their class (``workflow``)."""
    taken = {a for e in accepted for a in e.amplitude_for(rig)}
    have = {a for e in EFFECTS.values() if e.kind == "nuisance" and rig in e.rigs for a in e.amplitude_for(rig)}
    amps = tuple(a for a in DRIVE_GAIN_RECALIBRATION if a in have and a not in taken)
    return Effect("drive_gain", "nuisance", amps, {}, (rig,),
                  "a gain error of the motor drive (torque constant): masses, dampings, spring and force gain "
                  "recalibrated at once")


def ripple_adds_to_recalibration(rp_before: np.ndarray, rp_ripple: np.ndarray, rp_recal: np.ndarray,
                                 train: np.ndarray, test: np.ndarray) -> float:
    """Held-out gain, in null standard deviations (:func:`~awiwi_drake.discrepancy.screen.gain_z`), of the
    ripple's correction added on top of the recalibrated model.

    ``rp_*`` are the projected window residuals (windows x samples) before the step, with the ripple, and
    with the recalibration.  The ripple's correction ``d = rp_before - rp_ripple`` is scaled by least squares
    to the recalibrated residual on the training windows and scored on the held-out windows: a ripple that
    explains something the recalibration does not passes ``min_z`` again; one that explains the same
    residual adds nothing (about 0: its correction is then white against what is left)."""
    d = rp_before - rp_ripple
    dd = float((d[train] ** 2).sum())
    if dd <= 0.0:
        return 0.0
    alpha = float((rp_recal[train] * d[train]).sum()) / dd
    return gain_z(rp_recal[test], rp_recal[test] - alpha * d[test])


EQUIVALENT_EFFECTS = {frozenset(("motor_friction", "guide_friction"))}
"""Pairs that act as the same torque on one motor (the constant part of guide friction is motor Coulomb
friction, issue 12): when both pass every test they are one class "not separable", also as a leftover
after other effects were added (other ties after an accepted effect are form mismatches: "unresolved")."""

SEPARATING_EXPERIMENTS = {
    frozenset(("motor_friction", "guide_friction")):
        "step the tendon tension (pretension or an external load) at a constant motor speed: "
        "guide friction grows with tension, motor friction does not",
    frozenset(("motor_friction", "joint_friction")):
        "move the link slowly with the co-contraction held constant and measure the link angle: "
        "joint friction acts at link reversals, motor friction at motor reversals",
    frozenset(("spring_hysteresis", "guide_friction")):
        "slow load-unload cycles with the motor still and the tendon pulled from the link side: "
        "spring hysteresis stays a loop in force vs elongation, guide friction needs tendon sliding "
        "over the guide",
    frozenset(("spring_hysteresis", "motor_friction")):
        "slow force cycles at several speeds: spring hysteresis is rate-independent in force vs "
        "elongation, motor friction depends on motor velocity",
    frozenset(("delay", "nominal_motor")):
        "a high-frequency chirp (beyond the motor-spring mode): a delay adds phase lag growing "
        "linearly with frequency, an inertia or damping error changes the gain",
    frozenset(("link_sensor", "motor_sensor")):
        "read the link angle against an independent reference (a jig at known angles) or zero the "
        "motor encoders at a mechanical stop: a link-encoder bias and motor-encoder biases shift the "
        "tendon elongations alike",
    frozenset(("force_sensor", "nominal_spring")):
        "load the tendon with known weights: a force-sensor gain error scales the reading, a "
        "stiffness error the elongation at a given force",
    frozenset(("motor_ripple", "drive_gain")):
        "move the motor over at least two periods of the ripple's order at constant speed, and hold it at a "
        "few fixed angles while stepping the commanded torque: a ripple repeats with the motor angle, a "
        "drive-gain error scales with the commanded torque",
    frozenset(("motor_ripple", "motor_friction")):
        "slow constant-speed runs over several motor revolutions in both directions: ripple is "
        "periodic in the motor angle, friction depends on the direction only",
}


def separating_experiment(members: list) -> str:
    """A suggested experiment that would tell the effects in ``members`` apart."""
    pair = frozenset(members[:2])
    if pair in SEPARATING_EXPERIMENTS:
        return SEPARATING_EXPERIMENTS[pair]
    sig = "; ".join(f"{m}: {EFFECTS[m].signature}" for m in members if m in EFFECTS)
    return ("excite the operating region where their signatures differ (see the residual maps): " + sig)
