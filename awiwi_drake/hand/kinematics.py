"""Finger kinematics (thesis section 5.2.1, Table 5.1, (5.2)-(5.3); thumb (5.19)).

Homogeneous transforms are 4x4 numpy arrays whose dtype follows the joint
angles (float, or object arrays of AutoDiffXd / symbolic Expression), so the
same functions serve forward kinematics, the tendon routing of the thumb and
tests.

Plant joints of a finger, in order (``finger_joint_names``):

* index / middle: abduction ``q_x0``, MCP ``q_x1``, PIP ``q_x2``, DIP ``q_x3``;
* ring: the same four, with ``q_43`` tied to ``q_42`` by (5.16) (3 DoF);
* fifth: hematometacarpal ``q_5h`` first, then the four above, ``q_53`` tied (4 DoF);
* thumb: base flexion ``q_10``, base abduction ``q_11``, PIP ``q_12``, DIP ``q_13``.
"""

from __future__ import annotations

import numpy as np

from ..parameters.hand import FingerParams, ThumbParams

__all__ = ["rot_y", "rot_z", "rot_axis", "translation", "M21", "finger_joint_names",
           "finger_frames", "thumb_frames", "thumb_base_transform"]

_FINGER_DIGIT = {"thumb": 1, "index": 2, "middle": 3, "ring": 4, "fifth": 5}


def _eye_like(q) -> np.ndarray:
    dtype = float if isinstance(q, (float, int, np.floating)) else object
    return np.eye(4, dtype=dtype) if dtype is float else np.eye(4).astype(object)


def rot_z(q) -> np.ndarray:
    """Homogeneous rotation about z by ``q`` (M10, M43, M65, M87 of Table 5.1)."""
    T = _eye_like(q)
    c, s = np.cos(q), np.sin(q)
    T[0, 0], T[0, 1], T[1, 0], T[1, 1] = c, -s, s, c
    return T


def rot_y(q) -> np.ndarray:
    """Homogeneous rotation about y by ``q``."""
    T = _eye_like(q)
    c, s = np.cos(q), np.sin(q)
    T[0, 0], T[0, 2], T[2, 0], T[2, 2] = c, s, -s, c
    return T


def rot_axis(axis, q) -> np.ndarray:
    """Homogeneous rotation by ``q`` about the unit ``axis`` (Rodrigues' formula)."""
    T = _eye_like(q)
    k = np.asarray(axis, dtype=float)
    if abs(np.linalg.norm(k) - 1.0) > 1e-12:
        raise ValueError(f"rot_axis: axis must be a unit vector, got {k}")
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    R = np.eye(3) + np.sin(q) * K + (1.0 - np.cos(q)) * (K @ K)
    T[:3, :3] = R
    return T


def translation(x: float, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    """Homogeneous translation (M32, M54, M76, M98 of Table 5.1)."""
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


# Table 5.1 M21: turns the abduction axis (z) into the flexion axis (rotation +90 deg about x).
M21 = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])


def finger_joint_names(finger: str, params=None) -> list[str]:
    """Names ``q<digit><j>`` of the plant joints of ``finger`` (``q5h`` for the HMC)."""
    if finger not in _FINGER_DIGIT:
        raise ValueError(f"finger must be one of {tuple(_FINGER_DIGIT)}, got {finger!r}")
    d = _FINGER_DIGIT[finger]
    names = [f"q{d}{j}" for j in range(4)]
    if finger == "fifth":
        names = [f"q{d}h"] + names
    return names


def finger_frames(p: FingerParams, q) -> list[np.ndarray]:
    """Frames of a finger in its base frame, (5.2): ``[T_abd, T_mcp, T_pip, T_dip, T_tip]``.

    ``q`` holds the plant joints (``finger_joint_names``); for the fifth finger the HMC angle comes first, a
    rotation about ``p.hmc_axis`` (the four-bar of section 5.5 replaced by one revolute joint, chosen).  Each
    frame is the joint frame *after* its rotation, so its z axis is the joint axis.
    """
    q = list(q)
    T = np.eye(4)
    if p.has_hmc:                                             # the chosen HMC offset, fifth only
        T = rot_axis(p.hmc_axis, q.pop(0)) @ translation(p.hmc_offset)
    if len(q) != 4:
        raise ValueError(f"q: expected {4 + int(p.has_hmc)} joint angles, got {len(q) + int(p.has_hmc)}")
    T_abd = T @ rot_z(q[0])                                                              # M10
    T_mcp = T_abd @ M21 @ translation(p.base_offset) @ rot_z(q[1])                      # M21 M32 M43
    T_pip = T_mcp @ translation(p.proximal_length) @ rot_z(q[2])                        # M54 M65
    T_dip = T_pip @ translation(p.middle_length, 0.0, p.middle_lateral) @ rot_z(q[3])   # M76 M87
    T_tip = T_dip @ translation(p.distal_length, 0.0, p.distal_lateral)                 # M98
    return [T_abd, T_mcp, T_pip, T_dip, T_tip]


def thumb_base_transform(p: ThumbParams, q10, q11) -> np.ndarray:
    """``T^12_10`` of (5.19): frame 12 (below the PIP) in the thumb base frame 10.

    Chosen structure (Fig 5.13 shows the axes, Table 5.2 the points): base
    flexion ``q10`` about z, then base abduction ``q11`` about the rotated y
    axis, then the metacarpal along x (``metacarpal_length``, chosen).
    """
    return rot_z(q10) @ rot_y(q11) @ translation(p.metacarpal_length)


def thumb_frames(p: ThumbParams, q) -> list[np.ndarray]:
    """Thumb frames in frame 10: ``[T_base(q10), T_12 (PIP, after q12), T_dip (after q13), T_tip]``."""
    q = list(q)
    if len(q) != 4:
        raise ValueError(f"q: expected 4 thumb joint angles, got {len(q)}")
    T_b = rot_z(q[0])
    T12 = T_b @ rot_y(q[1]) @ translation(p.metacarpal_length)
    T_pip = T12 @ rot_z(q[2])
    T_dip = T_pip @ translation(p.proximal_length) @ rot_z(q[3])
    T_tip = T_dip @ translation(p.distal_length)
    return [T_b, T_pip, T_dip, T_tip]
