"""Motor model (thesis ch. 3): the laws (the motor rig, :func:`~awiwi_drake.rigs.motor_rig`, is generated from them).

Dynamics at the output shaft (3.5): ``B thdd = sat(u) + tau_fric(thd) + tau_ripple(th) - tau_load`` with the
reflected inertia (3.1), the friction law (3.8) and the ripple (:class:`MotorParams`); ``tau_load = r_m f`` for a
tendon.
"""

from __future__ import annotations

import numpy as np

from awiwi_drake._math import clip
from awiwi_drake.components.friction import atan_friction
from awiwi_drake.parameters.components import MotorParams

__all__ = [
    "reflected_inertia",
    "motor_friction_torque",
    "motor_ripple_torque",
    "saturate_torque",
    "motor_drive_torque",
    "motor_acceleration",
    "tendon_motor_params",
]


def reflected_inertia(motor_inertia: float, gearbox_inertia: float, gear_ratio: float) -> float:
    """Total inertia at the output shaft (3.1): ``B = B_motor alpha^-2 + B_gearbox``.

    ``gear_ratio`` is input/output speed (100 for the Awiwi harmonic drive), so
    ``alpha_gear = 1/gear_ratio`` and ``alpha^-2 = gear_ratio^2``.
    """
    if motor_inertia < 0 or gearbox_inertia < 0:
        raise ValueError("reflected_inertia: motor_inertia and gearbox_inertia must be >= 0 [kg m^2]")
    if gear_ratio <= 0:
        raise ValueError(f"reflected_inertia: gear_ratio = {gear_ratio} must be > 0")
    return motor_inertia * gear_ratio ** 2 + gearbox_inertia


def motor_friction_torque(omega, p: MotorParams):
    """Friction torque acting on the motor (3.8), Table 3.3, plus linear damping.

    ``tau_fric = -(gamma2 atan(gamma1 w) + gamma3 w) - d w`` (zero when
    ``p.friction`` is off, except the damping ``d``). Works element-wise for
    float, AutoDiffXd and Expression arrays.
    """
    tau = -p.damping * omega
    if p.friction:
        tau = tau + atan_friction(omega, p.coulomb_torque, p.friction_slope, p.viscous_friction)
    return tau


def motor_ripple_torque(theta, p: MotorParams):
    """Position-dependent ripple torque (3.5), zero when ``p.ripple`` is off.

    ``a_m sin(N th + phi_m) + a_o sin(th + phi_o)`` with ``N = gear_ratio`` (motor-shaft and output bearing),
    plus ``sum_k a_k sin(n_k th) + b_k cos(n_k th)`` over ``p.ripple_harmonics`` (flat ``(n_k, a_k, b_k)``
    triples, e.g. a fitted motor's).  ``p``: one MotorParams, or a tuple of one per motor.
    """
    if isinstance(p, tuple):
        return _per_motor(motor_ripple_torque, p, theta)
    if not p.ripple:
        return 0.0 * theta
    tau = (p.ripple_motor_amplitude * np.sin(p.gear_ratio * theta + p.ripple_motor_phase)
           + p.ripple_output_amplitude * np.sin(theta + p.ripple_output_phase))
    h = getattr(p, "ripple_harmonics", ())
    for k in range(0, len(h), 3):
        tau = tau + h[k + 1] * np.sin(h[k] * theta) + h[k + 2] * np.cos(h[k] * theta)
    return tau


def _per_motor(law, p, *args):
    """``law(*args, p)`` with ``p`` one MotorParams for all motors or a tuple of one per motor (the
    arguments' entries): motors that share a parameter set are evaluated together, entry by entry for
    float, AutoDiffXd and Expression arrays alike."""
    groups: dict = {}
    for i, pi in enumerate(p):
        groups.setdefault(pi, []).append(i)
    out = [None] * len(p)
    for pi, ix in groups.items():
        vals = law(*(np.asarray(a)[ix] if np.ndim(a) else a for a in args), pi)
        for k, i in enumerate(ix):
            out[i] = vals[k]
    return np.array(out, dtype=float) if all(isinstance(v, float) for v in out) else np.array(out)


def tendon_motor_params(p, tendon_names):
    """The motor parameters of a drive: ``p.motor`` (one set for all), or, when ``p.tendon_motors``
    overrides tendons by name, a tuple of one :class:`MotorParams` per tendon (errors name the entry).
    The overrides must keep ``pulley_radius`` (the routing's), torque limit and saturation of ``p.motor``."""
    if not p.tendon_motors:
        return p.motor
    names = list(tendon_names)
    motors = [p.motor] * len(names)
    for tendon, mp in p.tendon_motors:
        if tendon not in names:
            raise ValueError(f"tendon_motors: unknown tendon {tendon!r}; tendons are {', '.join(names)}")
        i = names.index(tendon)
        if motors[i] is not p.motor:
            raise ValueError(f"tendon_motors: tendon {tendon!r} is given twice")
        for f in ("pulley_radius", "torque_limit", "saturation"):
            if getattr(mp, f) != getattr(p.motor, f):
                raise ValueError(f"tendon_motors[{tendon!r}].{f} = {getattr(mp, f)!r} differs from motor.{f} = "
                                 f"{getattr(p.motor, f)!r}: it is set for all tendons by motor")
        motors[i] = mp
    return tuple(motors)


def saturate_torque(u, p: MotorParams):
    """Commanded torque clipped to ``+-torque_limit`` when ``p.saturation`` is on (``p``: one
    MotorParams, or a tuple of one per motor)."""
    if isinstance(p, tuple):
        return _per_motor(saturate_torque, p, u)
    if not p.saturation:
        return u
    return clip(u, -p.torque_limit, p.torque_limit)


def motor_drive_torque(theta, omega, u, p: MotorParams):
    """The torque of (3.5) on the output shaft apart from the load: ``sat(u) + tau_fric + tau_ripple`` [Nm]
    (``p``: one MotorParams, or a tuple of one per motor)."""
    if isinstance(p, tuple):
        return _per_motor(motor_drive_torque, p, theta, omega, u)
    tau = saturate_torque(u, p)
    if p.friction or p.damping:
        tau = tau + motor_friction_torque(omega, p)
    if p.ripple:
        tau = tau + motor_ripple_torque(theta, p)
    return tau


def motor_acceleration(theta, omega, u, load_torque, p: MotorParams):
    """Output-shaft acceleration of (3.5): ``(sat(u) + tau_fric + tau_ripple - load) / B`` (``p``: one
    MotorParams, or a tuple of one per motor, e.g. :func:`tendon_motor_params`)."""
    if isinstance(p, tuple):
        return _per_motor(motor_acceleration, p, theta, omega, u, load_torque)
    return (motor_drive_torque(theta, omega, u, p) - load_torque) / p.inertia
