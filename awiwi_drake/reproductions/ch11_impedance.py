"""Thesis ch. 11: two-time-scale and cascaded impedance control (Fig 11.2-11.4).

The controllers are :mod:`awiwi_drake.control.impedance`; :meth:`GainDiagram.plot` draws Fig 11.4 (and 15.26).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from typing import Sequence

import numpy as np

from awiwi_drake.control.base import closed_loop
from awiwi_drake.analysis import Chirp, Step, linearize, simulate
from awiwi_drake.control.compare import gain_diagram, step_metrics
from awiwi_drake.control.impedance import impedance_controller
from awiwi_drake.parameters import FlexibleJointParams, JointRigParams
from awiwi_drake.parameters.control import CONTROL_RATE_HZ as RATE, ImpedanceParams, ImpedanceSweepParams
from awiwi_drake.plotting import figure_axes, label_axes, plot_traces
from awiwi_drake.rigs import flexible_joint_rig, joint_rig

__all__ = ["ImpedanceStep", "GainDiagram", "impedance_step", "impedance_sweep", "impedance_frequency_response"]


@dataclass
class ImpedanceStep:
    """Fig 11.2-11.3: a joint step under impedance control: ``t`` [s], ``joint_angle`` and ``reference``
    [rad], and the step metrics of :func:`~awiwi_drake.control.compare.step_metrics` (``overshoot`` [%],
    ``rise_time``, ``settling_time`` [s], ...)."""

    label: str
    t: np.ndarray
    joint_angle: np.ndarray
    reference: np.ndarray
    metrics: dict

    @property
    def overshoot(self) -> float:
        """Overshoot [% of the step]."""
        return float(self.metrics["overshoot"])

    def plot(self, ax=None):
        return plot_traces(self.t, {f"{self.label}: overshoot {self.overshoot:.1f} %": self.joint_angle},
                           reference=self.reference, ylabel="joint angle [rad]", ax=ax, legend=dict(fontsize=8))


@dataclass
class GainDiagram:
    """Fig 11.4 / 15.26: gain ``|q / q_des|`` [-] over ``freq`` [Hz] of a loop (``label``): a simulated chirp, or
    the continuous loop linearised by Drake's ``Linearize`` (its ``linearization``, a
    :class:`~awiwi_drake.analysis.LinearizationResult`, and ``eigenvalues`` [1/s]), with its -3 dB ``bandwidth``
    below the DC gain [Hz] where computed (:func:`~awiwi_drake.control.compare.metrics.linear_bandwidth`) and the
    ``loop`` itself (to simulate)."""

    label: str
    freq: np.ndarray
    gain: np.ndarray
    eigenvalues: np.ndarray | None = None
    bandwidth: float = float("nan")
    linearization: object = None
    loop: object = field(repr=False, default=None)

    @property
    def resonance_hz(self) -> float:
        return float(self.freq[int(np.argmax(self.gain))])

    @property
    def peak_gain(self) -> float:
        return float(np.max(self.gain))

    @property
    def dc_gain(self) -> float:
        """|H(0)| = |D - C A^-1 B| of the linearisation [-]."""
        lin = self.linearization
        return float(abs((lin.D - lin.C @ np.linalg.solve(lin.A, lin.B))[0, 0]))

    def plot(self, ax=None, *, label: str | None = None, xscale: str = "linear"):
        """|q / q_des| against frequency, labelled ``label`` (default :attr:`label`) and, where computed, its -3 dB
        bandwidth marked (dotted); several diagrams drawn on one ``ax`` share it.  ``(fig, ax)``."""
        fig, ax = figure_axes(ax, figsize=(7, 4))
        text = self.label if label is None else label
        marked = np.isfinite(self.bandwidth)
        line, = ax.plot(self.freq, self.gain, label=f"{text} (-3 dB at {self.bandwidth:.2f} Hz)" if marked else text)
        if marked:
            ax.axvline(self.bandwidth, color=line.get_color(), ls=":", lw=1)
        ax.set_xscale(xscale)
        label_axes(ax, "gain |q / q_des|", xlabel="frequency [Hz]")
        return fig, ax


def _joint(kind: str, *, stiffness=None, pretension=None):
    """The flexible joint (mechanical ``stiffness``) or the joint rig (``pretension``); None: the defaults."""
    if kind == "flexible-joint":
        p = FlexibleJointParams() if stiffness is None else FlexibleJointParams(stiffness=stiffness)
        return flexible_joint_rig(params=p)
    return joint_rig(params=JointRigParams() if pretension is None else JointRigParams(pretension=pretension))


def _run(mode, joint_stiffness, rig, stiffness, pretension, t_final, reference):
    """The impedance loop at 3 kHz from rest under the link ``reference`` schedule; the run's log."""
    r = _joint(rig, stiffness=stiffness, pretension=pretension)
    loop = closed_loop(r, impedance_controller(r, ImpedanceParams(joint_stiffness=joint_stiffness), mode=mode),
                       rate_hz=RATE)
    op = r.operating_point()
    ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque, references={"joint_angle_reference": 0.0})
    return simulate(loop, ctx, t_final, inputs={"joint_angle_reference": reference, "external_torque": 0.0},
                    log=("joint_angle", "joint_angle_reference"), log_period=1 / RATE)


