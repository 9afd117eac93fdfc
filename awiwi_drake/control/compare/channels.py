"""The independent DoF of a finger/hand closed loop, for per-joint rows of the standard tests."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from awiwi_drake.analysis.schedules import PerEntry, Schedule
from awiwi_drake.control.base import ClosedLoop

__all__ = ["JointChannels", "joint_channels", "joint_inputs"]


@dataclass(frozen=True)
class _Affine(Schedule):
    """``offset + gain * inner(t)``: one DoF's schedule on a plant joint (``q = S q_dof``)."""

    inner: Schedule
    gain: float
    offset: float

    def __post_init__(self):      # inner is a schedule (checked when made); gain and offset come from the design
        pass

    def value(self, t):
        return self.offset + self.gain * self.inner.value(t)

    def breakpoints(self):
        return self.inner.breakpoints()


@dataclass
class JointChannels:
    """The independent DoF of a finger/hand loop, one metrics row each.

    ``S`` maps them to the plant joints (``q = S q_dof``; ring/fifth: the DIP follows the PIP,
    (5.16)); a DoF is named after its plant joint.  ``fingers``/``tendons``: the finger of each DoF
    and the slice of its tendons (its motors' torques are the DoF's input).  ``position``: index of
    the DoF within its finger.
    """

    names: list
    S: np.ndarray
    q0: np.ndarray
    fingers: list
    tendons: list
    position: list

    def disturbance_groups(self) -> list[list[int]]:
        """DoF loaded together in the disturbance test: the k-th joint of every finger (the fingers are
        mechanically independent, the palm is fixed), so each load sees the other joints free."""
        return [[i for i, p in enumerate(self.position) if p == k] for k in range(max(self.position) + 1)]


def joint_channels(loop: ClosedLoop) -> JointChannels | None:
    """:class:`JointChannels` of a finger/hand loop tracking ``joint_angle`` (None for the 1-DoF rigs)."""
    from awiwi_drake.hand.coupling import dof_selection
    from awiwi_drake.hand.diagrams import HandRig
    rig = loop.rig
    if not isinstance(rig, HandRig) or not loop.tracked_outputs or loop.tracked_outputs[0] != "joint_angle":
        return None
    coupling = rig.coupling
    S = dof_selection(coupling)
    parts = coupling.parts
    joint_names = rig.joint_names
    names, fingers, tendons, position = [], [], [], []
    col = ten = 0
    for fname, part in parts.items():
        k, m = part.dof_selection.shape[1], part.num_tendons
        for jj in range(k):
            names.append(joint_names[int(np.flatnonzero(S[:, col + jj])[0])])
            fingers.append(fname)
            tendons.append(slice(ten, ten + m))
            position.append(jj)
        col, ten = col + k, ten + m
    q0 = np.linalg.pinv(S) @ np.asarray(rig.operating_point().joint_angle, dtype=float)
    return JointChannels(names, S, q0, fingers, tendons, position)


def joint_inputs(ch: JointChannels, dof_schedules: Sequence[Schedule]) -> PerEntry:
    """Plant-joint schedules ``q_i = S_ij (q0_j + s_j(t))`` from one schedule per DoF."""
    entries = []
    for i in range(ch.S.shape[0]):
        j = int(np.flatnonzero(ch.S[i])[0])
        a = float(ch.S[i, j])
        entries.append(_Affine(dof_schedules[j], a, a * ch.q0[j]))
    return PerEntry(entries)
