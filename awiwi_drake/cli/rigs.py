"""CLI commands of the foundation: demo, export-diagrams, linearize, lqr, params."""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

from awiwi_drake.cli import CliError, parse_sets

__all__ = ["register"]


def _targets_help() -> str:
    from awiwi_drake.diagrams import TARGETS

    return "\n".join(f"  {name}: {entry['description']}" for name, entry in TARGETS.items())


def register(sub) -> None:
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("demo", help="simulate joint_rig (pretension ramp + position step), write plots and diagrams",
                       formatter_class=fmt)
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.add_argument("--backend", choices=["python", "symbolic"], default="symbolic")
    p.set_defaults(func=_demo)

    p = sub.add_parser("export-diagrams", help="write the rig diagram graphs (.dot, and .svg/.png with Graphviz)")
    p.add_argument("--out", default="diagrams", help="output folder (default diagrams/)")
    p.set_defaults(func=_export)

    epilog = "targets:\n" + _targets_help() + (
        "\n\n--set NAME=VALUE overrides any parameter by its dataclass field name (nested sets are searched,"
        "\ndotted paths like motor.inertia also work). Run 'awiwi-drake params RIG' to list the names.")
    p = sub.add_parser("linearize", help="print A, B and the poles at a rig's default operating point",
                       epilog=epilog, formatter_class=fmt)
    p.add_argument("rig", metavar="RIG")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    p.add_argument("--json", action="store_true", help="print one JSON object {A, B, poles, state_names}")
    p.set_defaults(func=_linearize)

    p = sub.add_parser("lqr", help="LQR gain and closed-loop poles at a rig's default operating point",
                       epilog=epilog + "\n\n--q gives the diagonal of Q in the rig's state order.", formatter_class=fmt)
    p.add_argument("rig", metavar="RIG")
    p.add_argument("--q", required=True, help="comma-separated diagonal of Q (state order)")
    p.add_argument("--r", required=True, help="comma-separated diagonal of R (one per motor)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    p.add_argument("--json", action="store_true", help="print one JSON object {K, closed_loop_poles}")
    p.set_defaults(func=_lqr)

    p = sub.add_parser("params", help="list a rig's parameters with units, ranges and sources", epilog=epilog,
                       formatter_class=fmt)
    p.add_argument("rig", metavar="RIG")
    p.set_defaults(func=_params)


def _floats(text: str, what: str) -> np.ndarray:
    try:
        vals = np.array([float(t) for t in text.split(",") if t.strip() != ""])
    except ValueError:
        raise CliError(f"{what}: cannot parse {text!r} as comma-separated numbers") from None
    if vals.size == 0 or not np.all(np.isfinite(vals)):
        raise CliError(f"{what}: expected finite comma-separated numbers, got {text!r}")
    return vals


def _build(name: str, sets) -> object:
    from awiwi_drake.diagrams import build_target

    return build_target(name, parse_sets(sets))


def _linearize(args) -> int:
    from awiwi_drake.analysis import linearize, poles_table

    rig = _build(args.rig, args.set)
    res = linearize(rig)
    if args.json:
        print(json.dumps(res.to_json()))
        return 0
    np.set_printoptions(precision=6, suppress=False, linewidth=140)
    print(f"{rig.name}: state = [{', '.join(rig.state_names)}], input = motor_torque")
    print("A =\n" + str(res.A))
    print("B =\n" + str(res.B))
    print("poles:\n" + poles_table(res))
    return 0


def _lqr(args) -> int:
    from awiwi_drake.analysis import lqr

    rig = _build(args.rig, args.set)
    q = _floats(args.q, "--q")
    r = _floats(args.r, "--r")
    if q.size != rig.num_states:
        raise CliError(f"--q has {q.size} entries; {args.rig} has {rig.num_states} states "
                       f"({', '.join(rig.state_names)})")
    m = rig.diagram.GetInputPort("motor_torque").size()
    if r.size != m:
        raise CliError(f"--r has {r.size} entries; {args.rig} has {m} motor input(s)")
    res = lqr(rig, np.diag(q), np.diag(r))
    if args.json:
        print(json.dumps(res.to_json()))
        return 0
    np.set_printoptions(precision=6, linewidth=140)
    print(f"{rig.name}: state = [{', '.join(rig.state_names)}]")
    print("K =\n" + str(res.K))
    print("closed-loop poles:\n" + "\n".join(f"  {p.real: .6g} {'+' if p.imag >= 0 else '-'} {abs(p.imag):.6g}j"
                                             for p in res.closed_loop_poles))
    return 0


def _params(args) -> int:
    from awiwi_drake.parameters import provenance_table
    from awiwi_drake.diagrams import TARGETS

    if args.rig not in TARGETS:
        raise CliError(f"unknown rig {args.rig!r}; choose one of {', '.join(sorted(TARGETS))}")
    print(provenance_table(TARGETS[args.rig]["params"]()))
    return 0


def _export(args) -> int:
    from awiwi_drake.diagrams import export_all

    for line in export_all(args.out):
        print(line)
    return 0


def _demo(args) -> int:
    from awiwi_drake.export import export_diagram
    from awiwi_drake.reproductions.demo import run_demo

    report, graphs = run_demo(pathlib.Path(args.out), backend=args.backend)
    for stem, diagram in graphs.items():
        export_diagram(diagram, args.out, stem, max_depth=1, quiet=True)
    print(report)
    return 0
