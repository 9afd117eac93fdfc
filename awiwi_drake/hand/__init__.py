"""The Awiwi hand: fingers (thesis ch. 5) and wrist (ch. 6, :mod:`.wrist`).

* :mod:`.kinematics`: Table 5.1 transforms, thumb base transform (5.19).
* :mod:`.coupling`: tendon lengths ``h(q)``, coupling matrices ``P(q) = dh/dq``
  ((5.5), (5.18), (5.22)), stiffness transformation (5.12), guide friction.
* :mod:`.estimation`: link-position estimation, pseudo-inverse (5.15) and
  Algorithm 1 (thumb base).
* :mod:`.plant`: continuous MultibodyPlant builders for each finger and the hand.
* :mod:`.diagrams`: ``finger_diagram`` / ``hand_diagram`` (motors, springs,
  routing, plant; Rig-compatible; close them with
  :func:`awiwi_drake.control.closed_loop`, e.g. the ``joint-pd`` controller).
* :mod:`.plots`.

The chapter 5-6 studies (Fig 5.7, poles vs pretension, coupling hold, wrist
compensation) are :mod:`awiwi_drake.reproductions.ch05_fingers` and
:mod:`~awiwi_drake.reproductions.ch06_wrist`; the Meshcat HTML recording is
:mod:`awiwi_drake.export.animation`.

``finger_diagram`` and ``hand_diagram`` are importable from
here (loaded on first use, so ``import awiwi_drake.hand`` stays light).
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
