"""Real-time factors of the rigs, fingers and hand under 3 kHz control, beside scipy and MuJoCo.

Run::

    PYTHONPATH=. python benchmarks/bench_rigs.py [--seconds 1.0] [--repeats 3] [--json out/bench_rigs.json]

Every case runs in its own process (``--case NAME`` runs one and prints its JSON),
one after the other, so a JIT cache, a warm-up or a leak of one case cannot help or
hurt another. Real-time factor (RTF) = simulated seconds / seconds; we report it on
the process CPU clock (``*_rtf``, robust to other jobs on a shared machine) and on
the wall clock (``*_wall_rtf``). Best of ``--repeats`` runs after one warm-up run
(numba kernels compile once and are cached on disk; the warm-up hides that).
The JSON also records the machine's load average at the start and the end of the run
(``load_average_start``/``_end``: 1, 5, 15 min) and the start time (UTC).

Cases (all at the Awiwi control rate, 3 kHz, zero-order hold):

* ``joint_rig_3khz``: the default ``joint_rig()`` under the demo's motor PD
  (``control.motor_position.joint_rig_position_loop``): the default loop, the rig sampled at the
  control period (Drake's ``DiscreteTimeApproximation``, fixed-step RK3 at 1/3000 s inside one
  discrete update per period, in the momentum/elongation coordinates of
  ``components.rig_system.rig_integration_system``; the default of ``closed_loop`` for sampled loops
  on single-joint rigs), in a raw ``Simulator`` loop (``joint_rig_3khz_rtf``: the baseline of ``simulate``'s own
  cost) and through ``analysis.simulate`` with logging and monitors on (``..._simulate_rtf``); beside it, also
  through ``simulate``, the continuous rig behind the hold with fixed-step RK3 at the control period in the outer
  ``Simulator`` (``..._continuous_rig_rtf``; the largest state difference between the two,
  ``..._sampled_vs_continuous_max_difference``, is round-off), and the error against a tight error-controlled run
  of the continuous rig (RK3, accuracy 1e-9). Every other case runs through ``simulate``, but the breakdown below.
* ``joint_rig_breakdown``: where one control period of the ``joint_rig_3khz`` loop goes, microseconds
  of CPU per period (``joint_rig_breakdown_*_us``), each figure the difference of two nested diagrams timed
  in the same process (best of ``--repeats``, interleaved): ``loop_us`` the default loop; ``rig_with_hold_us``
  the sampled rig alone as ``closed_loop`` adds it (``Rig.add_sampled`` with its hold), inputs fixed;
  ``rig_us`` the same without the hold; ``dynamics_us`` the ``DiscreteTimeApproximation`` alone (no input
  multiplexer, no state demultiplexer, no ``LinkRigOutputs_``); ``dynamics_linear_us`` the same
  approximation of a ``SymbolicVectorSystem`` of the same size (states, inputs, rows) whose rows are one
  variable each (the approximation's own machinery and the evaluator's environment, not the laws);
  ``discrete_floor_us`` that linear system as a discrete ``SymbolicVectorSystem`` updated once per period
  (the ``Simulator``'s cost of one periodic update); ``lean_loop_us`` the floor of this representation, *not*
  a structure of the package: the same rig dynamics and PD law with nothing a user addresses (no hold, no
  state demultiplexer, no outputs system, the PD one gain on ``[references, state]`` fed by one source, no
  controller sub-diagram), with its final state's largest difference to the default loop's
  (``..._lean_loop_max_state_difference``, round-off: the same loop). Differences: ``controller_and_sources_us``
  (the PD with its reference, one ``TrajectoryAffineSystem``, and its reading of the rig's state), ``hold_us``, ``rig_plumbing_us`` (multiplexer, demultiplexer, outputs system), ``laws_us`` (the three
  RK3 stages' and the output's evaluation of the rig's nonlinear expressions), ``approximation_us``.
* ``scipy_reference``: the same equations and controller in numpy with
  ``scipy.integrate.solve_ivp`` (RK23, rtol 1e-4) per control period.
* ``finger_index_3khz``: the index finger under the joint-space motor PD.
* ``hand_3khz``: the whole hand (19 DoF, 38 tendons, wrist input at 0) under the
  joint PD, with the thesis's physics on (motor friction and ripple, guide friction,
  spring hysteresis), with ripple and guide friction only, with all three off, and with
  the default ``HandRigParams()`` (keys ``hand_3khz_rtf``, ``..._ripple_guide_friction_rtf``,
  ``..._physics_off_rtf``, ``..._default_rtf``).
* ``batch_rigs``: 512 joint rigs in one system (``rigs.batch``) under 512 motor PDs
  (C++: a sparse gain on the batch state plus a constant), the batch sampled at 3 kHz as one
  ``DiscreteTimeApproximation`` (``BatchedRig.sampled_diagram``), rig-seconds per CPU-second;
  beside it the continuous batch behind a zero-order hold (``batch_continuous_...``) and the largest
  state difference between the two.
* ``mujoco_callback`` / ``mujoco_linear``: the same antagonistic joint (two motor
  rotors, two fixed tendons, one link) in MuJoCo, RK4 at 1/3000 s with the PD in the
  stepping loop: (a) the exact nonlinear tension-only spring and the (3.8) motor
  friction through ``mjcb_passive`` (a Python callback per evaluation); (b) MuJoCo's
  native tendon spring, a *different model*: linear and two-sided, stiffness and
  rest length from the spring at the pretension, motor friction as joint damping.
  null when MuJoCo is absent (``pip install .[bench]``).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

import numpy as np

RATE = 3000.0
CASES = ("joint_rig_3khz", "joint_rig_breakdown", "scipy_reference", "finger_index_3khz", "hand_3khz", "batch_rigs",
         "mujoco_callback", "mujoco_linear")


def _clock():
    return time.process_time(), time.perf_counter()


def _rtf(seconds, t0):
    cpu, wall = _clock()
    return seconds / (cpu - t0[0]), seconds / (wall - t0[1])


def _best(fn, repeats):
    """(cpu rtf, wall rtf, extra) of the best of ``repeats`` runs after one warm-up."""
    fn()
    runs = [fn() for _ in range(repeats)]
    best = max(runs, key=lambda r: r[0])
    return best


# --- cases -----------------------------------------------------------------------------------------
def _simulated(system, ctx, seconds, **kw):
    """(cpu rtf, wall rtf, result) of one ``analysis.simulate`` run (fixed-step RK3 at the control period, nothing
    logged unless ``kw`` says otherwise; a divergence raises its ``SimulationDivergedError``)."""
    from awiwi_drake.analysis import simulate
    kw = dict(dict(log=(), mode="fixed_step", step=1.0 / RATE), **kw)
    t0 = _clock()
    res = simulate(system, ctx, seconds, **kw)
    return _rtf(seconds, t0) + (res,)


def _fixed_rk3(diagram, ctx, seconds):
    """The raw ``Simulator`` loop (fixed-step RK3 at the control period): only the baselines that measure what
    ``simulate`` itself costs (``joint_rig_3khz_rtf`` against ``..._simulate_rtf``) and Drake's own cost per period
    of each structure (``joint_rig_breakdown``) use it; every other case runs through :func:`_simulated`."""
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
    sim = Simulator(diagram, ctx)
    ResetIntegratorFromFlags(sim, "runge_kutta3", 1.0 / RATE)
    sim.get_mutable_integrator().set_fixed_step_mode(True)
    sim.Initialize()
    t0 = _clock()
    sim.AdvanceTo(seconds)
    state = diagram.GetOutputPort("state").Eval(ctx) if diagram.HasOutputPort("state") else \
        ctx.get_continuous_state_vector().CopyToVector()
    return _rtf(seconds, t0) + (np.array(state),)


def _joint_loop(seconds, sampled_rig=True):
    from awiwi_drake.control.motor_position import joint_rig_position_loop
    from awiwi_drake.rigs import joint_rig
    from awiwi_drake.parameters.rigs import DemoScenario
    rig = joint_rig()
    scen = DemoScenario(t_final=seconds, ramp_time=min(0.5, seconds / 3), step_time=seconds / 2)
    loop = joint_rig_position_loop(rig, scen, sampled_rig=sampled_rig)
    ctx = loop.create_context(rig.operating_point(pretension=scen.f_start))
    return rig, scen, loop.diagram, ctx


def case_joint_rig_3khz(seconds, repeats):
    from awiwi_drake.analysis import rig_monitors

    def run():    # the raw Simulator loop: the baseline that measures simulate's own overhead (..._simulate_rtf)
        _, _, d, ctx = _joint_loop(seconds)
        return _fixed_rk3(d, ctx, seconds)
    cpu, wall, x_fixed = _best(run, repeats)

    def run_simulate(sampled_rig=True):     # the loop as a user runs it: logging and monitors on
        rig, _, d, ctx = _joint_loop(seconds, sampled_rig=sampled_rig)
        out = _simulated(d, ctx, seconds, log=("joint_angle",), monitors=rig_monitors(rig))
        return out[:2] + ((out[2], d.GetOutputPort("state").Eval(ctx).copy()),)
    s_cpu, s_wall, (res, x_simulated) = _best(run_simulate, repeats)
    # the continuous rig behind the hold, fixed-step RK3 at the control period in the outer Simulator
    c_cpu, c_wall, (_, x_cont) = _best(lambda: run_simulate(sampled_rig=False), repeats)
    # tight reference: error-controlled RK3 at accuracy 1e-9 (the continuous rig), logged at the same times
    _, _, d, ctx = _joint_loop(seconds, sampled_rig=False)
    ref = _simulated(d, ctx, seconds, log=("joint_angle",), log_period=1.0 / RATE, mode="error_controlled",
                     step=None, max_step=1.0 / RATE, accuracy=1e-9)[2]
    err = float(np.max(np.abs(res["joint_angle"][:, 0] - np.interp(res.t, ref.t, ref["joint_angle"][:, 0]))))
    return dict(joint_rig_3khz_rtf=cpu, joint_rig_3khz_wall_rtf=wall, joint_rig_3khz_simulate_rtf=s_cpu,
                joint_rig_3khz_simulate_wall_rtf=s_wall, joint_rig_3khz_max_error_rad=err,
                joint_rig_3khz_final_joint_angle=float(x_fixed[0]), joint_rig_3khz_continuous_rig_rtf=c_cpu,
                joint_rig_3khz_continuous_rig_wall_rtf=c_wall,
                joint_rig_3khz_sampled_vs_continuous_max_difference=float(np.max(np.abs(x_simulated - x_cont))))


def _period_us(diagram, ctx, seconds):
    """CPU microseconds per control period of a raw ``Simulator`` run: Drake's own cost of a structure, without
    ``simulate`` (the breakdown's differences of nested diagrams)."""
    from pydrake.systems.analysis import Simulator
    sim = Simulator(diagram, ctx)
    sim.Initialize()
    t0 = time.process_time()
    sim.AdvanceTo(seconds)
    return (time.process_time() - t0) / (seconds * RATE) * 1e6


def case_joint_rig_breakdown(seconds, repeats):
    import pydrake.symbolic as sym
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import SymbolicVectorSystem

    from awiwi_drake.components.rig_system import rig_integration_system, sampled_dynamics
    from awiwi_drake.rigs import joint_rig

    h = 1.0 / RATE
    rig = joint_rig()
    op = rig.operating_point()
    u = np.concatenate([op.motor_torque, op.external_torque])
    z0 = rig.sampled_state(op.state)

    def loop():
        _, _, d, ctx = _joint_loop(seconds)
        return _period_us(d, ctx, seconds)

    def rig_alone(hold):
        b = DiagramBuilder()
        ports = rig.add_sampled(b, h, hold_applied_torque=hold)
        ports.export(b)
        d = b.Build()
        ctx = d.CreateDefaultContext()
        d.GetInputPort("motor_torque").FixValue(ctx, op.motor_torque)
        d.GetInputPort("external_torque").FixValue(ctx, op.external_torque)
        ports.dynamics.GetMyMutableContextFromRoot(ctx).SetDiscreteState(0, z0)
        return _period_us(d, ctx, seconds)

    def alone(system, discrete=False):
        b = DiagramBuilder()
        dyn = b.AddSystem(system if discrete else sampled_dynamics(system, h))
        b.ExportInput(dyn.get_input_port(), "u")
        d = b.Build()
        ctx = d.CreateDefaultContext()
        d.get_input_port().FixValue(ctx, u)
        dyn.GetMyMutableContextFromRoot(ctx).SetDiscreteState(0, z0)
        return _period_us(d, ctx, seconds)

    def linear(period=0.0):     # the rig system's size (states, inputs, rows), one variable per row: no laws
        xs = [sym.Variable(f"z{i}") for i in range(len(z0))]
        us = [sym.Variable(f"u{i}") for i in range(len(u))]
        rows = [-1e-3 * sym.Expression(v) for v in xs]
        return SymbolicVectorSystem(state=xs, input=us, dynamics=rows, output=xs, time_period=period)

    def lean_loop():    # not a package structure: the floor of this rig representation (see the module doc)
        from pydrake.systems.primitives import MatrixGain, Multiplexer, TrajectorySource
        from pydrake.trajectories import PiecewisePolynomial

        from awiwi_drake.control.motor_position import demo_references
        from awiwi_drake.parameters.rigs import DemoScenario, MotorPositionGains
        scen = DemoScenario(t_final=seconds, ramp_time=min(0.5, seconds / 3), step_time=seconds / 2)
        t, refs = demo_references(rig, scen)
        g, m, nx = MotorPositionGains(), len(op.motor_torque), len(z0)
        eye = np.eye(m)
        b = DiagramBuilder()
        dynamics = rig_integration_system(rig.drive.model)
        dyn = b.AddSystem(sampled_dynamics(dynamics, h))
        inputs = b.AddSystem(Multiplexer([m, len(op.external_torque)]))
        ref = b.AddSystem(TrajectorySource(PiecewisePolynomial.FirstOrderHold(
            t, np.vstack([refs["theta_reference"], refs["tendon_force_reference"]]))))
        meas = b.AddSystem(Multiplexer([2 * m, nx]))
        pd = b.AddSystem(MatrixGain(np.hstack([g.kp * eye, rig.params.motor.pulley_radius * eye,
                                               np.zeros((m, nx - 2 * m)), -g.kp * eye, -g.kd * eye])))
        b.Connect(ref.get_output_port(), meas.get_input_port(0))
        b.Connect(dyn.get_output_port(), meas.get_input_port(1))
        b.Connect(meas.get_output_port(), pd.get_input_port())
        b.Connect(pd.get_output_port(), inputs.get_input_port(0))
        b.Connect(inputs.get_output_port(), dyn.get_input_port())
        b.ExportInput(inputs.get_input_port(1), "external_torque")
        b.ExportOutput(dyn.get_output_port(), "state")
        d = b.Build()
        ctx = d.CreateDefaultContext()
        d.GetInputPort("external_torque").FixValue(ctx, np.zeros(len(op.external_torque)))
        dyn.GetMyMutableContextFromRoot(ctx).SetDiscreteState(0, rig.sampled_state(
            rig.operating_point(pretension=scen.f_start).state))
        us = _period_us(d, ctx, seconds)
        lean_state[:] = d.GetOutputPort("state").Eval(ctx)
        return us

    lean_state = np.zeros(len(z0))
    cases = dict(lean_loop=lean_loop, loop=loop, rig_with_hold=lambda: rig_alone(True), rig=lambda: rig_alone(False),
                 dynamics=lambda: alone(rig_integration_system(rig.drive.model)),
                 dynamics_linear=lambda: alone(linear()), discrete_floor=lambda: alone(linear(h), discrete=True))
    best = {k: np.inf for k in cases}
    for k, fn in cases.items():     # warm-up (kernels, caches)
        fn()
    for _ in range(repeats):        # interleaved, so a change of load hits every variant alike
        for k, fn in cases.items():
            best[k] = min(best[k], fn())
    out = {f"joint_rig_breakdown_{k}_us": v for k, v in best.items()}
    _, _, d, ctx = _joint_loop(seconds)     # the lean loop is the same loop: its final state against the default's
    _period_us(d, ctx, seconds)
    out["joint_rig_breakdown_lean_loop_max_state_difference"] = float(np.max(np.abs(
        d.GetOutputPort("state").Eval(ctx) - lean_state)))
    out.update(joint_rig_breakdown_controller_and_sources_us=best["loop"] - best["rig_with_hold"],
               joint_rig_breakdown_hold_us=best["rig_with_hold"] - best["rig"],
               joint_rig_breakdown_rig_plumbing_us=best["rig"] - best["dynamics"],
               joint_rig_breakdown_laws_us=best["dynamics"] - best["dynamics_linear"],
               joint_rig_breakdown_approximation_us=best["dynamics_linear"] - best["discrete_floor"])
    return out


def case_scipy_reference(seconds, repeats):
    from scipy.integrate import solve_ivp

    from awiwi_drake.components.motor import motor_acceleration
    from awiwi_drake.parameters.rigs import MotorPositionGains
    from awiwi_drake.control.motor_position import motor_references

    def run():
        rig, scen, _, _ = _joint_loop(seconds)
        p, spring = rig.params, rig.spring
        r, rq, m, dq = p.motor.pulley_radius, p.link_pulley_radius, p.link_inertia, p.link_damping
        gains = MotorPositionGains()
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

        x = rig.operating_point(pretension=scen.f_start).state.copy()
        u_hold = rig.operating_point(pretension=scen.f_start).motor_torque.copy()
        dt = 1.0 / RATE
        t0 = _clock()
        for k in range(int(round(seconds * RATE))):
            t = k * dt
            sol = solve_ivp(rhs, (t, t + dt), x, method="RK23", args=(u_hold,), rtol=1e-4, atol=1e-7)
            x = sol.y[:, -1]
            th_ref = np.array([np.interp(t + dt, t_knots, theta_ref[0]), np.interp(t + dt, t_knots, theta_ref[1])])
            u_hold = (np.array([np.interp(t + dt, t_knots, ff[0]), np.interp(t + dt, t_knots, ff[1])])
                      + gains.kp * (th_ref - x[2:4]) - gains.kd * x[4:6])
        return _rtf(seconds, t0) + (x,)
    cpu, wall, x = _best(run, max(1, repeats - 1))
    return dict(scipy_reference_rtf=cpu, scipy_reference_wall_rtf=wall, scipy_final_joint_angle=float(x[0]))


def _hand_like(target, seconds, repeats, params=None):
    from awiwi_drake.control import closed_loop
    from awiwi_drake.control.joint_pd import joint_pd_controller
    from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram

    def run():
        rig = hand_diagram(params=params) if target == "hand" else finger_diagram(finger=target, params=params)
        cl = closed_loop(rig, joint_pd_controller(rig))
        q_ref = np.array(rig.operating_point().joint_angle, dtype=float)
        q_ref[1 if target != "hand" else 5] += 0.2
        ctx = cl.create_context(rig.operating_point(), references={"joint_angle_reference": q_ref})
        return _simulated(cl, ctx, seconds)
    return _best(run, repeats)


def case_finger_index_3khz(seconds, repeats):
    cpu, wall, _ = _hand_like("index", seconds, repeats)
    return dict(finger_index_3khz_rtf=cpu, finger_index_3khz_wall_rtf=wall)


def case_hand_3khz(seconds, repeats):
    """The hand under the joint PD: physics off, ripple + guide friction, all on (``hand_3khz_rtf``), and the
    default ``HandRigParams()`` (whatever the defaults switch on), each stated explicitly."""
    from awiwi_drake.parameters.hand import HandRigParams
    out = {}
    cases = (("hand_3khz_physics_off", HandRigParams().with_physics(ripple=False, hysteresis=False,
                                                                    guide_friction=False)),
             ("hand_3khz_ripple_guide_friction", HandRigParams().with_physics(ripple=True, hysteresis=False,
                                                                              guide_friction=True)),
             ("hand_3khz", HandRigParams().with_physics(ripple=True, hysteresis=True, guide_friction=True)),
             ("hand_3khz_default", HandRigParams()))
    for key, params in cases:
        try:
            cpu, wall, _ = _hand_like("hand", seconds, repeats, params=params)
            out.update({f"{key}_rtf": cpu, f"{key}_wall_rtf": wall})
        except RuntimeError as exc:   # e.g. SimulationDivergedError: fixed-step RK3 at 3 kHz diverged
            out.update({f"{key}_rtf": None, f"{key}_wall_rtf": None, f"{key}_note": str(exc)})
    return out


def case_batch_rigs(seconds, repeats, num_copies=512):
    import scipy.sparse as sp
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import Adder, ConstantVectorSource, SparseMatrixGain, ZeroOrderHold

    from awiwi_drake.rigs.batch import batched_joint_rig
    from awiwi_drake.parameters.rigs import MotorPositionGains

    def motor_pd(N, theta_ref, u0, kp, kd):
        """u_i = u0_i + kp_i (theta*_i - theta_i) - kd omega_i for every copy, in C++: a sparse gain on the
        batch state plus a constant, sampled and held at 3 kHz."""
        rows = np.arange(2 * N)
        copy, motor = rows // 2, rows % 2
        cols_th, cols_om = 6 * copy + 2 + motor, 6 * copy + 4 + motor
        K = sp.csc_matrix((np.r_[-kp.repeat(2), np.full(2 * N, -kd)], (np.r_[rows, rows], np.r_[cols_th, cols_om])),
                          shape=(2 * N, 6 * N))
        offset = (u0 + kp[:, None] * theta_ref).ravel()
        return K, offset

    def run(sampled=True):
        br = batched_joint_rig(num_copies)
        rig = br.single
        rng = np.random.default_rng(0)
        pre = rng.uniform(10.0, 40.0, num_copies)
        ops = [rig.operating_point(pretension=f) for f in pre]
        g = MotorPositionGains()
        kp = rng.uniform(0.5, 1.5, (num_copies, 1)) * g.kp
        theta_ref = np.array([op.state[2:4] for op in ops]) + rng.normal(scale=0.05, size=(num_copies, 2))
        u0 = np.array([op.motor_torque for op in ops])
        K, offset = motor_pd(num_copies, theta_ref, u0, kp.ravel(), g.kd)
        b = DiagramBuilder()
        # the default: the batch sampled at the control period (it samples the PD itself); else behind a hold
        plant = b.AddSystem(br.sampled_diagram(1.0 / RATE) if sampled else br.diagram)
        gain = b.AddSystem(SparseMatrixGain(K))
        const = b.AddSystem(ConstantVectorSource(offset))
        add = b.AddSystem(Adder(2, 2 * num_copies))
        b.Connect(plant.GetOutputPort("state"), gain.get_input_port())
        b.Connect(gain.get_output_port(), add.get_input_port(0))
        b.Connect(const.get_output_port(), add.get_input_port(1))
        if sampled:
            b.Connect(add.get_output_port(), plant.GetInputPort("motor_torque"))
        else:
            hold = b.AddSystem(ZeroOrderHold(1.0 / RATE, 2 * num_copies))
            b.Connect(add.get_output_port(), hold.get_input_port())
            b.Connect(hold.get_output_port(), plant.GetInputPort("motor_torque"))
        b.ExportInput(plant.GetInputPort("external_torque"), "external_torque")
        d = b.Build()
        ctx = d.CreateDefaultContext()
        x, u, e = br.stack(ops)
        if sampled:
            plant.GetMyMutableContextFromRoot(ctx).SetDiscreteState(x)
        else:
            plant.GetMyMutableContextFromRoot(ctx).SetContinuousState(x)
            hold.GetMyMutableContextFromRoot(ctx).SetDiscreteState(u)
        d.GetInputPort("external_torque").FixValue(ctx, e)
        out = _simulated(d, ctx, seconds)
        x_end = (plant.GetMyContextFromRoot(ctx).get_discrete_state_vector() if sampled else
                 plant.GetMyContextFromRoot(ctx).get_continuous_state_vector()).CopyToVector()
        return out[:2] + (x_end,)
    cpu, wall, x = _best(run, max(1, repeats - 1))
    c_cpu, c_wall, x_c = _best(lambda: run(sampled=False), max(1, repeats - 1))
    return dict(batch_rig_seconds_per_cpu_second=cpu * num_copies,
                batch_rig_seconds_per_wall_second=wall * num_copies, batch_num_copies=num_copies,
                batch_continuous_rig_seconds_per_cpu_second=c_cpu * num_copies,
                batch_sampled_vs_continuous_max_difference=float(np.max(np.abs(x - x_c))))


_MJCF = """
<mujoco model="antagonistic_joint">
  <option timestep="{dt}" integrator="RK4" gravity="0 0 0"/>
  <worldbody>
    <body name="link"><joint name="q" type="hinge" axis="0 0 1" damping="{dq}"/>
      <inertial pos="0 0 0" mass="0.02" diaginertia="{m} {m} {m}"/></body>
    <body name="rotor1"><joint name="th1" type="hinge" axis="0 0 1" damping="{dm}"/>
      <inertial pos="0 0 0" mass="0.1" diaginertia="{B} {B} {B}"/></body>
    <body name="rotor2"><joint name="th2" type="hinge" axis="0 0 1" damping="{dm}"/>
      <inertial pos="0 0 0" mass="0.1" diaginertia="{B} {B} {B}"/></body>
  </worldbody>
  <tendon>
    <fixed name="t1" {spring}><joint joint="th1" coef="{r}"/><joint joint="q" coef="{mrq}"/></fixed>
    <fixed name="t2" {spring}><joint joint="th2" coef="{r}"/><joint joint="q" coef="{rq}"/></fixed>
  </tendon>
  <actuator>
    <motor joint="th1" ctrllimited="true" ctrlrange="-{lim} {lim}"/>
    <motor joint="th2" ctrllimited="true" ctrlrange="-{lim} {lim}"/>
  </actuator>
</mujoco>
"""


def _mujoco_case(seconds, repeats, linear: bool):
    try:
        import mujoco
    except ImportError:
        return None
    from awiwi_drake.components.motor import motor_friction_torque
    from awiwi_drake.parameters.rigs import DemoScenario, MotorPositionGains
    from awiwi_drake.control.motor_position import motor_references
    from awiwi_drake.rigs import joint_rig
    rig = joint_rig()
    p, spring = rig.params, rig.spring
    r, rq = p.motor.pulley_radius, p.link_pulley_radius
    scen = DemoScenario(t_final=seconds, ramp_time=min(0.5, seconds / 3), step_time=seconds / 2)
    op = rig.operating_point(pretension=scen.f_start)
    x0 = float(np.ravel(spring.inverse_force(np.array([scen.f_end])))[0])
    if linear:   # different model: linear two-sided tendon springs at the end pretension's stiffness
        k = float(spring.stiffness(np.array([x0]))[0])
        spring_attr = f'stiffness="{k!r}" springlength="{x0 - scen.f_end / k!r}"'
        # linearised (3.8) at rest as joint damping
        dm = p.motor.coulomb_torque * p.motor.friction_slope + p.motor.viscous_friction
    else:
        spring_attr, dm = "", 0.0
    xml = _MJCF.format(dt=1.0 / RATE, dq=p.link_damping, m=p.link_inertia, B=p.motor.inertia, dm=dm,
                       r=r, rq=rq, mrq=-rq, lim=p.motor.torque_limit, spring=spring_attr)
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    t_knots = np.linspace(0.0, seconds, 601)
    pre = np.interp(t_knots, [0.0, scen.ramp_time, scen.t_final], [scen.f_start, scen.f_end, scen.f_end])
    q_ref = np.where(t_knots >= scen.step_time, scen.link_step, 0.0)
    theta_ref, ff = motor_references(rig, t_knots, pre, q_ref)
    gains = MotorPositionGains()

    def passive(m_, d_):
        # exact spring: tension-only polynomial on the tendon elongation (MuJoCo's tendon length
        # is our x up to the constant set by the initial state), plus the (3.8) motor friction
        f = spring.force(d_.ten_length.copy())
        # -J^T f with J = [[-rq, r, 0], [rq, 0, r]] (the fixed tendons above)
        d_.qfrc_passive[0] += rq * (f[0] - f[1])
        d_.qfrc_passive[1:3] += -r * f + motor_friction_torque(d_.qvel[1:3], p.motor)

    def run():
        mujoco.set_mjcb_passive(None if linear else passive)
        mujoco.mj_resetData(model, data)
        # tendon length = r th - rq q (t1), r th + rq q (t2): equal to our elongation x with offsets 0
        data.qpos[:] = [op.state[0], op.state[2], op.state[3]]
        mujoco.mj_forward(model, data)
        dt = 1.0 / RATE
        n = int(round(seconds * RATE))
        t0 = _clock()
        for k in range(n):
            t = k * dt
            th = np.array([np.interp(t, t_knots, theta_ref[0]), np.interp(t, t_knots, theta_ref[1])])
            u = (np.array([np.interp(t, t_knots, ff[0]), np.interp(t, t_knots, ff[1])])
                 + gains.kp * (th - data.qpos[1:3]) - gains.kd * data.qvel[1:3])
            data.ctrl[:] = u
            mujoco.mj_step(model, data)
        out = _rtf(seconds, t0) + (data.qpos.copy(),)
        mujoco.set_mjcb_passive(None)
        return out
    cpu, wall, qpos = _best(run, repeats)
    return cpu, wall, float(qpos[0])


def case_mujoco_callback(seconds, repeats):
    res = _mujoco_case(seconds, repeats, linear=False)
    if res is None:
        return dict(mujoco_callback_rtf=None, mujoco_note="mujoco not installed (pip install .[bench])")
    return dict(mujoco_callback_rtf=res[0], mujoco_callback_wall_rtf=res[1], mujoco_callback_final_joint_angle=res[2])


def case_mujoco_linear(seconds, repeats):
    res = _mujoco_case(seconds, repeats, linear=True)
    if res is None:
        return dict(mujoco_linear_rtf=None)
    return dict(mujoco_linear_rtf=res[0], mujoco_linear_wall_rtf=res[1], mujoco_linear_final_joint_angle=res[2])


# --- driver ------------------------------------------------------------------------------------------
def run_case(name, seconds, repeats):
    return globals()[f"case_{name}"](seconds, repeats)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.0, help="simulated seconds per run (rigs)")
    ap.add_argument("--hand-seconds", type=float, default=0.2, help="simulated seconds per run (finger, hand)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated subset of {', '.join(CASES)}")
    ap.add_argument("--case", default=None, help=argparse.SUPPRESS)   # one case, in this process
    ap.add_argument("--json", default=None, metavar="OUT", help="write every figure to this JSON file")
    args = ap.parse_args(argv)
    if args.case:
        secs = args.hand_seconds if args.case in ("finger_index_3khz", "hand_3khz") else args.seconds
        print(json.dumps(run_case(args.case, secs, args.repeats)))
        return 0
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    for c in cases:
        if c not in CASES:
            ap.error(f"--cases: unknown case {c!r}; known: {', '.join(CASES)}")
    out = dict(seconds=args.seconds, hand_seconds=args.hand_seconds, repeats=args.repeats, clock="process CPU time",
               load_average_start=list(os.getloadavg()), started_utc=time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()))
    for c in cases:
        cmd = [sys.executable, __file__, "--case", c, "--seconds", str(args.seconds),
               "--hand-seconds", str(args.hand_seconds), "--repeats", str(args.repeats)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            out[f"{c}_error"] = proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "failed"
            print(f"{c:20s} FAILED: {out[f'{c}_error']}", flush=True)
            continue
        res = json.loads(proc.stdout.strip().splitlines()[-1])
        out.update(res)
        print(f"{c:20s} " + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in res.items()),
              flush=True)
    for key in ("joint_rig_3khz_rtf", "scipy_reference_rtf", "finger_index_3khz_rtf", "hand_3khz_rtf",
                "batch_rig_seconds_per_cpu_second", "mujoco_callback_rtf", "mujoco_linear_rtf"):
        out.setdefault(key, None)
    if out["joint_rig_3khz_rtf"] and out["scipy_reference_rtf"]:
        out["joint_rig_vs_scipy"] = out["joint_rig_3khz_rtf"] / out["scipy_reference_rtf"]
    else:
        out["joint_rig_vs_scipy"] = None
    for other in ("mujoco_callback", "mujoco_linear"):
        if out.get(f"{other}_rtf") and out["joint_rig_3khz_rtf"]:
            out[f"joint_rig_vs_{other}"] = out["joint_rig_3khz_rtf"] / out[f"{other}_rtf"]
    out["load_average_end"] = list(os.getloadavg())      # a shared machine: the load beside the figures
    print(f"joint_rig_vs_scipy = {out['joint_rig_vs_scipy']}; load average {out['load_average_start'][0]:.1f} "
          f"at the start, {out['load_average_end'][0]:.1f} at the end")
    if args.json:
        pathlib.Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        pathlib.Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
    raise SystemExit(main())
