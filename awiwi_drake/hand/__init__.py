"""The Awiwi hand: fingers (thesis ch. 5) and wrist (ch. 6); docs/ARCHITECTURE.md maps the modules.

``finger_diagram`` and ``hand_diagram`` (Rig-compatible; close them with
:func:`awiwi_drake.control.closed_loop`) are importable from here, loaded on first use so that
``import awiwi_drake.hand`` stays light; the chapter 5-6 studies are in :mod:`awiwi_drake.reproductions`.
"""

from .coupling import (FingerCoupling, LinearFingerCoupling, ThumbCoupling, HandCoupling,
                       finger_coupling, hand_coupling, joint_stiffness, reduced_coupling_matrix)
from .kinematics import finger_frames, finger_joint_names, thumb_base_transform, thumb_frames

__all__ = ["FingerCoupling", "LinearFingerCoupling", "ThumbCoupling", "HandCoupling",
           "finger_coupling", "hand_coupling", "joint_stiffness", "reduced_coupling_matrix",
           "finger_frames", "finger_joint_names", "thumb_base_transform", "thumb_frames",
           "finger_diagram", "hand_diagram"]

_LAZY = {"finger_diagram": "diagrams", "hand_diagram": "diagrams"}


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
