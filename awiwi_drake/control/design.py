"""What a finger/hand controller was designed with: its ``design`` (read by compare's standard tests and users).

:class:`ChainDesign` is the joint stage -> force distribution -> force law chain's (ch. 7, 10, 12-14; its design
point is :func:`~awiwi_drake.control.chain.chain_design_point`), :class:`BacksteppingDesign` the 15.5 finger
backstepping's (:class:`~awiwi_drake.control.finger_backstepping.FingerBacksteppingLaw`).  ``k`` DoF, ``n`` plant
joints, ``m`` tendons.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

__all__ = ["ControllerDesign", "ChainDesign", "BacksteppingDesign"]


@dataclass
class ControllerDesign:
    """The design point of a finger/hand controller: ``selection`` ``S`` (n, k), plant joints per DoF;
    ``coupling_matrix`` ``P S`` (m, k) [m] at the design point; its ``tendon_force`` ``f_op`` (m) [N] and
    ``torque_offset`` ``tau_op = -(P S)^T f_op`` (k) [Nm]; ``time_constant`` [s], the slowest designed tracking
    mode (compare's step window; None where the controller reports none); ``force_gains``, the force level's gains
    (the chain's :class:`~awiwi_drake.control.tendon_force.TendonForceGains`, the ch. 16 selection of the optimal
    backstepping; None where the law's own).  Where the law has the closed form of its rest held by friction:
    ``dead_band`` (k) [rad], the half-width of its friction dead band per DoF, and ``friction_hold(e, dof_load)``,
    per DoF the fraction of its friction bound the frictions must hold for the loop to rest at the DoF errors ``e``
    [rad] under the DoF loads ``dof_load`` [Nm] (all <= 1: a rest held by friction)."""

    selection: np.ndarray
    coupling_matrix: np.ndarray
    tendon_force: np.ndarray
    torque_offset: np.ndarray
    time_constant: float | None = None
    force_gains: Any = None
    dead_band: np.ndarray | None = None
    friction_hold: Callable | None = None

    @property
    def static_stiffness(self) -> np.ndarray | None:
        """The static stiffness [Nm/rad] per DoF the design promises to a constant load on that DoF alone (the
        others held at their references by their own laws); None when the design has none."""
        return None


@dataclass
class ChainDesign(ControllerDesign):
    """The chain's design (:class:`ControllerDesign` and): ``op``, the rig's operating point it was designed at;
    ``fingers`` (names; None for a one-joint sub-rig); ``joint_angle`` ``q_op`` (n) [rad];
    ``mechanical_stiffness``, the desired (5.12) blocks per finger [Nm/rad]; once built into a
    :class:`~awiwi_drake.control.chain.TendonChainController`: its ``joint_law``, ``distribution_method`` and, for
    the per-joint designs, ``joint_design`` (:class:`~awiwi_drake.control.joint_design.JointDesign`)."""

    op: Any = None
    fingers: tuple | None = None
    joint_angle: np.ndarray | None = None
    mechanical_stiffness: list | None = None
    joint_law: Any = None
    distribution_method: str | None = None
    joint_design: Any = None

    @property
    def static_stiffness(self) -> np.ndarray | None:
        """The per-joint design's decoupled static stiffness [Nm/rad]
        (:attr:`~awiwi_drake.control.joint_design.JointDesign.static_stiffness`)."""
        return None if self.joint_design is None else np.asarray(self.joint_design.static_stiffness, dtype=float)


@dataclass
class BacksteppingDesign(ControllerDesign):
    """The 15.5 finger backstepping's design (:class:`ControllerDesign` and): the DoF ``inertia`` ``M`` (k, k)
    [kg m^2]; its gains ``Kp`` [Nm/rad], ``Kd`` [Nm s/rad] (k, k), ``K3``, ``K4`` [1/s] (m); with a (9.2) observer,
    its ``observer_rest_modes`` (k) [1/s]."""

    inertia: np.ndarray | None = None
    Kp: np.ndarray | None = None
    Kd: np.ndarray | None = None
    K3: np.ndarray | None = None
    K4: np.ndarray | None = None
    observer_rest_modes: np.ndarray | None = None

    @property
    def static_stiffness(self) -> np.ndarray:
        """``1 / (Kp^-1)_jj`` [Nm/rad]: with the load observed the rest is ``Kp e = S^T tau_ext``
        (:class:`~awiwi_drake.control.finger_backstepping.ObservedBacksteppingController`)."""
        return 1.0 / np.diag(np.linalg.inv(np.atleast_2d(np.asarray(self.Kp, dtype=float))))
