"""Shared test helper: the spectral radius of a finger/hand under a static law sampled behind a zero-order hold."""

from __future__ import annotations

import numpy as np
from pydrake.systems.primitives import Linearize

from awiwi_drake.analysis import linearize
from awiwi_drake.control import closed_loop
from awiwi_drake.control.base import StaticLawController


def sampled_radius(rig, law, rate_hz: float) -> float:
    """Spectral radius of ``rig`` under ``law`` sampled at ``rate_hz`` behind a zero-order hold (ideal sensors): the
    law's state feedback K from Drake's Linearize of the continuous loop (B K = A_cl - A, checked), the plant
    discretised exactly (matrix exponential of Drake's linearisation)."""
    from scipy.linalg import expm
    op = rig.operating_point()
    lin = linearize(rig, op)
    loop = closed_loop(rig, StaticLawController(law), rate_hz=None, sensors="ideal")
    ctx = loop.create_context(op, references={"joint_angle_reference": op.joint_angle})
    A_cl = Linearize(loop.diagram, ctx, input_port_index=loop.diagram.GetInputPort("joint_angle_reference").get_index(),
                     output_port_index=loop.diagram.GetOutputPort("joint_angle").get_index()).A()
    A, B = lin.A, lin.B
    K = np.linalg.lstsq(B, A_cl - A, rcond=None)[0]
    np.testing.assert_allclose(B @ K, A_cl - A, atol=1e-8 * np.abs(A_cl).max())     # the law is state feedback
    n, m = B.shape
    E = expm(np.block([[A, B], [np.zeros((m, n + m))]]) / rate_hz)
    return float(np.max(np.abs(np.linalg.eigvals(E[:n, :n] + E[:n, n:] @ K))))
