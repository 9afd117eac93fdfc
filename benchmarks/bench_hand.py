"""Speed of the finger and hand models: real-time factor and Linearize time.

Usage::

    PYTHONPATH=. python benchmarks/bench_hand.py [--sim-time 0.2] [--repeat 3] [--json out.json]

For one finger (index) and the whole hand (wrist input at 0):

* open loop: motors held by their operating-point torques, error-controlled
  RK3 (accuracy 1e-4, max step 1 ms);
* closed loop: the 3 kHz joint-space PD (ZeroOrderHold) with a small step
  reference, (a) error-controlled RK3 (accuracy 1e-4) and (b) fixed-step RK3
  at the control period (one integrator step per controller sample);
* time of ``analysis.linearize`` (Drake ``Linearize``);
* time of the plant's ``integration_modes`` (the fixed-step stability check ``analysis.simulate`` runs at the
  start and at the end of every fixed-step run, and during it every ``FIXED_STEP_CHECK_INTERVAL`` simulated seconds),
  and its share of the fixed-step closed loop run through ``simulate``: (checks during the run) x (time of one
  check) / (the run's wall time).

Every run goes through ``analysis.simulate`` (nothing logged); real-time factor = its ``info["realtime_factor"]``,
simulated time / wall time of the integration (best of ``--repeat``).  The
figures depend on the machine load; run on an idle core for comparable numbers.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from awiwi_drake.analysis import simulate
from awiwi_drake.analysis.linear import linearize
from awiwi_drake.control import closed_loop, make_controller
from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram


def _run(system, context, t_final, *, fixed_step=None, accuracy=1e-4, max_step=1e-3):
    """One run through ``analysis.simulate`` (RK3, nothing logged): its result (``info``: ``realtime_factor``,
    ``steps``, ``wall_time``, ``stability_checks``)."""
    if fixed_step:
        return simulate(system, context, t_final, log=(), mode="fixed_step", step=fixed_step)
    return simulate(system, context, t_final, log=(), mode="error_controlled", accuracy=accuracy, max_step=max_step)


def _best(runs):
    """The fastest of ``runs`` (results): its real-time factor and integrator steps."""
    info = max((r.info for r in runs), key=lambda i: i["realtime_factor"])
    return info["realtime_factor"], info["steps"]


def _build(target):
    return hand_diagram(wrist=True) if target == "hand" else finger_diagram(finger=target)


def bench(target: str, sim_time: float, repeat: int) -> dict:
    out = dict(target=target)
    t0 = time.perf_counter()
    rig = _build(target)
    out["build_s"] = time.perf_counter() - t0
    lin_times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        linearize(rig)
        lin_times.append(time.perf_counter() - t0)
    out["linearize_s"] = min(lin_times)
    leaf = rig.diagram.GetSubsystemByName("hand_dynamics")
    leaf_ctx = leaf.GetMyContextFromRoot(rig.context())
    leaf.integration_modes(leaf_ctx)                 # the kernels' first compile is not the check's cost
    mode_times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        leaf.integration_modes(leaf_ctx)
        mode_times.append(time.perf_counter() - t0)
    out["modes_s"] = min(mode_times)
    out["open_loop_rtf"], out["open_loop_steps"] = _best([_run(rig, rig.context(), sim_time) for _ in range(repeat)])
    n = rig.num_joints
    q_ref = np.zeros(n)
    q_ref[1 if target != "hand" else 5] = 0.2
    for mode, kw in (("closed_loop_rtf", {}), ("closed_loop_fixed_step_rtf", {"fixed_step": 1.0 / 3000})):
        runs = []
        for _ in range(repeat):
            r = _build(target)
            cl = closed_loop(r, make_controller("joint-pd", r))
            ctx = cl.create_context(r.operating_point(), references={"joint_angle_reference": q_ref})
            runs.append(_run(cl, ctx, sim_time, **kw))
        out[mode], out[mode.replace("rtf", "steps")] = _best(runs)
    info = runs[-1].info          # the fixed-step closed loop: the stability checks' share of its wall time
    out["check_share"] = (len(info["stability_checks"]) - 1) * out["modes_s"] / info["wall_time"]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sim-time", type=float, default=0.2, help="simulated seconds per run")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--targets", default="index,hand")
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    rows = []
    print(f"{'target':8s} {'build s':>8s} {'lin s':>7s} {'modes s':>8s} {'open RTF':>9s} "
          f"{'ctrl RTF':>9s} {'ctrl fixed RTF':>15s} {'check share':>12s}")
    for target in args.targets.split(","):
        r = bench(target, args.sim_time, args.repeat)
        rows.append(r)
        print(f"{target:8s} {r['build_s']:8.2f} {r['linearize_s']:7.3f} {r['modes_s']:8.4f} "
              f"{r['open_loop_rtf']:9.3f} {r['closed_loop_rtf']:9.3f} {r['closed_loop_fixed_step_rtf']:15.3f} "
              f"{r['check_share']:12.2%}",
              flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
