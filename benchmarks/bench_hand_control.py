"""The whole hand closed through the thesis's control chain: real-time factor and where the time goes.

Usage::

    PYTHONPATH=. python benchmarks/bench_hand_control.py [--sim-time 0.1]
                                                         [--controllers joint-pd,cascaded,cascaded@sdre,cascaded:no-observer,backstepping]
                                                         [--physics default,off,on,stick-slip] [--json out.json] [--no-profile]

For each registered hand controller (``joint-pd``: the 3 kHz motor PD; ``cascaded``: joint impedance ->
force distribution (7.6) -> tendon force PD (10.2) with friction/ripple feed-forward, joint angles from the
tendon-length estimator; ``cascaded@sdre``: the same chain with the ch. 14 tendon SDRE as the force law
(``HandChainParams(tendon_law="sdre")``, gains re-solved at 200 Hz); ``backstepping``: 15.5 for the hand at 3 kHz, joint angles estimated) the hand
(``hand_diagram()``, wrist input at 0; ``--physics``: the plant's thesis effects as configured by default,
all off, all on, or all on with the joints' stick-slip friction too, each row says which) is
closed with ``closed_loop`` at the registered rate, every joint reference stepped by 0.05 rad (a fixed input value of
the context, so no schedule source runs every period), and simulated
with the default mode of ``analysis.simulate`` (fixed-step RK3 at the control period; with several rates
at their common period), after a warm-up
run of two control periods (kernel generation and JIT compilation are not timed).  All controllers run in
one process, one after the other, so their ratios are measured under the same load.

Real-time factor (RTF) = simulated seconds per second of the process's CPU clock (``rtf``; robust to other
jobs on a shared machine) and of the wall clock (``wall_rtf``).  Where the time goes (unless
``--no-profile``): the CPU time of each system's work measured apart on a copy of its loop context
(``isolated_us_per_call``: every continuous system's derivatives, MultibodyPlant included; every Python
system's periodic update and vector outputs), the CPU time per period of each stage of the fused chain inside a
short run (``stage_us_per_period``: ``closed_loop`` closes the hand through ONE discrete system,
:class:`~awiwi_drake.control.fused.FusedChain_`, holding estimator, joint stage, distribution and force law), and how often Drake calls each Python callback per control
period (``callbacks_per_period``, counted by cProfile in a 0.01 s run; cProfile's times are not used, it
slows the many small Python calls several-fold).  Cost per period ~ sum of cost x calls; the C++ primitives
(Mux, Demux, MatrixGain, Adder, ZeroOrderHold) and the integrator make the rest.  The machine's load
average is printed with the figures.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import time

import numpy as np
from pydrake.systems.framework import Diagram, PortDataType

from awiwi_drake.analysis import simulate
from awiwi_drake.control import closed_loop, get_entry, make_controller
from awiwi_drake.hand.diagrams import hand_diagram


def _calls(prof: cProfile.Profile, periods: float) -> dict:
    """Calls per control period of each Python callback that Drake's C++ calls (exact counts)."""
    out = {}
    for (file, line, fn), (_cc, nc, _tt, _ct, callers) in pstats.Stats(prof).stats.items():
        if file != "~" and callers and all(c[0] == "~" for c in callers) and "awiwi_drake/" in file:
            out[f"{file.split('awiwi_drake/')[-1]}:{line}:{fn}"] = nc / periods
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def _time(fn, n: int = 200) -> float:
    """CPU time of one call [us], best of three batches of ``n``."""
    fn()
    best = np.inf
    for _ in range(3):
        t0 = time.process_time()
        for _ in range(n):
            fn()
        best = min(best, (time.process_time() - t0) / n)
    return best * 1e6


