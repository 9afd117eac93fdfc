"""Every finger x every per-joint design: the designed closed-loop poles against Drake's linearisation of the finger.

Usage::

    PYTHONPATH=. python benchmarks/design_poles.py [--fingers thumb,index,middle,ring,fifth]
                                                   [--designs cascaded,pd,two-time-scale,pole-placement,lqr]
                                                   [--json out.json] [--poles]

For each finger (the design model's plant: motor friction linearised in motion, no hysteresis or guide friction, as
``tests/test_joint_design.py``) and each per-joint design (``control.joint_design``), ``check_design_poles`` linearises
the whole finger closed by the chain (continuous, sharing, true joint state) and :meth:`PoleCheck.matches` follows
each designed pole to the loop pole it becomes (one to one along ``D + s E``), certifies it where the neglected
coupling allows (``found``: a DoF the coupling does not reach, or an isolated Gershgorin disc), and names the coupling
that moves the others (the inertia matrix or the tendons).  One row per finger and design: the z restriction's
invariance residual, how far the loop's coupling is from the closed form (inertia + tendons), poles found / designed,
the largest move of a pole not found, and the DoF's ``(M^-1)_jj M_jj``.  On the ring and the fifth the z coordinates are
not invariant (the stiff PIP/DIP coupling element of (5.16) is a plant DoF of its own): nothing is certified there.  ``--poles`` prints every pole.  The table
in docs/REPRODUCTIONS.md ("every joint-level law per joint") is this script's output.
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fingers", default="thumb,index,middle,ring,fifth")
    ap.add_argument("--designs", default="cascaded,pd,two-time-scale,pole-placement,lqr")
    ap.add_argument("--json", default=None, help="write the rows to this file")
    ap.add_argument("--poles", action="store_true", help="print every designed pole and its match")
    a = ap.parse_args(argv)
    from awiwi_drake.control.joint_design import DESIGNS, check_design_poles, design_motor
    from awiwi_drake.hand.diagrams import finger_diagram
    from awiwi_drake.parameters.hand import FINGERS, FingerRigParams
    fingers, designs = a.fingers.split(","), a.designs.split(",")
    for f in fingers:
        if f not in FINGERS:
            print(f"design_poles: --fingers: unknown finger {f!r}; use {','.join(FINGERS)}", file=sys.stderr)
            return 2
    for d in designs:
        if d not in DESIGNS:
            print(f"design_poles: --designs: unknown design {d!r}; use {','.join(DESIGNS)}", file=sys.stderr)
            return 2
    rows = []
    print(f"| finger | design | invariance | coupling residual | found / designed | largest move not found "
          f"(cause) | (M^-1)_jj M_jj per DoF |\n|---|---|---|---|---|---|---|")
    for f in fingers:
        for d in designs:
            p = FingerRigParams.for_finger(f).with_physics(hysteresis=False, guide_friction=False)
            t0 = time.process_time()
            c = check_design_poles(finger_diagram(finger=f, params=p.replace(motor=design_motor(p.motor))), d)
            ms = c.matches()
            lost = [m for m in ms if not m.found]
            worst = max(lost, key=lambda m: m.move) if lost else None
            row = dict(finger=f, design=d, invariance=c.invariance_residual, coupling_residual=c.coupling_residual,
                       found=sum(m.found for m in ms), designed=len(ms), stable=c.stable,
                       largest_move=None if worst is None else worst.move,
                       cause=None if worst is None else f"{worst.dof} {worst.cause}",
                       inertia_ratio=dict(zip(c.dof_names, map(float, c.inertia_ratio))),
                       found_dofs=sorted({m.dof for m in ms if m.found}), cpu_s=time.process_time() - t0,
                       poles=[dict(dof=m.dof, design=str(m.design), loop=str(m.loop), found=m.found, radius=m.radius,
                                   cause=m.cause) for m in ms])
            rows.append(row)
            move = "-" if worst is None or c.invariance_residual > 1e-9 else f"{100 * worst.move:.0f} % ({row['cause']})"
            ratios = ", ".join(f"{k} {v:.2g}" for k, v in row["inertia_ratio"].items())
            found = (f"{row['found']} / {row['designed']} ({', '.join(row['found_dofs']) or 'none'})"
                     if c.invariance_residual <= 1e-9 else "not comparable: z not invariant")
            print(f"| {f} | {d} | {c.invariance_residual:.1e} | {c.coupling_residual:.1e} | {found} | {move} | "
                  f"{ratios} |", flush=True)
            if a.poles:
                print(c.table())
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
