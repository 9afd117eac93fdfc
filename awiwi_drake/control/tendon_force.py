"""Tendon force control (ch. 10, (10.2)-(10.12)) on the tendon rig.

Plant (10.1): ``B thdd = tau_fric(thd) + tau_ripple(th) + u - r_m f_t(th)`` (the
tendon is fixed at its far end, so the force is a function of the motor angle).

Controller (10.2)::

    u = Kp (f_des - f) - Kd fdot_hat + [r_m f]_ff + [-tau_fric_hat(thd)]_ff

with ``fdot_hat = alpha(f) thd`` (``alpha = d f_t / d theta``, the rig's force
map) and gains by identification to a damped second-order error dynamics
(10.10)-(10.11)::

    Kp = w^2 B / alpha,   Kd = 2 xi w B / alpha.

*Fixed gains* evaluate ``alpha`` at the design force (30 N, Fig 10.2); *scheduled gains* at the reference force
(10.12), by linear interpolation in a table (section 10.3).  The thesis's ``beta`` in ``Kp = w^2 B / beta`` equals
``alpha`` for a force that depends on ``theta`` only.

Near slack the slope is ``alpha(clip(f, min_schedule_force, f_max))`` on the *taut* table (the slack row, where
``alpha = 0``, is not kept): a noisy reading near or below 0 N never extrapolates ``alpha < 0``, which would turn the
``-Kd fdot_hat`` damping into positive feedback.  References outside ``[0, f_max]`` raise
:class:`~awiwi_drake.analysis.InfeasibleForceError`.  At rest without the force feed-forward the force settles at
``f_des Kp / (Kp + r_m)`` (10.3); with it the error vanishes (10.4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from awiwi_drake._math import clip, is_float, scalar_value
from awiwi_drake.analysis.simulate import InfeasibleForceError
from awiwi_drake.control.base import StaticLaw, StaticLawController, check_gain, check_gains
from awiwi_drake.control.compiled import float_inputs, motor_law_kernels
from awiwi_drake.parameters.control import TendonForceGains

__all__ = ["ForceMap", "force_map", "interp", "TendonForceLaw", "tendon_pd_controller",
           "tendon_scheduled_controller", "identified_gains", "steady_state_force_without_feedforward"]


def interp(x, xp: np.ndarray, fp: np.ndarray):
    """Piecewise-linear interpolation for float and AutoDiffXd (derivative = local slope); outside the table the
    end segments are extrapolated (callers clamp or validate first, as :class:`ForceMap` does)."""
    xp = np.asarray(xp, float)
    fp = np.asarray(fp, float)
    if isinstance(x, np.ndarray) and x.dtype != object and x.size > 1:   # a float bank: the lean path
        x = np.asarray(x, dtype=float)
        i = np.minimum(np.maximum(np.searchsorted(xp, x) - 1, 0), len(xp) - 2)
        x0, f0 = xp[i], fp[i]
        return f0 + (fp[i + 1] - f0) / (xp[i + 1] - x0) * (x - x0)
    if np.ndim(x) > 0 and np.size(x) > 1:  # element-wise (a bank of tendons), any scalar type
        return np.array([interp(xi, xp, fp) for xi in np.asarray(x, dtype=object).reshape(-1)], dtype=object)
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
    """Tabulated static tendon force ``f(theta)`` of a rig and its slope ``alpha(theta)`` over increasing ``theta``:
    the taut, strictly increasing part only; ``slack_angle``: the largest tabulated angle with ``f = 0``."""

    theta: np.ndarray
    force: np.ndarray
    alpha: np.ndarray
    slack_angle: float

    @property
    def max_force(self) -> float:
        return float(self.force[-1])

    def check_force(self, f, name: str = "tendon_force_reference"):
        """Validate a force argument (or each of a bank's) against the table ``[0, max_force]``; return the float value(s)."""
        if isinstance(f, np.ndarray) and f.dtype == float and f.size > 1:   # a float bank: one vectorised check
            vals = f.reshape(-1)
            if np.all(np.isfinite(vals) & (vals >= 0.0) & (vals <= self.max_force)):
                return vals.copy()
        vals = [scalar_value(x) for x in np.asarray(f, dtype=object).reshape(-1)]
        for i, v in enumerate(vals):
            if not (math.isfinite(v) and 0.0 <= v <= self.max_force):
                where = f"[{i}]" if len(vals) > 1 else ""
                raise InfeasibleForceError(f"{name}{where} = {v!r} N is outside the tendon force table [0, {self.max_force:.4g}] N "
                                 f"(force_map(f_max=...) tabulates up to f_max)")
        return vals[0] if len(vals) == 1 else np.array(vals)

    @classmethod
    def from_spring(cls, spring, motor_pulley_radius: float, *, f_max: float = 200.0, num: int = 2000) -> "ForceMap":
        """The map of a tendon whose spring elongation is ``r_m theta`` (+ a constant): ``f = spring.force(r_m theta)``,
        ``alpha = r_m k_t``.  For a finger/hand tendon at fixed joints (the path term of the elongation is
        constant), e.g. the hand's lever mechanism ``tendon_spring(params.spring)``."""
        r_m = float(motor_pulley_radius)
        x_hi = float(np.ravel(spring.inverse_force(np.array([f_max])))[0])
        x_lo = float(np.ravel(spring.inverse_force(np.array([1e-3])))[0])
        x = np.linspace(x_lo, x_hi, num)
        fo = np.asarray(spring.force(x), dtype=float)
        alpha = r_m * np.asarray(spring.stiffness(x), dtype=float)
        keep = np.concatenate([[True], np.diff(fo) > 0]) & (fo > 0)
        x_slack = float(np.ravel(spring.inverse_force(np.array([0.0])))[0])
        return cls(x[keep] / r_m, fo[keep], alpha[keep], x_slack / r_m)

    def force_at(self, theta):
        return interp(theta, self.theta, self.force)

    def theta_of_force(self, f):
        """Motor angle holding the static force ``f`` in ``[0, max_force]`` (slack point at ``f = 0``)."""
        self.check_force(f, "force")
        return interp(f, np.concatenate([[0.0], self.force]), np.concatenate([[self.slack_angle], self.theta]))

    def alpha_of_force(self, f, floor: float | None = None):
        """``d f / d theta`` at force ``f`` [N/rad] (float or AutoDiffXd), ``f`` clamped to ``[max(floor, force[0]),
        max_force]`` (derivative 0 outside), never extrapolated."""
        lo = float(self.force[0]) if floor is None else max(float(floor), float(self.force[0]))
        return interp(clip(f, lo, self.max_force), self.force, self.alpha)


def force_map(rig: Any, *, f_max: float = 200.0, num: int = 600) -> ForceMap:
    """Tabulate the ``tendon_force`` output of a rig with state ``[theta, omega]`` over motor angles at rest; the
    slope is ``r_m tendon_stiffness`` when the rig outputs it, else the centred difference of the force."""
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
    slack_angle = float(th[first - 1]) if first > 0 else float(th[0])
    # the slack row (f = 0, alpha = 0) is not kept: interpolating the slope between it and the first taut
    # row (and extrapolating below it) gives meaningless, even negative, slopes near slack
    th, fo = th[first: top + 1], fo[first: top + 1]
    alpha = np.array([slope(t) for t in th]) if kport is not None else np.gradient(fo, th)
    keep = np.concatenate([[True], np.diff(fo) > 0])
    return ForceMap(th[keep], fo[keep], alpha[keep], slack_angle)


def identified_gains(alpha, inertia: float, omega: float, xi: float):
    """(10.11): ``Kp = w^2 B / alpha``, ``Kd = 2 xi w B / alpha`` for a force slope ``alpha`` [N/rad]
    (a number or an array of slopes, e.g. a gain-schedule table)."""
    check_gains("alpha", alpha, owner="tendon force design", positive=True)
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
    """(10.2) with fixed (design force) or scheduled (reference force) gains, for a bank of ``size`` tendons.

    ``fmap``: one :class:`ForceMap` for every tendon or ``size`` maps (each tendon's own spring curve; tendons
    sharing a map object are evaluated together).  ``ripple_scale`` > 0 adds the ripple feed-forward of section 3.2,
    ``-ripple_scale tau_ripple(theta)`` (input ``motor_angle``).  ``path_velocity=True`` adds the input
    ``tendon_path_velocity`` ``P(q) qdot`` [m/s]: the force rate becomes ``alpha (omega + v_path / r_m)``, the
    derivative of ``f(r_m theta + h(q))``.
    """

    inputs = {"tendon_force_reference": 1, "tendon_force": 1, "motor_velocity": 1}
    output_size = 1

    def __init__(self, fmap, motor: Any, gains: TendonForceGains | None = None, *,
                 scheduled: bool = False, name: str | None = None, size: int = 1, ripple_scale: float = 0.0,
                 path_velocity: bool = False):
        g = gains or TendonForceGains()
        self.name = name or ("tendon_scheduled" if scheduled else "tendon_pd")
        size = int(size)
        if size < 1:
            raise ValueError(f"{self.name}: size = {size} must be >= 1")
        self._groups = None
        if isinstance(fmap, (list, tuple)):          # one map per tendon
            if len(fmap) != size or not all(isinstance(fm, ForceMap) for fm in fmap):
                raise ValueError(f"{self.name}: fmap must be a ForceMap or {size} ForceMaps (one per tendon), "
                                 f"got {len(fmap)} entries")
            groups: dict = {}
            for i, fm in enumerate(fmap):
                groups.setdefault(id(fm), (fm, []))[1].append(i)
            if len(groups) > 1:                      # a bank per distinct map, inputs scattered by tendon
                self._groups = [(np.array(ix), TendonForceLaw(fm, motor, gains, scheduled=scheduled, name=self.name,
                                                              size=len(ix), ripple_scale=ripple_scale,
                                                              path_velocity=path_velocity))
                                for fm, ix in groups.values()]
            self.fmaps = tuple(fmap)
            fmap = fmap[0]
        else:
            self.fmaps = (fmap,) * size
        self.ripple_scale = check_gain("ripple_scale", ripple_scale, allow_zero=True, owner=self.name)
        self.inputs = {"tendon_force_reference": size, "tendon_force": size, "motor_velocity": size}
        if self.ripple_scale > 0:
            self.inputs["motor_angle"] = size
        self.path_velocity = bool(path_velocity)
        if self.path_velocity:
            self.inputs["tendon_path_velocity"] = size
        self.output_size = size
        check_gain("natural_frequency", g.natural_frequency, owner=self.name)
        check_gain("damping_ratio", g.damping_ratio, owner=self.name)
        self.fmap, self.motor, self.gains, self.scheduled = fmap, motor, g, bool(scheduled)
        self.inertia = check_gain("inertia", motor.inertia, owner=self.name)
        self.r_m = check_gain("pulley_radius", motor.pulley_radius, owner=self.name)
        w, xi = g.natural_frequency, g.damping_ratio
        fmap.check_force(g.design_force, "design_force")
        fmap.check_force(g.min_schedule_force, "min_schedule_force")
        self.alpha_floor = float(fmap.alpha_of_force(g.min_schedule_force))
        # table of gains over the force table: scheduled = interpolation in it (held at min_schedule_force below)
        self._kp_tab, self._kd_tab = identified_gains(np.maximum(fmap.alpha, self.alpha_floor), self.inertia, w, xi)
        self.kp_fixed, self.kd_fixed = identified_gains(float(fmap.alpha_of_force(g.design_force)),
                                                        self.inertia, w, xi)

    def gains_at(self, f_ref):
        """(Kp, Kd) used at reference force ``f_ref`` (a bank: one entry per tendon, each with its own map)."""
        if self._groups is not None:
            self._check_bank(f_ref, "tendon_force_reference")
            kp = np.empty(self.output_size, dtype=np.asarray(f_ref).dtype)
            kd = np.empty_like(kp)
            for ix, law in self._groups:
                kp[ix], kd[ix] = law.gains_at(np.asarray(f_ref)[ix])
            return kp, kd
        self.fmap.check_force(f_ref)
        if not self.scheduled:
            return self.kp_fixed, self.kd_fixed
        fr = clip(f_ref, float(self.fmap.force[0]), self.fmap.max_force)
        return interp(fr, self.fmap.force, self._kp_tab), interp(fr, self.fmap.force, self._kd_tab)

    def _check_bank(self, f, name):
        """Each tendon's reference against its own table; the error names the tendon's index in the bank."""
        vals = np.asarray(f)
        for ix, law in self._groups:
            for i in ix:
                v = scalar_value(vals[i])
                if not (math.isfinite(v) and 0.0 <= v <= law.fmap.max_force):
                    raise InfeasibleForceError(f"{name}[{i}] = {v!r} N is outside the tendon force table of that "
                                               f"tendon [0, {law.fmap.max_force:.4g}] N")

    def __call__(self, u):
        if self.output_size > 1 and float_inputs(u, self.inputs):
            return self._compiled_call(u)
        return self.evaluate(u)

    def _compiled_call(self, u):
        """The float bank's fast path: one compiled call (:func:`_force_law_kernel`), equal to :meth:`evaluate`
        (tests/test_control_tendon.py).  An infeasible reference raises as :meth:`evaluate` does."""
        k = self.__dict__.get("_kernel") or self._build_kernel()
        fn, tabs, flags, out = k
        m = self.output_size
        zeros = tabs[-1]
        bad = fn(u["tendon_force_reference"], u["tendon_force"], u["motor_velocity"],
                 u["motor_angle"] if self.ripple_scale > 0 else zeros,
                 u["tendon_path_velocity"] if self.path_velocity else zeros, *tabs[:-1], *flags, out)
        if bad >= 0:
            return self.evaluate(u)          # raises, naming the tendon
        return out[:m].copy()

    def _build_kernel(self):
        ff = motor_law_kernels(self.motor)
        laws = [law for _, law in self._groups] if self._groups is not None else [self]
        group = np.zeros(self.output_size, dtype=np.int64)
        if self._groups is not None:
            for g, (ix, _) in enumerate(self._groups):
                group[ix] = g
        L = max(law.fmap.force.size for law in laws)

        def table(get):
            t = np.zeros((len(laws), L))
            for g, law in enumerate(laws):
                v = get(law)
                t[g, :v.size], t[g, v.size:] = v, v[-1]
            return t
        tabs = (group, np.array([law.fmap.force.size for law in laws], dtype=np.int64),
                table(lambda l: l.fmap.force), table(lambda l: l._kp_tab), table(lambda l: l._kd_tab),
                table(lambda l: l.fmap.alpha), np.array([l.kp_fixed for l in laws]), np.array([l.kd_fixed for l in laws]),
                np.array([max(float(self.gains.min_schedule_force), float(l.fmap.force[0])) for l in laws]),
                np.array([l.fmap.max_force for l in laws]), np.zeros(self.output_size))
        g = self.gains
        flags = (self.scheduled, self.path_velocity, bool(g.force_feedforward), bool(g.friction_compensation),
                 float(g.friction_scale), float(self.ripple_scale), float(self.r_m))
        self._kernel = (ff["force_law"], tabs, flags, np.empty(self.output_size))
        return self._kernel

    def evaluate(self, u):
        """(10.2) for every tendon: the law as written (float, AutoDiffXd); :meth:`__call__` takes a compiled
        fast path for a float bank."""
        from awiwi_drake.components import motor_friction_torque, motor_ripple_torque
        if self._groups is not None:                 # one map per tendon: each group's bank, scattered back
            self._check_bank(u["tendon_force_reference"], "tendon_force_reference")
            sample = np.asarray(u["tendon_force_reference"])
            out = np.empty(self.output_size, dtype=float if sample.dtype == float else object)
            for ix, law in self._groups:
                out[ix] = law.evaluate({k: np.asarray(v)[ix] for k, v in u.items()})
            return out
        one = self.output_size == 1
        fd = u["tendon_force_reference"][0] if one else u["tendon_force_reference"]
        f = u["tendon_force"][0] if one else u["tendon_force"]
        w = u["motor_velocity"][0] if one else u["motor_velocity"]
        kp, kd = self.gains_at(fd)
        # slope at the measured force clamped to [min_schedule_force, f_max]: > 0 even for readings <= 0
        w_el = w if not self.path_velocity else w + (
            u["tendon_path_velocity"][0] if one else u["tendon_path_velocity"]) / self.r_m
        fdot = self.fmap.alpha_of_force(f, floor=self.gains.min_schedule_force) * w_el
        tau = kp * (fd - f) - kd * fdot
        if self.gains.force_feedforward:
            tau = tau + self.r_m * f
        if self.gains.friction_compensation:
            tau = tau - self.gains.friction_scale * motor_friction_torque(w, self.motor)
        if self.ripple_scale > 0:
            th = u["motor_angle"][0] if one else u["motor_angle"]
            tau = tau - self.ripple_scale * motor_ripple_torque(th, self.motor)
        return np.array([tau]) if one else np.asarray(tau).reshape(-1)


def tendon_pd_controller(rig: Any, gains: TendonForceGains | None = None, *, fmap: ForceMap | None = None):
    """Registered factory ``tendon-pd``: (10.2) with gains fixed at the design force."""
    return StaticLawController(TendonForceLaw(fmap or force_map(rig), _motor(rig), gains, scheduled=False))


def tendon_scheduled_controller(rig: Any, gains: TendonForceGains | None = None, *, fmap: ForceMap | None = None):
    """Registered factory ``tendon-scheduled``: (10.2) with gains (10.11) scheduled on the reference."""
    return StaticLawController(TendonForceLaw(fmap or force_map(rig), _motor(rig), gains, scheduled=True))
