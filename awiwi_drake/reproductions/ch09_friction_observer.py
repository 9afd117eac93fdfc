"""Thesis ch. 9: friction observer and compensation on the antagonistic joint (Fig 9.3).

The observer (9.2) and the link-side friction law are :mod:`awiwi_drake.control.friction_observer`.
"""

from __future__ import annotations

import numpy as np

from awiwi_drake.analysis import simulate
from awiwi_drake.control.backstepping import impedance_controller
from awiwi_drake.control.base import closed_loop
from awiwi_drake.control.friction_observer import with_link_friction
from awiwi_drake.parameters.backstepping import AntagonisticBacksteppingGains, ImpedanceBacksteppingGains
from awiwi_drake.parameters.hand_control import FrictionObserverParams, LinkFrictionParams
from awiwi_drake.parameters.rigs import JointRigParams
from awiwi_drake.reproductions.ch15_backstepping import BacksteppingRun, plot_run_traces, sine_reference
from awiwi_drake.rigs import joint_rig

__all__ = ["friction_tracking_run", "chattering", "plot_friction_runs"]


def friction_tracking_run(*, compensate: bool, amplitude: float = 0.3, frequency: float = 0.5,
                          t_final: float = 4.0, friction: LinkFrictionParams | None = None,
                          observer: FrictionObserverParams | None = None, gains=None, dt: float = 1e-3):
    """Fig 9.3: slow sinusoidal tracking of the antagonistic joint with link-side stick-slip friction.

    The joint rig's link gets the friction torque of :class:`LinkFriction` on its
    ``external_torque`` input; the antagonistic backstepping impedance controller estimates the
    disturbance with the observer (9.2) and, with ``compensate=True``, cancels it (``u = u_c +
    tau_fric_hat``). Returns a :class:`~awiwi_drake.reproductions.ch15_backstepping.BacksteppingRun`
    with the true friction as its ``disturbance`` and the observer's estimate as ``friction_estimate``.
    """
    fp = friction or LinkFrictionParams()
    rig = joint_rig(params=JointRigParams().replace(link_inertia=fp.test_joint_inertia))
    g = gains or AntagonisticBacksteppingGains()
    obs = observer or FrictionObserverParams()
    ig = ImpedanceBacksteppingGains(stiffness=g.stiffness, damping=g.damping, k3=g.k3, k4=g.k4, observer_gain=obs.gain)
    ctrl = impedance_controller(rig, ig, pretension=g.pretension, reference_derivatives=4, compensate=compensate)
    loop = closed_loop(rig, ctrl, rate_hz=None)
    diagram, cl, fr = with_link_friction(loop.diagram, fp)
    ctx = diagram.CreateDefaultContext()
    op = rig.operating_point(pretension=g.pretension)
    loop.diagram.GetSubsystemByName("rig").GetMyMutableContextFromRoot(ctx).SetContinuousState(op.state)
    res = simulate(diagram, ctx, t_final, inputs={"joint_angle_reference": sine_reference(amplitude, frequency)},
                   log=("state", "motor_torque", "controller_lyapunov", "controller_external_torque_estimate",
                        "link_friction", "joint_angle_reference"), log_period=dt, max_step=dt, accuracy=1e-6)
    F = res["link_friction"][:, 0]
    return BacksteppingRun("with compensation" if compensate else "without compensation", res.t, res["state"],
                           res["motor_torque"], res["controller_lyapunov"][:, 0], res["joint_angle_reference"][:, 0],
                           F, friction_estimate=res["controller_external_torque_estimate"][:, 0])


def chattering(run, *, after: float = 0.0) -> float:
    """Mean absolute rate of change of the motor torques [Nm/s] (total variation per second)."""
    m = run.t >= after
    u = run.command[m]
    return float(np.sum(np.abs(np.diff(u, axis=0))) / (run.t[m][-1] - run.t[m][0]))


def plot_friction_runs(runs, *, ax=None):
    """Fig 9.3: tracking error with/without friction compensation."""
    return plot_run_traces(runs, lambda r: r.q - r.reference, "tracking error [rad]", ax=ax)
