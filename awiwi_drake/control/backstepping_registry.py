"""Registry entries for ctrl1's comparison tool: ``backstepping`` and ``optimal-backstepping``.

* ``backstepping``: the impedance backstepping controller matching the rig
  (flexible joint: (15.51)-(15.81) with the rig's own spring law, linear or
  nonlinear; joint rig: the antagonistic controller (15.82)-(15.106)), with the
  external-torque observer (9.2).
* ``backstepping-position``: the position controller (15.11)-(15.50)
  (linear flexible joint only).
* ``optimal-backstepping``: the impedance controller whose gains
  ``(Kp,imp, Kd,imp, K3, K4)`` are fitted (ch. 16, scipy least squares) to the
  LQR of the rig with Table 16.1's weights in torque coordinates
  (``R = 1e-3``: with Table 16.1's ``R = 0.1`` the LQR gain is below the
  structural floor of the backstepping feedback, see REPRODUCTIONS.md).
  On the joint rig: the antagonistic law with gains fitted to the LQR of the
  rig at its operating point (:class:`JointRigOptimalGainsCase`, N = 2 torque
  coordinates), inside a gain box bounded by the loop rate (``rate_limited_case``).

Loop option: sampled at the thesis's 3 kHz, with Kd,imp limited to ``m f_s / 4``
(the impedance damping puts a link pole at ``-Kd,imp / m``; the limit keeps
``h lambda >= -1/4``).  Why: with the limit computed for 30 kHz (Kd,imp = 5.4e-3 on
the joint rig's 7.2e-7 kg m^2 link, ``h lambda = -2.5`` at 3 kHz) the 3 kHz step
saturated 48 % of the time and did not settle; at rest that loop is still stable (the exact
one-period map of the sampled loop, AutoDiff through the Simulator, has spectral radius 0.9943; a
one-period-delay model had said 1.018) and turns unstable from Kd,imp ~ 6.65e-3, so the failure is the
step's saturation, not a linear instability at rest (tests/test_backstepping.py, docs/REPRODUCTIONS.md);
with Kd,imp = m f_s / 4 = 5.4e-4
the 3 kHz step settles in 0.22 s without saturation (docs/REPRODUCTIONS.md,
ch. 15).  The limit is conservative at higher rates (``--rate 30000``).
``--rate 0`` runs it continuously.
"""

from __future__ import annotations

from awiwi_drake.control.registry import register_controller

_LOOP = {"rate_hz": 3000.0}   # the thesis's control rate (section 15.5 experiments); see the module docstring


def _sampled_damping(rig, damping: float) -> float:
    """Kd,imp limited so that the link pole -Kd,imp/m stays at |h lambda| <= 1/4 ... 1 of the sampled loop."""
    return min(damping, rig.params.link_inertia * _LOOP["rate_hz"] / 4.0)


def _backstepping(rig):
    from awiwi_drake.control.backstepping import impedance_controller
    from awiwi_drake.parameters.backstepping import AntagonisticBacksteppingGains, ImpedanceBacksteppingGains
    from awiwi_drake.parameters.rigs import JointRigParams
    g = AntagonisticBacksteppingGains() if isinstance(rig.params, JointRigParams) else ImpedanceBacksteppingGains()
    return impedance_controller(rig, g.replace(damping=_sampled_damping(rig, g.damping)))


def _position(rig):
    from awiwi_drake.control.backstepping import position_controller
    return position_controller(rig)


def _optimal(rig):
    from awiwi_drake.control.backstepping import impedance_controller
    from awiwi_drake.control.optimal_gains import optimize_gains, rate_limited_case
    from awiwi_drake.parameters.backstepping import JointRigOptimalGainsCase, OptimalGainsCase
    from awiwi_drake.parameters.rigs import JointRigParams
    if isinstance(rig.params, JointRigParams):
        case = rate_limited_case(JointRigOptimalGainsCase(), rig.params.link_inertia, _LOOP["rate_hz"])
        fit = optimize_gains(rig, case, starts=16)
    else:
        fit = optimize_gains(rig, OptimalGainsCase(r_weight=1e-3))
    return impedance_controller(rig, fit.gains)


register_controller("backstepping", _backstepping, rigs=("flexible-joint", "joint-rig"), loop_options=_LOOP,
                    description="impedance backstepping (ch. 15.3-15.5), rig's spring law, external-torque observer")
register_controller("backstepping-position", _position, rigs=("flexible-joint",), loop_options=_LOOP,
                    description="position backstepping of the linear flexible joint (15.11)-(15.50)")
register_controller("optimal-backstepping", _optimal, rigs=("flexible-joint", "joint-rig"), loop_options=_LOOP,
                    description="impedance backstepping with gains fitted to the LQR (ch. 16)")
