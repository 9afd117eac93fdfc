"""Thesis ch. 10: tendon force control experiments (Fig 10.1-10.3) as functions returning data.

The controllers are :mod:`awiwi_drake.control.tendon_force`; :meth:`TendonSteps.plot` draws Fig 10.3.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from awiwi_drake.control.base import closed_loop
from awiwi_drake.analysis import Step, simulate
from awiwi_drake.control.compare import fit_second_order_step, step_metrics
from awiwi_drake.control.sensors import force_sensor
from awiwi_drake.control.tendon_force import (ForceMap, force_map, steady_state_force_without_feedforward,
                                              tendon_pd_controller, tendon_scheduled_controller)
from awiwi_drake.parameters import MotorParams, TendonRigParams
from awiwi_drake.parameters.control import CONTROL_RATE_HZ as RATE, ForceSensorParams, TendonForceGains
from awiwi_drake.plotting import figure_axes, label_axes, plot_traces
from awiwi_drake.rigs import tendon_rig

__all__ = ["FeedforwardRun", "TendonSteps", "tendon_feedforward_experiment", "tendon_step_experiment"]

def _tendon_step(factory, f0, f1, t_step, t_final, log, *, realistic: bool, gains=None, fmap=None):
    """A fresh tendon rig under ``factory``'s controller at 3 kHz (``realistic``: ripple, the force sensor,
    333 us delay) at rest at ``f0`` [N], its reference stepping to ``f1`` at ``t_step``: ``(rig, loop, log)``."""
    rig = tendon_rig(params=TendonRigParams(motor=MotorParams(ripple=realistic)))
    ctrl = factory(rig, gains, fmap=fmap) if gains is not None or fmap is not None else factory(rig)
    sensors = {"tendon_force": force_sensor(ForceSensorParams())} if realistic else None
    loop = closed_loop(rig, ctrl, rate_hz=RATE, delay=333e-6 if realistic else None, sensors=sensors)
    op = rig.operating_point(tendon_force=f0)
    ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque, references={"tendon_force_reference": f0})
    return rig, loop, simulate(loop, ctx, t_final, inputs={"tendon_force_reference": Step(t_step, f1, f0)}, log=log,
                               log_period=1 / RATE)


@dataclass
class FeedforwardRun:
    """Fig 10.1: the same force step with and without the feed-forward terms of (10.2).

    ``with_feedforward`` / ``without_feedforward`` [N] over ``t`` [s], the ``reference`` [N] and
    ``expected_without`` [N], (10.3) at rest.
    """

    t: np.ndarray
    with_feedforward: np.ndarray
    without_feedforward: np.ndarray
    reference: np.ndarray
    expected_without: float

    def plot(self, ax=None):
        """Both force traces, the reference and (10.3); returns ``(fig, ax)``."""
        fig, ax = plot_traces(self.t, {"with feed-forward (10.2)": self.with_feedforward,
                                       "without feed-forward": self.without_feedforward},
                              reference=self.reference, ylabel="tendon force [N]", ax=ax)
        ax.axhline(self.expected_without, color="gray", ls=":", lw=1, label="(10.3): steady state without")
        label_axes(ax, "tendon force [N]", title="Fig 10.1", legend=dict(fontsize=8))
        return fig, ax


def tendon_feedforward_experiment(f0: float = 60.0, f1: float = 70.0, t_final: float = 1.0,
                                  fmap: ForceMap | None = None) -> FeedforwardRun:
    """Fig 10.1: force step ``f0 -> f1`` [N] at 0.05 s with and without the feed-forward terms of (10.2)
    (ideal sensor, no ripple)."""
    fmap = fmap or force_map(tendon_rig())
    out = {}
    for label, g in (("with", TendonForceGains()),
                     ("without", TendonForceGains(force_feedforward=False, friction_compensation=False))):
        rig, loop, log = _tendon_step(tendon_pd_controller, f0, f1, 0.05, t_final,
                                      ("tendon_force", "tendon_force_reference"), realistic=False, gains=g, fmap=fmap)
        out[label] = log
        if label == "without":
            kp = loop.controller.law.kp_fixed
            expected = steady_state_force_without_feedforward(f1, kp, rig.params.motor.pulley_radius)
    return FeedforwardRun(out["with"].t, out["with"]["tendon_force"][:, 0], out["without"]["tendon_force"][:, 0],
                          out["with"]["tendon_force_reference"][:, 0], float(expected))


@dataclass
class TendonSteps:
    """Force steps ``f0 -> f0 + step`` for one controller: traces and per-step metrics."""

    controller: str
    t: np.ndarray
    t_step: float
    step: float = 5.0
    forces: dict = field(default_factory=dict)     # f0 -> force trace [N]
    commands: dict = field(default_factory=dict)   # f0 -> command trace [Nm]
    metrics: dict = field(default_factory=dict)    # f0 -> dict(overshoot, settling_time, damping_ratio, ...)

    def plot(self, ax=None):
        """Fig 10.3: the force steps from each initial force, labelled with their damping ratio and overshoot, and
        the references dashed; ``(fig, ax)``."""
        fig, ax = figure_axes(ax, figsize=(7, 4))
        for f0, f in self.forces.items():
            m = self.metrics[f0]
            ax.plot(self.t, f, label=f"{f0:g} N: xi = {m['damping_ratio']:.2f}, OS = {m['overshoot']:.0f} %")
            ax.plot(self.t, np.where(self.t < self.t_step, f0, f0 + self.step), "k--", lw=0.8)
        label_axes(ax, "tendon force [N]", title=f"{self.controller} gains", legend=dict(fontsize=8))
        return fig, ax


def tendon_step_experiment(scheduled: bool, *, initial_forces: Sequence[float] = (10.0, 20.0, 30.0, 40.0),
                           step: float = 5.0, t_final: float = 0.25, realistic: bool = True,
                           gains: TendonForceGains | None = None, fmap: ForceMap | None = None) -> TendonSteps:
    """Fig 10.2-10.3: steps of ``step`` N from each initial force, fixed (30 N) or scheduled gains.

    ``realistic``: friction (3.8), ripple, 12-bit quantised noisy force sensor, 333 us delay.
    """
    fmap = fmap or force_map(tendon_rig())
    factory = tendon_scheduled_controller if scheduled else tendon_pd_controller
    t_step = 0.02
    res = TendonSteps("scheduled" if scheduled else "fixed", np.array([]), t_step, step)
    for f0 in initial_forces:
        _, _, log = _tendon_step(factory, f0, f0 + step, t_step, t_final, ("tendon_force", "motor_torque_command"),
                                 realistic=realistic, gains=gains or TendonForceGains(), fmap=fmap)
        f = log["tendon_force"][:, 0]
        m = step_metrics(log.t, f, f0, f0 + step, t_step, band=0.05)
        m.update({k: v for k, v in fit_second_order_step(log.t, f, f0, f0 + step, t_step).items()
                  if k in ("damping_ratio", "natural_frequency")})
        res.t = log.t
        res.forces[f0] = f
        res.commands[f0] = log["motor_torque_command"][:, 0]
        res.metrics[f0] = m
    return res
