"""Catalog laws, vectorised over model copies and generic in the scalar type.

Parameters arrive as arrays (one value per copy), so the foundation laws,
which take parameter dataclasses, are called with a light namespace holding
arrays.  Every function here works with float arrays (the fast path) and numpy
object arrays of AutoDiffXd (the scalar-conversion tests).
"""

from __future__ import annotations

import numpy as np

from awiwi_drake._math import positive_part
from awiwi_drake.parameters.discrepancy import CatalogBounds

__all__ = ["spring_force", "spring_with_hysteresis", "motor_friction", "ripple", "guide_friction",
           "joint_friction", "dahl_rate", "GUIDE_VELOCITY"]

GUIDE_VELOCITY = CatalogBounds().guide_velocity


def spring_force(x, coefficients):
    """Polynomial spring ``f = sum_k c_k x^k`` for ``x > 0``, else 0 (issue 6 contract)."""
    xp = positive_part(x)
    f = 0.0 * xp
    for c in reversed(coefficients):
        f = (f + c) * xp
    return f


def spring_with_hysteresis(x, w, coefficients, scale_rel, width):
    """Spring force with a stiffness-scale correction and a Dahl hysteresis offset ``h w``.

    The offset is gated by tension (no force when slack)."""
    f0 = spring_force(x, coefficients)
    return (1.0 + scale_rel) * f0 + width * w * np.tanh(f0 / 1.0)


def dahl_rate(xd, w, length, eps):
    """Normalised Dahl state rate ``w' = (x' - |x'| w) / delta``; ``w`` in [-1, 1]."""
    absv = np.sqrt(xd * xd + eps * eps)
    return (xd - absv * w) / length


def motor_friction(omega, coulomb, slope, viscous):
    """(3.8): torque acting on the motor ``-(g2 atan(g1 w) + g3 w)``."""
    return -(coulomb * np.arctan(slope * omega) + viscous * omega)


def ripple(theta, harmonics):
    """Torque periodic in the motor angle: ``sum a sin(n theta) + b cos(n theta)``."""
    tau = 0.0 * theta
    for order, a, b in harmonics:
        tau = tau + a * np.sin(order * theta) + b * np.cos(order * theta)
    return tau


def guide_friction(tendon_velocity, tension, c0, mu, v0):
    """Path friction on the tendon [N], opposing ``tendon_velocity`` (motor side).

    ``C0`` is (4.1) at the rig's total bending angle (speed independent);
    ``mu f`` is the tension-proportional (capstan, linearised) part of Ch. 9."""
    return (c0 + mu * positive_part(tension)) * np.tanh(tendon_velocity / v0)


def joint_friction(qd, coulomb, velocity):
    """Link-side Coulomb friction, regularised stick-slip: ``-F_c tanh(q'/v_s)``."""
    return -coulomb * np.tanh(qd / velocity)
