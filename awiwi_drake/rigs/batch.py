"""N copies of a single-joint rig in one system (Monte-Carlo runs, sweeps over inputs).

:func:`batched_joint_rig` builds ``num_copies`` joint rigs (Fig 5.9) as one
:class:`~awiwi_drake.components.fused_drive.TendonDriveBatch_` (one compiled loop over the copies).  The
copies share the rig's parameters; inputs and initial states differ per copy, copy-major.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import System

from awiwi_drake.components.fused_drive import TendonDriveBatch_
from awiwi_drake.components.rig_system import sampled_dynamics
from awiwi_drake.parameters.rigs import JointRigParams
from awiwi_drake.rigs.base import OperatingPoint
from awiwi_drake.rigs.rigs import joint_rig

__all__ = ["BatchedRig", "batched_joint_rig"]


@dataclass
class BatchedRig:
    """``num_copies`` copies of ``single`` (a :class:`~awiwi_drake.rigs.base.Rig`) in ``diagram``."""

    diagram: System
    single: object
    num_copies: int

    def stack(self, ops) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(state, motor_torque, external_torque) of the batch from one operating point per copy
        (or one for all)."""
        ops = [ops] * self.num_copies if isinstance(ops, OperatingPoint) else list(ops)
        if len(ops) != self.num_copies:
            raise ValueError(f"batched rig: {len(ops)} operating points for {self.num_copies} copies")
        ext = [np.zeros(1) if op.external_torque is None else np.asarray(op.external_torque, float) for op in ops]
        return (np.concatenate([op.state for op in ops]), np.concatenate([op.motor_torque for op in ops]),
                np.concatenate(ext))

    def sampled_diagram(self, period: float) -> System:
        """A new batch system sampled at ``period`` [s]: the copies as *one* Drake ``DiscreteTimeApproximation``
        (:func:`~awiwi_drake.components.rig_system.sampled_dynamics`: fixed-step RK3, one step per period,
        inputs held), the same ports and state order (the discrete state). In a loop sampled at ``period`` it
        replaces the batch behind a zero-order hold: the same trajectories to round-off, and the integrator
        steps the copies' contiguous state inside one system instead of walking a diagram's state."""
        system = TendonDriveBatch_[float](self.single.drive.model, self.num_copies)
        system.set_name(self.diagram.get_name())
        return sampled_dynamics(system, period)

    def context(self, ops=None):
        """A context with every copy at ``ops`` (default: the rig's default operating point), inputs fixed."""
        x, u, e = self.stack(self.single.operating_point() if ops is None else ops)
        ctx = self.diagram.CreateDefaultContext()
        ctx.SetContinuousState(x)
        self.diagram.GetInputPort("motor_torque").FixValue(ctx, u)
        self.diagram.GetInputPort("external_torque").FixValue(ctx, e)
        return ctx


def batched_joint_rig(num_copies: int, *, params: JointRigParams | None = None) -> BatchedRig:
    """``num_copies`` joint rigs with ``params`` in one system; ``BatchedRig.diagram`` is the
    :class:`~awiwi_drake.components.fused_drive.TendonDriveBatch_` itself, not wrapped in a Diagram, so a loop
    around it holds the copies' state in one contiguous block."""
    single = joint_rig(params=params)
    system = TendonDriveBatch_[float](single.drive.model, num_copies)
    system.set_name(f"joint_rig_x{num_copies}")
    return BatchedRig(system, single, int(num_copies))
