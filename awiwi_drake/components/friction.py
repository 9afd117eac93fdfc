"""Friction laws (thesis ch. 3, 4 and 9): the one place each friction law is written.

Every law returns the force or torque *acting on* the moving body (its power is never positive), except
the two magnitudes of the guide friction, (4.1) and the capstan loss.  The laws are generic in the scalar
type (float, AutoDiffXd, Expression), and their parameters are plain numbers (or arrays, one per copy).

========================  ====================================================
:func:`regularized_sign`  ``tanh(v / v_s)``: smooth ``sign(v)`` below ``v_s``
:func:`atan_friction`     (3.8), Table 3.3: ``-(g2 atan(g1 w) + g3 w)``
:func:`stribeck_level`   Stribeck curve ``Fc + (Fs - Fc) exp(-(v/v_s)^2)`` (the sliding level)
:func:`stribeck_friction` smooth Stribeck (stick-slip) law
:func:`stick_slip_rate`   the Stribeck level as a presliding (LuGre) state: joint stick-slip in the finger plant
:func:`guide_friction_force`    (4.1), Fig 4.10: ``C0 (1 - exp(-C1 alpha))``
:func:`capstan_friction_force`  capstan loss ``f (1 - exp(-mu alpha))`` (Fig 4.11)
:func:`guide_friction`    directional guide friction on a sliding tendon (regularised sign)
:func:`dahl_rate`         rate-independent Dahl friction state ``dF/dt = (v/delta)(W - s F)``
:func:`dahl_path`         the same law solved exactly along a sampled (piecewise-linear) path
:func:`guide_friction_rate`     guide friction as a Dahl state (the finger and hand drive)
:func:`joint_friction_bound`    the most the guides, the lever's hysteresis and the joints can hold per DoF (ch. 9's bound)
========================  ====================================================
"""

from __future__ import annotations

import numpy as np

from awiwi_drake._math import clip, positive_part
from awiwi_drake.parameters.components import GuideFrictionParams

__all__ = ["regularized_sign", "atan_friction", "stribeck_level", "stribeck_friction", "stick_slip_rate", "guide_friction_force",
           "capstan_friction_force", "guide_friction", "dahl_rate", "dahl_path", "guide_friction_level", "guide_friction_rate",
           "joint_breakaway_bound", "joint_friction_bound"]


def regularized_sign(v, smoothing_velocity):
    """``tanh(v / v_s)``: ``sign(v)`` smoothed below ``smoothing_velocity`` ``v_s`` (> 0)."""
    return np.tanh(v / smoothing_velocity)


def atan_friction(v, coulomb, slope, viscous):
    """Friction (3.8), Table 3.3, acting on a shaft turning at ``v`` [rad/s].

    ``tau = -(gamma2 atan(gamma1 v) + gamma3 v)`` with ``coulomb`` gamma2 [Nm],
    ``slope`` gamma1 [s/rad] and ``viscous`` gamma3 [Nm s/rad]. The torque
    needed to turn the shaft at constant speed is its negative.
    """
    return -(coulomb * np.arctan(slope * v) + viscous * v)


def stribeck_friction(v, coulomb, static, stribeck_velocity, smoothing_velocity, viscous=0.0):
    """Smooth Stribeck (stick-slip) friction acting on a body moving at ``v``.

    ``-(Fc + (Fs - Fc) exp(-(v/v_s)^2)) tanh(v/v_eps) - d v`` with Coulomb level
    ``coulomb`` Fc, breakaway level ``static`` Fs, Stribeck velocity ``v_s``,
    sign-smoothing velocity ``v_eps`` and viscous coefficient ``viscous`` d.
    With ``static == coulomb`` it is regularised Coulomb friction.
    """
    return -stribeck_level(v, coulomb, static, stribeck_velocity) * regularized_sign(v, smoothing_velocity) - viscous * v


def stribeck_level(v, coulomb, static, stribeck_velocity):
    """The Stribeck curve ``W(v) = Fc + (Fs - Fc) exp(-(v / v_s)^2)``: the friction level of a contact sliding
    at ``v`` (``static`` Fs at rest, falling to ``coulomb`` Fc over the Stribeck velocity ``v_s``)."""
    return coulomb + (static - coulomb) * np.exp(-(v / stribeck_velocity) ** 2)


