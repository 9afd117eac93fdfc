"""Real-time factor of the rigs, open loop and with a 3 kHz discrete controller.

Run: ``python benchmarks/bench_rigs.py [--seconds 2] [--json out/bench_rigs.json]``

For each rig and backend we time ``Simulator.AdvanceTo`` (error-controlled RK3,
max step 1/3000 s, accuracy 1e-4, no logging) and report the real-time factor
RTF = simulated seconds / wall seconds. The joint rig with the 3 kHz motor PD
(the demo controller, Drake primitives) is compared with a hand-written numpy +
``scipy.integrate.solve_ivp`` implementation of the same equations in the same
process (one ``solve_ivp`` call per control period, zero-order hold), so the
ratio does not depend on the machine. Timings are medians of ``--repeats`` runs.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import time

import numpy as np
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from scipy.integrate import solve_ivp

from awiwi_drake.components.motor import motor_acceleration
from awiwi_drake.rigs import flexible_joint_rig, joint_rig, tendon_rig
from awiwi_drake.control.motor_position import joint_rig_position_loop
from awiwi_drake.parameters.rigs import DemoScenario, MotorPositionGains
from awiwi_drake.rigs.demo import motor_references

RATE = 3000.0


def _advance(diagram, context, seconds: float, integrator: str = "runge_kutta3") -> float:
    """RTF of one run; ``integrator`` may end in ``"-fixed"`` (fixed step at the control period)."""
    fixed = integrator.endswith("-fixed")
    integrator = integrator.replace("-fixed", "")
    sim = Simulator(diagram, context)
    ResetIntegratorFromFlags(sim, integrator, 1.0 / RATE)
    if fixed:
        sim.get_mutable_integrator().set_fixed_step_mode(True)
    elif integrator == "runge_kutta3":
        sim.get_mutable_integrator().set_target_accuracy(1e-4)
    sim.Initialize()
    t0 = time.perf_counter()
    sim.AdvanceTo(seconds)
    _advance.last_state = sim.get_context().get_continuous_state_vector().CopyToVector()
    return seconds / (time.perf_counter() - t0)


def open_loop_rtf(build, backend, seconds):
    rig = build(backend=backend)
    op = rig.operating_point()
    ctx = rig.context(op)
    state = op.state.copy()
    state[min(1, len(state) - 1)] += 0.5   # start with some motion
    ctx.SetContinuousState(state)
    return _advance(rig.diagram, ctx, seconds)


def closed_loop_rtf_joint(backend, seconds, integrator="runge_kutta3"):
    rig = joint_rig(backend=backend)
    scen = DemoScenario(t_final=seconds, ramp_time=min(0.5, seconds / 3), step_time=seconds / 2)
    loop = joint_rig_position_loop(rig, scen)
    ctx = loop.create_context(rig.operating_point(pretension=scen.f_start))
    return _advance(loop.diagram, ctx, seconds, integrator)


def scipy_reference_rtf(seconds):
    """Same joint-rig equations and controller, numpy + solve_ivp, ZOH at 3 kHz."""
    rig = joint_rig()
    p = rig.params
    spring = rig.spring
    r, rq, m, dq = p.motor.pulley_radius, p.link_pulley_radius, p.link_inertia, p.link_damping
    gains = MotorPositionGains()
    scen = DemoScenario(t_final=seconds, ramp_time=min(0.5, seconds / 3), step_time=seconds / 2)
    t_knots = np.linspace(0.0, seconds, 601)
    pre = np.interp(t_knots, [0.0, scen.ramp_time, scen.t_final], [scen.f_start, scen.f_end, scen.f_end])
    q_ref = np.where(t_knots >= scen.step_time, scen.link_step, 0.0)
    theta_ref, ff = motor_references(rig, t_knots, pre, q_ref)

    def rhs(t, x, u):
        q, qd, th, w = x[0], x[1], x[2:4], x[4:6]
        xs = np.array([r * th[0] - rq * q, r * th[1] + rq * q])
        f = spring.force(xs)
        acc = motor_acceleration(th, w, u, r * f, p.motor)
        return np.concatenate([[qd, (rq * (f[0] - f[1]) - dq * qd) / m], w, acc])

    op = rig.operating_point(pretension=scen.f_start)
    x = op.state.copy()
    dt = 1.0 / RATE
    n = int(round(seconds * RATE))
    t0 = time.perf_counter()
    for k in range(n):
        t = k * dt
        th_ref = np.array([np.interp(t, t_knots, theta_ref[0]), np.interp(t, t_knots, theta_ref[1])])
        u = np.array([np.interp(t, t_knots, ff[0]), np.interp(t, t_knots, ff[1])]) \
            + gains.kp * (th_ref - x[2:4]) - gains.kd * x[4:6]
        sol = solve_ivp(rhs, (t, t + dt), x, method="RK23", args=(u,), rtol=1e-4, atol=1e-7)
        x = sol.y[:, -1]
    return seconds / (time.perf_counter() - t0), x


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per run")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=None, help="write the figures to this JSON file")
    args = ap.parse_args(argv)
    rows = []

    def record(name, backend, fn):
        vals = [fn() for _ in range(args.repeats)]
        rtf = statistics.median(vals)
        rows.append(dict(case=name, backend=backend, rtf=rtf))
        print(f"{name:34s} {backend:9s} RTF {rtf:8.2f}x", flush=True)
        return rtf

    for build in (tendon_rig, flexible_joint_rig, joint_rig):
        for backend in ("python", "symbolic"):
            record(f"{build.__name__} open loop", backend, lambda: open_loop_rtf(build, backend, args.seconds))
    cl = {}
    for backend in ("python", "symbolic"):
        cl[backend] = record("joint_rig + 3 kHz motor PD", backend, lambda: closed_loop_rtf_joint(backend, args.seconds))
    closed_loop_rtf_joint("symbolic", args.seconds)
    x_rk3 = _advance.last_state
    cl["symbolic+rk2"] = record("joint_rig + 3 kHz PD, fixed RK2 @ 1/3 ms", "symbolic",
                                lambda: closed_loop_rtf_joint("symbolic", args.seconds, "runge_kutta2"))
    x_rk2 = _advance.last_state
    print(f"fixed RK2 vs RK3 (1e-4): final link angle differs by {abs(x_rk2[0] - x_rk3[0]):.2e} rad, "
          f"motor angles by {np.max(np.abs(x_rk2[2:4] - x_rk3[2:4])):.2e} rad")
    for backend in ("python", "symbolic"):
        cl[f"{backend}+rk3-fixed"] = record("joint_rig + 3 kHz PD, fixed RK3 @ 1/3 ms", backend,
                                           lambda: closed_loop_rtf_joint(backend, args.seconds, "runge_kutta3-fixed"))
    x_rk3f = _advance.last_state
    print(f"fixed RK3 vs RK3 (1e-4): final link angle differs by {abs(x_rk3f[0] - x_rk3[0]):.2e} rad")
    ref = record("joint_rig + 3 kHz PD (numpy+solve_ivp)", "scipy", lambda: scipy_reference_rtf(args.seconds)[0])
    for backend, v in cl.items():
        print(f"ratio drake/{backend} : scipy reference = {v / ref:.2f}")
    best = max(cl.values())
    print(f"target: joint_rig with 3 kHz controller >= 20x real time -> best {best:.1f}x "
          f"({'met' if best >= 20 else 'NOT met'}); no slower than scipy -> {'met' if best >= ref else 'NOT met'}")
    if args.json:
        pathlib.Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        pathlib.Path(args.json).write_text(json.dumps(dict(rows=rows, seconds=args.seconds), indent=1))


if __name__ == "__main__":
    main()
