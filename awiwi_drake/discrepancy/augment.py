"""The diagnosis as parameters of the package's rig builders (issue 12, item 4, in part).

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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .catalog import PARAM_INDEX

__all__ = ["AugmentedParameters", "augmented_rig_parameters", "TRANSFERRED"]

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

    want = JointRigParams if dx.rig == "joint" else TendonRigParams
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
        elif eff == "nominal_link" and dx.rig == "joint":
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