def stick_slip_rate(torque, v, coulomb, static, stribeck_velocity, presliding_angle):
    """``d tau_f / dt`` of the stick-slip friction torque ``tau_f`` acting on a joint turning at ``v`` [rad/s].

    The Stribeck curve :func:`stribeck_level` ``W(v)`` as the level of a presliding (bristle) state, the LuGre
    model without its micro-damping (Canudas de Wit et al. 1995)::

        d tau_f / dt = -sigma0 (v + |v| tau_f / W(v)),   sigma0 = Fs / delta

    (``presliding_angle`` delta [rad]).  At rest the joint is held by a spring of stiffness ``sigma0``: it sticks
    (a torque ``tau`` applied slowly from rest, ``0 <= tau < Fs``, deflects it by ``-delta ln(1 - tau / Fs)`` while
    ``v << v_s``, and no further) until the torque passes the breakaway level ``Fs``; sliding steadily it carries
    ``-W(v) sign(v)``, which falls from ``Fs`` to ``Fc`` as the speed rises (the negative slope that makes it
    stick and slip).  Unlike the memoryless :func:`stribeck_friction` it needs no sign smoothing: its stiffness is
    ``sigma0``, not ``Fs / v_eps``.  It is passive with the storage ``S = tau_f^2 / (2 sigma0)``:
    ``dS/dt = -tau_f v - |v| tau_f^2 / W <= -tau_f v``.
    """
    sigma0 = static / presliding_angle
    return -sigma0 * (v + np.abs(v) * torque / stribeck_level(v, coulomb, static, stribeck_velocity))


def _bending_angle(bending_angle, who):
    a = np.asarray(bending_angle, dtype=float)
    if np.any(a < 0) or not np.all(np.isfinite(a)):
        raise ValueError(f"{who}: bending_angle must be finite and >= 0 [rad], got {bending_angle}")
    return a


def guide_friction_force(bending_angle, p: GuideFrictionParams = GuideFrictionParams()):
    """Guide friction magnitude (4.1): ``F = C0 (1 - exp(-C1 alpha))`` [N].

    ``bending_angle`` alpha [rad] is the total angle the tendon wraps on its
    guides (>= 0). Independent of tension and speed (Fig 4.10).
    """
    a = _bending_angle(bending_angle, "guide_friction_force")
    return p.c0 * (1.0 - np.exp(-p.c1 * a))


def capstan_friction_force(tension, bending_angle, p: GuideFrictionParams = GuideFrictionParams()):
    """Tension-proportional (capstan) guide friction: ``F = f (1 - exp(-mu alpha))`` [N].

    The force lost between the two ends of a tendon pulled with tension ``f``
    around a total angle alpha (Euler-Eytelwein). Generic in the scalar type of ``tension``.
    """
    a = _bending_angle(bending_angle, "capstan_friction_force")
    return tension * (1.0 - np.exp(-p.mu * a))


def guide_friction(sliding_velocity, tension, constant, capstan_exponent, smoothing_velocity):
    """Directional friction on a tendon sliding through its guides [N].

    The tension added at the pulling end of a tendon that slides at
    ``sliding_velocity`` (> 0: pulled towards that end)::

        F = C s + f (exp(mu alpha s) - 1),   s = tanh(v / v_s)

    with ``constant`` C [N] the tension-independent part (e.g. (4.1) at the
    path's bending angle), ``capstan_exponent`` ``mu alpha`` [-] (capstan:
    ``f e^{+mu alpha}`` at the pulling end, ``f e^{-mu alpha}`` when released, the
    loss :func:`capstan_friction_force`) and ``tension`` f >= 0 at the other end.
    ``F`` has the sign of the sliding velocity, so it dissipates: ``F v >= 0``.
    """
    s = regularized_sign(sliding_velocity, smoothing_velocity)
    return constant * s + tension * (np.exp(capstan_exponent * s) - 1.0)


def dahl_rate(state, velocity, level, presliding_length, smoothing_velocity):
    """Rate-independent Dahl friction state: ``dF/dt = (v / delta) (W - s F)``, ``s = tanh(v / v_s)``.

    ``F`` [N] is the friction force carried by a contact sliding at ``velocity`` v [m/s]; it
    moves with the sliding distance, not with time: after a reversal it crosses from ``-W`` to
    ``+W`` (``level`` W >= 0 [N], the sliding friction) within a few ``presliding_length``
    delta [m]. At rest it is a spring of stiffness ``W / delta``; sliding, its relaxation rate is
    ``|v| / delta`` (independent of W).  Passive for ``|F| <= W``.  The argument of tanh is clipped at +-40
    only to keep its AutoDiff derivative finite.
    """
    s = np.tanh(clip(velocity / smoothing_velocity, -40.0, 40.0))
    return (velocity / presliding_length) * (level - s * state)