def impedance_step(mode: str = "two-time-scale", *, joint_stiffness: float = 0.3, rig: str = "flexible-joint",
                   stiffness: float | None = None, pretension: float | None = None, step: float = 0.3,
                   t_final: float = 0.3) -> ImpedanceStep:
    """Fig 11.2-11.3: link step under impedance control (``stiffness``: mechanical k of the flexible joint)."""
    log = _run(mode, joint_stiffness, rig, stiffness, pretension, t_final, Step(0.02, step))
    m = step_metrics(log.t, log["joint_angle"][:, 0], 0.0, step, 0.02)
    return ImpedanceStep(f"{mode}, Kp_imp = {joint_stiffness:g} Nm/rad", log.t, log["joint_angle"][:, 0],
                         log["joint_angle_reference"][:, 0], m)


def impedance_sweep(mode: str = "two-time-scale", *, joint_stiffness: float | None = None, rig: str = "joint-rig",
                    stiffness: float | None = None, pretension: float | None = None, f_start: float | None = None,
                    f_stop: float | None = None, duration: float | None = None,
                    amplitude: float | None = None) -> GainDiagram:
    """Fig 11.4: chirp of the link reference (3 kHz loop), gain diagram |q / q_des|(f).

    Defaults (:class:`ImpedanceSweepParams`): the two-time-scale (singular perturbation) impedance of
    Fig 11.4 on the antagonistic joint rig, Kp_imp = 4 Nm/rad, chirp 5-60 Hz over 3 s, 0.02 rad.
    """
    given = dict(joint_stiffness=joint_stiffness, f_start=f_start, f_stop=f_stop, duration=duration, amplitude=amplitude)
    sp = ImpedanceSweepParams().replace(**{k: v for k, v in given.items() if v is not None})
    log = _run(mode, sp.joint_stiffness, rig, stiffness, pretension, sp.duration,
               Chirp(sp.amplitude, sp.f_start, sp.f_stop, sp.duration))
    f, g = gain_diagram(log.t, log["joint_angle_reference"][:, 0], log["joint_angle"][:, 0], sp.f_start, sp.f_stop)
    return GainDiagram(f"{mode}, simulated chirp", f, g)


def impedance_frequency_response(mode: str = "two-time-scale", *, joint_stiffness: float | None = None,
                                 rig: str = "joint-rig", stiffness: float | None = None,
                                 pretension: float | None = None, freqs: Sequence[float] | None = None) -> GainDiagram:
    """|q / q_des|(f) of the *continuous* impedance loop linearised by Drake's ``Linearize``.

    The exact small-signal counterpart of :func:`impedance_sweep` (no 3 kHz hold); also returns the
    closed-loop eigenvalues.  Default frequencies: 0.5-70 Hz (Fig 11.4).
    """
    sp = ImpedanceSweepParams()
    joint_stiffness = sp.joint_stiffness if joint_stiffness is None else joint_stiffness
    freqs = np.linspace(0.5, 70.0, 700) if freqs is None else np.asarray(freqs, float)
    r = _joint(rig, stiffness=stiffness, pretension=pretension)
    loop = closed_loop(r, impedance_controller(r, ImpedanceParams(joint_stiffness=joint_stiffness), mode=mode),
                       rate_hz=None)
    op = r.operating_point()
    ctx = loop.create_context(state=op.state, references={"joint_angle_reference": 0.0})
    lin = linearize(loop.diagram, context=ctx, input="joint_angle_reference", outputs=("joint_angle",))
    g = np.abs(lin.bode(omega=2 * np.pi * freqs).response)
    return GainDiagram(f"{mode}, linearised", freqs, g, lin.poles)
