"""Test rigs (diagram builders) of the thesis: motor, tendon, flexible joint, antagonistic joint.

The registry of named plants that the CLI accepts (rigs, fingers, hand) is
:data:`awiwi_drake.diagrams.TARGETS` (it needs :mod:`awiwi_drake.hand`, which sits beside
this package and may use it, never the reverse).
"""

from awiwi_drake.rigs.base import OperatingPoint, Rig, add_revolute_link
from awiwi_drake.rigs.rigs import flexible_joint_rig, joint_rig, motor_rig, tendon_rig

__all__ = ["OperatingPoint", "Rig", "motor_rig", "tendon_rig", "flexible_joint_rig", "joint_rig"]
