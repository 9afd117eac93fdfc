"""Parameters of the physical components: motor (ch. 3), spring mechanism and tendon (ch. 4).

Thesis values cite their table/equation; chosen values say why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from awiwi_drake.parameters.base import Parameters, param

__all__ = [
    "MotorParams",
    "PolynomialSpringParams",
    "LinearSpringParams",
    "SpringMechanismGeometry",
    "HysteresisParams",
    "TendonParams",
    "GuideFrictionParams",
    "TendonGuideParams",
    "JointFrictionParams",
]

#: Fig 3.3b read at full speed: (speed [rad/s], current [A]) (reading accuracy of the figure: +-10 %).
FIG_3_3B_FULL_SPEED_CURRENT = (15.0, 1.3)
# Torque constant [Nm/A]: the friction law (3.8) with MotorParams' Table 3.3 values needs 1.408 Nm at that speed,
# over that current (recomputed with the one (3.8) law by tests/test_control_motor.py). MotorParams.torque_constant;
# also turns the ripple currents of Fig 3.4b into torques.
_TORQUE_PER_AMPERE = 1.0829


@dataclass(frozen=True)
class MotorParams(Parameters):
    """Geared PMSM + harmonic drive, seen at the output shaft (ch. 3).

    Dynamics (3.5): ``B thdd = sat(u) + tau_fric(thd) + tau_ripple(th) - r_m f``; friction (3.8)
    ``-(gamma2 atan(gamma1 thd) + gamma3 thd)``; ripple: a motor-shaft bearing component (period
    ``2 pi / gear_ratio`` at the output) and an output-bearing one (period ``2 pi``), plus optional
    further orders ``ripple_harmonics``, flat ``(order, sin amplitude, cos amplitude)`` triples.
    """

    inertia: float = param(2e-3, unit="kg m^2", low=0.0, low_inclusive=False,
                           source="Tables 12.1, 13.1, 14.1, 14.2 (output side, (3.1))", doc="B at the output shaft")
    friction: bool = param(True, unit="-", source="chosen: the thesis's motor model includes (3.8)")
    friction_slope: float = param(10.0, unit="s/rad", low=0.0, low_inclusive=False,
                                  source="Table 3.3, gamma1")
    coulomb_torque: float = param(0.5586, unit="Nm", low=0.0, source="Table 3.3, gamma2")
    viscous_friction: float = param(0.0356, unit="Nm s/rad", low=0.0, source="Table 3.3, gamma3")
    damping: float = param(0.0, unit="Nm s/rad", low=0.0,
                           source="chosen: 0, (3.8) already holds the viscous term; (12.8) sets d_theta",
                           doc="extra linear damping d_theta")
    ripple: bool = param(False, unit="-",
                         source="chosen: off by default; switch on to study compensation (Fig 3.4-3.6)")
    ripple_motor_amplitude: float = param(
        round(0.05 * _TORQUE_PER_AMPERE, 4), unit="Nm", low=0.0,
        source="chosen from Fig 3.4b: 0.1 A peak-to-peak x 1.08 Nm/A (torque constant implied by Fig 3.3b/Table 3.3)")
    ripple_output_amplitude: float = param(
        round(0.025 * _TORQUE_PER_AMPERE, 4), unit="Nm", low=0.0,
        source="chosen from Fig 3.4b: 0.05 A peak-to-peak x 1.08 Nm/A (the slower, smaller component)")
    ripple_motor_phase: float = param(0.0, unit="rad", source="chosen: arbitrary reference")
    ripple_output_phase: float = param(0.0, unit="rad", source="chosen: arbitrary reference")
    ripple_harmonics: tuple = param((), unit="(-, Nm, Nm)",
                                    source="chosen: none; the thesis measures the two components above (Fig 3.4b); "
                                           "further orders come from a fit (discrepancy write-back)")
    torque_constant: float = param(
        round(_TORQUE_PER_AMPERE, 4), unit="Nm/A", low=0.0, low_inclusive=False,
        source=("fitted: the thesis measured it at the output shaft (section 3.2) but prints no value; "
                "(3.8) with Table 3.3 gives 1.408 Nm at 15 rad/s where Fig 3.3b reads ~1.3 A: "
                "1.083 Nm/A (output side)"))
    gear_ratio: float = param(100.0, unit="-", low=1.0, source="ch. 3: harmonic drive 1:100",
                              doc="input/output speed ratio (1/alpha_gear)")
    saturation: bool = param(True, unit="-", source="chosen: real amplifiers saturate")
    torque_limit: float = param(3.0, unit="Nm", low=0.0, low_inclusive=False,
                                source="chosen: 180 N x r_m (0.9 Nm) + Table 3.3 friction at 15 rad/s (1.41 Nm), with margin")
    pulley_radius: float = param(0.005, unit="m", low=0.0, high=0.05, low_inclusive=False,
                                 source=("chosen: not given; 5 mm keeps 180 N at 0.9 Nm, the order of the Table 3.3 "
                                         "torques"), doc="r_m, the motor pulley winding the tendon")

    def _validate(self) -> None:
        h = self.ripple_harmonics
        if len(h) % 3:
            raise ValueError(f"MotorParams.ripple_harmonics must hold (order, sin amplitude, cos amplitude) triples, "
                             f"got {len(h)} numbers")
        for k in range(0, len(h), 3):
            if not h[k] > 0:
                raise ValueError(f"MotorParams.ripple_harmonics[{k}] = {h[k]}: an order must be > 0 (periods per "
                                 f"output revolution)")


@dataclass(frozen=True)
class PolynomialSpringParams(Parameters):
    """Calibration-polynomial spring: ``f(x) = sum_k c_k x^k`` (k = 1..K) for x > 0, else 0.

    The thesis's real-time form (ch. 4, "Calibration"). Must be increasing on
    ``[0, max_elongation]`` (checked on a fine grid).
    """

    coefficients: tuple = param((2.0e4,), unit="N/m^k", vector=True,
                                source="chosen: placeholder linear spring; rigs use the lever fit")
    max_elongation: float = param(0.006, unit="m", low=0.0, high=0.1, low_inclusive=False,
                                  source="chosen: the lever mechanism's range (~6 mm, Fig 4.7)")

    def _validate(self) -> None:
        if len(self.coefficients) == 0:
            raise ValueError("PolynomialSpringParams.coefficients must hold at least c1")
        if self.coefficients[0] < 0:
            raise ValueError(f"PolynomialSpringParams.coefficients[0] = {self.coefficients[0]} must be >= 0 "
                             "(a spring cannot push at zero elongation)")
        x = np.linspace(0.0, self.max_elongation, 401)
        dfdx = sum(k * c * x ** (k - 1) for k, c in enumerate(self.coefficients, start=1))
        bad = np.nonzero(dfdx <= 0.0)[0]
        if bad.size and not (bad.size == 1 and bad[0] == 0 and self.coefficients[0] == 0.0):
            i = bad[1] if (bad[0] == 0 and self.coefficients[0] == 0.0 and bad.size > 1) else bad[0]
            raise ValueError(
                f"PolynomialSpringParams.coefficients: the spring curve is not increasing at x = {x[i]:.6g} m "
                f"(df/dx = {dfdx[i]:.6g} N/m) within [0, max_elongation = {self.max_elongation} m]")


@dataclass(frozen=True)
class LinearSpringParams(Parameters):
    """Linear torsional/translational spring (flexible joint (12.8), ch. 15 test rig)."""

    stiffness: float = param(0.605, unit="Nm/rad", low=0.0, low_inclusive=False, source="Table 12.1, k")


@dataclass(frozen=True)
class SpringMechanismGeometry(Parameters):
    """Lever + linear spring ("tangent alpha") mechanism of Fig 4.6 / Table 4.1.

    Planar geometry [m]: the tendon runs from the motor-side pulley M over the lever pulley P to the fixed
    pulley F; the lever turns about the pivot C; a linear spring joins the lever point Q to the anchor S.
    Pulleys are modelled by their centres.  At ``lever_straight_angle`` the tendon is straight and the
    stiffness unbounded (the tangent-alpha property).  The thesis prints no numbers for Table 4.1: these
    were chosen so that the force-angle curve matches Fig 4.8b (175 N at 48 deg, convex, dL ~6 mm, Fig 4.7).
    """

    pulley_spacing: float = param(0.060, unit="m", low=0.0, low_inclusive=False,
                                  source="chosen: |MF| = 60 mm, fits the forearm module")
    lever_length: float = param(0.015, unit="m", low=0.0, low_inclusive=False,
                                source="chosen: pivot to lever-pulley distance")
    pivot_offset: float = param(-0.015, unit="m",
                                source="chosen: pivot C on the line MF, 15 mm left of its midpoint")
    lever_straight_angle: float = param(math.radians(70.0), unit="rad", low=0.0, high=math.pi / 2,
                                        low_inclusive=False,
                                        source="chosen: tendon straight at 70 deg, beyond the 50 deg range of Fig 4.8b")
    spring_arm: float = param(0.012, unit="m", low=0.0, low_inclusive=False,
                              source="chosen: pivot to spring attachment Q (opposite arm)")
    spring_anchor: tuple = param((-0.025, -0.060), unit="m", vector=True,
                                 source="chosen: anchor S below the lever, spring nearly perpendicular to its arm")
    spring_constant: float = param(12462.0, unit="N/m", low=0.0, low_inclusive=False,
                                   source="chosen: K tuned so that f(48 deg) = 175 N (Fig 4.8b)")
    max_lever_angle: float = param(math.radians(55.0), unit="rad", low=0.0, high=math.pi / 2,
                                   low_inclusive=False,
                                   source="chosen: mechanical stop a little beyond the 50 deg of Fig 4.8b")

    def _validate(self) -> None:
        if len(self.spring_anchor) != 2:
            raise ValueError("SpringMechanismGeometry.spring_anchor must be a 2-vector (x, y) [m]")
        if self.max_lever_angle >= self.lever_straight_angle:
            raise ValueError(
                f"SpringMechanismGeometry.max_lever_angle = {self.max_lever_angle} must be below "
                f"lever_straight_angle = {self.lever_straight_angle} (the curve is singular there)")


@dataclass(frozen=True)
class HysteresisParams(Parameters):
    """Rate-independent hysteresis of the spring mechanism (Fig 4.8b, point A).

    A Dahl-type friction force ``z`` in the lever adds to the elastic force
    (:func:`~awiwi_drake.components.spring.hysteresis_rate`):
    ``dz/dt = (w / delta) xdot (1 - tanh(xdot / v_s) z / w)``, ``w = beta f_el(x) + z0``.
    The loop half-width at force f is ``beta f + z0``: the full width at 70 N is
    ``2 (70 beta + z0)``; after a reversal ``z`` crosses the loop within a few ``delta``.
    """

    enabled: bool = param(False, unit="-", source="chosen: off by default (optional effect)")
    width_ratio: float = param(0.1, unit="-", low=0.0,
                               source="chosen: full width 2 x 0.1 x 70 N = 14 N at 70 N (Fig 4.8b: 10-20 N)")
    width_offset: float = param(0.0, unit="N", low=0.0, source="chosen: loop closes at zero force")
    presliding_length: float = param(
        4e-4, unit="m", low=0.0, low_inclusive=False,
        source=("chosen: the thesis prints no reversal shape; delta is the smallest presliding length for "
                "which fixed-step RK3 at the 3 kHz control period is stable on every finger and the hand at the "
                "operating point's 20 N (not at every pretension: the thumb under joint-pd at 40 N grows a numerical "
                "oscillation, README; docs/REPRODUCTIONS.md, 'Thesis physics at 3 kHz'): the state's relaxation rate |xdot|/delta "
                "and the presliding stiffness w/delta in parallel with the spring both enter |h lambda|"))
    smoothing_velocity: float = param(1e-4, unit="m/s", low=0.0, low_inclusive=False,
                                      source="chosen: v_s, smooth sign(xdot) for integration")


@dataclass(frozen=True)
class TendonParams(Parameters):
    """Dyneema tendon in series with the mechanism (ch. 4, section 5.1).

    ``k_t = E S / l0``.
    """

    youngs_modulus: float = param(100e9, unit="Pa", low=0.0, low_inclusive=False,
                                  source="chosen: the tendons are Dyneema (ch. 4, Fig 4.3; k_t = E S / l0, section 5.1, prints no E): a typical UHMWPE fibre modulus")
    diameter: float = param(1.0e-3, unit="m", low=0.0, low_inclusive=False,
                            source="chosen: 1 mm braided tendon")
    rest_length: float = param(0.4, unit="m", low=0.0, low_inclusive=False,
                               source="chosen: forearm motor to finger joint, about 40 cm")
    fill_factor: float = param(0.5, unit="-", low=0.0, high=1.0, low_inclusive=False,
                               source="chosen: braid fill factor, effective load-bearing fraction of the section")

    @property
    def cross_section(self) -> float:
        """Effective load-bearing cross-section S [m^2]."""
        return self.fill_factor * math.pi * self.diameter ** 2 / 4.0


@dataclass(frozen=True)
class GuideFrictionParams(Parameters):
    """Tendon guide friction: bending-angle law (4.1) and a capstan variant.

    (4.1): ``F = C0 (1 - exp(-C1 alpha))`` (independent of tension and speed); capstan:
    ``F = f (1 - exp(-mu alpha))`` (ch. 9 reports routing friction of 10-50 % of the measured force).
    """

    c0: float = param(2.2, unit="N", low=0.0,
                      source=("Fig 4.10: the 6.5 mm Dyneema curve (the hand's pulleys) saturates near 2 N at 200 deg; "
                              "with c1, 1.96 / 2.12 N on the finger paths (bending 180 / 270 deg), 10 % of the 20 N "
                              "pretension: the low end of ch. 9's routing friction, '10 % to 50 %. That is for a "
                              "measured force of 20 N the effective pulling force is between 10 N and 30 N'"))
    c1: float = param(0.7, unit="1/rad", low=0.0,
                      source="chosen: with c0, 0.2 N at 8 deg and 2.0 N at 200 deg (Fig 4.10 range 0.2-2 N)")
    mu: float = param(0.1, unit="-", low=0.0, high=1.0,
                      source="Fig 4.11: sliding friction coefficients 0.05-0.2; 0.1 gives 30 % loss at 200 deg (ch. 9: 10-50 %)")


@dataclass(frozen=True)
class TendonGuideParams(Parameters):
    """The guide friction of one tendon path, given directly (``FingerDriveParams.tendon_guides``).

    The two numbers of :func:`~awiwi_drake.components.friction.guide_friction`, the tension-independent part C
    and the capstan exponent ``mu alpha``, for one tendon whose guides differ from the rest (e.g. a discrepancy
    diagnosis's write-back).
    """

    constant: float = param(0.0, unit="N", low=0.0, high=100.0,
                            source="(4.1): C0 (1 - exp(-C1 alpha)); Fig 4.10 tops at ~2 N for the hand's pulleys",
                            doc="tension-independent sliding friction of the path")
    capstan_exponent: float = param(0.0, unit="-", low=0.0, high=3.0,
                                    source="Fig 4.11: mu 0.05-0.2 over 1-4 rad of bending; ch. 9: 10-50 % loss",
                                    doc="mu alpha of the capstan law on the path")


@dataclass(frozen=True)
class JointFrictionParams(Parameters):
    """Stick-slip friction of a finger joint (its bearing), :func:`~awiwi_drake.components.friction.stick_slip_rate`.

    The Stribeck curve ``W(v) = Fc + (Fs - Fc) exp(-(v/v_s)^2)`` as the level of a presliding state of stiffness
    ``Fs / delta``.  The thesis names the joints' stick-slip (Fig 15.25: the cascaded loop's "vibrations ... caused by
    the stick-slip effect"; ch. 9, ch. 11 "stick-slip effects in the joint are preventing the link to reach the
    desired joint position") but prints no level, so the levels are chosen.
    """

    coulomb: float = param(0.01, unit="Nm", low=0.0, high=1.0,
                           source=("chosen: 10 mNm, 14 % of the 0.07 Nm one tendon at 10 N puts on the PIP "
                                   "(r22 = 7 mm): ch. 9's 'tendon friction reaches 10 % to 50 %' taken at its low "
                                   "end for a joint with bearings (15.5.3)"))
    static: float = param(0.015, unit="Nm", low=0.0, high=1.0,
                          source="chosen: breakaway 1.5x the Coulomb level, the drop that makes the joint stick and slip")
    stribeck_velocity: float = param(0.05, unit="rad/s", low=0.0, high=10.0, low_inclusive=False,
                                     source=("chosen: the level falls from breakaway to Coulomb over 0.05 rad/s, 2 % of the "
                                             "2.2 rad/s peak speed of Fig 15.25's sine (20 deg at 1 Hz), so a sliding "
                                             "joint carries the Coulomb level for most of each stroke"))
    presliding_angle: float = param(
        0.05, unit="rad", low=0.0, high=0.5, low_inclusive=False,
        source=("chosen by the fixed-step stability of the hand's integrator (RK3 at the 3 kHz control period h): at "
                "rest the joint is held by the presliding spring sigma0 = Fs / delta, which raises the square of the "
                "plant's fastest mode |h lambda_0|^2 by at most h^2 sigma0 lambda_max(M^-1); it stays inside RK3's "
                "region along that mode's ray (|h lambda| < |z_b|) for sigma0 <= (|z_b|^2 - |h lambda_0|^2) / (h^2 "
                "lambda_max(M^-1)), least on the fifth finger at 35 N: 0.37 Nm/rad (its damped PIP/DIP coupling mode, "
                "|h lambda_0| = 2.27, |z_b| = 2.33, lambda_max(M^-1) = 7.65e6 1/(kg m^2); index 0.61, thumb 0.60; "
                "pretension 10-35 N). sigma0 = 0.3 Nm/rad, delta = Fs / sigma0 = 0.05 rad. The memoryless law "
                "stribeck_friction cannot stick at this step: its slope Fs / v_eps needs h Fs M^-1_jj / v_eps <= 2.51 "
                "(RK3's real-axis bound), v_eps >= 2.5 rad/s on the index PIP and 10.7 rad/s on its DIP, above the "
                "2.2 rad/s peak of Fig 15.25's sine (docs/REPRODUCTIONS.md)"),
        doc="delta: the deflection over which the friction builds up to its breakaway level")

    def _validate(self) -> None:
        super()._validate()
        if self.static < self.coulomb:
            raise ValueError(f"JointFrictionParams.static = {self.static} Nm must be >= coulomb = {self.coulomb} Nm "
                             "(the Stribeck level falls from the breakaway to the Coulomb level)")
