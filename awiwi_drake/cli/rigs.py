"""CLI commands of the foundation: demo, export-diagrams, linearize, lqr, params."""

from __future__ import annotations

import argparse
import json

import numpy as np

from awiwi_drake.cli import CliError, add_parameter_options, load_parameters, output_dir

__all__ = ["register"]


def _targets_help() -> str:
    from awiwi_drake.rigs import TARGETS

    return "\n".join(f"  {name}: {entry['description']}" for name, entry in TARGETS.items())


def _target_names() -> list[str]:
    from awiwi_drake.rigs import TARGETS

    return list(TARGETS)


def register(sub) -> None:
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("demo", help="simulate joint-rig (pretension ramp + position step), write plots and diagrams",
                       formatter_class=fmt)
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.add_argument("--backend", choices=["compiled", "python", "symbolic"], default="compiled",
                   help="tendon-drive backend: compiled (default: one system with a numba kernel generated from "
                        "the laws), python (separate TemplateSystems) or symbolic (one C++ SymbolicVectorSystem)")
    p.set_defaults(func=_demo)

    p = sub.add_parser("export-diagrams", help="write the rig diagram graphs (.dot, and .svg/.png with Graphviz)")
    p.add_argument("--out", default="diagrams", help="output folder (default diagrams/)")
    p.set_defaults(func=_export)

    epilog = "targets:\n" + _targets_help() + (
        "\n\nParameters: --config FILE.yaml, then --set NAME=VALUE (field names as listed by"
        "\n'awiwi-drake params RIG'; nested sets are searched, dotted paths like motor.inertia also work).")
    rig_help = "target rig: " + ", ".join(_target_names())
    p = sub.add_parser("linearize", help="print A, B and the poles at a rig's default operating point",
                       epilog=epilog, formatter_class=fmt)
    p.add_argument("rig", metavar="RIG", choices=_target_names(), help=rig_help)
    add_parameter_options(p)
    p.add_argument("--json", action="store_true", help="print one JSON object {A, B, poles, state_names}")
    p.set_defaults(func=_linearize)

    p = sub.add_parser("lqr", help="LQR gain and closed-loop poles at a rig's default operating point",
                       epilog=epilog + "\n\n--q gives the diagonal of Q in the rig's state order.", formatter_class=fmt)
    p.add_argument("rig", metavar="RIG", choices=_target_names(), help=rig_help)
    req = p.add_argument_group("required options")
    req.add_argument("--q", required=True, help="comma-separated diagonal of Q (state order)")
    req.add_argument("--r", required=True, help="comma-separated diagonal of R (one per motor)")
    add_parameter_options(p)
    p.add_argument("--json", action="store_true", help="print one JSON object {K, closed_loop_poles}")
    p.set_defaults(func=_lqr)

    p = sub.add_parser("params", help="list a rig's parameters with units, ranges and sources (or print them as YAML)",
                       epilog=epilog + "\n\n'params RIG --yaml > my.yaml' writes a file that --config reads back.",
                       formatter_class=fmt)
    p.add_argument("rig", metavar="RIG", choices=_target_names(), help=rig_help)
    add_parameter_options(p)
    p.add_argument("--yaml", action="store_true",
                   help="print the parameter set as YAML (Drake's yaml_dump_typed) instead of the table")
    p.set_defaults(func=_params)


def _floats(text: str, what: str) -> np.ndarray:
    try:
        vals = np.array([float(t) for t in text.split(",") if t.strip() != ""])
    except ValueError:
        raise CliError(f"{what}: cannot parse {text!r} as comma-separated numbers") from None
    if vals.size == 0 or not np.all(np.isfinite(vals)):
        raise CliError(f"{what}: expected finite comma-separated numbers, got {text!r}")
    return vals


def _params_of(args):
    from awiwi_drake.rigs import TARGETS

    return load_parameters(TARGETS[args.rig]["params"](), args)


def _build(args) -> object:
    from awiwi_drake.rigs import build_target

    return build_target(args.rig, params=_params_of(args))


def _linearize(args) -> int:
    from awiwi_drake.analysis import linearize, poles_table

    rig = _build(args)
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

    rig = _build(args)
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
    from awiwi_drake.parameters.yaml_io import to_yaml

    params = _params_of(args)
    print(to_yaml(params) if args.yaml else provenance_table(params), end="\n" if not args.yaml else "")
    return 0


def _export(args) -> int:
    from awiwi_drake.diagrams import export_all

    for line in export_all(output_dir(args.out)):
        print(line)
    return 0


def _demo(args) -> int:
    from awiwi_drake.rigs.demo_run import run_demo

    report = run_demo(output_dir(args.out), backend=args.backend)
    print(report)
    return 0