def dahl_path(position, level, presliding_length, smoothing_velocity=0.0, dt=None, initial_state=0.0):
    """:func:`dahl_rate` solved exactly along a sampled path (float arrays).

    Between samples ``k`` and ``k + 1`` (``dt`` [s] apart) the sliding coordinate ``position`` x [m] moves at the
    constant speed ``v = dx / dt`` and the ``level`` W [N] (one value per sample, or a scalar) is linear in time.
    With ``s = tanh(v / v_s)`` (``smoothing_velocity`` v_s [m/s]; ``sign(v)`` when it is 0, as ``v_s -> 0``) the
    rate law ``dF/dt = (v/delta)(W - s F)`` is linear in F on the segment, and with ``c = dx / delta``,
    ``lambda = c s >= 0``::

        F_{k+1} = F_k e^{-lambda} + c (W_k phi1(lambda) + (W_{k+1} - W_k) phi2(lambda)),
        phi1 = (1 - e^{-lambda}) / lambda,   phi2 = (lambda - 1 + e^{-lambda}) / lambda^2

    (``phi1(0) = 1``, ``phi2(0) = 1/2``): exact for any step, with no step-size bound as an explicit integration of
    the rate form has; a segment without travel leaves ``F`` unchanged. Returns ``F`` at every sample [N],
    ``F_0 = initial_state``. For a fixed path ``F - F_0 e^{...}`` is linear in ``level``: a loop ``W = beta f + z0``
    from rest is ``beta`` times the path's response to ``f`` plus ``z0`` times its response to 1.
    """
    x = np.asarray(position, dtype=float)
    if x.ndim != 1 or x.size == 0:
        raise ValueError(f"dahl_path: position must be a non-empty 1-D array, got shape {x.shape}")
    if not presliding_length > 0:
        raise ValueError(f"dahl_path: presliding_length = {presliding_length} must be > 0 [m]")
    if smoothing_velocity < 0 or (smoothing_velocity > 0 and not (dt is not None and dt > 0)):
        raise ValueError(f"dahl_path: smoothing_velocity = {smoothing_velocity} needs a sample period dt > 0 "
                         f"(got {dt}); 0 is the sign limit")
    W = np.broadcast_to(np.asarray(level, dtype=float), x.shape)
    dx = np.diff(x)
    c = dx / presliding_length
    s = np.sign(dx) if smoothing_velocity == 0 else np.tanh(np.clip(dx / (dt * smoothing_velocity), -40.0, 40.0))
    lam = c * s
    e = np.exp(-lam)
    small = lam < 1e-4
    safe = np.where(small, 1.0, lam)
    phi1 = np.where(small, 1.0 - lam / 2 + lam ** 2 / 6, -np.expm1(-lam) / safe)
    phi2 = np.where(small, 0.5 - lam / 6 + lam ** 2 / 24, (lam + np.expm1(-lam)) / safe ** 2)
    drive = c * (W[:-1] * phi1 + (W[1:] - W[:-1]) * phi2)
    out = np.empty(x.shape)
    F = out[0] = float(initial_state)
    for k, (ek, dk) in enumerate(zip(e.tolist(), drive.tolist())):
        F = F * ek + dk
        out[k + 1] = F
    return out


def guide_friction_level(tension, constant, capstan_exponent, direction):
    """Sliding level W [N] of the guide friction of a tendon moving in ``direction`` s in [-1, 1].

    ``W = C + f ((e^{mu alpha} - 1)(1 + s) / 2 + (1 - e^{-mu alpha})(1 - s) / 2)``: the (4.1) part C plus the
    capstan rise when pulled (s = +1) or the loss when released (s = -1), so that the Dahl state's steady
    sliding force ``s W`` equals :func:`guide_friction` at ``s = +-1``.
    """
    rise = np.exp(capstan_exponent) - 1.0
    loss = 1.0 - np.exp(-capstan_exponent)
    return constant + tension * (rise * (1.0 + direction) + loss * (1.0 - direction)) * 0.5


