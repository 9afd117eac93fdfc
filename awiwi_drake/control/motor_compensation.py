"""Motor-level compensation (ch. 3): a motor PD with friction (3.8) and ripple feed-forward.

``u = Kp (th_r - th) + Kd (w_r - w) - s_f tau_fric(w) - tau_r_hat(th)``: the
ripple estimate is fed forward with a conservative amplitude (ch. 3:
over-compensation injects energy). The identification experiments (Fig 3.3,
3.5-3.6) are :mod:`awiwi_drake.reproductions.ch03_motor`.
"""

from __future__ import annotations

import numpy as np

from awiwi_drake.components import motor_friction_torque, motor_ripple_torque
from awiwi_drake.control.base import StaticLaw, check_gain
from awiwi_drake.parameters.components import MotorParams

__all__ = ["MotorPdLaw"]


class MotorPdLaw(StaticLaw):
    """PD on a motor position/velocity reference with optional friction and ripple feed-forward.

    ``u = Kp (th_r - th) + Kd (w_r - w) - s_f tau_fric(w) - tau_r_hat(th)``; ``ripple``: the estimated motor
    (a :class:`~awiwi_drake.parameters.components.MotorParams` whose ripple fields hold the estimate, e.g. from
    :func:`~awiwi_drake.reproductions.ch03_motor.identify_ripple`), ``tau_r_hat`` its (3.5).
    """

    name = "motor_pd"
    inputs = {"motor_angle_reference": 1, "motor_velocity_reference": 1, "motor_angle": 1, "motor_velocity": 1}
    output_size = 1

    def __init__(self, motor: MotorParams, kp: float, kd: float, *, friction_scale: float = 0.0,
                 ripple: MotorParams | None = None):
        self.motor = motor
        self.kp = check_gain("position_gain", kp, owner=self.name)
        self.kd = check_gain("velocity_gain", kd, owner=self.name)
        self.friction_scale = check_gain("friction_scale", friction_scale, owner=self.name, allow_zero=True)
        self.ripple = ripple

    def feedforward(self, theta, omega):
        ff = -self.friction_scale * motor_friction_torque(omega, self.motor)
        if self.ripple is not None:
            ff = ff - motor_ripple_torque(theta, self.ripple)
        return ff

    def __call__(self, u):
        th, w = u["motor_angle"][0], u["motor_velocity"][0]
        fb = self.kp * (u["motor_angle_reference"][0] - th) + self.kd * (u["motor_velocity_reference"][0] - w)
        return np.array([fb + self.feedforward(th, w)])
