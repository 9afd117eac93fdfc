"""The diagram graphs committed under ``diagrams/`` (regenerate: ``awiwi-drake export-diagrams``).

``DIAGRAM_EXPORTS`` lists ``(file_stem, builder, max_depth)``: ``builder()``
returns a Diagram. Other parts of the package append their entries.
"""

from __future__ import annotations

from awiwi_drake.export import export_diagram, graphviz_available

__all__ = ["DIAGRAM_EXPORTS", "export_all", "export_entries"]


def _tendon():
    from awiwi_drake.rigs import tendon_rig
    return tendon_rig().diagram


def _flexible():
    from awiwi_drake.rigs import flexible_joint_rig
    return flexible_joint_rig().diagram


def _joint():
    from awiwi_drake.rigs import joint_rig
    return joint_rig().diagram


def _joint_loop():
    from awiwi_drake.rigs import joint_rig
    from awiwi_drake.control.motor_position import joint_rig_position_loop
    return joint_rig_position_loop(joint_rig()).diagram


def _index_loop_wrist():
    from awiwi_drake.control import closed_loop, make_controller
    from awiwi_drake.hand.diagrams import finger_diagram
    rig = finger_diagram(finger="index", wrist=True)
    return closed_loop(rig, make_controller("joint-pd", rig)).diagram


def _hand(stem):
    def build():
        from awiwi_drake.hand.diagrams import HAND_DIAGRAM_EXPORTS
        return dict((s, b) for s, b, _ in HAND_DIAGRAM_EXPORTS)[stem]()
    return build


DIAGRAM_EXPORTS = [
    ("tendon_rig", _tendon, None),
    ("flexible_joint_rig", _flexible, None),
    ("joint_rig", _joint, 1),
    ("joint_rig_deep", _joint, None),
    ("joint_rig_position_loop", _joint_loop, 1),
    ("hand_top", _hand("hand_top"), 1),
    ("hand_deep", _hand("hand_deep"), None),
    ("hand_finger_index_control_wrist", _index_loop_wrist, 1),
    ("hand_finger_ring_deep", _hand("hand_finger_ring_deep"), None),
]


def export_all(out_dir="diagrams") -> list[str]:
    """Export every entry of ``DIAGRAM_EXPORTS``; returns one line per file written or skipped."""
    return export_entries(DIAGRAM_EXPORTS, out_dir)


def export_entries(entries, out_dir="diagrams") -> list[str]:
    """Export ``(stem, builder, max_depth)`` entries; one line per file written or skipped."""
    lines = []
    for stem, builder, depth in entries:
        res = export_diagram(builder(), out_dir, stem, max_depth=depth, quiet=True)
        lines.append(f"wrote {res.dot}" + "".join(f", {p.name}" for p in res.images))
        if graphviz_available():
            lines.extend(f"  not rendered: {why}" for why in res.skipped)
    if not graphviz_available():
        lines.append("note: Graphviz 'dot' not found: only .dot files were written "
                     "(install the Debian package 'graphviz' for .svg/.png)")
    return lines
