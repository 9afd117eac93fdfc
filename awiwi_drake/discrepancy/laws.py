"""Catalog laws, vectorised over model copies and generic in the scalar type.

One truth: the catalog forms call the foundation laws
(:mod:`awiwi_drake.components.friction` (3.8), guide and stick-slip friction,
:func:`~awiwi_drake.components.motor.motor_ripple_torque`,
:class:`~awiwi_drake.components.spring.PolynomialSpring`,
:func:`~awiwi_drake.components.spring.hysteresis_rate`).  Catalog
parameters arrive as arrays (one value per model copy), so the laws, which
read attributes of parameter dataclasses, receive a namespace holding arrays.
Every function works with float arrays (fast path) and numpy object arrays of
AutoDiffXd (scalar-conversion tests).
"""

from __future__ import annotations

import functools
from types import SimpleNamespace

import numpy as np

from awiwi_drake.components.friction import atan_friction, stribeck_friction
from awiwi_drake.components.friction import guide_friction as guide_friction_law
from awiwi_drake.components.motor import motor_ripple_torque
from awiwi_drake.components.spring import PolynomialSpring, hysteresis_rate
from awiwi_drake.parameters.discrepancy import CatalogBounds

__all__ = ["spring_force", "hysteresis_force", "hysteresis_force_rate", "motor_friction", "ripple",
           "guide_friction", "joint_friction", "GUIDE_VELOCITY", "HYSTERESIS_VELOCITY"]

GUIDE_VELOCITY = CatalogBounds().guide_velocity
HYSTERESIS_VELOCITY = CatalogBounds().hysteresis_velocity
BACKLASH_SMOOTHING = CatalogBounds().backlash_smoothing
BACKLASH_NEWTON_STEPS = CatalogBounds().backlash_newton_steps


@functools.lru_cache(maxsize=64)
def _spring(coefficients: tuple) -> PolynomialSpring:
    return PolynomialSpring(tuple(float(c) for c in coefficients))


def spring_force(x, coefficients):
    """Polynomial spring ``f = sum_k c_k x^k`` for ``x > 0``, else 0 (issue 6 contract)."""
    return _spring(tuple(coefficients)).force(x)


def hysteresis_force(z, f_elastic, gate_force=1.0):
    """The hysteresis force ``z`` [N] on top of the elastic force, gated by tension (none when slack)."""
    return z * np.tanh(f_elastic / gate_force)


def hysteresis_force_rate(z, x, xd, f_elastic, width, length):
    """Dahl hysteresis of the foundation (:func:`hysteresis_rate`) with a constant loop
    half-width ``width`` [N] reached within ``length`` [m] of travel: ``sigma = width / length``."""
    p = SimpleNamespace(width_ratio=0.0, width_offset=width, presliding_length=length,
                        smoothing_velocity=HYSTERESIS_VELOCITY)
    return hysteresis_rate(z, x, xd, f_elastic, p)


def motor_friction(omega, coulomb, slope, viscous):
    """(3.8): torque acting on the motor ``-(g2 atan(g1 w) + g3 w)`` (:func:`atan_friction`)."""
    return atan_friction(omega, coulomb, slope, viscous)


def ripple(theta, harmonics):
    """Torque periodic in the motor angle: ``sum a sin(n theta) + b cos(n theta)``
    (the foundation's ripple law per harmonic, sine and cosine phases)."""
    tau = 0.0 * theta
    for order, a, b in harmonics:
        for amp, phase in ((a, 0.0), (b, 0.5 * np.pi)):
            p = SimpleNamespace(ripple=True, gear_ratio=order, ripple_motor_amplitude=amp,
                                ripple_motor_phase=phase, ripple_output_amplitude=0.0, ripple_output_phase=0.0)
            tau = tau + motor_ripple_torque(theta, p)
    return tau


def guide_friction(tendon_velocity, tension, c0, mu_alpha, v0):
    """Path friction on the tendon [N] between motor and spring, opposing the tendon motion
    (:func:`~awiwi_drake.components.friction.guide_friction`).

    ``c0``: the speed- and tension-independent magnitude of (4.1) at the rig's
    bending angle; ``mu_alpha``: capstan exponent (tension-proportional part, ch. 9);
    ``v0``: velocity scale of the smoothed sliding direction."""
    return guide_friction_law(tendon_velocity, tension, c0, mu_alpha, v0)


def joint_friction(qd, coulomb, velocity):
    """Link-side Coulomb friction, regularised stick-slip: ``-F_c tanh(q'/v_s)``
    (:func:`~awiwi_drake.components.friction.stribeck_friction` without a breakaway peak)."""
    return stribeck_friction(qd, coulomb, coulomb, velocity, velocity)
