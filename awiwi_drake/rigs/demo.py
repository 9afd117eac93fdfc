"""Parameters and references of the main demo (the loop: :mod:`awiwi_drake.control.motor_position`).

Scenario (:class:`DemoScenario`): the pretension ramps from ``f_start`` to
``f_end`` with the link at rest, then the link steps to ``link_step`` rad.
References are turned into motor-angle set points through the rig's own spring
law (``x_i = f^-1(f_pre)``, ``theta_i* = (x_i +- r_q q*) / r_m``); each motor runs
a PD loop with tendon-force feedforward at 3 kHz.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from awiwi_drake.parameters.base import Parameters, param
from awiwi_drake.rigs.base import Rig

__all__ = ["DemoScenario", "MotorPositionGains", "motor_references"]


@dataclass(frozen=True)
class MotorPositionGains(Parameters):
    """Per-motor PD gains of the demo controller (output shaft)."""

    kp: float = param(40.0, unit="Nm/rad", low=0.0, low_inclusive=False,
                      source="chosen: 0.56 Nm Coulomb friction (Table 3.3) leaves a 0.014 rad motor error")
    kd: float = param(0.4, unit="Nm s/rad", low=0.0,
                      source="chosen: with B = 2e-3 and the linearised friction (5.6 Nm s/rad) the loop is overdamped")
    rate_hz: float = param(3000.0, unit="Hz", low=1.0, source="ch. 1/10: Awiwi control rate 3 kHz")


@dataclass(frozen=True)
class DemoScenario(Parameters):
    """Pretension ramp then a link position step."""

    f_start: float = param(5.0, unit="N", low=0.0, low_inclusive=False, source="chosen: light pretension")
    f_end: float = param(30.0, unit="N", low=0.0, low_inclusive=False, source="chosen: Fig 15.26 range (20 N) and above")
    ramp_time: float = param(0.5, unit="s", low=0.0, low_inclusive=False, source="chosen: slow against the joint rig's fastest mode, so the ramp is quasi-static")
    step_time: float = param(0.7, unit="s", low=0.0, source="chosen: after the ramp settles")
    link_step: float = param(0.3, unit="rad", low=-1.5, high=1.5, source="chosen: a finger-sized step")
    t_final: float = param(1.2, unit="s", low=0.0, low_inclusive=False, source="chosen: 0.5 s after the step, enough for it to settle")


def motor_references(rig: Rig, t: np.ndarray, pretension: np.ndarray, link_angle: np.ndarray):
    """Motor-angle set points and feedforward torques realising pretension and link angle.

    Returns ``(theta_ref (2, T), torque_ff (2, T))`` for the joint rig.
    """
    p = rig.params
    r, rq = p.motor.pulley_radius, p.link_pulley_radius
    x = np.asarray(rig.spring.inverse_force(np.asarray(pretension, dtype=float)), dtype=float)
    theta = np.stack([(x + rq * link_angle) / r, (x - rq * link_angle) / r])
    ff = np.stack([r * np.asarray(pretension), r * np.asarray(pretension)])
    return theta, ff
