"""The whole hand closed through the thesis's control chain: real-time factor and where the time goes.

Usage::

    PYTHONPATH=. python benchmarks/bench_hand_control.py [--sim-time 0.05] [--controllers joint-pd,cascaded,backstepping]
                                                         [--json out.json] [--profile]

For each registered hand controller (``joint-pd``: today's 3 kHz motor PD; ``cascaded``: joint impedance ->
force distribution (7.6) -> tendon force PD (10.2) with friction/ripple feed-forward, joint angles from the
tendon-length estimator; ``backstepping``: 15.5 for the hand, 6 kHz law, 3 kHz estimator) the hand
(``hand_diagram()``, wrist input at 0, the thesis physics of the plant as it is configured by default) is
closed with ``closed_loop`` at the registered rate, every joint reference stepped by 0.05 rad, and simulated
with the default mode of ``analysis.simulate`` (fixed-step RK3 at the control period), after a warm-up
run of two control periods (JIT compilation of the drive kernels is not timed).  Real-time factor =
simulated time / wall time on one core.  ``--profile`` prints the functions that take the time (cProfile,
tottime), grouped by module.  The figures depend on the machine load.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import time
from collections import defaultdict

import numpy as np

from awiwi_drake.analysis import simulate
from awiwi_drake.control import closed_loop, get_entry, make_controller
from awiwi_drake.hand.diagrams import hand_diagram


def run(name: str, sim_time: float, profile: bool = False) -> dict:
    rig = hand_diagram()
    t0 = time.perf_counter()
    loop = closed_loop(rig, make_controller(name, rig), **get_entry(name, rig).loop_options)
    build = time.perf_counter() - t0
    op = rig.operating_point()
    inputs = {"joint_angle_reference": op.joint_angle + 0.05}
    # warm-up: the first simulation compiles the drive's kernels (numba) and fills caches
    simulate(loop, loop.create_context(op), 2.0 / loop.rate_hz, inputs=inputs, log=("joint_angle",))
    ctx = loop.create_context(op)
    prof = cProfile.Profile() if profile else None
    t0 = time.perf_counter()
    if prof:
        prof.enable()
    simulate(loop, ctx, sim_time, inputs=inputs, log=("joint_angle",))
    if prof:
        prof.disable()
    wall = time.perf_counter() - t0
    row = dict(controller=name, rate_hz=loop.rate_hz, estimator=bool(loop.estimated), build_s=build,
               sim_time=sim_time, wall_s=wall, rtf=sim_time / wall)
    if prof:
        by_module = defaultdict(float)
        for (file, _line, _fn), (_cc, _nc, tt, _ct, _callers) in pstats.Stats(prof).stats.items():
            key = file.split("awiwi_drake/")[-1] if "awiwi_drake/" in file else (
                "numpy" if "numpy" in file else "drake (C++ and bindings)" if file == "~" else file.rsplit("/", 1)[-1])
            by_module[key] += tt
        row["time_by_module"] = dict(sorted(by_module.items(), key=lambda kv: -kv[1])[:8])
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sim-time", type=float, default=0.05, help="simulated seconds per controller")
    ap.add_argument("--controllers", default="joint-pd,cascaded,backstepping")
    ap.add_argument("--profile", action="store_true", help="also print where the time goes")
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    rows = []
    print(f"{'controller':14s} {'rate Hz':>8s} {'estimator':>9s} {'build s':>8s} {'wall s':>8s} {'RTF':>8s}")
    for name in [n.strip() for n in args.controllers.split(",") if n.strip()]:
        r = run(name, args.sim_time, args.profile)
        rows.append(r)
        print(f"{name:14s} {r['rate_hz']:8.0f} {str(r['estimator']):>9s} {r['build_s']:8.2f} {r['wall_s']:8.2f} "
              f"{r['rtf']:8.4f}")
        for mod, tt in r.get("time_by_module", {}).items():
            print(f"    {tt:7.2f} s  {mod}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