def isolated_costs(diagram, root) -> dict:
    """CPU time per call [us] of each system's work, measured apart on a copy of its loop context.

    For every system with continuous state: ``CalcTimeDerivatives`` (the state nudged each call so nothing
    is cached; MultibodyPlant included); every periodic discrete update of a Python system; every vector
    output of a Python system (an input re-fixed each call to invalidate it; the cost of that is subtracted).
    """
    out = {}
    for sys_ in _leaves(diagram):
        python = not type(sys_).__module__.startswith("pydrake")
        sub = diagram.GetSubsystemContext(sys_, root)
        ctx = sys_.CreateDefaultContext()
        ctx.SetTimeStateAndParametersFrom(sub)
        fixed = []
        for i in range(sys_.num_input_ports()):
            port = sys_.get_input_port(i)
            if port.HasValue(sub) and port.get_data_type() == PortDataType.kVectorValued:
                v = np.array(port.Eval(sub), dtype=float)
                port.FixValue(ctx, v)
                fixed.append((port, v))
        name = sys_.GetSystemPathname()
        if sys_.num_continuous_states():
            x = ctx.get_continuous_state_vector().CopyToVector()
            d = sys_.AllocateTimeDerivatives()

            def deriv():
                x[0] += 1e-12
                ctx.SetContinuousState(x)
                sys_.CalcTimeDerivatives(ctx, d)

            def nudge():
                x[0] += 1e-12
                ctx.SetContinuousState(x)
            out[f"{name}: derivatives"] = _time(deriv) - _time(nudge)
        if not python:
            continue
        xc = ctx.get_continuous_state_vector().CopyToVector() if sys_.num_continuous_states() else None

        def invalidate():               # every input re-fixed and the state nudged: nothing stays cached
            for port, v in fixed:
                port.FixValue(ctx, v)
            if xc is not None:
                xc[0] += 1e-12
                ctx.SetContinuousState(xc)
        base = _time(invalidate)
        if sys_.num_discrete_state_groups() and sys_.GetUniquePeriodicDiscreteUpdateAttribute() is not None:
            def update():
                invalidate()
                sys_.EvalUniquePeriodicDiscreteUpdate(ctx)
            out[f"{name}: discrete update"] = _time(update, 50) - base
        for i in range(sys_.num_output_ports()):
            op = sys_.get_output_port(i)
            if op.get_data_type() != PortDataType.kVectorValued:
                continue

            def ev(op=op):
                invalidate()
                op.Eval(ctx)
            t = _time(ev) - base
            if t > 1.0:
                out[f"{name}: output {op.get_name()}"] = t
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def stage_costs(loop, op, refs, sim_time: float = 0.03) -> dict:
    """CPU time per control period [us] of each stage of the fused chain (``closed_loop``'s default for the hand,
    :class:`~awiwi_drake.control.fused.FusedChain_`) and of the plant's derivatives, inside a ``sim_time`` run of the
    loop (each call timed with the thread's CPU clock; the stages are nested: ``sample`` holds the estimator, the
    joint stage, the path velocity and the last law, ``update`` holds ``sample`` (evaluated there first) and the
    distribution)."""
    fused = loop.fused
    if fused is None:
        return {}
    acc: dict = {}
    saved = []

    def wrap(obj, name, key):
        """Time ``obj.name`` (a class: every instance, e.g. the copies ``simulate`` makes; else this object)."""
        fn = getattr(obj, name)

        def timed(*a, **k):
            t = time.thread_time()
            try:
                return fn(*a, **k)
            finally:
                acc[key] = acc.get(key, 0.0) + time.thread_time() - t
        saved.append((obj, name, obj.__dict__.get(name)))
        setattr(obj, name, timed)

    plant = next(s for s in _leaves(loop.diagram) if s.num_continuous_states())
    wrap(type(fused), "_calc_sample", "sample (estimator, joint stage, path velocity, law)")
    wrap(type(fused), "_update", "update (sample + distribution)")
    wrap(fused.estimator, "estimate", "estimator (5.15, Algorithm 1)")     # shared by the copies (float)
    if fused.joint_law is not None:
        wrap(type(fused.joint_law), "__call__", "joint stage")
    if fused.dist is not None:
        wrap(fused.dist, "step", "distribution (7.6)")
    sdre = getattr(fused.law, "initial_gain", None) is not None
    wrap(type(fused.law), "__call__", ("tendon force law (SDRE ch. 14)" if sdre else "tendon force law (10.2)")
         if fused.joint_law is not None else "law")
    if sdre:
        wrap(type(fused.law), "gains", "tendon SDRE gain re-solve (every 1/sdre_update_rate)")
    if fused.obs is not None:
        wrap(fused.obs, "compensation", "friction observer (9.2): compensation")
        wrap(fused.obs, "next_state", "friction observer (9.2): update")
    wrap(type(plant), "DoCalcTimeDerivatives", "plant derivatives (3 per period)")
    try:
        c0 = time.process_time()
        simulate(loop, loop.create_context(op, references=refs), sim_time, log=("joint_angle",))
        total = time.process_time() - c0
    finally:
        for obj, name, old in reversed(saved):
            if old is None:
                delattr(obj, name)
            else:
                setattr(obj, name, old)
    periods = sim_time * loop.rate_hz
    out = {k: v / periods * 1e6 for k, v in acc.items()}
    out["whole loop"] = total / periods * 1e6
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def _leaves(system):
    for s in system.GetSystems():
        if isinstance(s, Diagram):
            yield from _leaves(s)
        else:
            yield s


PHYSICS = {  # the hand plant's thesis effects, each case stated explicitly (the defaults may change)
    "default": None,
    "off": dict(ripple=False, hysteresis=False, guide_friction=False),
    "on": dict(ripple=True, hysteresis=True, guide_friction=True),
    "stick-slip": dict(ripple=True, hysteresis=True, guide_friction=True, joint_friction=True),
}


