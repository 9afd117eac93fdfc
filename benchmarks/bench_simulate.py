"""``simulate`` on a sampled loop: fixed step at the control period (the default) against error control.

Run: ``python benchmarks/bench_simulate.py [--seconds 1.2] [--repeats 3] [--json out/bench_simulate.json]``

The demo loop (joint rig, pretension ramp then a 0.3 rad link step under the 3 kHz
motor-position PD; ``awiwi-drake demo``) is run through
:func:`awiwi_drake.analysis.simulate` four ways, each logging ``joint_angle`` and
``tendon_force`` at every step:

* ``mode="auto"`` -- the default loop: the rig sampled at the control period (Drake's
  ``DiscreteTimeApproximation``, fixed-step RK3 at 1/3000 s inside one discrete update per period);
* ``mode="auto"`` on the continuous rig behind the hold (``sampled_rig=False``): fixed-step RK3 at
  the control period in the outer ``Simulator`` -- the same trajectory to round-off, slower;
* ``mode="error_controlled"`` at accuracy 1e-5 (the continuous rig; the default before the fixed step);
* ``mode="auto"`` with the rig's monitors (slack, saturation, over-range) -- their cost when nothing
  or something happens (the step saturates the motors briefly);
* a tight reference: error-controlled RK3 at accuracy 1e-10, max step 2e-5 s.

Accuracy is the largest ``|joint_angle - reference|`` [rad] over the whole run (ramp and step
transient), the reference interpolated at the run's log times. JSON keys (all floats):
``simulate_fixed_step_rtf``, ``simulate_error_controlled_rtf``, ``simulate_fixed_step_max_error_rad``,
``simulate_error_controlled_max_error_rad``, ``simulate_monitored_rtf``, ``simulate_monitor_overhead``
(wall time with monitors / without, fixed step), ``simulate_monitor_events`` (count),
``simulate_continuous_rig_rtf``, ``simulate_sampled_vs_continuous_rig_max_difference_rad``.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import statistics

import numpy as np

from awiwi_drake.analysis import rig_monitors, simulate
from awiwi_drake.control.motor_position import joint_rig_position_loop
from awiwi_drake.rigs import joint_rig
from awiwi_drake.parameters.rigs import DemoScenario


def _run(seconds: float, **kw):
    rig = joint_rig()
    scen = DemoScenario(t_final=seconds, ramp_time=min(0.5, seconds / 3), step_time=seconds / 2)
    loop = joint_rig_position_loop(rig, scen, sampled_rig=kw.pop("sampled_rig", True))
    ctx = loop.create_context(rig.operating_point(pretension=scen.f_start))
    monitors = rig_monitors(rig) if kw.pop("monitored", False) else ()
    return simulate(loop.diagram, ctx, seconds, log=("joint_angle", "tendon_force"), monitors=monitors, **kw)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    T = args.seconds

    ref = _run(T, mode="error_controlled", accuracy=1e-10, max_step=2e-5, sampled_rig=False)

    def timed(**kw):
        runs = [_run(T, **kw) for _ in range(args.repeats)]
        wall = statistics.median(r.info["wall_time"] for r in runs)
        res = runs[-1]
        err = float(np.max(np.abs(res["joint_angle"][:, 0] - np.interp(res.t, ref.t, ref["joint_angle"][:, 0]))))
        return T / wall, err, res, wall

    fixed_rtf, fixed_err, fixed, fixed_wall = timed()
    cont_rtf, cont_err, cont, _ = timed(sampled_rig=False)
    ec_rtf, ec_err, ec, _ = timed(mode="error_controlled", accuracy=1e-5, max_step=1 / 3000, sampled_rig=False)
    mon_rtf, mon_err, mon, mon_wall = timed(monitored=True)
    out = dict(simulate_fixed_step_rtf=fixed_rtf, simulate_error_controlled_rtf=ec_rtf,
               simulate_fixed_step_max_error_rad=fixed_err, simulate_error_controlled_max_error_rad=ec_err,
               simulate_monitored_rtf=mon_rtf, simulate_monitor_overhead=mon_wall / fixed_wall,
               simulate_monitor_events=float(len(mon.events)), simulate_continuous_rig_rtf=cont_rtf,
               simulate_sampled_vs_continuous_rig_max_difference_rad=float(
                   np.max(np.abs(fixed["joint_angle"] - cont["joint_angle"]))))
    print(f"joint rig + 3 kHz motor PD, demo scenario, {T:g} s simulated, median of {args.repeats}:")
    print(f"  fixed-step RK3 at 1/3000 s (default): {fixed_rtf:6.2f}x real time, max |dq| {fixed_err:.2e} rad "
          f"({fixed.info['mode']}, {fixed.info['steps']} steps)")
    print(f"  continuous rig, fixed-step RK3:       {cont_rtf:6.2f}x real time, max |dq| {cont_err:.2e} rad, "
          f"{out['simulate_sampled_vs_continuous_rig_max_difference_rad']:.1e} rad from the sampled rig")
    print(f"  error-controlled RK3, accuracy 1e-5:   {ec_rtf:6.2f}x real time, max |dq| {ec_err:.2e} rad "
          f"({ec.info['steps']} steps)")
    print(f"  fixed step + rig monitors:            {mon_rtf:6.2f}x real time (x{out['simulate_monitor_overhead']:.3f} "
          f"wall time), {len(mon.events)} events: " + "; ".join(str(e) for e in mon.events[:3]))
    if args.json:
        p = pathlib.Path(args.json)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(out, indent=1))
        print(f"wrote {p}")
    return out


if __name__ == "__main__":
    main()
