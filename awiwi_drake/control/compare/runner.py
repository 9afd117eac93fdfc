"""What the standard tests share: the run record (:class:`TestRun`), the start settled at the initial reference
(:func:`settle`, through :func:`awiwi_drake.analysis.simulate`) and the motors' applied torque and limit."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from awiwi_drake.analysis import simulate
from awiwi_drake.control.base import ClosedLoop
from awiwi_drake.rigs.base import Rig

__all__ = ["TestRun", "applied_port", "torque_limit", "settle"]


@dataclass
class TestRun:
    """Time series of one test on one closed loop (t = 0 at the test start)."""

    controller: str
    test: str
    t: np.ndarray
    reference: np.ndarray
    output: np.ndarray
    command: np.ndarray
    disturbance: np.ndarray
    state: np.ndarray
    meta: dict = field(default_factory=dict)


def applied_port(loop: ClosedLoop) -> str:
    """The torque the motors receive: the rig's ``applied_torque`` (after its amplifier limit) when it has one."""
    return "applied_torque" if loop.diagram.HasOutputPort("applied_torque") else "motor_torque"


def torque_limit(loop: ClosedLoop, size: int):
    """The command limit [Nm] per motor: the loop's ``saturation`` or the rig's amplifier limit (None: none)."""
    limit = loop.saturation
    if limit is None and isinstance(loop.rig, Rig) and loop.rig.torque_limit is not None:
        limit = np.full(size, float(loop.rig.torque_limit))  # the rig's own amplifier limit
    return limit


def settle(loop: ClosedLoop, reference: float, *, t_settle: float, max_step: float = 2e-4, state=None,
           motor_torque=None):
    """A context of ``loop`` settled at the constant ``reference`` (time reset to 0).

    The start is the rig's operating point for the tracked output at ``reference``
    (``tendon_force=...``, ``joint_angle=...``; else its default one) unless
    ``state`` is given.
    """
    if state is None and isinstance(loop.rig, Rig):
        try:  # start at the rig's equilibrium for the reference when the rig offers one
            op = loop.rig.operating_point(**{loop.tracked_outputs[0]: reference})
        except (TypeError, ValueError):
            op = loop.rig.operating_point()
        state = np.asarray(op.state, dtype=float)
        motor_torque = op.motor_torque if motor_torque is None else motor_torque
    refs = {r: reference for r in loop.references}
    from awiwi_drake.control.compare.channels import joint_channels
    ch = joint_channels(loop)
    if ch is not None:   # finger/hand: the reference on every DoF, relative to the operating point
        refs = {loop.references[0]: ch.S @ (ch.q0 + reference)}
    ctx = loop.create_context(state=state, motor_torque=motor_torque, references=refs)
    if t_settle > 0:
        simulate(loop, ctx, t_settle, log=(), max_step=max_step, accuracy=1e-6)  # advances ctx
    ctx.SetTime(0.0)
    return ctx
