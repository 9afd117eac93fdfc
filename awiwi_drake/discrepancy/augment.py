"""The diagnosis as parameters of the package's rig and finger builders (issue 12, item 4).

:func:`augmented_rig_parameters` writes the fitted catalog parameters into the
parameter dataclasses the rest of the package builds from (``JointRigParams``,
``TendonRigParams``: ``joint_rig(params=...)``, ``tendon_rig(params=...)``), where
the builders have the same law:

========================= =========================================================
catalog                   rig parameters
========================= =========================================================
``motor_friction``        ``motor.friction``, ``coulomb_torque``, ``friction_slope``,
                          ``viscous_friction`` ((3.8), the one law of both)
``nominal_motor``         ``motor.inertia * (1 + rel)``, ``motor.damping + add``
``nominal_link``          ``link_inertia * (1 + rel)``, ``link_damping + add``
========================= =========================================================

Everything else that was accepted is listed in ``not_representable`` (so is an effect localised to one
tendon, e.g. ``motor_friction on tendon 2``: the rig's motors share one ``MotorParams``): the rig
builders have no input delay, link-side Coulomb friction, guide friction on the
rig's tendon, spring drift or sensor calibrations, their ripple is one harmonic at
the gear ratio, and their spring polynomial is derived from the lever geometry
(``SpringModelParams``), not a free scale.  ``spring_hysteresis`` is not transferred
either: the catalog's Dahl form (fitted initial state, constant width) has not been
cross-checked against the rig's hysteresis option, so writing it would be a claim
without a test.

Fingers (:func:`augmented_finger_parameters`): the accepted per-tendon effects are written into
``FingerRigParams.tendon_motors`` (one :class:`~awiwi_drake.parameters.components.MotorParams` per
tendon, ``finger_diagram(params=...)``), with the law the diagnosis fitted:

========================= =========================================================
finger catalog            that tendon's motor
========================= =========================================================
``motor_friction``        ``friction``, ``coulomb_torque``, ``friction_slope``, ``viscous_friction`` ((3.8))
``motor_ripple``          ``ripple``, ``ripple_harmonics`` (the two fitted orders)
``nominal_motor``         ``inertia + motor_inertia_abs``, ``damping + motor_damping_add``
``spring_hysteresis``     that tendon's ``tendon_springs`` entry: ``hysteresis`` on, ``width_ratio``,
                          ``width_offset``, ``presliding_length`` (the package's loop, Fig 4.8b)
``guide_friction``        that tendon's ``tendon_guides`` entry (``TendonGuideParams``: constant C and capstan
                          exponent; added to the path's own guides, the Dahl law being linear in its level);
                          the finger diagnosis sees it in the links' equation, between the force sensor and the
                          joints, where the package's guides act (ch. 4: "the guidings from the fingers to the
                          spring mechanisms")
========================= =========================================================

Not representable (listed with the reason): the sensor calibrations ``nominal_spring`` and ``force_sensor``
(the measurement, not the plant).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .catalog import PARAM_INDEX

__all__ = ["AugmentedParameters", "augmented_rig_parameters", "augmented_finger_parameters", "TRANSFERRED"]

TRANSFERRED = ("motor_friction", "nominal_motor", "nominal_link")
"""Accepted effects written into the rig parameters (the others are listed as not representable)."""


@dataclass(frozen=True)
class AugmentedParameters:
    """Rig parameters with the accepted effects switched on (``params``), the effects
    written (``applied``) and those the rig builders cannot represent (``not_representable``)."""

    params: object
    applied: list = field(default_factory=list)
    not_representable: list = field(default_factory=list)


def augmented_rig_parameters(dx, base) -> AugmentedParameters:
    """Write the accepted effects of diagnosis ``dx`` into ``base`` (the rig parameters
    the dataset's nominal model corresponds to: ``JointRigParams`` for a ``joint``
    dataset, ``TendonRigParams`` for ``tendon``) and return a validated copy."""
    from awiwi_drake.parameters import JointRigParams, TendonRigParams

    want = JointRigParams if dx.rig == "joint-rig" else TendonRigParams
    if not isinstance(base, want):
        raise ValueError(f"augmented_rig_parameters: a {dx.rig!r} diagnosis needs {want.__name__}, "
                         f"got {type(base).__name__}")
    p = np.asarray(dx.final_parameters, float)

    def g(name):
        return float(p[PARAM_INDEX[name]])

    accepted = [s.effect for s in dx.steps]
    motor = base.motor
    applied, missing = [], []
    single = {e: pl for e, pl in dx.places.items() if pl.startswith("tendon ")}
    for eff in accepted:
        if eff in single:   # the rig's motors share one MotorParams: a one-tendon effect has no place there
            missing.append(f"{eff} on {single[eff]}")
            continue
        if eff == "motor_friction":
            motor = motor.replace(friction=True, coulomb_torque=g("motor_coulomb"),
                                  friction_slope=g("motor_slope"), viscous_friction=g("motor_viscous"))
        elif eff == "nominal_motor":
            motor = motor.replace(inertia=motor.inertia * (1.0 + g("motor_inertia_rel")),
                                  damping=motor.damping + g("motor_damping_add"))
        elif eff == "nominal_link" and dx.rig == "joint-rig":
            pass  # written below
        else:
            missing.append(eff)
            continue
        applied.append(eff)
    out = base.replace(motor=motor)
    if "nominal_link" in applied:
        out = out.replace(link_inertia=base.link_inertia * (1.0 + g("link_inertia_rel")),
                          link_damping=base.link_damping + g("link_damping_add"))
    return AugmentedParameters(out, applied, missing)


_FINGER_NOT_REPRESENTABLE = {
    "nominal_spring": "a force-sensor scale: a calibration of the measurement, not of the plant",
    "force_sensor": "a force-sensor offset: a calibration of the measurement, not of the plant",
}


def augmented_finger_parameters(dx, base) -> AugmentedParameters:
    """Write the accepted per-tendon effects of finger diagnosis ``dx``
    (:class:`~awiwi_drake.discrepancy.finger.FingerDiagnosis`) into ``base`` (the dataset's
    :class:`~awiwi_drake.parameters.hand.FingerRigParams`) as ``tendon_motors`` overrides (module
    docstring; ``spring_hysteresis`` into ``tendon_springs``); returns the validated copy, the effects written and
    those not representable (with why)."""
    from awiwi_drake.components.motor import tendon_motor_params
    from awiwi_drake.parameters.components import HysteresisParams, TendonGuideParams
    from awiwi_drake.parameters.hand import FingerRigParams

    if not isinstance(base, FingerRigParams):
        raise ValueError(f"augmented_finger_parameters: a finger diagnosis needs FingerRigParams, "
                         f"got {type(base).__name__}")
    names = list(dx.tendon_names)
    mp = tendon_motor_params(base, names)
    motors = dict(zip(names, mp if isinstance(mp, tuple) else [mp] * len(names)))
    changed, applied, missing = set(), [], []
    for st in dx.steps:
        tendon, g = names[st.tendon - 1], st.parameters
        what = f"{st.effect} on {st.place}"
        motor = motors[tendon]
        if st.effect == "motor_friction":
            if motor.friction:
                missing.append(f"{what}: the motor already has (3.8) friction; two laws do not add into one")
                continue
            motor = motor.replace(friction=True, coulomb_torque=g["motor_coulomb"], friction_slope=g["motor_slope"],
                                  viscous_friction=g["motor_viscous"])
        elif st.effect == "motor_ripple":
            extra = (g["ripple_order_1"], g["ripple_sin1"], g["ripple_cos1"],
                     g["ripple_order_2"], g["ripple_sin2"], g["ripple_cos2"])
            motor = (motor.replace(ripple_harmonics=motor.ripple_harmonics + extra) if motor.ripple else
                     motor.replace(ripple=True, ripple_motor_amplitude=0.0, ripple_output_amplitude=0.0,
                                   ripple_harmonics=extra))
        elif st.effect in ("spring_hysteresis", "guide_friction"):
            continue                                    # a tendon_springs / tendon_guides entry, below
        elif st.effect == "nominal_motor":
            inertia, damping = motor.inertia + g["motor_inertia_abs"], motor.damping + g["motor_damping_add"]
            if not (inertia > 0 and damping >= 0):
                missing.append(f"{what}: inertia {inertia:.3g} kg m^2 / damping {damping:.3g} N m s/rad is not "
                               f"physical")
                continue
            motor = motor.replace(inertia=inertia, damping=damping)
        else:
            missing.append(f"{what}: {_FINGER_NOT_REPRESENTABLE.get(st.effect, 'no finger parameter holds it')}")
            continue
        motors[tendon] = motor
        changed.add(tendon)
        applied.append(what + (f" ({st.status})" if st.status != "confirmed" else ""))
    keep = tuple((t, p) for t, p in base.tendon_motors if t not in changed)
    out = base.replace(tendon_motors=keep + tuple((t, motors[t]) for t in names if t in changed))
    springs = dict(out.tendon_springs)
    for st in dx.steps:
        if st.effect != "spring_hysteresis":
            continue
        tendon, g = names[st.tendon - 1], st.parameters
        sp = springs.get(tendon, base.spring)
        if sp.hysteresis.enabled:
            missing.append(f"spring_hysteresis on {st.place}: the spring already has a loop; two do not add into one")
            continue
        springs[tendon] = sp.replace(hysteresis=HysteresisParams(
            enabled=True, width_ratio=g["hysteresis_ratio"], width_offset=g["hysteresis_width"],
            presliding_length=g["hysteresis_length"]))
        applied.append(f"spring_hysteresis on {st.place}" + (f" ({st.status})" if st.status != "confirmed" else ""))
    out = out.replace(tendon_springs=tuple(springs.items()))
    guides = dict(out.tendon_guides)
    from awiwi_drake.hand.diagrams import finger_diagram
    gm = finger_diagram(finger=base.finger_name, params=base).drive.model.guide_friction
    C0, E0 = gm.levels() if gm is not None else (np.zeros(len(names)), np.zeros(len(names)))
    for st in dx.steps:
        if st.effect != "guide_friction":
            continue
        i, g = st.tendon - 1, st.parameters
        # rise when pulled: e^{E} - 1 = (e^{E0} - 1) + capstan (e^{mu} - 1); the constants add
        rise = np.expm1(E0[i]) + g["guide_capstan"] * np.expm1(g["guide_mu"])
        guides[names[i]] = TendonGuideParams(constant=float(C0[i] + g["guide_c0"]), capstan_exponent=float(np.log1p(rise)))
        applied.append(f"guide_friction on {st.place}" + (f" ({st.status})" if st.status != "confirmed" else ""))
    out = out.replace(tendon_guides=tuple(guides.items()))
    return AugmentedParameters(out, applied, missing)
