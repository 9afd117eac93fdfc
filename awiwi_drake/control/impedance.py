"""Joint impedance control on top of tendon force control (ch. 11).

Link side (11.4), regulation form without the negligible ``M qdd_des`` and
Coriolis/gravity terms of a finger (ch. 5)::

    tau_des = Kp_imp (q_des - q) - Kd_imp qdot

Desired tendon forces from the coupling pseudo-inverse plus the pretension
null-space term (section 11.3, ch. 7)::

    f_des = f_pre + c^+ tau_des      (tau = sum_i c_i f_i)

Three tendon-level laws turn ``f_des`` into motor torques (motor ``i`` winds
tendon ``i`` on a pulley of radius ``r_m``):

``pd`` (baseline, no impedance layer)
    PD on the motor angles towards the motor angles that hold the link at
    ``q_des`` (equilibrium family of the rig linearisation, exact for these
    rigs): ``u = u_ref(q_des) + Kp_m (theta_ref(q_des) - theta) - Kd_m thetadot``.
    The joint stiffness at rest is the mechanical stiffness in series with
    the motor position loop.
``two-time-scale`` (11.3)
    motor-position inner loop towards the motor angle that generates
    ``f_des``: ``theta_des = theta + (f_des - f) / alpha`` (``alpha = r_m k_t``,
    exact for a linear spring, first order otherwise)::

        u = r_m f + Kp_m (theta_des - theta) - Kd_m thetadot + b_hat(thetadot)

    with ``Kp_m = B w_m^2``, ``Kd_m = 2 xi_m w_m B``.
``cascaded`` (11.16)
    linearising force controller so that the force error obeys
    ``e_f'' + 2 xi_f w_f e_f' + w_f^2 e_f = 0`` (the cascaded form needs a law in
    ``f``, not ``theta``, section 11.7)::

        u = r_m f + b_hat + (B / alpha) (w_f^2 (f_des - f) + 2 xi_f w_f (fdot_des - fdot)),
        fdot = k_t (r_m thetadot - c qdot),  fdot_des = -c^+ Kp_imp qdot

Rigs: the flexible joint (``c = [1]``, ``r_m = 1``: the "tendon force" is the
spring torque) and the antagonistic joint rig (``c = [r_q, -r_q]``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from awiwi_drake._math import smax
from awiwi_drake.control.base import StaticLaw, StaticLawController, check_gain
from awiwi_drake.control.registry import rig_kind
from awiwi_drake.parameters.components import MotorParams
from awiwi_drake.parameters.control import ImpedanceParams

__all__ = ["Transmission", "transmission", "ImpedanceLaw", "MotorPdLaw", "impedance_controller", "MODES"]

MODES = ("pd", "two-time-scale", "cascaded")


@dataclass(frozen=True)
class Transmission:
    """Static transmission of a joint rig: ``tau = c . f``, motor pulley ``r_m``, pretension, motors."""

    coupling: np.ndarray      # c_i [m] (or 1 for the flexible joint)
    pulley_radius: float      # r_m
    pretension: np.ndarray    # f_pre per tendon [N] (or [Nm])
    motor: MotorParams
    compensate_friction: bool
    min_alpha: float = 0.0    # floor of r_m k_t in the laws: a slack tendon has k_t = 0

    @property
    def pseudo_inverse(self) -> np.ndarray:
        c = self.coupling
        return c / float(c @ c)


def transmission(rig: Any) -> Transmission:
    """The :class:`Transmission` of a flexible-joint or joint rig (from its parameters)."""
    kind = rig_kind(rig)
    p = rig.params
    if kind == "flexible_joint":
        # the rig's motor: no (3.8) friction, linear damping d_theta (12.8); nothing to compensate
        motor = MotorParams(inertia=p.motor_inertia, friction=False, damping=p.motor_damping, ripple=False,
                            saturation=False)
        return Transmission(np.array([1.0]), 1.0, np.array([0.0]), motor, False, 0.05 * p.stiffness)
    if kind == "joint_rig":
        rq = p.link_pulley_radius
        k_pre = float(np.ravel(rig.operating_point().info["tendon_stiffness"])[0])
        # floor: 5 % of the stiffness at pretension (chosen: keeps the laws finite when a tendon goes slack)
        return Transmission(np.array([rq, -rq]), p.motor.pulley_radius, np.full(2, p.pretension), p.motor, True,
                            0.05 * p.motor.pulley_radius * k_pre)
    raise ValueError(f"impedance control needs a joint rig (flexible-joint or joint-rig), got {kind!r}")


class ImpedanceLaw(StaticLaw):
    """Joint impedance (11.4) over a tendon law ``pd`` / ``two-time-scale`` (11.3) / ``cascaded`` (11.16)."""

    def __init__(self, tr: Transmission, params: ImpedanceParams | None = None, *, mode: str = "two-time-scale"):
        if mode not in MODES[1:]:
            raise ValueError(f"impedance mode {mode!r} unknown; use one of {', '.join(MODES[1:])}")
        p = params or ImpedanceParams()
        self.name = mode.replace("-", "_")
        self.mode, self.tr, self.params = mode, tr, p
        self.kp_imp = check_gain("joint_stiffness", p.joint_stiffness, owner=self.name)
        self.kd_imp = check_gain("joint_damping", p.joint_damping, owner=self.name, allow_zero=True)
        B = tr.motor.inertia
        wm = check_gain("motor_bandwidth", p.motor_bandwidth, owner=self.name)
        xm = check_gain("motor_damping_ratio", p.motor_damping_ratio, owner=self.name)
        self.kp_m, self.kd_m = B * wm ** 2, 2 * xm * wm * B
        wf = check_gain("force_bandwidth", p.force_bandwidth, owner=self.name)
        xf = check_gain("force_damping_ratio", p.force_damping_ratio, owner=self.name)
        self.kf, self.kfd = wf ** 2, 2 * xf * wf
        n = len(tr.coupling)
        self.inputs = {"link_angle_reference": 1, "link_angle": 1, "link_velocity": 1, "motor_velocity": n,
                       "tendon_force": n, "tendon_stiffness": n}
        self.output_size = n

    def desired_forces(self, q_des, q, qdot):
        tau = self.kp_imp * (q_des - q) - self.kd_imp * qdot
        return self.tr.pretension + self.tr.pseudo_inverse * tau

    def __call__(self, u):
        from awiwi_drake.components import motor_friction_torque
        tr = self.tr
        q, qd = u["link_angle"][0], u["link_velocity"][0]
        w, f, k = u["motor_velocity"], u["tendon_force"], u["tendon_stiffness"]
        f_des = self.desired_forces(u["link_angle_reference"][0], q, qd)
        B, r = tr.motor.inertia, tr.pulley_radius
        comp = -motor_friction_torque(w, tr.motor) if (tr.compensate_friction and self.params.friction_compensation) \
            else 0.0 * w
        alpha = smax(r * k, tr.min_alpha)
        if self.mode == "two-time-scale":
            theta_err = (f_des - f) / alpha  # theta_des - theta
            return r * f + self.kp_m * theta_err - self.kd_m * w + comp
        fdot = k * (r * w - tr.coupling * qd)
        fdot_des = tr.pseudo_inverse * (-self.kp_imp * qd)  # d/dt f_des without the acceleration term
        return r * f + comp + (B / alpha) * (self.kf * (f_des - f) + self.kfd * (fdot_des - fdot))


class MotorPdLaw(StaticLaw):
    """``u = u_ref(r) + Kp_m (theta_ref(r) - theta) - Kd_m thetadot`` on the motor coordinates of ``state``."""

    def __init__(self, lin, motor_index, inertia: float, params: ImpedanceParams | None = None):
        from awiwi_drake.control.linear import reference_maps
        p = params or ImpedanceParams()
        self.name = "pd"
        wm = check_gain("motor_bandwidth", p.motor_bandwidth, owner=self.name)
        xm = check_gain("motor_damping_ratio", p.motor_damping_ratio, owner=self.name)
        B = check_gain("inertia", inertia, owner=self.name)
        self.kp_m, self.kd_m = B * wm ** 2, 2 * xm * wm * B
        self.Nx, self.Nu = reference_maps(lin.A, lin.B, lin.C["link_angle"])
        self.x0, self.u0 = lin.x0, lin.u0
        self.r0 = float(np.ravel(lin.y0["link_angle"])[0])
        self.ith, self.iw = list(motor_index[0]), list(motor_index[1])
        self.inputs = {"link_angle_reference": 1, "state": lin.A.shape[0]}
        self.output_size = lin.B.shape[1]

    def __call__(self, u):
        x = u["state"]
        dr = u["link_angle_reference"][0] - self.r0
        x_ref = self.x0 + self.Nx * dr
        return (self.u0 + self.Nu * dr + self.kp_m * (x_ref[self.ith] - x[self.ith])
                - self.kd_m * (x[self.iw] - x_ref[self.iw]))


def impedance_controller(rig: Any, params: ImpedanceParams | None = None, *, mode: str = "two-time-scale"):
    """Registered factories ``pd``, ``two-time-scale``, ``cascaded``."""
    if mode == "pd":
        from awiwi_drake.control.linear import linearize_rig
        tr = transmission(rig)
        lin = linearize_rig(rig, outputs=("state", "link_angle"))
        names = list(rig.state_names)
        n = len(tr.coupling)
        ith = [names.index(nm) for nm in (("theta",) if n == 1 else ("theta1", "theta2"))]
        iw = [names.index(nm) for nm in (("thetadot",) if n == 1 else ("omega1", "omega2"))]
        return StaticLawController(MotorPdLaw(lin, (ith, iw), tr.motor.inertia, params))
    return StaticLawController(ImpedanceLaw(transmission(rig), params, mode=mode))
