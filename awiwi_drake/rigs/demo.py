"""References of the main demo (the loop: :mod:`awiwi_drake.control.motor_position`).

Scenario (:class:`~awiwi_drake.parameters.rigs.DemoScenario`): the pretension ramps from ``f_start`` to
``f_end`` with the link at rest, then the link steps to ``link_step`` rad.
References are turned into motor-angle set points through the rig's own spring
law (``x_i = f^-1(f_pre)``, ``theta_i* = (x_i +- r_q q*) / r_m``); each motor runs
a PD loop with tendon-force feedforward at 3 kHz.
"""

from __future__ import annotations

import numpy as np

from awiwi_drake.rigs.base import Rig

__all__ = ["motor_references"]


def motor_references(rig: Rig, t: np.ndarray, pretension: np.ndarray, joint_angle: np.ndarray):
    """Motor-angle set points and feedforward torques realising pretension and link angle.

    Returns ``(theta_ref (2, T), torque_ff (2, T))`` for the joint rig.
    """
    p = rig.params
    r, rq = p.motor.pulley_radius, p.link_pulley_radius
    x = np.asarray(rig.spring.inverse_force(np.asarray(pretension, dtype=float)), dtype=float)
    theta = np.stack([(x + rq * joint_angle) / r, (x - rq * joint_angle) / r])
    ff = np.stack([r * np.asarray(pretension), r * np.asarray(pretension)])
    return theta, ff
