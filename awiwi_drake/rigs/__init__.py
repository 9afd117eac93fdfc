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


def build_target(name: str, overrides: dict | None = None, *, params=None, **kwargs) -> Rig:
    """Build a registered target by CLI name, from ``params`` (default: the target's defaults)
    with ``NAME=VALUE`` parameter ``overrides`` applied."""
    if name not in TARGETS:
        raise ValueError(f"unknown rig {name!r}; choose one of {', '.join(sorted(TARGETS))}")
    entry = TARGETS[name]
    params = entry["params"]() if params is None else params
    if overrides:
        params = params.with_overrides(overrides)
    return entry["builder"](params=params, **kwargs)


# --- fingers and hand (thesis ch. 5-6), registered here with lazy imports -------------------------
def _hand_target(finger: str | None):
    def build(*, params=None, backend: str | None = None):
        from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram
        kw = {} if backend is None else {"backend": backend}
        if finger is None:
            return hand_diagram(params=params, wrist=True, **kw)
        return finger_diagram(finger=finger, params=params, **kw)
    build.__name__ = f"{finger or 'hand'}_target"
    return build


def _register_hand_targets() -> None:
    import functools
    from awiwi_drake.parameters.hand import FINGERS, FingerRigParams, HandRigParams
    dof = {"thumb": "4 DoF (tensegrity base (5.20)-(5.22), PIP, DIP), 8 tendons",
           "index": "4 DoF (Table 5.1, (5.5)), 8 tendons", "middle": "4 DoF (as the index), 8 tendons",
           "ring": "3 DoF (PIP/DIP coupled (5.16), 4 plant joints), 6 tendons",
           "fifth": "4 DoF (hematometacarpal + ring-like), 5 plant joints, 8 tendons"}
    for f in FINGERS:
        TARGETS[f"finger-{f}"] = dict(
            builder=_hand_target(f), params=functools.partial(FingerRigParams.for_finger, f),
            description=f"{f} finger: {dof[f]}; state [q, q_dot, theta, omega]; operating point: "
                        "pretension=20 N, q=0")
    TARGETS["hand"] = dict(
        builder=_hand_target(None), params=HandRigParams,
        description="whole hand: 21 plant joints (19 DoF), 38 motors and springs, wrist input held at 0; "
                    "state [q (21), q_dot (21), theta (38), omega (38)]")


_register_hand_targets()
