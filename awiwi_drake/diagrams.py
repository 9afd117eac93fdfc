"""Named plants and diagram lists (top layer: it may use every plant package).

* ``TARGETS`` maps the names the CLI accepts (``awiwi-drake linearize NAME``) to
  ``dict(builder, params, description)``; ``builder(params=...)`` (fingers
  and hand: any ``finger_diagram``/``hand_diagram`` keyword) returns a :class:`~awiwi_drake.rigs.Rig` (the rigs, each finger, the hand);
  :func:`build_target` builds one with ``NAME=VALUE`` overrides.
* ``DIAGRAM_EXPORTS`` lists ``(file_stem, builder, max_depth)`` of the graphs
  committed under ``diagrams/`` (regenerate: ``awiwi-drake export-diagrams``);
  ``builder()`` returns a Diagram.
"""

from __future__ import annotations

import functools

from awiwi_drake.export import export_diagram, graphviz_available
from awiwi_drake.parameters.hand import FINGERS, FingerRigParams, HandRigParams
from awiwi_drake.parameters.rigs import FlexibleJointParams, JointRigParams, TendonRigParams
from awiwi_drake.rigs import Rig, flexible_joint_rig, joint_rig, tendon_rig

__all__ = ["TARGETS", "build_target", "DIAGRAM_EXPORTS", "export_all"]

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


# --- fingers and hand (thesis ch. 5-6), with lazy imports ----------------------------------------
def _hand_target(finger: str | None):
    def build(*, params=None, **kw):
        from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram
        if finger is None:
            return hand_diagram(params=params, **kw)
        return finger_diagram(finger=finger, params=params, **kw)
    build.__name__ = f"{finger or 'hand'}_target"
    return build


def _register_hand_targets() -> None:
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


# --- diagram graphs ---------------------------------------------------------------------------
def _plant(name: str, **kw):
    """Builder of the diagram of target ``name`` with its default parameters."""
    return lambda: build_target(name, **kw).diagram


def _loop(name: str, controller: str, **kw):
    """Builder of target ``name`` closed by the registered ``controller``."""
    def build():
        from awiwi_drake.control import closed_loop, make_controller
        rig = build_target(name, **kw)
        return closed_loop(rig, make_controller(controller, rig)).diagram
    return build


def _demo_loop():
    from awiwi_drake.control.motor_position import joint_rig_position_loop
    return joint_rig_position_loop(joint_rig()).diagram


DIAGRAM_EXPORTS = [
    ("tendon_rig", _plant("tendon-rig"), None),
    ("flexible_joint_rig", _plant("flexible-joint"), None),
    ("joint_rig", _plant("joint-rig"), 1),
    ("joint_rig_deep", _plant("joint-rig"), None),
    ("joint_rig_position_loop", _demo_loop, 1),
    ("hand_top", _plant("hand"), 1),
    ("hand_deep", _plant("hand"), None),
    ("hand_finger_index_control_wrist", _loop("finger-index", "joint-pd", wrist=True), 1),
    ("hand_finger_ring_deep", _plant("finger-ring"), None),
]


def export_all(out_dir="diagrams") -> list[str]:
    """Export every entry of ``DIAGRAM_EXPORTS``; returns one line per file written or skipped."""
    lines = []
    for stem, builder, depth in DIAGRAM_EXPORTS:
        res = export_diagram(builder(), out_dir, stem, max_depth=depth, quiet=True)
        lines.append(f"wrote {res.dot}" + "".join(f", {p.name}" for p in res.images))
        if graphviz_available():
            lines.extend(f"  not rendered: {why}" for why in res.skipped)
    if not graphviz_available():
        lines.append("note: Graphviz 'dot' not found: only .dot files were written "
                     "(install the Debian package 'graphviz' for .svg/.png)")
    return lines