def guide_friction_rate(force, sliding_velocity, tension, constant, capstan_exponent, presliding_length,
                        smoothing_velocity):
    """``dF/dt`` of the guide friction ``F`` [N] of a tendon sliding through its guides (Dahl form).

    Dahl's law ``dF/dt = (v W - |v| F) / delta`` with the level :func:`guide_friction_level`
    (its direction ``s = tanh(v / v_s)``): ``F`` is the tension added at the pulling end; sliding
    gives ``+-W`` (the (4.1) constant and/or the capstan law), and at rest the guides hold the
    tendon with the presliding stiffness ``W / delta`` instead of the damping ``C / v_s`` of a
    regularised sign (which makes the light finger links stiff for explicit integration).  The
    relaxation takes ``|v|`` exactly, not :func:`dahl_rate`'s ``v tanh(v / v_s)``: then ``|F| <= W`` holds
    at every speed, the bound the ch. 9 observer uses (:func:`joint_friction_bound`).
    """
    s = np.tanh(clip(sliding_velocity / smoothing_velocity, -40.0, 40.0))
    level = guide_friction_level(tension, constant, capstan_exponent, s)
    return (sliding_velocity * level - np.abs(sliding_velocity) * force) / presliding_length


def joint_breakaway_bound(joint_level, selection=None):
    """``sum_l |S_lj| F_l`` (k) [Nm]: the most the joints' own friction can put on each DoF ``j``, the constant part of
    :func:`joint_friction_bound` (computed once per rig, not per call): ``joint_level`` ``F`` (n) [Nm] the breakaway
    level ``Fs`` of each joint's stick-slip (:func:`stick_slip_rate` keeps ``|tau_f| <= Fs``, 0 where it has none),
    ``selection`` ``S`` (n x k) the DoF map ``q = S w`` (None: the identity).  None when no joint has friction."""
    if joint_level is None or not np.any(np.asarray(joint_level, dtype=float) > 0):
        return None
    level = np.asarray(joint_level, dtype=float)
    return level.copy() if selection is None else np.abs(np.asarray(selection, dtype=float)).T @ level


def joint_friction_bound(coupling, tension, constant, capstan_exponent, hysteresis_width=0.0, joint_hold=None,
                         selection=None):
    """``B_j = sum_i |(P S)_ij| (W_i(f_i + w_i) + w_i) + sum_l |S_lj| F_l`` (k) [Nm]: the largest torque the unmeasured
    friction can put on each DoF ``j`` (the tendons' guides and lever, and the joints' own), the bound of the ch. 9
    observer's estimate.

    ``coupling`` ``P`` (m x n): ``P(q)`` (a joint torque is ``-P^T`` of the tendon forces); ``selection`` ``S``
    (n x k): the DoF map ``q = S w`` (a joint torque ``tau`` is the DoF torque ``S^T tau``; None: the identity, k =
    n); ``tension`` ``f`` (m) [N]: the measured tendon forces (negative parts count as 0); ``constant``,
    ``capstan_exponent``: each path's guide friction (:func:`guide_friction_level`, pulled end, the larger
    direction); ``hysteresis_width`` ``w`` (m) [N]: the half-width of the lever's hysteresis loop (Fig 4.8b) when the
    measurement misses it, else 0; ``joint_hold`` (k) [Nm]: ``sum_l |S_lj| F_l``, the most the joints' own friction
    can hold on each DoF (:func:`joint_breakaway_bound` of their breakaway levels, a constant; None: no joint
    friction).

    Which friction a measurement misses follows from where it sits (ch. 4): the spring sensor (the lever's angle,
    calibrated to a force polynomial ``phi``) is in the forearm, so the guides of the wrist, palm and finger (4.1) are
    always between it and the joints; the lever's friction (the hysteresis ``z``, ``|z| <= w``) is inside the
    mechanism, so the calibration ``phi(x)`` misses it while the lever's tension ``phi(x) + z`` holds it.  The guides
    carry at most their sliding level at the tension they pass (:func:`guide_friction_rate`: ``|g| <= W``), which is
    ``phi + z <= f + w``: hence ``W(f + w)``.  The joints' friction (their bearings, ch. 9's "joint friction" that the
    observer (9.2) "identifies") is beyond every tendon sensor, mapped to the DoF as the tendons' torque is, by
    ``S^T``."""
    f, w = positive_part(tension), hysteresis_width
    A = np.asarray(coupling) if selection is None else np.asarray(coupling) @ selection
    B = np.abs(A).T @ (guide_friction_level(f + w, constant, capstan_exponent, 1.0) + w)
    return B if joint_hold is None else B + joint_hold
