"""The catalog of physically named candidate effects.

Every candidate is a switch in :class:`~awiwi_drake.discrepancy.model.DiscrepancyModel_`
(or, for ``delay``, a time shift of the replayed commands, i.e. a delay block in
front of the motor input): parameters that are zero turn it off.  Each
parameter has a unit, bounds and a screening perturbation; *amplitude*
parameters enter (almost) linearly and are screened by regression, *shape*
parameters are screened on a small grid and freed in the simulation fit.

Catalog (names are part of the contract):

=================== ======================================================================
``motor_friction``   (3.8): ``tau = -(g2 atan(g1 w) + g3 w)`` on each motor
``motor_ripple``     ``tau = sum_k a_k sin(n_k theta) + b_k cos(n_k theta)`` (orders per rev)
``spring_hysteresis`` force offset ``h w``, Dahl state ``w' = (x' - |x'| w) / delta``, ``w(0)`` fitted
``joint_friction``   link Coulomb ``-F_c tanh(q'/v_s)`` (stick-slip, regularised)
``guide_friction``   tendon-path friction ``C0 s + f (exp(mu_a s) - 1)``, ``s = tanh(v/v0)``, opposing the tendon motion
``spring_drift``     spring force scaled by ``1 + c (t - t_mid)`` (creep over the run)
``backlash``         play ``+-b`` between link and tendon pulley (:func:`~awiwi_drake.components.routing.joint_backlash_angle`)
``delay``            applied torque ``u(t - T)``
=================== ======================================================================

Per-tendon effects (``PLACED_EFFECTS``: motor friction, guide friction, hysteresis) carry a place on
the joint rig: the masks ``place_1``/``place_2`` switch them per tendon; the screen tries both tendons
and each alone, so a diagnosis names effect and place ("guide_friction on tendon 2").

Nuisance candidates (calibration, not new physics): ``force_sensor`` (gain and
offsets), ``link_sensor`` (link-encoder bias and scale), ``motor_sensor``
(motor-encoder biases), ``nominal_motor`` (B, d), ``nominal_spring`` (stiffness
scale), ``nominal_link`` (m, d_q).  ``spring_drift`` acts per shooting window
(the scale at the window's mid-time), see :meth:`ReplayEngine.simulate`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from awiwi_drake.parameters.discrepancy import CatalogBounds

__all__ = ["ParamSpec", "Effect", "param_specs", "PARAM_NAMES", "PARAM_INDEX", "PARAM_UNITS", "EFFECTS",
           "effects_for_rig", "PHYSICAL_EFFECTS", "NUISANCE_EFFECTS", "PLACED_EFFECTS"]


@dataclass(frozen=True)
class ParamSpec:
    """One catalog parameter: value that turns it off, bounds, screening perturbation."""

    name: str
    unit: str
    off: float
    low: float
    high: float
    perturbation: float
    doc: str
    regularisation: bool = False
    """A sharpness parameter whose bound is a numerical limit (integrator stability or
    regularisation): resting on it means "as sharp as the model allows", not an
    unidentified parameter, so it does not count as "at a bound"."""


def param_specs(bounds: CatalogBounds | None = None) -> list[ParamSpec]:
    """Ordered parameter specs of the whole catalog (order = model parameter vector)."""
    b = bounds or CatalogBounds()
    rmax = b.ripple_amplitude_max
    nrel = b.nominal_relative_max
    specs = [
        ParamSpec("motor_coulomb", "Nm", 0.0, 0.0, b.motor_coulomb_max, 0.02, "gamma2 of (3.8)"),
        ParamSpec("motor_slope", "s/rad", 10.0, *b.motor_slope_range, 1.0, "gamma1 of (3.8) (Table 3.3 default)",
                  regularisation=True),
        ParamSpec("motor_viscous", "Nm s/rad", 0.0, 0.0, b.motor_viscous_max, 0.005, "gamma3 of (3.8)"),
    ]
    for m in (1, 2):
        for k in (1, 2):
            specs += [ParamSpec(f"ripple_sin{k}_m{m}", "Nm", 0.0, -rmax, rmax, 0.01,
                                f"ripple sine coefficient, harmonic {k}, motor {m}"),
                      ParamSpec(f"ripple_cos{k}_m{m}", "Nm", 0.0, -rmax, rmax, 0.01,
                                f"ripple cosine coefficient, harmonic {k}, motor {m}")]
    specs += [
        ParamSpec("ripple_order_1", "1/rev", 1.0, 1.0, b.ripple_order_max, 0.0, "order of ripple harmonic 1"),
        ParamSpec("ripple_order_2", "1/rev", 2.0, 1.0, b.ripple_order_max, 0.0, "order of ripple harmonic 2"),
        ParamSpec("hysteresis_width", "N", 0.0, 0.0, b.hysteresis_width_max, 0.5, "hysteresis half-width h"),
        ParamSpec("hysteresis_length", "m", 2e-4, *b.hysteresis_length_range, 0.0, "Dahl transition length"),
        ParamSpec("hysteresis_initial", "-", 0.0, -1.0, 1.0, 0.2,
                  "Dahl state w/h at the dataset start (one unknown shared by all windows)", regularisation=True),
        ParamSpec("joint_coulomb", "Nm", 0.0, 0.0, b.joint_coulomb_max, 0.002, "link Coulomb torque"),
        ParamSpec("joint_velocity", "rad/s", 0.05, *b.joint_velocity_range, 0.0, "link friction velocity scale",
                  regularisation=True),
        ParamSpec("guide_c0", "N", 0.0, 0.0, b.guide_c0_max, 0.3, "C0 of (4.1) (at the rig's bending angle)"),
        ParamSpec("guide_mu", "-", 0.0, 0.0, b.guide_mu_max, 0.01, "capstan exponent mu*alpha (tension-proportional part)"),
        ParamSpec("delay", "s", 0.0, 0.0, b.delay_max, 0.002, "pure input delay"),
        ParamSpec("force_gain", "-", 0.0, -b.force_gain_max, b.force_gain_max, 0.01, "force sensor gain error"),
        ParamSpec("force_offset_1", "N", 0.0, -b.force_offset_max, b.force_offset_max, 0.5, "force sensor 1 offset"),
        ParamSpec("force_offset_2", "N", 0.0, -b.force_offset_max, b.force_offset_max, 0.5, "force sensor 2 offset"),
        ParamSpec("motor_inertia_rel", "-", 0.0, -nrel, nrel, 0.05, "relative error of B"),
        ParamSpec("motor_damping_add", "Nm s/rad", 0.0, -0.05, 0.2, 0.002, "added motor damping"),
        ParamSpec("spring_scale_rel", "-", 0.0, -nrel, nrel, 0.02, "relative error of the spring force"),
        ParamSpec("link_inertia_rel", "-", 0.0, -nrel, nrel, 0.05, "relative error of m"),
        ParamSpec("link_damping_add", "Nm s/rad", 0.0, -0.05, 0.2, 2e-4, "added link damping"),
        ParamSpec("spring_drift", "1/s", 0.0, -b.spring_drift_max, b.spring_drift_max, 2e-3,
                  "relative spring-force change per second of the run (creep), zero at mid-record"),
        ParamSpec("link_bias", "rad", 0.0, -b.encoder_bias_max, b.encoder_bias_max, 0.01, "link encoder bias"),
        ParamSpec("link_scale_rel", "-", 0.0, -b.encoder_scale_max, b.encoder_scale_max, 0.02,
                  "link encoder scale error"),
        ParamSpec("motor_bias_1", "rad", 0.0, -b.encoder_bias_max, b.encoder_bias_max, 0.01, "motor 1 encoder bias"),
        ParamSpec("motor_bias_2", "rad", 0.0, -b.encoder_bias_max, b.encoder_bias_max, 0.01, "motor 2 encoder bias"),
        ParamSpec("backlash", "rad", 0.0, 0.0, b.backlash_max, 0.005,
                  "half-width of the play between link and tendon pulley (dead zone at the joint)"),
        ParamSpec("place_1", "-", 1.0, 0.0, 1.0, 0.0,
                  "place mask: the per-tendon effects (PLACED_EFFECTS) act on tendon/motor 1 (1) or not (0)",
                  regularisation=True),
        ParamSpec("place_2", "-", 1.0, 0.0, 1.0, 0.0,
                  "place mask: the per-tendon effects act on tendon/motor 2 (1) or not (0)", regularisation=True),
    ]
    return specs


PARAM_NAMES = [s.name for s in param_specs()]
PARAM_INDEX = {n: i for i, n in enumerate(PARAM_NAMES)}
PARAM_UNITS = {s.name: s.unit for s in param_specs()}  # the unit of every fitted parameter (reports, CLI)


@dataclass(frozen=True)
class Effect:
    """A candidate augmentation.

    Attributes
    ----------
    name : str
        Catalog name.
    kind : str
        ``"physical"`` or ``"nuisance"``.
    amplitude : tuple[str]
        Parameters that scale the effect (screened by regression).
    shape : dict[str, tuple]
        Shape parameters and the grid screened for each.
    rigs : tuple[str]
        Rigs on which the effect exists.
    signature : str
        Where it shows in the residual (for the report).
    """

    name: str
    kind: str
    amplitude: tuple
    shape: dict
    rigs: tuple
    signature: str

    def amplitude_for(self, rig: str) -> tuple:
        """Amplitude parameters that exist on ``rig`` (drop motor-2/link/force-2 ones)."""
        if rig == "joint-rig":
            return self.amplitude
        return tuple(a for a in self.amplitude if not a.endswith(("_m2", "_2")))


EFFECTS = {e.name: e for e in (
    Effect("motor_friction", "physical", ("motor_coulomb", "motor_viscous"),
           {"motor_slope": (3.0, 10.0, 30.0)}, ("tendon-rig", "joint-rig"),
           "motor-torque residual odd in motor velocity, saturating (atan); peaks at reversals"),
    Effect("motor_ripple", "physical",
           ("ripple_sin1_m1", "ripple_cos1_m1", "ripple_sin2_m1", "ripple_cos2_m1",
            "ripple_sin1_m2", "ripple_cos1_m2", "ripple_sin2_m2", "ripple_cos2_m2"),
           {}, ("tendon-rig", "joint-rig"),
           "residual periodic in motor angle: lines at integer cycles per revolution"),
    Effect("spring_hysteresis", "physical", ("hysteresis_width", "hysteresis_initial"),
           {"hysteresis_length": (5e-5, 2e-4, 8e-4)}, ("tendon-rig", "joint-rig"),
           "force residual depends on the direction of elongation (loop in force vs elongation)"),
    Effect("joint_friction", "physical", ("joint_coulomb",),
           {"joint_velocity": (0.01, 0.05, 0.2)}, ("joint-rig",),
           "force-difference residual odd in link velocity, stick near link reversals"),
    Effect("guide_friction", "physical", ("guide_c0", "guide_mu"), {}, ("tendon-rig", "joint-rig"),
           "motor-torque residual odd in tendon velocity and growing with tension"),
    Effect("spring_drift", "physical", ("spring_drift",), {}, ("tendon-rig", "joint-rig"),
           "force residual proportional to the force and growing over the run (creep of the spring mechanism)"),
    Effect("backlash", "physical", ("backlash",), {}, ("joint-rig",),
           "link angle moves without a tendon-force change where the joint torque reverses (dead zone at the joint)"),
    Effect("delay", "physical", ("delay",), {}, ("tendon-rig", "joint-rig"),
           "residual-input cross-correlation peaks at a positive lag; phase lag growing with frequency"),
    Effect("force_sensor", "nuisance", ("force_gain", "force_offset_1", "force_offset_2"), {},
           ("tendon-rig", "joint-rig"), "force residual proportional to force or constant"),
    Effect("link_sensor", "nuisance", ("link_bias", "link_scale_rel"), {}, ("joint-rig",),
           "link-angle residual constant or proportional to the link angle; forces consistent"),
    Effect("motor_sensor", "nuisance", ("motor_bias_1", "motor_bias_2"), {}, ("tendon-rig", "joint-rig"),
           "motor-angle residual constant, force residual following the spring stiffness"),
    Effect("nominal_motor", "nuisance", ("motor_inertia_rel", "motor_damping_add"), {},
           ("tendon-rig", "joint-rig"), "motor-torque residual in phase with acceleration or velocity"),
    Effect("nominal_spring", "nuisance", ("spring_scale_rel",), {}, ("tendon-rig", "joint-rig"),
           "force residual proportional to the modelled force"),
    Effect("nominal_link", "nuisance", ("link_inertia_rel", "link_damping_add"), {}, ("joint-rig",),
           "link-mode frequency or damping wrong"),
)}

PHYSICAL_EFFECTS = tuple(k for k, e in EFFECTS.items() if e.kind == "physical")
PLACED_EFFECTS = ("motor_friction", "guide_friction", "spring_hysteresis")
"""Effects that act on each tendon (its motor, its guide path, its spring mechanism) and can be
localised to one of them by the place masks ``place_1``/``place_2`` (the joint rig's two tendons)."""
NUISANCE_EFFECTS = tuple(k for k, e in EFFECTS.items() if e.kind == "nuisance")


def effects_for_rig(rig: str, outputs: list[str]) -> list[Effect]:
    """Candidates that can act and be seen on ``rig`` with the measured ``outputs``."""
    has_force = any(o.startswith("tendon_force") for o in outputs)
    return [e for e in EFFECTS.values() if rig in e.rigs and (has_force or e.name != "force_sensor")
            and ("joint_angle" in outputs or e.name != "link_sensor")]


def default_vector() -> np.ndarray:
    """The catalog parameter vector with every effect off."""
    return np.array([s.off for s in param_specs()])
