"""Test rigs (diagram builders) and the registry of linearisable targets.

``TARGETS`` maps the names the CLI accepts (``awiwi-drake linearize NAME``) to
``(builder, params_class, description)``; ``builder(params=..., backend=...)``
returns a :class:`Rig`. Finger and hand targets are registered by
:mod:`awiwi_drake.hand` (lazy imports keep ``import awiwi_drake`` fast).
"""

from awiwi_drake.rigs.base import OperatingPoint, Rig, add_revolute_link
from awiwi_drake.rigs.rigs import DEFAULT_BACKEND, flexible_joint_rig, joint_rig, tendon_rig
from awiwi_drake.parameters.rigs import FlexibleJointParams, JointRigParams, TendonRigParams

__all__ = ["OperatingPoint", "Rig", "tendon_rig", "flexible_joint_rig", "joint_rig", "TARGETS", "build_target"]

TARGETS = {
    "tendon-rig": dict(
        builder=tendon_rig, params=TendonRigParams,
        description="one motor + spring mechanism, far end fixed (ch. 10); state [theta, omega]; "
                    "operating point: tendon_force=20 N"),
    "flexible-joint": dict(
        builder=flexible_joint_rig, params=FlexibleJointParams,
        description="4th-order flexible joint (12.8), Table 12.1; state [q, q_dot, theta, theta_dot] as in (12.10); "
                    "fields link_inertia (m), motor_inertia (b), stiffness (k), link_damping (d_q), "
                    "motor_damping (d_theta)"),
    "joint-rig": dict(
        builder=joint_rig, params=JointRigParams,
        description="one link, two antagonistic motors + lever springs (Fig 5.9); "
                    "state [q, q_dot, theta1, theta2, omega1, omega2]; operating point: pretension=20 N, q=0"),
}


def build_target(name: str, overrides: dict | None = None, **kwargs) -> Rig:
    """Build a registered target by CLI name with ``NAME=VALUE`` parameter overrides."""
    if name not in TARGETS:
        raise ValueError(f"unknown rig {name!r}; choose one of {', '.join(sorted(TARGETS))}")
    entry = TARGETS[name]
    params = entry["params"]()
    if overrides:
        params = params.with_overrides(overrides)
    return entry["builder"](params=params, **kwargs)