def run(name: str, sim_time: float, profile: bool = True, physics: str = "default") -> dict:
    """One row; ``name`` a registered controller, or ``<chain controller>:no-observer`` (a registry variant) for the
    chain without its default ch. 9 friction observer, or ``<chain controller>@<tendon law>`` for the chain with
    ``HandChainParams(tendon_law=...)`` (e.g. ``cascaded@sdre``: the ch. 14 tendon SDRE as the force law)."""
    from awiwi_drake.parameters.hand import HandRigParams
    from awiwi_drake.parameters.hand_control import HandChainParams
    switches = PHYSICS[physics]
    rig = hand_diagram(params=None if switches is None else HandRigParams().with_physics(**switches))
    base, _, law = name.partition("@")
    opts = {"chain_params": HandChainParams(tendon_law=law)} if law else {}
    t0 = time.perf_counter()
    loop = closed_loop(rig, make_controller(base, rig, **opts), **get_entry(base, rig).loop_options)
    build = time.perf_counter() - t0
    op = rig.operating_point()
    # the stepped reference is a fixed input value of the context (no schedule source evaluated every period)
    refs = {"joint_angle_reference": op.joint_angle + 0.05}
    # warm-up: the first simulation generates/compiles the drive's kernels (numba) and fills caches
    simulate(loop, loop.create_context(op, references=refs), 2.0 / loop.rate_hz, log=("joint_angle",))
    ctx = loop.create_context(op, references=refs)
    c0, w0 = time.process_time(), time.perf_counter()
    simulate(loop, ctx, sim_time, log=("joint_angle",))
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    periods = sim_time * loop.rate_hz
    row = dict(controller=name, physics=physics, rate_hz=loop.rate_hz, estimator=bool(loop.estimated), build_s=build,
               sim_time=sim_time, cpu_s=cpu, wall_s=wall, rtf=sim_time / cpu, wall_rtf=sim_time / wall,
               cpu_us_per_period=cpu / periods * 1e6)
    if profile:
        prof = cProfile.Profile()
        prof.enable()
        simulate(loop, loop.create_context(op, references=refs), 0.01, log=("joint_angle",))
        prof.disable()
        row["callbacks_per_period"] = _calls(prof, 0.01 * loop.rate_hz)
        ictx = loop.create_context(op)
        loop.diagram.GetInputPort("joint_angle_reference").FixValue(ictx, refs["joint_angle_reference"])
        row["isolated_us_per_call"] = isolated_costs(loop.diagram, ictx)
        row["stage_us_per_period"] = stage_costs(loop, op, refs)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sim-time", type=float, default=0.1, help="simulated seconds per controller")
    ap.add_argument("--controllers", default="joint-pd,cascaded,cascaded@sdre,cascaded:no-observer,backstepping",
                    help="registered hand controllers; '<chain controller>:no-observer' without the ch. 9 observer; "
                         "'<chain controller>@sdre' with the ch. 14 tendon SDRE as the chain's force law")
    ap.add_argument("--no-profile", action="store_true", help="skip where the time goes (isolated costs, call counts)")
    ap.add_argument("--physics", default="default",
                    help="comma list of the hand plant's physics: default (HandRigParams()), off (no ripple, "
                         "hysteresis, guide friction), on (all three), stick-slip (all three and the joints' "
                         "stick-slip friction, off by default)")
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    physics = [p.strip() for p in args.physics.split(",") if p.strip()]
    for p in physics:
        if p not in PHYSICS:
            ap.error(f"--physics: {p!r} is not one of {', '.join(PHYSICS)}")
    load = os.getloadavg()
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs")
    rows = []
    print(f"{'controller':14s} {'physics':>8s} {'rate Hz':>8s} {'estimator':>9s} {'build s':>8s} {'RTF cpu':>8s} "
          f"{'RTF wall':>9s} {'us/period':>10s}")
    for name, phys in [(n.strip(), p) for p in physics for n in args.controllers.split(",") if n.strip()]:
        try:
            r = run(name, args.sim_time, not args.no_profile, phys)
        except ValueError as exc:       # a controller that refuses this plant says why (e.g. guide friction)
            rows.append(dict(controller=name, physics=phys, rtf=None, note=str(exc)))
            print(f"{name:14s} {phys:>8s} refused: {exc}", flush=True)
            continue
        rows.append(r)
        print(f"{name:14s} {phys:>8s} {r['rate_hz']:8.0f} {str(r['estimator']):>9s} {r['build_s']:8.2f} "
              f"{r['rtf']:8.3f} {r['wall_rtf']:9.3f} {r['cpu_us_per_period']:10.0f}", flush=True)
        if "isolated_us_per_call" in r:
            print("    CPU time per call, measured apart:")
            for where, us in r["isolated_us_per_call"].items():
                print(f"    {us:9.1f} us  {where}")
            if r.get("stage_us_per_period"):
                print("    fused chain, CPU time per control period inside a 0.03 s run (stages nested):")
                for where, us in r["stage_us_per_period"].items():
                    print(f"    {us:9.1f} us  {where}")
            print("    calls per control period (Python callbacks):")
            for where, k in r["callbacks_per_period"].items():
                print(f"    {k:9.1f}     {where}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(dict(load_average=load, rows=rows), fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
