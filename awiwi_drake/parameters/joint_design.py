"""Per-joint design targets of the hand's joint-level stage (:mod:`awiwi_drake.control.joint_design`).

Each independent DoF of a finger/the hand is designed on its own reduced model: the link (its
inertia ``M_jj`` at the operating point) driven through the closed tendon force loop, in the
measurable coordinates ``z = [q, qdot, tau, tau_dot]`` (Drake ``Linearize``).  The thesis designed
its laws on the flexible joint (Tables 12.1, 13.1, 14.2) and says only that they were "applied to
the 19 joints of the hand"; the per-joint targets below are chosen and say why.
"""

from __future__ import annotations

from dataclasses import dataclass

from awiwi_drake.parameters.base import Parameters, param

__all__ = ["JointDesignParams"]


@dataclass(frozen=True)
class JointDesignParams(Parameters):
    """Targets of the per-joint designs on the reduced model ``z = [q, qdot, tau, tau_dot]``."""

    position_bandwidth: float = param(
        60.0, unit="rad/s", low=0.0, low_inclusive=False,
        source="chosen: a fifth of the chain's 300 rad/s force loop (HandChainParams.force_bandwidth), so "
               "the joint pair stays behind the force loop it acts through (15.5.3)",
        doc="pole placement: omega1 of (12.13) (omega2: the joint's own tendon-link pair, see joint_design)")
    damping_ratio: float = param(0.7, unit="-", low=0.0, low_inclusive=False,
                                 source="chosen: as xi1 = xi2 = 0.7 of Table 12.1",
                                 doc="cascaded: of the slowest mode; pole placement: xi1 = xi2 of (12.13)")
    pair_damping_min: float = param(
        0.05, unit="-", low=0.0, high=1.0, low_inclusive=False,
        source="chosen: the least damping pole placement gives the joint's own pair when it lowers xi2 to keep the "
               "motor-held damping Kd - K_taud K_jj >= 0 (joint_design.motor_held_damping; measured: the index "
               "PIP / DIP need 0.37 / 0.21, the thumb's DoF 0.24-0.41); below it the design is refused",
        doc="pole placement: lower end of the xi2 search")
    lqr_angle_error: float = param(
        0.05, unit="rad", low=0.0, low_inclusive=False,
        source="chosen: Bryson's rule, an acceptable joint error of ~3 deg (the compare step is 0.2 rad)")
    lqr_velocity: float = param(
        12.0, unit="rad/s", low=0.0, low_inclusive=False,
        source="chosen: Bryson's rule, the peak velocity of a 0.2 rad step at the 60 rad/s joint bandwidth (0.2 x 60). "
               "Measured (sampled_loop_poles, 3 kHz, estimator, default physics with guide friction): the former "
               "5 rad/s made the index DIP's torque gain K_tau = 21.5 and left the fast PIP/DIP mode at +1.06 +- 4382j "
               "1/s (|z| = 1.00035); that mode (whole-finger M^-1 with the springs and the presliding of hysteresis "
               "and guides; absent from the per-joint models) sees the torque feedback ~1.5 periods late, where a "
               "positive gain removes damping (halving the DIP's K_tau alone: -47 1/s). 12 rad/s (with lqr_input "
               "0.05 Nm) damps it on every finger and the hand (tests/test_joint_design.py)")
    lqr_torque_error: float = param(
        0.05, unit="Nm", low=0.0, low_inclusive=False,
        source="chosen: Bryson's rule, 0.05 Nm ~ 10 % of a finger joint's torque range (the chosen 0.5 Nm/rad "
               "impedance, Fig 15.22's single-joint testbed, x 0.2 rad "
               "is 0.1 Nm)")
    lqr_torque_rate: float = param(
        1.0, unit="Nm/s", low=0.0, low_inclusive=False,
        source="chosen: Bryson's rule, the torque error above over ~50 ms. The LQR/SDRE stages measure the motors' "
               "rate sigma = tau_dot + K_jj qdot (joint_stage), weighted with the bound lqr_torque_rate + K_jj "
               "lqr_velocity (joint_design._lqr_weights). Measured at 3 kHz with the estimator and the default "
               "physics without guide friction, lqr_velocity 5 rad/s (control.joint_design.sampled_loop_poles): index "
               "slowest pole -16 1/s, DIP link mode (~3930 rad/s) damped at -30 1/s (5 Nm/s: -11 1/s); one bound "
               "sigma <= 5 Nm/s for every joint held the thumb base (K_jj = 47 Nm/rad) to -0.66 1/s, with the sum "
               "-2.0 1/s (guide friction on: see lqr_velocity)")
    lqr_input: float = param(
        0.05, unit="Nm", low=0.0, low_inclusive=False,
        source="chosen: Bryson's rule on the desired joint torque, the torque error's bound (the input is a torque "
               "request the force loop turns into that torque). Measured (sampled_loop_poles, index and thumb, 3 kHz): "
               "with the former 0.1 Nm the fast PIP/DIP mode (see lqr_velocity) is unstable when the motors' "
               "friction is off (index +32 1/s at 4388 rad/s); 0.05 Nm is stable with the default physics, without "
               "guide friction, without motor friction and ripple, and on the design model's plant (true state)")
    sdre_torque_range: float = param(
        0.2, unit="Nm", low=0.0, low_inclusive=False,
        source="chosen: the SDRE table spans tau_op +- 0.2 Nm (a 0.2 rad step on 0.5-1 Nm/rad joints)")
    sdre_points: int = param(5, unit="-", low=2,
                             source="chosen: 5 pointwise-linear models per DoF (the spring slope is smooth, Fig 4.8b)")
