"""Tendon elasticity and guide friction (thesis ch. 4, section 5.1)."""

from __future__ import annotations

import numpy as np

from awiwi_drake.parameters.components import GuideFrictionParams, TendonParams

__all__ = ["tendon_stiffness", "series_stiffness", "guide_friction_force", "capstan_friction_force",
           "guide_friction_tension"]


def tendon_stiffness(p: TendonParams) -> float:
    """Axial stiffness of the tendon ``k_t = E S / l0`` [N/m] (section 5.1)."""
    return p.youngs_modulus * p.cross_section / p.rest_length


def series_stiffness(k_mechanism, k_tendon):
    """Stiffness of the mechanism and the tendon in series: ``(1/k_m + 1/k_t)^-1``.

    A slack mechanism (``k_m = 0``) gives 0.
    """
    k_mechanism = np.asarray(k_mechanism, dtype=float)
    if np.any(k_mechanism < 0) or k_tendon <= 0:
        raise ValueError("series_stiffness: k_mechanism must be >= 0 and k_tendon > 0 [N/m]")
    return np.where(k_mechanism > 0, k_mechanism * k_tendon / np.where(k_mechanism > 0, k_mechanism + k_tendon, 1.0), 0.0)


def guide_friction_force(bending_angle, p: GuideFrictionParams = GuideFrictionParams()):
    """Guide friction magnitude (4.1): ``F = C0 (1 - exp(-C1 alpha))`` [N].

    ``bending_angle`` alpha [rad] is the total angle the tendon wraps on its
    guides (>= 0). Independent of tension and speed (Fig 4.10).
    """
    a = np.asarray(bending_angle, dtype=float)
    if np.any(a < 0) or not np.all(np.isfinite(a)):
        raise ValueError(f"guide_friction_force: bending_angle must be finite and >= 0 [rad], got {bending_angle}")
    return p.c0 * (1.0 - np.exp(-p.c1 * a))


def capstan_friction_force(tension, bending_angle, p: GuideFrictionParams = GuideFrictionParams()):
    """Tension-proportional (capstan) guide friction: ``F = f (1 - exp(-mu alpha))`` [N].

    The force lost between the two ends of a tendon pulled with tension ``f``
    around a total angle alpha. Generic in the scalar type of ``tension``.
    """
    a = np.asarray(bending_angle, dtype=float)
    if np.any(a < 0) or not np.all(np.isfinite(a)):
        raise ValueError(f"capstan_friction_force: bending_angle must be finite and >= 0 [rad], got {bending_angle}")
    return tension * (1.0 - np.exp(-p.mu * a))


def guide_friction_tension(sliding_speed, magnitude, smoothing_velocity: float):
    """Friction force of the guides on a tendon sliding at ``sliding_speed`` [m/s]: ``F tanh(v / v_s)`` [N].

    ``magnitude`` F from (4.1) (:func:`guide_friction_force`) or the capstan form
    (:func:`capstan_friction_force`); ``tanh(v / v_s)`` is a smooth ``sign(v)``, so the
    power ``-F tanh(v / v_s) v`` taken from the tendon is never positive. Generic in the
    scalar type.
    """
    return magnitude * np.tanh(sliding_speed / smoothing_velocity)
