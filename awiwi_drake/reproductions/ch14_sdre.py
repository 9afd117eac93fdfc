"""Thesis ch. 14: SDRE control of the tendon rig (Fig 14.3) and of the nonlinear flexible joint (Fig 14.4-14.5).

The controllers are :mod:`awiwi_drake.control.sdre`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from awiwi_drake.control.base import closed_loop
from awiwi_drake.analysis import Samples, Step, simulate
from awiwi_drake.control.sdre import SDRE_GAIN, joint_sdre_controller, tendon_sdre_controller
from awiwi_drake.control.tendon_force import ForceMap, force_map
from awiwi_drake.parameters import FlexibleJointParams
from awiwi_drake.parameters.control import CONTROL_RATE_HZ as RATE, SdreJointParams, SdreTendonParams
from awiwi_drake.plotting import figure_axes, plot_traces
from awiwi_drake.rigs import flexible_joint_rig, tendon_rig

__all__ = ["SdreRun", "tendon_sdre_experiment", "joint_sdre_experiment", "hand_tendon_sdre_gains"]


@dataclass
class SdreRun:
    """One SDRE (or frozen-gain) run: the tracked output (``tendon_force`` [N] or ``joint_angle`` [rad])
    and its reference, the controller gain row(s), the command torque [Nm] and the rig's torque limit."""

    label: str
    output_name: str
    unit: str
    t: np.ndarray
    output: np.ndarray
    reference: np.ndarray
    gain: np.ndarray
    torque: np.ndarray
    torque_limit: float | None = None

    @property
    def saturated(self) -> np.ndarray:
        """Samples where the command exceeds the torque limit (the rig's amplifier clips it)."""
        if self.torque_limit is None:
            return np.zeros(len(self.t), bool)
        return np.abs(self.torque) > self.torque_limit

    def plot(self, ax=None):
        """Output against its reference, and the command with the torque limit; returns ``(fig, axes)``."""
        fig, ax = figure_axes(ax, nrows=2, ncols=1, figsize=(7, 5.5), sharex=True)
        plot_traces(self.t, {f"{self.output_name} ({self.label})": self.output}, reference=self.reference,
                    ylabel=f"{self.output_name} [{self.unit}]", ax=ax[0], legend=dict(fontsize=8))
        plot_traces(self.t, {f"commanded torque ({self.label})": self.torque}, ylabel="motor torque [Nm]", ax=ax[1],
                    legend=None)
        if self.torque_limit is not None:
            for s in (1, -1):
                ax[1].axhline(s * self.torque_limit, color="r", ls=":", lw=0.8,
                              label=f"torque limit +-{self.torque_limit:g} Nm" if s > 0 else None)
        ax[1].legend(fontsize=8)
        return fig, ax


def tendon_sdre_experiment(fixed: bool, *, schedule: Sequence[tuple[float, float]] = ((0.05, 40.0), (0.5, 45.0)),
                           t_final: float = 1.0, params: SdreTendonParams | None = None,
                           fmap: ForceMap | None = None) -> SdreRun:
    """Fig 14.3: 0 -> 40 -> 45 N with SDRE gains (200 Hz) or gains frozen at 30 N.

    ``torque`` is the command; ``saturated`` flags samples beyond the rig's ``torque_limit`` (3 Nm): with the
    Table 14.1 weights (position gain ~ sqrt(Q11 / R) = 1000 Nm/rad) both controllers saturate during most of
    the 0 -> 40 N transient.
    """
    fmap = fmap or force_map(tendon_rig())
    rig = tendon_rig()
    loop = closed_loop(rig, tendon_sdre_controller(rig, params, fixed=fixed, fmap=fmap), rate_hz=RATE)
    op = rig.operating_point(tendon_force=0.0)
    ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque, references={"tendon_force_reference": 0.0})
    ref = Samples([0.0, *(t for t, _ in schedule)], [0.0, *(r for _, r in schedule)])   # piecewise constant
    log = simulate(loop, ctx, t_final, inputs={"tendon_force_reference": ref},
                   log=("tendon_force", f"controller_{SDRE_GAIN}", "motor_torque", "tendon_force_reference"),
                   log_period=1 / RATE)
    u = log["motor_torque"][:, 0]
    limit = rig.params.motor.torque_limit  # the rig's amplifier saturates the command (Table 14.1 gains exceed it)
    return SdreRun("fixed gains" if fixed else "SDRE", "tendon_force", "N", log.t, log["tendon_force"][:, 0],
                   log["tendon_force_reference"][:, 0], log[f"controller_{SDRE_GAIN}"], u, limit)


def joint_sdre_experiment(fixed: bool, *, target: float = 1.0, external_torque: float = 0.0,
                          t_final: float = 1.5, params: SdreJointParams | None = None) -> SdreRun:
    """Fig 14.4-14.5: nonlinear flexible joint (Table 14.2 link inertia), link step, optional external load.

    The load is applied from t = 0 while the reference steps at 0.1 s.
    """
    p = params or SdreJointParams()
    rig = flexible_joint_rig(params=FlexibleJointParams(link_inertia=p.link_inertia), spring="nonlinear")
    loop = closed_loop(rig, joint_sdre_controller(rig, p, fixed=fixed), rate_hz=RATE)
    op = rig.operating_point(external_torque=external_torque)
    ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque,
                              references={"joint_angle_reference": 0.0},
                              disturbances={"external_torque": external_torque})
    log = simulate(loop, ctx, t_final, inputs={"joint_angle_reference": Step(0.1, target),
                                               "external_torque": external_torque},
                   log=("joint_angle", "controller_gain", "motor_torque", "joint_angle_reference"), log_period=1 / RATE)
    return SdreRun(("fixed gains" if fixed else "SDRE") + f", load {external_torque:g} Nm", "joint_angle", "rad",
                   log.t, log["joint_angle"][:, 0], log["joint_angle_reference"][:, 0], log["controller_gain"],
                   log["motor_torque"][:, 0], rig.torque_limit)


def hand_tendon_sdre_gains(forces: Sequence[float] = (2.0, 5.0, 20.0, 40.0, 80.0, 150.0), *, finger: str = "index",
                           chain=None) -> dict:
    """Section 14.4's finding on the hand: the chain's tendon SDRE gains (``tendon_law="sdre"``,
    :class:`~awiwi_drake.control.sdre.TendonSdreLaw`) of one tendon of ``finger`` (its spring law and motor) at the
    measured ``forces`` [N]: ``{"force", "alpha" [N/rad], "k_theta" [Nm/rad], "k_omega" [Nm s/rad]}``.  The thesis:
    "for the tendon control problem, the method only marginally contributes ... because the optimal gains do not
    change significantly"."""
    from awiwi_drake.components.spring import tendon_spring
    from awiwi_drake.parameters.hand import FingerRigParams
    from awiwi_drake.parameters.hand_control import HandChainParams
    from awiwi_drake.control.sdre import TendonSdreLaw
    c = chain or HandChainParams()
    p = FingerRigParams.for_finger(finger)
    fmap = ForceMap.from_spring(tendon_spring(p.spring), p.motor.pulley_radius)
    f = np.asarray(forces, dtype=float)
    law = TendonSdreLaw([fmap] * f.size, p.motor, q_diag=c.tendon_sdre_weights(p.motor.inertia), r=c.sdre_input_weight, design_forces=f,
                        update_period=1.0 / c.sdre_update_rate)
    k = law.initial_gain
    return {"force": f, "alpha": law.slopes(f), "k_theta": k[:f.size], "k_omega": k[f.size:]}
