"""Tendon force control (ch. 10, (10.2)-(10.12)) on the tendon rig.

Plant (10.1): ``B thdd = tau_fric(thd) + tau_ripple(th) + u - r_m f_t(th)`` (the
tendon is fixed at its far end, so the force is a function of the motor angle).

Controller (10.2)::

    u = Kp (f_des - f) - Kd fdot_hat + [r_m f]_ff + [-tau_fric_hat(thd)]_ff

with ``fdot_hat = alpha(f) thd`` (``alpha = d f_t / d theta``, the rig's force
map) and gains by identification to a damped second-order error dynamics
(10.10)-(10.11)::

    Kp = w^2 B / alpha,   Kd = 2 xi w B / alpha.

*Fixed gains* evaluate ``alpha`` at the design force (30 N, Fig 10.2);
*scheduled gains* evaluate it at the reference force (10.12), by linear
interpolation in a table (section 10.3: "a simple linear interpolation").
The thesis writes ``Kp = w^2 B / beta`` and ``Kd = 2 xi w B / alpha`` with
alpha, beta the derivatives of ``f_t`` and of ``fdot`` w.r.t. ``theta_dot``
and ``theta``; for a force that depends on ``theta`` only both equal
``d f_t / d theta``, which is what is used here.

Steady state (all derivatives zero, friction (3.8) vanishes at rest):
without the force feed-forward ``Kp (f_des - f) = r_m f`` (10.3), i.e.
``f = f_des Kp / (Kp + r_m)``; with it the error vanishes (10.4).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from awiwi_drake._math import is_float
from awiwi_drake.control.base import StaticLaw, StaticLawController, check_gain
from awiwi_drake.parameters.control import TendonForceGains

__all__ = ["ForceMap", "force_map", "interp", "TendonForceLaw", "tendon_pd_controller",
           "tendon_scheduled_controller", "identified_gains", "steady_state_force_without_feedforward"]


def interp(x, xp: np.ndarray, fp: np.ndarray):
    """Piecewise-linear interpolation for float and AutoDiffXd (derivative = local slope).

    Outside the table the end segments are extrapolated linearly.
    """
    xp = np.asarray(xp, float)
    fp = np.asarray(fp, float)
    if is_float(x):
        xv = float(np.asarray(x).reshape(-1)[0]) if np.ndim(x) else float(x)
    else:
        xi = np.asarray(x, dtype=object).reshape(-1)[0]
        xv = xi.value()
        x = xi
    i = int(np.clip(np.searchsorted(xp, xv) - 1, 0, len(xp) - 2))
    slope = (fp[i + 1] - fp[i]) / (xp[i + 1] - xp[i])
    return fp[i] + slope * (x - xp[i])


@dataclass
class ForceMap:
    """Tabulated static tendon force ``f(theta)`` of a rig and its slope ``alpha(theta)``.

    ``theta`` is increasing; only the taut, strictly increasing part is kept.
    """

    theta: np.ndarray
    force: np.ndarray
    alpha: np.ndarray

    def force_at(self, theta):
        return interp(theta, self.theta, self.force)

    def theta_of_force(self, f):
        return interp(f, self.force, self.theta)

    def alpha_of_force(self, f):
        """``d f / d theta`` at force ``f`` [N/rad] (float or AutoDiffXd)."""
        return interp(f, self.force, self.alpha)


def force_map(rig: Any, *, f_max: float = 200.0, num: int = 600) -> ForceMap:
    """Tabulate the rig's ``tendon_force`` output over motor angles (motor at rest).

    The rig must have the state ``[theta, omega]`` and output ``tendon_force``;
    the slope is ``r_m * tendon_stiffness`` when the rig outputs the stiffness,
    else the centred difference of the tabulated force.
    """
    d = rig.diagram
    if not d.HasOutputPort("tendon_force"):
        raise ValueError(f"force_map: rig {getattr(rig, 'name', '?')!r} has no output 'tendon_force'")
    ctx = d.CreateDefaultContext()
    for i in range(d.num_input_ports()):
        d.get_input_port(i).FixValue(ctx, np.zeros(d.get_input_port(i).size()))
    port = d.GetOutputPort("tendon_force")
    n = ctx.num_continuous_states()
    if n != 2:
        raise ValueError(f"force_map: expected a tendon rig with state [theta, omega], got {n} states")

    def f(th):
        ctx.SetContinuousState([th, 0.0])
        return float(port.Eval(ctx)[0])

    lo, hi = -0.01, 0.01
    while f(lo) > 1e-9 and lo > -1e3:
        lo *= 2.0
    while f(hi) < f_max and hi < 1e3:
        hi *= 2.0
    if f(hi) < f_max or f(lo) > 1e-9:
        raise ValueError("force_map: could not bracket the tendon force between slack and f_max")
    th = np.linspace(lo, hi, 4 * num)
    fo = np.array([f(t) for t in th])
    r_m = _motor(rig).pulley_radius
    kport = d.GetOutputPort("tendon_stiffness") if d.HasOutputPort("tendon_stiffness") else None

    def slope(t):  # d f / d theta = r_m k_t (exact, from the rig's stiffness output)
        ctx.SetContinuousState([t, 0.0])
        return r_m * float(kport.Eval(ctx)[0])

    taut = fo > 1e-6
    first = int(np.argmax(taut))
    top = int(np.argmax(fo >= f_max))
    th, fo = th[max(first - 1, 0): top + 1], fo[max(first - 1, 0): top + 1]
    alpha = np.array([slope(t) for t in th]) if kport is not None else np.gradient(fo, th)
    keep = np.concatenate([[True], np.diff(fo) > 0])
    return ForceMap(th[keep], fo[keep], alpha[keep])


def identified_gains(alpha: float, inertia: float, omega: float, xi: float) -> tuple[float, float]:
    """(10.11): ``Kp = w^2 B / alpha``, ``Kd = 2 xi w B / alpha`` (float)."""
    check_gain("alpha", alpha, owner="tendon force design")
    return omega ** 2 * inertia / alpha, 2.0 * xi * omega * inertia / alpha


def steady_state_force_without_feedforward(f_des: float, kp: float, pulley_radius: float) -> float:
    """(10.3) at rest with smooth friction (zero at zero speed): ``f = f_des Kp / (Kp + r_m)``."""
    return f_des * kp / (kp + pulley_radius)


def _motor(rig):
    p = getattr(getattr(rig, "params", None), "motor", None)
    if p is None:
        raise ValueError(f"rig {getattr(rig, 'name', '?')!r} has no params.motor (MotorParams)")
    return p


class TendonForceLaw(StaticLaw):
    """(10.2) with fixed (design force) or scheduled (reference force) gains."""

    inputs = {"tendon_force_reference": 1, "tendon_force": 1, "motor_velocity": 1}
    output_size = 1

    def __init__(self, fmap: ForceMap, motor: Any, gains: TendonForceGains | None = None, *,
                 scheduled: bool = False, name: str | None = None):
        g = gains or TendonForceGains()
        self.name = name or ("tendon_scheduled" if scheduled else "tendon_pd")
        check_gain("natural_frequency", g.natural_frequency, owner=self.name)
        check_gain("damping_ratio", g.damping_ratio, owner=self.name)
        self.fmap, self.motor, self.gains, self.scheduled = fmap, motor, g, bool(scheduled)
        self.inertia = check_gain("inertia", motor.inertia, owner=self.name)
        self.r_m = check_gain("pulley_radius", motor.pulley_radius, owner=self.name)
        w, xi = g.natural_frequency, g.damping_ratio
        # table of gains over the force table: scheduled = interpolation in it
        alpha = np.maximum(fmap.alpha, float(fmap.alpha_of_force(g.min_schedule_force)))
        self._kp_tab = w ** 2 * self.inertia / alpha
        self._kd_tab = 2 * xi * w * self.inertia / alpha
        self.kp_fixed, self.kd_fixed = identified_gains(float(fmap.alpha_of_force(g.design_force)),
                                                        self.inertia, w, xi)

    def gains_at(self, f_ref):
        """(Kp, Kd) used at reference force ``f_ref``."""
        if not self.scheduled:
            return self.kp_fixed, self.kd_fixed
        return interp(f_ref, self.fmap.force, self._kp_tab), interp(f_ref, self.fmap.force, self._kd_tab)

    def __call__(self, u):
        from awiwi_drake.components import motor_friction_torque
        fd = u["tendon_force_reference"][0]
        f = u["tendon_force"][0]
        w = u["motor_velocity"][0]
        kp, kd = self.gains_at(fd)
        fdot = self.fmap.alpha_of_force(f) * w
        tau = kp * (fd - f) - kd * fdot
        if self.gains.force_feedforward:
            tau = tau + self.r_m * f
        if self.gains.friction_compensation:
            tau = tau - self.gains.friction_scale * motor_friction_torque(w, self.motor)
        return np.array([tau])


def tendon_pd_controller(rig: Any, gains: TendonForceGains | None = None, *, fmap: ForceMap | None = None):
    """Registered factory ``tendon-pd``: (10.2) with gains fixed at the design force."""
    return StaticLawController(TendonForceLaw(fmap or force_map(rig), _motor(rig), gains, scheduled=False))


def tendon_scheduled_controller(rig: Any, gains: TendonForceGains | None = None, *, fmap: ForceMap | None = None):
    """Registered factory ``tendon-scheduled``: (10.2) with gains (10.11) scheduled on the reference."""
    return StaticLawController(TendonForceLaw(fmap or force_map(rig), _motor(rig), gains, scheduled=True))
