"""Motor-position PD with tendon-force feed-forward, and the joint-rig demo loop built with it.

The law, per motor (output shaft)::

    u = r_m f_ref + kp (theta_ref - theta) - kd omega

Port contract: inputs ``motor_angle_reference`` (m) [rad] and ``tendon_force_reference`` (m) [N] (the
feed-forward ``r_m f_ref`` holds the spring force), the measurement, and output ``motor_torque`` (m) [N m].
The measurement is the rig's ``state`` (its ``motor_angle[i]``/``motor_velocity[i]`` entries, by
``rig.state_names``) on a rig that reports its full state (the single-joint rigs), else ``motor_angle`` (m) and
``motor_velocity`` (m) (fingers and the hand, whose state holds joint angles they do not measure; rigs without
``state_names``). Given the reference up front (``reference=``: knots, linear between them), the references are
part of the law instead of inputs: ``u = y0(t) + D x`` with ``y0 = kp theta_ref(t) + r_m f_ref(t)``, one Drake
C++ ``TrajectoryAffineSystem`` (no reference ports, no source systems; measured: the demo loop's control period
costs ~13 % less than with two ``TrajectorySource`` s, a ``Multiplexer`` and an ``AffineSystem``, benchmarks/bench_rigs.py
``joint_rig_breakdown``). Either way it is C++ primitives, linear and scalar-convertible (float, AutoDiffXd).

:func:`joint_rig_position_loop` is the package's main demo (``awiwi-drake
demo``): the joint rig, the pretension ramping from ``f_start`` to ``f_end``
with the link at rest, then a link step; the references come from
:func:`motor_references` (the rig's own spring law: ``x_i = f^-1(f_pre)``, ``theta_i* = (x_i +- r_q q*) / r_m``)
and enter the law as its trajectory (``reference=``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import AffineSystem, Multiplexer, TrajectoryAffineSystem
from pydrake.trajectories import PiecewisePolynomial

from awiwi_drake.control.base import ClosedLoop, closed_loop
from awiwi_drake.parameters.rigs import DemoScenario, MotorPositionGains

__all__ = ["motor_position_controller", "motor_references", "demo_references", "joint_rig_position_loop"]


def _state_indices(rig: Any, m: int):
    """``(angle, velocity)`` indices of the motors in the rig's ``state`` output, or None when the controller
    must read ``motor_angle``/``motor_velocity`` (no full-state measurement, see the module docstring)."""
    from awiwi_drake.rigs.base import Rig
    if not isinstance(rig, Rig) or not rig.joint_sensors or not rig.diagram.HasOutputPort("state") \
            or rig.diagram.GetOutputPort("state").size() != len(rig.state_names):
        return None
    names = rig.state_names
    angle = [k for k, nm in enumerate(names) if nm.startswith("motor_angle[")]
    velocity = [k for k, nm in enumerate(names) if nm.startswith("motor_velocity[")]
    return (angle, velocity) if len(angle) == len(velocity) == m else None


def _check_reference(reference, m: int):
    """``reference = (t, motor_angle, tendon_force)`` as float arrays ``(T,), (m, T), (m, T)``."""
    if not (isinstance(reference, (tuple, list)) and len(reference) == 3):
        raise ValueError("motor_position_controller: reference must be (t, motor_angle, tendon_force), "
                         f"got {type(reference).__name__}")
    t = np.asarray(reference[0], dtype=float).reshape(-1)
    if t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0.0):
        raise ValueError("motor_position_controller: reference t must be >= 2 finite, strictly increasing times [s]")
    out = [t]
    for name, v in (("motor_angle", reference[1]), ("tendon_force", reference[2])):
        a = np.asarray(v, dtype=float)
        if a.shape != (m, t.size):
            raise ValueError(f"motor_position_controller: reference {name} has shape {a.shape}, expected "
                             f"({m}, {t.size}) (one row per motor, one column per time)")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"motor_position_controller: reference {name} must be finite")
        out.append(a)
    return out


def motor_position_controller(rig: Any, gains: MotorPositionGains | None = None, *,
                              pulley_radius: float | None = None, reference=None):
    """The motor-position PD of the module docstring for a rig with ``m`` motors (motor pulley radius
    ``pulley_radius`` [m], default the rig's ``params.motor.pulley_radius``).

    ``reference``: None (the references are the input ports ``motor_angle_reference``,
    ``tendon_force_reference``), or ``(t, motor_angle, tendon_force)``: knot times [s] ``(T,)``, motor-angle
    references [rad] and tendon-force references [N] ``(m, T)`` each, linear between knots and held beyond
    them (as a ``TrajectorySource`` of ``PiecewisePolynomial.FirstOrderHold`` gives them); the law then has
    no reference ports (module docstring)."""
    g = gains or MotorPositionGains()
    if not isinstance(g, MotorPositionGains):
        raise ValueError(f"motor_position_controller: gains must be MotorPositionGains, got {type(g).__name__}")
    m = rig.diagram.GetInputPort("motor_torque").size()
    r_m = rig.params.motor.pulley_radius if pulley_radius is None else float(pulley_radius)
    I = np.eye(m)
    idx = _state_indices(rig, m)
    if idx is None:     # measurements motor_angle, motor_velocity
        measured = (("motor_angle", m), ("motor_velocity", m))
        Dx = np.hstack([-g.kp * I, -g.kd * I])
    else:               # the rig's state: zero gain on everything but the motors
        measured = (("state", len(rig.state_names)),)
        Dx = np.zeros((m, len(rig.state_names)))
        Dx[:, idx[0]], Dx[:, idx[1]] = -g.kp * I, -g.kd * I
    b = DiagramBuilder()
    if reference is None:
        inputs = (("motor_angle_reference", m), ("tendon_force_reference", m)) + measured
        D = np.hstack([g.kp * I, r_m * I, Dx])
        law = b.AddNamedSystem("motor_position_law", AffineSystem(
            A=np.zeros((0, 0)), B=np.zeros((0, D.shape[1])), f0=np.zeros(0), C=np.zeros((m, 0)), D=D,
            y0=np.zeros(m)))
    else:
        t, theta, force = _check_reference(reference, m)
        inputs, D = measured, Dx

        def const(M):
            return PiecewisePolynomial(np.asarray(M, dtype=float))
        law = b.AddNamedSystem("motor_position_law", TrajectoryAffineSystem(
            const(np.zeros((0, 0))), const(np.zeros((0, D.shape[1]))), const(np.zeros((0, 1))),
            const(np.zeros((m, 0))), const(D), PiecewisePolynomial.FirstOrderHold(t, g.kp * theta + r_m * force)))
    if len(inputs) == 1:
        b.ExportInput(law.get_input_port(0), inputs[0][0])
    else:
        mux = b.AddNamedSystem("motor_position_inputs", Multiplexer([size for _, size in inputs]))
        b.Connect(mux.get_output_port(0), law.get_input_port(0))
        for i, (nm, _) in enumerate(inputs):
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
    The references of :func:`demo_references` are the law's trajectory (``reference=`` of
    :func:`motor_position_controller`); the loop's remaining input is ``external_torque``.  Start it with
    ``loop.create_context(rig.operating_point(pretension=scenario.f_start))``.
    """
    if getattr(rig, "name", None) != "joint-rig":
        raise ValueError(f"joint_rig_position_loop: needs a joint_rig, got {getattr(rig, 'name', rig)!r}")
    g = gains or MotorPositionGains()
    t, refs = demo_references(rig, scenario)
    ctrl = motor_position_controller(rig, g, reference=(t, refs["theta_reference"], refs["tendon_force_reference"]))
    return closed_loop(rig, ctrl, rate_hz=g.rate_hz, name="joint_rig_position_loop", sampled_rig=sampled_rig)
