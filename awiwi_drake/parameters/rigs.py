"""Parameters of the three test rigs (ch. 10/14.2.1, 12/15.2-15.4, 15.5/Fig 5.9) and of the joint-rig demo loop."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from awiwi_drake.parameters.base import Parameters, param
from awiwi_drake.parameters.components import (
    HysteresisParams, MotorParams, SpringMechanismGeometry, TendonParams)

__all__ = ["SpringModelParams", "TendonRigParams", "FlexibleJointParams", "JointRigParams", "MotorPositionGains",
           "DemoScenario"]


@dataclass(frozen=True)
class SpringModelParams(Parameters):
    """How a rig's tendon spring is modelled: the thesis's real-time form, a calibration polynomial fitted to
    the lever mechanism in series with the tendon (ch. 4: calibrated on the mounted tendon)."""

    geometry: SpringMechanismGeometry = field(default_factory=SpringMechanismGeometry)
    tendon: TendonParams = field(default_factory=TendonParams)
    include_tendon: bool = param(True, unit="-", source="ch. 4 'Calibration': measured on the mounted tendon")
    polynomial_degree: int = param(6, unit="-", low=1, high=12,
                                   source="chosen: degree 6 fits the lever+tendon curve within 0.1 N over 0-180 N (tests)")
    max_force: float = param(180.0, unit="N", low=1.0,
                             source="Fig 4.8b: the calibrated range ends near 180 N")
    hysteresis: HysteresisParams = field(default_factory=HysteresisParams)


@dataclass(frozen=True)
class TendonRigParams(Parameters):
    """One motor winding one tendon through one spring mechanism; far end fixed (ch. 10, 14.2.1)."""

    motor: MotorParams = field(default_factory=MotorParams)
    spring: SpringModelParams = field(default_factory=SpringModelParams)
    operating_force: float = param(20.0, unit="N", low=0.0, low_inclusive=False,
                                   source="chosen: default operating point inside the 10-45 N steps of Fig 10.2")

    def _validate(self) -> None:
        if self.operating_force > self.spring.max_force:
            raise ValueError(f"TendonRigParams.operating_force = {self.operating_force} N exceeds the calibrated "
                             f"range spring.max_force = {self.spring.max_force} N")


@dataclass(frozen=True)
class FlexibleJointParams(Parameters):
    """Fourth-order flexible joint (12.8); defaults are Table 12.1.

    ``spring_model="linear"`` uses ``stiffness`` only; ``pretension``,
    ``pulley_radius`` and ``spring`` belong to ``spring_model="nonlinear"``
    (the rig rejects them when changed for the linear model).

    ``m qdd = -d_q qd + tau_s + tau_ext``; ``b thdd = -d_th thd - tau_s + u`` with
    ``tau_s = k (th - q)`` (linear) or, for ``spring="nonlinear"``, the torque of an
    antagonistic pair of lever springs at pretension ``pretension`` on pulleys of
    radius ``pulley_radius`` (ch. 15.4: ``tau = phi(th - q)``, radii folded into phi).
    """

    spring_model: str = param("linear", unit="-", choices=("linear", "nonlinear"),
                              source="(12.8) is linear; ch. 15.4 studies the nonlinear spring")
    link_inertia: float = param(4e-7, unit="kg m^2", low=0.0, low_inclusive=False, source="Table 12.1, m")
    motor_inertia: float = param(2e-3, unit="kg m^2", low=0.0, low_inclusive=False, source="Table 12.1, b")
    stiffness: float = param(0.605, unit="Nm/rad", low=0.0, low_inclusive=False, source="Table 12.1, k")
    link_damping: float = param(0.0012, unit="Nm s/rad", low=0.0, source="Table 12.1, d_q")
    motor_damping: float = param(0.0012, unit="Nm s/rad", low=0.0, source="Table 12.1, d_theta")
    torque_limit: float = param(math.inf, unit="Nm", low=0.0, low_inclusive=False, finite=False,
                                source="chosen: unlimited, as in (12.8); set for saturation studies (ch. 15)")
    pretension: float = param(20.0, unit="N", low=0.0, low_inclusive=False,
                              source="chosen: nonlinear spring only; Fig 15.26 uses 20 N")
    pulley_radius: float = param(0.008, unit="m", low=0.0, low_inclusive=False,
                                 source="chosen: nonlinear spring only; finger pulleys are 5-10 mm")
    spring: SpringModelParams = field(default_factory=SpringModelParams)

    def _validate(self) -> None:
        if self.spring_model == "nonlinear" and self.pretension > self.spring.max_force:
            raise ValueError(f"FlexibleJointParams.pretension = {self.pretension} N exceeds the calibrated range "
                             f"spring.max_force = {self.spring.max_force} N")


@dataclass(frozen=True)
class JointRigParams(Parameters):
    """One link driven antagonistically by two motors through two lever springs (Fig 5.9, ch. 15.5).

    ``x1 = r_m th1 - r_q q + x0``, ``x2 = r_m th2 + r_q q + x0``; ``m qdd = r_q (f1 - f2) - d_q qd + tau_ext``.
    """

    motor: MotorParams = field(default_factory=MotorParams)
    spring: SpringModelParams = field(default_factory=SpringModelParams)
    link_inertia: float = param(7.2e-7, unit="kg m^2", low=0.0, low_inclusive=False,
                                source="Tables 14.2, 15.1, 16.1 (finger link)")
    link_damping: float = param(1e-3, unit="Nm s/rad", low=0.0, source="Table 15.1, b_q")
    link_pulley_radius: float = param(0.008, unit="m", low=0.0, high=0.05, low_inclusive=False,
                                      source="chosen: r_q, the index MCP pulley radius (FingerParams.mcp_radius; the thesis prints no radii)")
    pretension: float = param(20.0, unit="N", low=0.0, low_inclusive=False,
                              source="Fig 15.26: f_pre = 20 N (default operating point)")

    def _validate(self) -> None:
        if self.pretension > self.spring.max_force:
            raise ValueError(f"JointRigParams.pretension = {self.pretension} N exceeds the calibrated range "
                             f"spring.max_force = {self.spring.max_force} N")


@dataclass(frozen=True)
class MotorPositionGains(Parameters):
    """Per-motor PD gains of the joint-rig demo loop (:mod:`awiwi_drake.control.motor_position`, output shaft)."""

    kp: float = param(40.0, unit="Nm/rad", low=0.0, low_inclusive=False,
                      source="chosen: 0.56 Nm Coulomb friction (Table 3.3) leaves a 0.014 rad motor error")
    kd: float = param(0.4, unit="Nm s/rad", low=0.0,
                      source="chosen: with B = 2e-3 and the linearised friction (5.6 Nm s/rad) the loop is overdamped")
    rate_hz: float = param(3000.0, unit="Hz", low=1.0, source="ch. 1/10: Awiwi control rate 3 kHz")


@dataclass(frozen=True)
class DemoScenario(Parameters):
    """Joint-rig demo scenario (``awiwi-drake demo``): pretension ramp then a link position step."""

    f_start: float = param(5.0, unit="N", low=0.0, low_inclusive=False, source="chosen: light pretension")
    f_end: float = param(30.0, unit="N", low=0.0, low_inclusive=False, source="chosen: Fig 15.26 range (20 N) and above")
    ramp_time: float = param(0.5, unit="s", low=0.0, low_inclusive=False, source="chosen: slow against the joint rig's fastest mode, so the ramp is quasi-static")
    step_time: float = param(0.7, unit="s", low=0.0, source="chosen: after the ramp settles")
    link_step: float = param(0.3, unit="rad", low=-1.5, high=1.5, source="chosen: a finger-sized step")
    t_final: float = param(1.2, unit="s", low=0.0, low_inclusive=False, source="chosen: 0.5 s after the step, enough for it to settle")
