"""Tendon drive: N motors + N spring mechanisms + routing to n joints, as one sub-diagram.

The drive is one :class:`~awiwi_drake.components.fused_drive.TendonDrive_` system: numba kernels
generated from the law functions for float, the law functions themselves for AutoDiffXd/Expression;
one spring law per tendon, guide friction and hysteresis; every output port computes only its own
quantity.

The returned sub-diagram exports:

* inputs ``motor_torque`` (m) [Nm], ``joint_angle`` (n) [rad], and with
  hysteresis or guide friction ``joint_velocity`` (``rate_joints``) [rad/s] (no
  joint ports when n = 0, the tendon rig whose far end is fixed);
* outputs ``state``, ``motor_angle``, ``motor_velocity``, ``motor_state`` (2m),
  ``tendon_force`` (m) [N], ``tendon_stiffness`` (m) [N/m], ``elongation`` (m) [m],
  ``generalized_force`` (n) [Nm] (``-P^T f``), ``applied_torque`` (m) [Nm].

State: ``[theta (m), omega (m)]`` then, with hysteresis, ``z (m)``, then with guide friction
``g (m)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder

from awiwi_drake.components.fused_drive import DriveModel, GuideFrictionModel, TendonDrive_
from awiwi_drake.components.spring import TendonSprings
from awiwi_drake.parameters.components import HysteresisParams, MotorParams

__all__ = ["build_tendon_drive", "TendonDrive", "DRIVE_OUTPUTS"]

DRIVE_OUTPUTS = ("motor_angle", "motor_velocity", "motor_state", "tendon_force", "tendon_stiffness",
                 "elongation", "generalized_force", "applied_torque")


@dataclass(frozen=True)
class TendonDrive:
    """Handle of a built drive: the (sub-)diagram holding it, its sizes and its model."""

    diagram: Diagram
    num_tendons: int
    num_joints: int
    hysteresis: bool
    model: DriveModel

    @property
    def guide_friction(self) -> bool:
        """Whether the drive carries the guide friction state."""
        return self.model.has_guide_friction

    @property
    def num_states(self) -> int:
        return self.model.num_states - (2 * self.num_joints if self.model.has_link else 0)


def build_tendon_drive(*, motor: MotorParams, spring, coupling, offsets=None,
                       hysteresis: HysteresisParams = HysteresisParams(),
                       motor_pulley_radius: float | None = None, name: str = "tendon_drive",
                       guide_friction: GuideFrictionModel | None = None,
                       rate_joints: int | None = None) -> TendonDrive:
    """Build the motors + springs + routing sub-diagram (see module docstring).

    Parameters
    ----------
    motor : MotorParams
        Shared by all m motors.
    spring : spring law, or one law per tendon
        ``force(x)``/``stiffness(x)`` object (e.g. :func:`tendon_spring`), or a
        :class:`~awiwi_drake.components.spring.TendonSprings` (or a sequence of m laws):
        tendon ``i`` is evaluated with its own law.
    coupling : coupling object
        ``h(q)``, ``P(q)``, ``num_tendons``, ``num_joints`` (see :mod:`routing`).
    offsets : (m,) array, optional
        Elongation offsets x0 [m] (pretension with all angles zero).
    hysteresis : HysteresisParams
        Spring hysteresis (adds m states and the ``joint_velocity`` input).
    motor_pulley_radius : float, optional
        Transmission radius from elongation to motor angle; defaults to
        ``motor.pulley_radius``. The flexible joint uses 1 (torsional spring).
    name : str
        Name of the sub-diagram.
    guide_friction : GuideFrictionModel, optional
        Guide friction on every tendon path.
    rate_joints : int, optional
        Number of leading coupling joints with a ``joint_velocity`` input (default
        all); the rest (the hand's wrist length offsets) are quasi-static.
    """
    if not isinstance(motor, MotorParams):
        raise ValueError(f"build_tendon_drive: motor must be MotorParams, got {type(motor).__name__}")
    m, n = int(coupling.num_tendons), int(coupling.num_joints)
    r_m = motor.pulley_radius if motor_pulley_radius is None else float(motor_pulley_radius)
    if not r_m > 0:
        raise ValueError(f"build_tendon_drive: motor_pulley_radius = {r_m} must be > 0")
    offsets = np.zeros(m) if offsets is None else np.asarray(offsets, dtype=float)
    if offsets.shape != (m,) or not np.all(np.isfinite(offsets)):
        raise ValueError(f"build_tendon_drive: offsets must be {m} finite numbers [m], got {offsets!r}")
    if isinstance(spring, (list, tuple)):
        spring = TendonSprings(spring)
    if isinstance(spring, TendonSprings) and len(spring) != m:
        raise ValueError(f"build_tendon_drive: spring has {len(spring)} laws, one per tendon ({m}) expected")
    laws = spring.laws if isinstance(spring, TendonSprings) else (spring,) * m
    model = DriveModel(motor, laws, coupling, offsets, r_m, hysteresis, guide_friction, rate_joints)
    builder = DiagramBuilder()
    sys_ = builder.AddNamedSystem("drive", TendonDrive_[float](model))
    for i in range(sys_.num_input_ports()):
        builder.ExportInput(sys_.get_input_port(i), sys_.get_input_port(i).get_name())
    for i in range(sys_.num_output_ports()):
        builder.ExportOutput(sys_.get_output_port(i), sys_.get_output_port(i).get_name())
    diagram = builder.Build()
    diagram.set_name(name)
    return TendonDrive(diagram, m, n, bool(hysteresis.enabled), model)
