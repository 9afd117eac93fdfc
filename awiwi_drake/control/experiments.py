"""The thesis experiments of ch. 10-14 as functions returning data (used by notebooks and docs).

Every function builds rigs and controllers with the package's builders, runs
Drake's simulator through :func:`awiwi_drake.control.compare.simulate_loop`
and returns arrays/dataclasses; :mod:`awiwi_drake.control.plots` draws them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from awiwi_drake.analysis import simulate
from awiwi_drake.control.base import closed_loop
from awiwi_drake.control.compare import fit_second_order_step, simulate_loop, step_metrics
from awiwi_drake.control.impedance import impedance_controller
from awiwi_drake.control.lqr import design_lqr, lqr_controller
from awiwi_drake.control.sdre import joint_sdre_controller, tendon_sdre_controller
from awiwi_drake.control.sensors import force_sensor
from awiwi_drake.control.tendon_force import (ForceMap, force_map, steady_state_force_without_feedforward,
                                              tendon_pd_controller, tendon_scheduled_controller)
from awiwi_drake.parameters import FlexibleJointParams, JointRigParams, MotorParams, TendonRigParams
from awiwi_drake.parameters.control import (ForceSensorParams, ImpedanceParams, ImpedanceSweepParams, LqrParams,
                                            SdreJointParams, SdreTendonParams, TendonForceGains)
from awiwi_drake.rigs import flexible_joint_rig, joint_rig, tendon_rig

__all__ = ["TendonSteps", "tendon_feedforward_experiment", "tendon_step_experiment", "tendon_sdre_experiment",
           "lqr_trajectories", "joint_sdre_experiment", "impedance_step", "impedance_sweep",
           "impedance_frequency_response"]

RATE = 3000.0
DT = 1.0 / RATE


def _tendon_loop(factory, *, realistic: bool, gains=None, fmap=None, **kw):
    rig = tendon_rig(params=TendonRigParams(motor=MotorParams(ripple=realistic)), backend="symbolic")
    ctrl = factory(rig, gains, fmap=fmap) if gains is not None or fmap is not None else factory(rig)
    sensors = {"tendon_force": force_sensor(ForceSensorParams())} if realistic else None
    return rig, closed_loop(rig, ctrl, rate_hz=RATE, delay=333e-6 if realistic else None, sensors=sensors, **kw)


def _reference_schedule(steps: Sequence[tuple[float, float]], initial: float):
    def ref(t):
        r = initial
        for t_k, r_k in steps:
            if t >= t_k:
                r = r_k
        return r
    return ref


def tendon_feedforward_experiment(f0: float = 60.0, f1: float = 70.0, t_final: float = 1.0,
                                  fmap: ForceMap | None = None) -> dict:
    """Fig 10.1: force step with and without the feed-forward terms of (10.2) (ideal sensor, no ripple).

    Returns ``{"t", "with", "without", "reference", "expected_without"}`` where
    ``expected_without`` is (10.3) at rest.
    """
    fmap = fmap or force_map(tendon_rig())
    out = {}
    for label, g in (("with", TendonForceGains()),
                     ("without", TendonForceGains(force_feedforward=False, friction_compensation=False))):
        rig, loop = _tendon_loop(tendon_pd_controller, realistic=False, gains=g, fmap=fmap)
        op = rig.operating_point(tendon_force=f0)
        ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque,
                                  references={"tendon_force_reference": f0})
        log = simulate_loop(loop, ctx, t_final, DT, outputs=("tendon_force",),
                            inputs={"tendon_force_reference": _reference_schedule([(0.05, f1)], f0)})
        out[label] = log["tendon_force"][:, 0]
        out["t"] = log["t"]
        out["reference"] = log["tendon_force_reference"][:, 0]
        if label == "without":
            kp = loop.controller.law.kp_fixed
            out["expected_without"] = steady_state_force_without_feedforward(f1, kp, rig.params.motor.pulley_radius)
    return out


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
        rig, loop = _tendon_loop(factory, realistic=realistic, gains=gains or TendonForceGains(), fmap=fmap)
        op = rig.operating_point(tendon_force=f0)
        ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque,
                                  references={"tendon_force_reference": f0})
        log = simulate_loop(loop, ctx, t_final, DT, outputs=("tendon_force", "motor_torque_command"),
                            inputs={"tendon_force_reference": _reference_schedule([(t_step, f0 + step)], f0)})
        f = log["tendon_force"][:, 0]
        m = step_metrics(log["t"], f, f0, f0 + step, t_step, band=0.05)
        m.update({k: v for k, v in fit_second_order_step(log["t"], f, f0, f0 + step, t_step).items()
                  if k in ("damping_ratio", "natural_frequency")})
        res.t = log["t"]
        res.forces[f0] = f
        res.commands[f0] = log["motor_torque_command"][:, 0]
        res.metrics[f0] = m
    return res


def tendon_sdre_experiment(fixed: bool, *, schedule: Sequence[tuple[float, float]] = ((0.05, 40.0), (0.5, 45.0)),
                           t_final: float = 1.0, params: SdreTendonParams | None = None,
                           fmap: ForceMap | None = None) -> dict:
    """Fig 14.3: 0 -> 40 -> 45 N with SDRE gains (200 Hz) or gains frozen at 30 N.

    ``torque`` is the command; ``saturated`` flags samples beyond the rig's ``torque_limit`` (3 Nm): with the
    Table 14.1 weights (position gain ~ sqrt(Q11 / R) = 1000 Nm/rad) both controllers saturate during most of
    the 0 -> 40 N transient.
    """
    fmap = fmap or force_map(tendon_rig())
    rig = tendon_rig(backend="symbolic")
    loop = closed_loop(rig, tendon_sdre_controller(rig, params, fixed=fixed, fmap=fmap), rate_hz=RATE)
    op = rig.operating_point(tendon_force=0.0)
    ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque, references={"tendon_force_reference": 0.0})
    log = simulate_loop(loop, ctx, t_final, DT, outputs=("tendon_force", "controller_gain", "motor_torque"),
                        inputs={"tendon_force_reference": _reference_schedule(schedule, 0.0)})
    u = log["motor_torque"][:, 0]
    limit = rig.params.motor.torque_limit  # the rig's amplifier saturates the command (Table 14.1 gains exceed it)
    return dict(t=log["t"], force=log["tendon_force"][:, 0], reference=log["tendon_force_reference"][:, 0],
                gain=log["controller_gain"], torque=u, torque_limit=limit, saturated=np.abs(u) > limit)


def lqr_trajectories(r_values: Sequence[float] = (1e-4, 1e-2, 1.0), *, x0=(0.3, 0.0, 0.3, 0.0),
                     t_final: float = 0.2, params: LqrParams | None = None) -> dict:
    """Fig 13.2-13.3: regulation of the flexible joint (Table 13.1) from ``x0`` for each R (continuous loop)."""
    out = {}
    for r in r_values:
        rig = flexible_joint_rig(backend="python")
        design = design_lqr(rig, params, r=r)
        loop = closed_loop(rig, lqr_controller(rig, params, r=r), rate_hz=None)
        ctx = loop.create_context(state=np.asarray(x0, float), references={"link_angle_reference": 0.0})
        res = simulate(loop.diagram, ctx, t_final, log=("state", "motor_torque"), max_step=1e-4, accuracy=1e-7)
        out[r] = dict(t=res.t, state=res.signals["state"], u=res.signals["motor_torque"][:, 0], K=design.K,
                      S=design.S, Q=design.Q, R=design.R)
    return out


def joint_sdre_experiment(fixed: bool, *, target: float = 1.0, external_torque: float = 0.0,
                          t_final: float = 1.5, params: SdreJointParams | None = None) -> dict:
    """Fig 14.4-14.5: nonlinear flexible joint (Table 14.2 link inertia), link step, optional external load.

    The load is applied from t = 0 while the reference steps at 0.1 s.
    """
    p = params or SdreJointParams()
    rig = flexible_joint_rig(params=FlexibleJointParams(link_inertia=p.link_inertia), spring="nonlinear",
                             backend="symbolic")
    loop = closed_loop(rig, joint_sdre_controller(rig, p, fixed=fixed), rate_hz=RATE)
    op = rig.operating_point(external_torque=external_torque)
    ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque,
                              references={"link_angle_reference": 0.0},
                              disturbances={"external_torque": external_torque})
    log = simulate_loop(loop, ctx, t_final, DT, outputs=("link_angle", "controller_gain", "motor_torque"),
                        inputs={"link_angle_reference": _reference_schedule([(0.1, target)], 0.0),
                                "external_torque": lambda t: external_torque})
    return dict(t=log["t"], link_angle=log["link_angle"][:, 0], gain=log["controller_gain"],
                torque=log["motor_torque"][:, 0], reference=log["link_angle_reference"][:, 0])


def _joint(kind: str, *, stiffness=None, pretension=None):
    if kind == "flexible-joint":
        p = FlexibleJointParams() if stiffness is None else FlexibleJointParams(stiffness=stiffness)
        return flexible_joint_rig(params=p, backend="symbolic")
    return joint_rig(params=JointRigParams() if pretension is None else JointRigParams(pretension=pretension),
                     backend="symbolic")


def impedance_step(mode: str = "two-time-scale", *, joint_stiffness: float = 0.3, rig: str = "flexible-joint",
                   stiffness: float | None = None, pretension: float | None = None, step: float = 0.3,
                   t_final: float = 0.3) -> dict:
    """Fig 11.2-11.3: link step under impedance control (``stiffness``: mechanical k of the flexible joint)."""
    r = _joint(rig, stiffness=stiffness, pretension=pretension)
    loop = closed_loop(r, impedance_controller(r, ImpedanceParams(joint_stiffness=joint_stiffness), mode=mode),
                       rate_hz=RATE)
    op = r.operating_point()
    ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque, references={"link_angle_reference": 0.0})
    log = simulate_loop(loop, ctx, t_final, DT, outputs=("link_angle",),
                        inputs={"link_angle_reference": _reference_schedule([(0.02, step)], 0.0),
                                "external_torque": lambda t: 0.0})
    m = step_metrics(log["t"], log["link_angle"][:, 0], 0.0, step, 0.02)
    return dict(t=log["t"], link_angle=log["link_angle"][:, 0], reference=log["link_angle_reference"][:, 0], **m)


def impedance_sweep(mode: str = "two-time-scale", *, joint_stiffness: float | None = None, rig: str = "joint-rig",
                    stiffness: float | None = None, pretension: float | None = None, f_start: float | None = None,
                    f_stop: float | None = None, duration: float | None = None,
                    amplitude: float | None = None) -> dict:
    """Fig 11.4: chirp of the link reference (3 kHz loop), gain diagram |q / q_des|(f).

    Defaults (:class:`ImpedanceSweepParams`): the two-time-scale (singular perturbation) impedance of
    Fig 11.4 on the antagonistic joint rig, Kp_imp = 4 Nm/rad, chirp 5-60 Hz over 3 s, 0.02 rad.
    """
    from awiwi_drake.control.compare import gain_diagram
    sp = ImpedanceSweepParams()
    joint_stiffness = sp.joint_stiffness if joint_stiffness is None else joint_stiffness
    f_start = sp.f_start if f_start is None else f_start
    f_stop = sp.f_stop if f_stop is None else f_stop
    duration = sp.duration if duration is None else duration
    amplitude = sp.amplitude if amplitude is None else amplitude
    r = _joint(rig, stiffness=stiffness, pretension=pretension)
    loop = closed_loop(r, impedance_controller(r, ImpedanceParams(joint_stiffness=joint_stiffness), mode=mode),
                       rate_hz=RATE)
    op = r.operating_point()
    ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque, references={"link_angle_reference": 0.0})
    k = (f_stop - f_start) / duration
    log = simulate_loop(loop, ctx, duration, DT, outputs=("link_angle",),
                        inputs={"link_angle_reference": lambda t: amplitude * np.sin(2 * np.pi * (f_start * t + 0.5 * k * t * t)),
                                "external_torque": lambda t: 0.0})
    f, g = gain_diagram(log["t"], log["link_angle_reference"][:, 0], log["link_angle"][:, 0], f_start, f_stop)
    i = int(np.argmax(g))
    return dict(freq=f, gain=g, resonance_hz=float(f[i]), peak_gain=float(g[i]))


def impedance_frequency_response(mode: str = "two-time-scale", *, joint_stiffness: float | None = None,
                                 rig: str = "joint-rig", stiffness: float | None = None,
                                 pretension: float | None = None, freqs: Sequence[float] | None = None) -> dict:
    """|q / q_des|(f) of the *continuous* impedance loop linearised by Drake's ``Linearize`` (python backend).

    The exact small-signal counterpart of :func:`impedance_sweep` (no 3 kHz hold); also returns the
    closed-loop eigenvalues.  Default frequencies: 0.5-70 Hz (Fig 11.4).
    """
    from pydrake.systems.primitives import Linearize
    sp = ImpedanceSweepParams()
    joint_stiffness = sp.joint_stiffness if joint_stiffness is None else joint_stiffness
    freqs = np.linspace(0.5, 70.0, 700) if freqs is None else np.asarray(freqs, float)
    if rig == "flexible-joint":
        r = flexible_joint_rig(params=FlexibleJointParams() if stiffness is None else
                               FlexibleJointParams(stiffness=stiffness), backend="python")
    else:
        r = joint_rig(params=JointRigParams() if pretension is None else JointRigParams(pretension=pretension),
                      backend="python")
    loop = closed_loop(r, impedance_controller(r, ImpedanceParams(joint_stiffness=joint_stiffness), mode=mode),
                       rate_hz=None)
    op = r.operating_point()
    ctx = loop.create_context(state=op.state, references={"link_angle_reference": 0.0})
    d = loop.diagram
    lin = Linearize(d, ctx, input_port_index=d.GetInputPort("link_angle_reference").get_index(),
                    output_port_index=d.GetOutputPort("link_angle").get_index())
    A, B, C, D = (np.asarray(m) for m in (lin.A(), lin.B(), lin.C(), lin.D()))
    eye = np.eye(A.shape[0])
    g = np.array([abs((C @ np.linalg.solve(2j * np.pi * f * eye - A, B) + D)[0, 0]) for f in freqs])
    i = int(np.argmax(g))
    return dict(freq=freqs, gain=g, resonance_hz=float(freqs[i]), peak_gain=float(g[i]),
                eigenvalues=np.linalg.eigvals(A))
