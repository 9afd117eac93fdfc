"""Motor-position PD with tendon-force feed-forward, and the joint-rig demo loop built with it.

The law, per motor (output shaft)::

    u = r_m f_ref + kp (theta_ref - theta) - kd omega

Port contract: inputs ``motor_angle_reference`` (m) [rad],
``tendon_force_reference`` (m) [N] (the feed-forward ``r_m f_ref`` holds the
spring force), ``motor_angle`` (m), ``motor_velocity`` (m); output
``motor_torque`` (m) [N m].  It is Drake C++ primitives (a ``Multiplexer`` and a
stateless ``AffineSystem``), so it is linear and scalar-convertible.

:func:`joint_rig_position_loop` is the package's main demo (``awiwi-drake
demo``): the joint rig, the pretension ramping from ``f_start`` to ``f_end``
with the link at rest, then a link step; the references come from
:func:`motor_references` (the rig's own spring law: ``x_i = f^-1(f_pre)``, ``theta_i* = (x_i +- r_q q*) / r_m``) as
``TrajectorySource`` s wired into the :class:`~awiwi_drake.control.base.ClosedLoop`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import AffineSystem, Multiplexer, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from awiwi_drake.control.base import ClosedLoop, closed_loop
from awiwi_drake.parameters.rigs import DemoScenario, MotorPositionGains

__all__ = ["motor_position_controller", "motor_references", "demo_references", "joint_rig_position_loop"]


def motor_position_controller(rig: Any, gains: MotorPositionGains | None = None, *,
                              pulley_radius: float | None = None):
    """The motor-position PD of the module docstring for a rig with ``m`` motors (motor pulley radius
    ``pulley_radius`` [m], default the rig's ``params.motor.pulley_radius``)."""
    g = gains or MotorPositionGains()
    if not isinstance(g, MotorPositionGains):
        raise ValueError(f"motor_position_controller: gains must be MotorPositionGains, got {type(g).__name__}")
    m = rig.diagram.GetInputPort("motor_torque").size()
    r_m = rig.params.motor.pulley_radius if pulley_radius is None else float(pulley_radius)
    names = ("motor_angle_reference", "tendon_force_reference", "motor_angle", "motor_velocity")
    I = np.eye(m)
    D = np.hstack([g.kp * I, r_m * I, -g.kp * I, -g.kd * I])
    b = DiagramBuilder()
    mux = b.AddNamedSystem("motor_position_inputs", Multiplexer([m] * 4))
    law = b.AddNamedSystem("motor_position_law", AffineSystem(
        A=np.zeros((0, 0)), B=np.zeros((0, 4 * m)), f0=np.zeros(0), C=np.zeros((m, 0)), D=D, y0=np.zeros(m)))
    b.Connect(mux.get_output_port(0), law.get_input_port(0))
    for i, nm in enumerate(names):
        b.ExportInput(mux.get_input_port(i), nm)
    b.ExportOutput(law.get_output_port(0), "motor_torque")
    d = b.Build()
    d.set_name("motor_position_pd")
    return d


def motor_references(rig: Any, t: np.ndarray, pretension: np.ndarray, joint_angle: np.ndarray):
    """Motor-angle set points and feedforward torques realising pretension and link angle.

    Returns ``(theta_ref (2, T), torque_ff (2, T))`` for the joint rig.
    """
    p = rig.params
    r, rq = p.motor.pulley_radius, p.link_pulley_radius
    x = np.asarray(rig.spring.inverse_force(np.asarray(pretension, dtype=float)), dtype=float)
    theta = np.stack([(x + rq * joint_angle) / r, (x - rq * joint_angle) / r])
    ff = np.stack([r * np.asarray(pretension), r * np.asarray(pretension)])
    return theta, ff


def demo_references(rig: Any, scenario: DemoScenario | None = None) -> tuple[np.ndarray, dict]:
    """Knot times and references of the demo: ``pretension``, ``link_reference``, ``theta_reference``, ``tendon_force_reference``."""
    s = scenario or DemoScenario()
    grid = np.linspace(0.0, s.t_final, 601)
    grid = grid[np.abs(grid - s.step_time) > 1e-6]
    t = np.union1d(grid, [s.step_time - 1e-7, s.step_time])  # knots on both sides: a sharp step
    pre = np.interp(t, [0.0, s.ramp_time, s.t_final], [s.f_start, s.f_end, s.f_end])
    q_ref = np.where(t >= s.step_time, s.link_step, 0.0)
    theta_ref, _ = motor_references(rig, t, pre, q_ref)
    return t, dict(pretension=pre, link_reference=q_ref, theta_reference=theta_ref,
                   tendon_force_reference=np.stack([pre, pre]))


def joint_rig_position_loop(rig: Any, scenario: DemoScenario | None = None,
                            gains: MotorPositionGains | None = None, *, sampled_rig: bool = True) -> ClosedLoop:
    """The demo: ``rig`` (a joint rig) under :func:`motor_position_controller` at ``gains.rate_hz``.

    ``sampled_rig``: as in :func:`~awiwi_drake.control.base.closed_loop` (True: the rig sampled at the
    control period; False: the continuous rig behind a hold, e.g. for an error-controlled reference).
    The references of :func:`demo_references` are wired in as sources; the
    loop's remaining input is ``external_torque``.  Start it with
    ``loop.create_context(rig.operating_point(pretension=scenario.f_start))``.
    """
    if getattr(rig, "name", None) != "joint-rig":
        raise ValueError(f"joint_rig_position_loop: needs a joint_rig, got {getattr(rig, 'name', rig)!r}")
    g = gains or MotorPositionGains()
    t, refs = demo_references(rig, scenario)
    sources = {
        "motor_angle_reference": TrajectorySource(PiecewisePolynomial.FirstOrderHold(t, refs["theta_reference"])),
        "tendon_force_reference": TrajectorySource(
            PiecewisePolynomial.FirstOrderHold(t, refs["tendon_force_reference"])),
    }
    return closed_loop(rig, motor_position_controller(rig, g), rate_hz=g.rate_hz, sources=sources,
                       name="joint_rig_position_loop", sampled_rig=sampled_rig)
