"""Nominal dataset parameters used by the truth generator (centre of its random draw)."""

from __future__ import annotations

from awiwi_drake.parameters.discrepancy import TruthGeneratorParams

__all__ = ["nominal_defaults"]


def nominal_defaults(rig: str, gen: TruthGeneratorParams | None = None) -> dict:
    """Dataset ``parameters`` of the contract for ``rig`` from :class:`TruthGeneratorParams`."""
    g = gen or TruthGeneratorParams()
    p = {"motor_inertia": g.motor_inertia, "motor_damping": g.motor_damping,
         "motor_pulley_radius": g.motor_pulley_radius, "spring_poly": list(g.spring_poly)}
    if rig == "joint-rig":
        p.update(link_inertia=g.link_inertia, link_damping=g.link_damping,
                 link_pulley_radius=g.link_pulley_radius)
    return p
